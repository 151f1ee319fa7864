"""NoisySAN (Chen, Peng, Huang, Tian, arXiv 2403.04162) as declared: coloured noise inside the spiking neurons
explores in place of noise on the action. Training: :mod:`ilcsan.rl.methods.noisysan` (its series:
:mod:`ilcsan.rl.methods.coloured_noise`); where the noise enters the neurons: :mod:`ilcsan.snn.noise`."""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import UserError
from ..settings import setting
from .declaration import Declared

RETURN_REFERENCE: dict[str, float] = {
    "Ant": 6000.0, "HalfCheetah": 12000.0, "Hopper": 4000.0, "Walker2d": 6000.0, "Humanoid": 6000.0,
    "HumanoidStandup": 180000.0, "InvertedDoublePendulum": 10000.0, "BipedalWalker": 320.0,
}
"""NoisySAN's per-task return R* (``SUP_R`` in the authors' TD3 script in SpikingJelly's ``noisy_san`` example):
the weight of the noise penalty is k = max(0, R)/R*, R the latest evaluation's mean return."""


def return_reference(task: str, training) -> float:
    """R* of the penalty weight: ``--noisy-return-reference`` if given, else NoisySAN's value for a paper task."""
    if training.noisy_return_reference is not None:
        return float(training.noisy_return_reference)
    known = {name.lower(): value for name, value in RETURN_REFERENCE.items()}
    if task.lower() in known:
        return known[task.lower()]
    raise UserError(f"--exploration noisy on {task} needs --noisy-return-reference R (the return at which the noise "
                    f"penalty reaches full weight; NoisySAN's values: Hopper 4000, Ant 6000, HalfCheetah 12000)")


class NoisySANDeclaration(Declared):
    kind, name, title = "exploration", "noisy", "NoisySAN"
    paper = ("NoisySAN: coloured noise in every spiking layer's charge and spike transmission and in the decoder, "
             "with a learned decoder noise scale (Chen et al., arXiv 2403.04162)")
    option_help = "NoisySAN's coloured noise inside the spiking neurons (Chen et al. 2024; spiking actors only)"
    step_cost = 2.0
    """A training step with NoisySAN takes about this many plain steps' time (its noise is drawn and scaled per
    step)."""
    spiking_only = True
    spiking_reason = "it puts noise into spiking neurons, and DAN has none"
    training = "ilcsan.rl.methods.noisysan:NoisySAN"

    @dataclass(frozen=True)
    class Settings:
        noisy_sigma: float = setting(0.5, "NoisySAN: sigma_init; a layer of D neurons gets the fixed noise scale "
                                          "sigma_init/sqrt(D) on charge and transmission, the decoder's learned "
                                          "scale starts at sigma_init/sqrt(M)", bounds="positive")
        noisy_beta: float = setting(1.0, "NoisySAN: spectral exponent of the noise, power ~ 1/f^beta (0 white, 1 "
                                         "pink: the paper's choice, 2 brown)", bounds="non-negative")
        noisy_return_reference: float | None = setting(
            None, "NoisySAN: the return R* at which the noise penalty's weight max(0, R)/R* reaches 1 (default per "
                  "paper task: Hopper 4000, Walker2d/Ant/Humanoid 6000, HalfCheetah 12000, ...; needed for other "
                  "tasks)", bounds="positive")

    @classmethod
    def check(cls, task: str, training) -> None:
        return_reference(task, training)
