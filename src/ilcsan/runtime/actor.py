"""The deployed actor: a fully spiking actor loaded from a bundle; ``act`` is the deployed call."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .bundle_format import (
    backbone_synapses,
    check_encoder_widths,
    checked_meta,
    decoder_synapses,
    intra_bias_at_first_step,
    intra_synapses,
    read_array,
    read_bundle,
)
from .host import HostSide, deterministic_spike_train, gaussian_stimulation, li_voltages, select_statistic, squash
from .neurons import CLIF, Dynamic
from .pipeline import Workspace
from .synapses import Synapses, steps_accumulator


@dataclass
class DeployedActor(HostSide):
    """A fully spiking actor loaded from a deploy bundle; ``act`` is the deployed call.

    ``last_sop`` / ``last_sop_by_layer`` count the accumulates of the last inference, ``total_sop``,
    ``total_sop_by_layer`` and ``inferences`` add up over calls. Buffers are preallocated: use one
    instance per thread.
    """

    meta: dict[str, Any]
    mu: np.ndarray
    sigma: np.ndarray
    layers: tuple[Synapses, ...]
    intra: Synapses | None
    decoder: Synapses
    neuron: CLIF | Dynamic
    obs_mean: np.ndarray
    obs_std: np.ndarray
    obs_clip: float
    action_scale: np.ndarray
    action_offset: np.ndarray
    last_sop_by_layer: dict[str, int] = field(default_factory=dict)
    total_sop_by_layer: dict[str, int] = field(default_factory=dict)
    total_sop: int = 0
    inferences: int = 0
    workspace: Workspace = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.workspace = Workspace(self.timesteps, self.layers, self.neuron, self.intra,
                                   intra_bias_at_first_step=intra_bias_at_first_step(self.meta))
        # per-call constants, resolved once: SOP per spike of each train, the decoder's accumulate, the host's
        inputs = self.workspace.trains[:-1]  # each layer's presynaptic train: one spike = fan_out SOP
        self._fan_outs = [(layer.name, spikes, layer.fan_out) for layer, spikes in zip(self.layers, inputs,
                                                                                         strict=True)]
        if self.intra is not None:  # output spikes of steps 1..T−1 feed I_2..I_T
            self._fan_outs.append((self.intra.name, self.workspace.trains[-1][:-1], self.intra.fan_out))
        self._decode = steps_accumulator(self.decoder)
        self._host = (float(self.meta["enc_v_th"]), float(self.meta["alpha_v_li"]), str(self.meta["statistic"]))

    # ---------------------------------------------------------------------------- construction
    @classmethod
    def load(cls, path: str | Path) -> DeployedActor:
        """Read a bundle (``np.load(allow_pickle=False)``: data only) and check every array and key."""
        arrays, meta = read_bundle(path)
        return cls.from_arrays(arrays, meta, source=str(path))

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray], meta: Mapping[str, Any],
                    source: str = "bundle") -> DeployedActor:
        """Build the runtime from bundle arrays and metadata (what :mod:`ilcsan.deploy.bundle` writes)."""
        meta = checked_meta(meta, source)
        state_dim, action_dim = len(meta["obs_mean"]), len(meta["action_scale"])
        population_in, population_out = int(meta["population_in"]), int(meta["population_out"])
        mu = read_array(arrays, "encoder.mu", (state_dim, population_in), source)
        sigma = read_array(arrays, "encoder.sigma", (state_dim, population_in), source)
        check_encoder_widths(sigma, "encoder.sigma", source)
        layers = backbone_synapses(arrays, state_dim * population_in, action_dim * population_out, source)
        intra = intra_synapses(arrays, meta, action_dim, population_out, source)
        decoder = decoder_synapses(arrays, action_dim, population_out, source)
        return cls(dict(meta), mu, sigma, layers, intra, decoder, _neuron(meta),
                   np.asarray(meta["obs_mean"], np.float64), np.asarray(meta["obs_std"], np.float64),
                   float(meta["obs_clip"]), np.asarray(meta["action_scale"], np.float32),
                   np.asarray(meta["action_offset"], np.float32))

    # -------------------------------------------------------------------------------- properties
    @property
    def timesteps(self) -> int:
        return int(self.meta["T"])

    @property
    def task(self) -> str | None:
        """The task the actor was trained on (meta ``task``; None in a bundle that does not name it)."""
        task = self.meta.get("task")
        return str(task) if task else None

    @property
    def contact_forces(self) -> str | None:
        """How the task's contact forces read in training (meta ``contact_forces``; None in an older bundle)."""
        value = self.meta.get("contact_forces")
        return str(value) if value else None

    @property
    def label(self) -> str:
        """What the bundle holds, for messages: its preset and weight format."""
        return f"{self.meta.get('preset', 'actor')} · deploy bundle, {self.meta.get('weights', 'float32')} weights"

    @property
    def last_sop(self) -> int:
        """Synaptic operations (accumulates) of the last inference."""
        return sum(self.last_sop_by_layer.values())

    # ------------------------------------------------------------------------------------- acting
    def act(self, observation: Any) -> np.ndarray:
        """Deterministic action for one observation (N,) → (M,), or a batch (B, N) → (B, M), float32."""
        batch, single = self.check_observation(observation)
        if single:
            return self._act_one(batch[0])
        return np.stack([self._act_one(row) for row in batch])

    def spike_trains(self, observation: Any) -> list[np.ndarray]:
        """Encoder output and every layer's spikes (T, D) for one raw observation (copies, for analysis)."""
        batch, _ = self.check_observation(observation)
        self._forward(self.normalize(batch[0]))
        return [train.copy() for train in self.workspace.trains]

    def _act_one(self, observation: np.ndarray) -> np.ndarray:
        return squash(self._forward(self.normalize(observation)), self.action_scale, self.action_offset)

    def _forward(self, state: np.ndarray) -> np.ndarray:
        """Normalised state (N,) → O (M,); the spike trains stay in ``workspace.trains`` until the next call."""
        workspace = self.workspace
        encoder_threshold, alpha_li, statistic = self._host
        stimulation = gaussian_stimulation(state, self.mu, self.sigma)
        deterministic_spike_train(stimulation, self.timesteps, encoder_threshold, out=workspace.encoded)
        workspace.run()
        counts = {name: int(np.count_nonzero(spikes)) * fan_out for name, spikes, fan_out in self._fan_outs}
        drive, counts[self.decoder.name] = self._decode(workspace.trains[-1])
        self._count(counts)
        return select_statistic(li_voltages(drive, alpha_li), statistic)

    def _count(self, counts: dict[str, int]) -> None:
        self.last_sop_by_layer = counts
        for name, count in counts.items():
            self.total_sop_by_layer[name] = self.total_sop_by_layer.get(name, 0) + count
        self.total_sop += sum(counts.values())
        self.inferences += 1


def _neuron(meta: Mapping[str, Any]) -> CLIF | Dynamic:
    """The backbone's neuron and its constants from the meta (the dynamic neuron's θ default to MDC-SAN's)."""
    if meta["neuron"] == "clif":
        return CLIF(float(meta["alpha_c"]), float(meta["alpha_v"]), float(meta["v_th"]))
    defaults = Dynamic()
    return Dynamic(float(meta["alpha_c"]), float(meta["v_th"]),
                   *(float(meta.get(name, getattr(defaults, name))) for name in ("theta_v", "theta_u", "theta_r",
                                                                                 "theta_s")))
