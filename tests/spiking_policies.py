"""Policies for the energy, deploy, quantize and NIR tests: random actors that really spike, and a
hand-made actor whose spikes are known exactly. No training."""

from __future__ import annotations

import numpy as np
import torch

from ilcsan.actors import build_actor
from ilcsan.config import INTRA_MASKS, actor_config
from ilcsan.deploy import DeployedActor
from ilcsan.deploy.bundle import bundle_arrays, bundle_meta
from ilcsan.deploy.policy import Policy


def random_policy(preset: str = "ilc-san", state_dim: int = 11, action_dim: int = 3, seed: int = 0,
                  gain: float = 3.0, bias_shift: float = 0.3, **overrides) -> Policy:
    """A randomly initialised actor with weights scaled by ``gain`` and biases shifted so that plenty of
    neurons spike (a fresh actor is nearly silent), and a non-trivial frozen normaliser."""
    config = actor_config(preset, **overrides)
    rng = np.random.default_rng(seed)
    scale = rng.uniform(0.5, 2.0, action_dim)
    offset = rng.uniform(-0.5, 0.5, action_dim)
    actor = build_actor(config, state_dim, action_dim, scale, offset, seeds=(seed,))
    with torch.no_grad():
        for name, parameter in actor.named_parameters():
            if name.startswith("layers.") and name.endswith("weight"):
                parameter.mul_(gain)
            elif name.startswith("layers.") and name.endswith("bias"):
                parameter.add_(bias_shift)
            elif name.startswith("intra."):
                parameter.mul_(2.0)
            elif name.startswith("decoder."):
                parameter.mul_(0.5)
    actor.eval()
    return Policy(actor, config, "Hopper", rng.normal(0.0, 0.5, state_dim), rng.uniform(0.5, 2.0, state_dim), 3.0,
                  scale, offset, {})


FULLY_SPIKING = [
    ("ilc-san", {}),
    *[("ilc-san", {"intra": variant}) for variant in INTRA_MASKS if variant != "intra"],
    *[("ilc-san", {"decoder": decoder, "alpha_v_li": alpha}) for decoder in ("last", "max", "mean")
      for alpha in (1.0, 0.75, 0.5) if (decoder, alpha) != ("last", 1.0)],
    ("ilc-san", {"hidden": (64,)}),
    ("ilc-san", {"hidden": (64, 48, 40)}),
    ("ilc-san", {"hidden": (40, 40, 40, 40)}),
    ("ilc-san", {"neuron": "dynamic"}),
    ("ilc-san", {"neuron": "dynamic", "intra": "self+bias", "decoder": "max", "alpha_v_li": 0.75}),
    ("ilc-san", {"population_in": 5, "population_out": 7, "timesteps": 8}),
    ("ilc-san", {"timesteps": 2}),
    ("popsan", {"decoder": "last"}),  # PopSAN's backbone with the membrane-voltage decoder
    ("ilc-san", {"intra_timing": "authors"}),  # b_intra from t = 1, as the authors' code
    ("ilc-san", {"intra_timing": "authors", "intra": "self+bias", "timesteps": 2}),
    ("ilc-san", {"intra_timing": "authors", "intra": "self"}),  # no bias: the same actor as the paper's timing
]
"""Every fully spiking actor the deploy paths take: (preset, switches)."""


def deployed(policy: Policy) -> DeployedActor:
    """The policy's deploy bundle, loaded by the numpy runtime without a file."""
    return DeployedActor.from_arrays(bundle_arrays(policy), bundle_meta(policy))


def case_id(case) -> str:
    preset, overrides = case
    return preset + "".join(f"-{key}={value}" for key, value in overrides.items())


def observations(policy: Policy, count: int = 16, seed: int = 1) -> np.ndarray:
    """Raw observations around the normaliser's mean, some beyond the clip."""
    rng = np.random.default_rng(seed)
    return policy.obs_mean + policy.obs_std * rng.normal(0.0, 1.5, (count, policy.state_dim))


HAND_STATE_DIM = 3  # Pendulum-v1
HAND_RATES = {"FC1": 0.5, "FC2": 0.9, "Group FC": 0.9, "Intra FC": 0.7}
HAND_SOP = {"FC1": 30, "FC2": 18, "Group FC": 9, "Intra FC": 14}


def hand_made_policy() -> Policy:
    """An ILC-SAN for Pendulum (N = 3, M = 1) with P_in = P_out = 2, one hidden layer of 2, whose spikes are
    known for every observation:

    * encoder: neuron 0 of each state dimension has σ = 1e6 (A = 1 > 0.999: spikes at all 5 steps),
      neuron 1 has μ = 100, σ = 0.1 (A = 0: never) → FC1 input rate 3·5/(6·5) = 0.5;
    * hidden h0 ← 1.0 · enc0: C = 1, 1.5, … spikes at t = 1..5; h1 ← 0.3 · enc0: C = 0.3, 0.45, 0.525,
      0.5625, 0.58125, H = 0.3, 0.675, 0.525, 0.5625, 0.58125 → spikes at t = 2..5 → FC2 rate 9/10;
    * output o0 ← 1.0 · h0 (t = 1..5), o1 ← 0.3 · h0 (t = 2..5); intra weights and bias 0 → Group FC
      rate 9/10; Intra FC: spikes of t = 1..4 (4 + 3) / (T·P_out = 10) = 0.7 (the authors' convention).

    SOP per inference: FC1 15 spikes × 2 = 30, FC2 9 × 2 = 18, Group FC 9 × 1 = 9, Intra FC 7 × 2 = 14.
    """
    config = actor_config("ilc-san", hidden=(2,), population_in=2, population_out=2)
    actor = build_actor(config, HAND_STATE_DIM, 1, [2.0], seeds=(0,))
    with torch.no_grad():
        actor.encoder.mu.copy_(torch.tensor([[[0.0, 100.0]] * HAND_STATE_DIM]))
        actor.encoder.sigma.copy_(torch.tensor([[[1e6, 0.1]] * HAND_STATE_DIM]))
        first, output = actor.layers
        first.weight.zero_()
        first.weight[0, 0, 0], first.weight[0, 1, 0] = 1.0, 0.3
        first.bias.zero_()
        output.weight.zero_()
        output.weight[0, 0, 0], output.weight[0, 1, 0] = 1.0, 0.3
        output.bias.zero_()
        actor.intra.weight.zero_()
        actor.intra.bias.zero_()
    actor.eval()
    zeros, ones = np.zeros(HAND_STATE_DIM), np.ones(HAND_STATE_DIM)
    return Policy(actor, config, "Pendulum-v1", zeros, ones, 3.0, np.array([2.0]), np.array([0.0]), {})
