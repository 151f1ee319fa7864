"""A trained actor as a deployable policy: ``ilcsan.load(path).predict(obs)``.

``load`` accepts a run directory (its ``policy.pt``, the actor of the best evaluation), a ``policy.pt``
file, or a ``checkpoint.pt`` (the actor of the last evaluation). ``predict`` maps a numpy observation,
one (N,) or a batch (B, N), to the deterministic action with the frozen normaliser, the same call a
robot program makes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..actors import build_actor
from ..compute.programs import CompiledPerShape
from ..config import RECORDED_BEFORE_CONTACT_FORCES, ActorConfig
from ..errors import UserError
from ..files import safe_torch_load
from ..methods import DEFAULT_ALGORITHM
from ..rl.algorithms import algorithm_class
from ..rl.normalizer import RunningNormalizer
from ..rl.tasks import action_bounds, make_env
from ..runs.checkpoint import CHECKPOINT_FORMAT, POLICY_FORMAT, first_readout, missing_state, module_state
from ..runs.directory import CHECKPOINT, POLICY, RunDirectory
from ..runtime.host import HostSide


def resolve_policy_file(path: str | Path) -> Path:
    """A run directory → its policy.pt; a file → itself. Clear errors for everything else."""
    path = Path(path)
    if path.is_dir():
        run = RunDirectory(path)
        if run.file(POLICY).is_file():
            return run.file(POLICY)
        seeds = sorted(p.name for p in path.glob("seed*") if RunDirectory(p).file(POLICY).is_file())
        if seeds:
            raise UserError(f"{path} holds several seeds ({', '.join(seeds)}); pass one of them, "
                            f"e.g. {path / seeds[0]}")
        if run.file(CHECKPOINT).is_file():
            return run.file(CHECKPOINT)
        raise UserError(f"{path} has no policy.pt yet: the run has not finished its first evaluation")
    if not path.exists():
        raise UserError(f"{path} does not exist; pass a run directory, a policy.pt or a checkpoint.pt")
    if path.suffix in EXPORT_SUFFIXES:
        raise UserError(f"{path} is {EXPORT_SUFFIXES[path.suffix]}, not a trained policy: pass the run directory, "
                        "policy.pt or checkpoint.pt it was exported from")
    return path


EXPORT_SUFFIXES = {".npz": "a deploy bundle (`ilcsan evaluate` and `ilcsan lava` also take one)",
                   ".nir": "a NIR graph (run it in a NIR consumer: docs/nir-consumers.md)"}
"""What ``ilcsan export`` writes, named in the error when one is passed where a policy is needed."""


@dataclass
class Policy(HostSide):
    """A trained actor with its frozen observation normaliser; ``predict`` is the deployed call.

    ``predict`` runs the actor eagerly; after :meth:`compile` it runs one compiled program per batch size, as the
    training loop acts: many times faster per call once compiled (``benchmarks/deploy_latency.py`` measures both),
    the first call of each batch size compiling for a while; the same actions to float rounding.
    """

    actor: torch.nn.Module
    actor_config: ActorConfig
    task: str
    obs_mean: np.ndarray
    obs_std: np.ndarray
    obs_clip: float
    action_scale: np.ndarray
    action_offset: np.ndarray
    info: dict[str, Any]
    forward: Callable[[torch.Tensor], torch.Tensor] | None = None
    """What ``predict`` calls: the actor itself, or after :meth:`compile` its compiled programs."""
    contact_forces: str = RECORDED_BEFORE_CONTACT_FORCES
    """How its task's contact forces read in training (:data:`~ilcsan.config.CONTACT_FORCES`)."""

    def __post_init__(self) -> None:
        if self.forward is None:
            self.forward = self.actor

    def compile(self) -> Policy:
        """Run ``predict`` through compiled programs (:class:`~ilcsan.compute.programs.CompiledPerShape`);
        returns the policy."""
        if self.forward is self.actor:
            self.forward = CompiledPerShape(self.actor)
        return self

    @property
    def compiled(self) -> bool:
        return self.forward is not self.actor

    @property
    def expects(self) -> str:
        return f"{self.task} policy"

    @property
    def label(self) -> str:
        """What the policy holds, for messages: its actor preset."""
        return str(self.actor_config.preset)

    def check_observation(self, observation: Any) -> tuple[np.ndarray, bool]:
        """:meth:`HostSide.check_observation`, also for a torch tensor (on any device, with or without grad)."""
        if torch.is_tensor(observation):
            observation = observation.detach().cpu().numpy()
        return super().check_observation(observation)

    @torch.no_grad()
    def predict(self, observation: Any) -> np.ndarray:
        """Deterministic action(s) for one observation (N,) → (M,) or a batch (B, N) → (B, M)."""
        batch, single = self.check_observation(observation)
        state = torch.as_tensor(self.normalize(batch)).unsqueeze(0)
        action = self.forward(state)[0].numpy()
        return action[0] if single else action

    @torch.no_grad()
    def run(self, observation: Any, engine: str | None = None):
        """The full forward pass (spikes of every layer, LI voltages) for analysis."""
        batch, _ = self.check_observation(observation)
        return self.actor.run(torch.as_tensor(self.normalize(batch)).unsqueeze(0), engine)


def _state_to_policy(data: dict[str, Any], actor_state: dict[str, torch.Tensor], path: Path,
                     readouts: int = 1) -> Policy:
    """The policy ``data`` describes, its actor's parameters and persistent buffers from ``actor_state``
    (:func:`~ilcsan.runs.checkpoint.slice_state` of one seed), each checked before anything is allocated;
    ``readouts`` per action dimension of those tensors (a SAC checkpoint's actor has 2, of which the first acts)."""
    config = ActorConfig.from_dict(data["actor_config"])
    state_dim, action_dim = int(data["state_dim"]), int(data["action_dim"])
    scale = np.asarray(data["action_scale"], dtype=np.float64)
    offset = np.asarray(data["action_offset"], dtype=np.float64)
    obs_mean, obs_std = np.asarray(data["obs_mean"], np.float64), np.asarray(data["obs_std"], np.float64)
    obs_clip = float(data["obs_clip"])
    consistent = (state_dim >= 1 and action_dim >= 1 and obs_mean.shape == obs_std.shape == (state_dim,)
                  and scale.shape == offset.shape == (action_dim,) and np.all(obs_std > 0) and obs_clip > 0
                  and all(np.all(np.isfinite(a)) for a in (scale, offset, obs_mean, obs_std, obs_clip)))
    if not consistent:
        raise UserError(f"{path}: its sizes or normaliser statistics are inconsistent or not finite; the file is "
                        "corrupt")
    # check every tensor against the configuration before allocating anything: an untrusted file must not
    # make us build a huge network
    with torch.device("meta"):
        skeleton = build_actor(config, state_dim, action_dim, scale, offset, seeds=(0,))
    if readouts > 1 and isinstance(actor_state, dict):  # a SAC checkpoint's actor: its mean's populations
        actor_state = first_readout({name: value for name, value in actor_state.items() if torch.is_tensor(value)},
                                    skeleton)
    for name, expected in module_state(skeleton).items():
        value = actor_state.get(name) if isinstance(actor_state, dict) else None
        if not torch.is_tensor(value):
            raise UserError(f"{path} has {missing_state(skeleton, name)}")
        if tuple(value.shape) != tuple(expected.shape):
            raise UserError(f"{path}: {name!r} has shape {tuple(value.shape)}, the actor needs "
                            f"{tuple(expected.shape)}; the file is corrupt or mismatched")
        if not torch.all(torch.isfinite(value)):
            raise UserError(f"{path}: {name!r} contains NaN or inf; the file is corrupt or its run diverged")
    actor = build_actor(config, state_dim, action_dim, scale, offset, seeds=(0,))
    with torch.no_grad():
        for name, tensor in module_state(actor).items():
            tensor.copy_(actor_state[name])
    actor.eval()
    return Policy(actor, config, data["task"], obs_mean, obs_std, obs_clip, scale, offset,
                  {key: data.get(key) for key in ("step", "seed", "eval_return_mean")},
                  contact_forces=data.get("contact_forces") or RECORDED_BEFORE_CONTACT_FORCES)


def _checkpoint_as_policy(data: dict[str, Any]) -> dict[str, Any]:
    """The policy fields of a training checkpoint: its actor with the normaliser frozen where it stands.

    Checkpoints hold the action bounds; for older ones without them the task's environment is built once
    to read them."""
    config = data["config"]
    normalizer = RunningNormalizer(1, len(data["normalizer"]["mean"]))
    normalizer.load(0, data["normalizer"])
    contact_forces = config.get("contact_forces") or RECORDED_BEFORE_CONTACT_FORCES
    if "action_scale" in data and "action_offset" in data:
        scale, offset = data["action_scale"], data["action_offset"]
    else:
        env = make_env(config["task"], contact_forces=contact_forces)
        scale, offset = action_bounds(env)
        env.close()
    return {"actor_config": config["actor"], "state_dim": data["state_dim"], "action_dim": data["action_dim"],
            "action_scale": scale, "action_offset": offset, "obs_mean": normalizer.mean[0],
            "obs_std": normalizer.std[0], "obs_clip": normalizer.clip, "task": config["task"],
            "contact_forces": contact_forces,
            "step": data["step"], "seed": config.get("seed")}


def load(path: str | Path, compile: bool = False) -> Policy:
    """Load a trained actor from a run directory, a policy.pt or a checkpoint.pt; ``compile``: see
    :meth:`Policy.compile`."""
    policy = _load(path)
    return policy.compile() if compile else policy


def _load(path: str | Path) -> Policy:
    file = resolve_policy_file(path)
    data = safe_torch_load(file, "policy")
    try:
        if data["format"] == POLICY_FORMAT:
            return _state_to_policy(data, data["actor"], file)
        if data["format"] == CHECKPOINT_FORMAT:
            readouts = algorithm_class(data["config"].get("algorithm") or DEFAULT_ALGORITHM).readouts
            return _state_to_policy(_checkpoint_as_policy(data), data["actor"], file, readouts)
    except UserError:
        raise
    except (KeyError, TypeError, AttributeError, ValueError, IndexError, RuntimeError) as error:
        raise UserError(f"{file} is incomplete or corrupt ({type(error).__name__}: {str(error)[:120]}); it is "
                        "damaged or from another version of ilcsan") from None
    raise UserError(f"{file} has format {data['format']!r}; expected an ilcsan policy or checkpoint")
