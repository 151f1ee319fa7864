"""Signs that a spiking actor is stuck: the collapsed start of Hopper and its kind.

The decoder's output is O = V_T = Σ_t (W_D S_t + b_D) (Eq. (7)-(8a), α_V^LI = 1) and the action a = tanh(O).
Once |O| is large, tanh'(O) ≈ 0 and the critic's gradient barely reaches the actor; once the output spikes no
longer depend on the state, the actor computes a constant and the surrogate gradient (|H_t − V_th| < w, Section
III-D) is the only way back. Five numbers per seed, measured at every evaluation (the columns
:data:`ilcsan.runs.directory.DIAGNOSTICS` of ``metrics.csv``):

``saturated_actions``      share of action components with |a − offset| > 0.99 · scale (|tanh(O)| > 0.99) over the
                           evaluation's states;
``action_spread``          the largest range (max − min) of an action component over the evaluation's states, in
                           units of its full range 2 · scale: 0 when the seed acts with one constant action;
``frozen_output_neurons``  share of the M·P_out output neurons whose spike train S_1..S_T is the same for every
                           state of a replay batch;
``surrogate_active``       share of output-neuron steps with |H_t − V_th| < w over that batch: where the surrogate
                           gradient can flow at all;
``mean_abs_preaction``     mean |O| over that batch and the M action dimensions.

A seed acts with a *constant saturated action* (:func:`constant_saturated_action`) when nearly every evaluation
action is saturated and no action component moves by more than a hundredth of its range: the same corner of the
action box for every state (a few output neurons may still respond to the state without moving a saturated action).
It is *stuck* (:func:`is_stuck`) when, at its last evaluations, it acted with one constant action that almost no
gradient can move (:func:`stuck_reason`): saturated (tanh is flat there), or decoded from output neurons that fire the
same spike trains for every state (the surrogate gradient then sees no state; PopSAN's firing-rate decoder on Hopper
does this without saturating every component).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import torch

from .output import ActorOutput

DIAGNOSTIC_STATES = 1000
"""Replayed states per seed on which each evaluation measures the replay-batch diagnostics."""
SATURATION = 0.99
"""An action component is saturated when |tanh(O)| exceeds this."""
CONSTANT_SATURATED_SHARE = 0.99
"""The share of saturated evaluation actions from which, with an action spread below :data:`CONSTANT_SPREAD`, a
seed's action is a constant corner of the action box."""
CONSTANT_SPREAD = 0.01
"""An action spread below this (a hundredth of each component's range) is one constant action."""


def saturated_share(actions: np.ndarray, scale: np.ndarray, offset: np.ndarray) -> float:
    """Share of the components of ``actions`` (..., M) with |a − offset| > :data:`SATURATION` · scale."""
    actions = np.asarray(actions, dtype=np.float64)
    if actions.size == 0:
        return float("nan")
    return float(np.mean(np.abs(actions - offset) > SATURATION * np.asarray(scale)))


class EvaluationActions:
    """What each seed's actions over an evaluation's running episodes say: the share of saturated components
    (:func:`saturated_share`) and the action spread (each component's max − min over 2 · scale, the largest)."""

    def __init__(self, seeds: int, scale: np.ndarray, offset: np.ndarray):
        self.scale, self.offset = np.asarray(scale), np.asarray(offset)
        self.saturated, self.total = np.zeros(seeds), np.zeros(seeds)
        self.low = np.full((seeds, len(self.scale)), np.inf)
        self.high = np.full((seeds, len(self.scale)), -np.inf)

    def observe(self, actions: np.ndarray, running: np.ndarray) -> None:
        """The actions (K, E, M) of one step, ``running`` (K, E) the episodes whose actions were taken."""
        saturated = np.abs(actions - self.offset) > SATURATION * self.scale  # (K, E, M)
        self.saturated += (saturated * running[..., None]).sum(axis=(1, 2))
        self.total += running.sum(axis=1) * actions.shape[-1]
        taken = running[..., None]
        self.low = np.minimum(self.low, np.where(taken, actions, np.inf).min(axis=1))
        self.high = np.maximum(self.high, np.where(taken, actions, -np.inf).max(axis=1))

    def rows(self) -> list[dict[str, float]]:
        """Each seed's ``saturated_actions`` and ``action_spread`` (NaN without a single action)."""
        spread = np.where(np.isfinite(self.high - self.low), (self.high - self.low) / (2 * self.scale), np.nan)
        return [{"saturated_actions": float(s / t) if t else float("nan"),
                 "action_spread": float(np.max(row)) if t else float("nan")}
                for s, t, row in zip(self.saturated, self.total, spread, strict=True)]


def output_diagnostics(output: ActorOutput, threshold: float, surrogate_width: float) -> dict[str, np.ndarray]:
    """``frozen_output_neurons``, ``surrogate_active`` and ``mean_abs_preaction`` of each of the K seeds, (K,) each,
    from one forward pass over a batch of states run with ``membranes=True``; a deep actor (no spikes) gets only
    ``mean_abs_preaction``."""
    result = {"mean_abs_preaction": output.readout.abs().mean(dim=(1, 2)).double().cpu().numpy()}
    if output.output_spikes is None:
        return result
    spikes = output.output_spikes  # (K, T, B, M·P)
    frozen = (spikes == spikes[:, :, :1]).all(dim=2).all(dim=1)  # (K, M·P): the same train for every state
    active = ((output.membranes - threshold).abs() < surrogate_width).double()
    result["frozen_output_neurons"] = frozen.double().mean(dim=1).cpu().numpy()
    result["surrogate_active"] = active.mean(dim=(1, 2, 3)).cpu().numpy()
    return result


@torch.no_grad()
def diagnose_actor(actor, states: torch.Tensor) -> list[dict[str, float]]:
    """The replay-batch diagnostics of each seed for normalised ``states`` (K, B, N), without touching the global
    random stream (a Bernoulli encoder draws from it)."""
    with torch.random.fork_rng(devices=[]):
        output = actor.run(states, membranes=True)
    neuron = getattr(actor, "neuron", None)
    params = neuron.params if neuron is not None else None
    values = output_diagnostics(output, params.threshold if params else 0.0, params.surrogate_width if params else 0.0)
    return [{name: float(array[index]) for name, array in values.items()} for index in range(states.shape[0])]


STUCK_EVALUATIONS = 3
"""Evaluations in a row after the random phase with one stuck action (:func:`stuck_reason`) before a seed counts as
stuck."""
CONSTANT_FROZEN_SHARE = 0.99
"""The share of frozen output neurons from which, with an action spread below :data:`CONSTANT_SPREAD`, a seed's
constant action comes from spike trains that do not depend on the state."""


def is_stuck(rows: Sequence[Mapping[str, float]], start_steps: int) -> bool:
    """Whether the last :data:`STUCK_EVALUATIONS` evaluation rows after the random phase (step > ``start_steps``)
    each acted with one constant action that almost no gradient can move (:func:`stuck_reason`)."""
    recent = [row for row in rows if row.get("step", 0) > start_steps][-STUCK_EVALUATIONS:]
    return len(recent) == STUCK_EVALUATIONS and all(stuck_reason(row) for row in recent)


def stuck_reason(row: Mapping[str, float]) -> str | None:
    """Why an evaluation row's seed acted with one constant action that almost no gradient can move, in words, or
    None: the action is saturated (:func:`constant_saturated_action`), or it is constant (spread below
    :data:`CONSTANT_SPREAD`) and at least :data:`CONSTANT_FROZEN_SHARE` of the output neurons fire the same spike
    train for every state (None for rows without these measurements, e.g. a deep actor's frozen share)."""
    if constant_saturated_action(row):
        return "one constant, saturated action (tanh is flat there)"
    frozen, spread = row.get("frozen_output_neurons"), row.get("action_spread")
    if frozen is None or spread is None or not (np.isfinite(frozen) and np.isfinite(spread)):
        return None
    if frozen >= CONSTANT_FROZEN_SHARE and spread < CONSTANT_SPREAD:
        return "one constant action decoded from output neurons that fire the same spike train for every state"
    return None


def constant_saturated_action(row: Mapping[str, float]) -> bool:
    """Whether an evaluation row says the seed acted with one constant, saturated action (False for rows without the
    two measurements)."""
    saturated, spread = row.get("saturated_actions"), row.get("action_spread")
    if saturated is None or spread is None or not (np.isfinite(saturated) and np.isfinite(spread)):
        return False
    return saturated >= CONSTANT_SATURATED_SHARE and spread < CONSTANT_SPREAD
