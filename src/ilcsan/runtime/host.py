"""What the host computes around a deployed spiking network (dense floating point, numpy only).

The frozen observation normaliser, the encoders, the statistic of the decoder's LI voltages and the
action scaling. :class:`~.actor.DeployedActor` and the NIR host path (:mod:`ilcsan.deploy.nir.host`) both call
these functions; they mirror the PyTorch actor's :mod:`ilcsan.snn.encoders` and :mod:`ilcsan.snn.decoders`
operation for operation, in float32.
"""

from __future__ import annotations

import numbers
from typing import Any

import numpy as np

from .errors import UserError


class HostSide:
    """What every deployable actor does on the host around its network (:class:`~.actor.DeployedActor`,
    ``ilcsan.Policy``): check the observations a robot passes in, normalise them with the frozen statistics
    ``obs_mean``/``obs_std``/``obs_clip`` and scale actions with ``action_scale``/``action_offset`` — fields the
    subclass declares. ``expects`` names the actor in shape errors."""

    obs_mean: np.ndarray
    obs_std: np.ndarray
    obs_clip: float
    action_scale: np.ndarray
    action_offset: np.ndarray

    @property
    def expects(self) -> str:
        return "actor"

    @property
    def state_dim(self) -> int:
        return int(self.obs_mean.shape[0])

    @property
    def action_dim(self) -> int:
        return int(self.action_scale.shape[0])

    def normalize(self, observation: np.ndarray) -> np.ndarray:
        """The frozen normaliser clip((s − mean)/std, ±clip) → float32 (:func:`normalize`)."""
        return normalize(observation, self.obs_mean, self.obs_std, self.obs_clip)

    def check_observation(self, observation: Any) -> tuple[np.ndarray, bool]:
        """Real, finite numbers of shape (N,) or (B, N) → a (B, N) float64 array and whether one was given alone;
        anything else (strings, complex numbers, objects, another shape, NaN or inf) is a :class:`UserError`."""
        try:
            raw = np.asarray(observation)
            if raw.dtype.kind == "O" and all(isinstance(x, numbers.Real) for x in raw.flat):
                raw = raw.astype(np.float64)  # Python numbers; an int beyond float64 raises OverflowError
            if raw.dtype.kind not in "biuf":  # strings, bytes, complex, dates, objects: not sensor readings
                raise TypeError(raw.dtype)
            array = raw.astype(np.float64)
        except (TypeError, ValueError, OverflowError):
            raise UserError(f"observation must be real numbers of shape ({self.state_dim},) or "
                            f"(B, {self.state_dim})") from None
        single = array.ndim == 1
        if array.ndim not in (1, 2) or array.shape[-1] != self.state_dim or array.size == 0:
            raise UserError(f"observation has shape {array.shape}; this {self.expects} expects "
                            f"({self.state_dim},) or (B, {self.state_dim})")
        if not np.all(np.isfinite(array)):
            raise UserError("observation contains NaN or inf; check the sensor readings before acting")
        return (array[None] if single else array), single


def normalize(observation: np.ndarray, mean: np.ndarray, std: np.ndarray, clip: float) -> np.ndarray:
    """The frozen normaliser clip((s − mean)/std, ±clip) of raw observations (…, N) → float32."""
    scaled = (np.asarray(observation, np.float64) - np.asarray(mean, np.float64)) / np.asarray(std, np.float64)
    return np.minimum(np.maximum(scaled, -clip), clip).astype(np.float32)  # = np.clip, without its overhead


def gaussian_stimulation(state: np.ndarray, mu: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Eq. (9): A = exp(−½((s_i − μ)/σ)²), state (N,), μ/σ (N, P_in) → (N·P_in,) float32."""
    z = (state[:, None] - mu) / sigma
    return np.exp(-0.5 * z * z).reshape(-1)


def deterministic_spike_train(stimulation: np.ndarray, timesteps: int, threshold: float,
                              out: np.ndarray | None = None) -> np.ndarray:
    """E_pop_det's soft-reset IF neurons (Eq. (4)): v ← v + A; S = [v > V_th]; v ← v − V_th S → (T, D) bool."""
    spikes = np.empty((timesteps, stimulation.size), dtype=bool) if out is None else out
    threshold = np.float32(threshold)
    voltage = stimulation.copy()  # 0 + A
    for t in range(timesteps):
        if t:
            np.add(voltage, stimulation, voltage)
        np.greater(voltage, threshold, spikes[t])
        if t + 1 < timesteps:  # v − V_th·S: V_th subtracted where S = 1, v unchanged (v − 0) elsewhere
            np.subtract(voltage, threshold, voltage, where=spikes[t])
    return spikes


def bernoulli_spike_train(stimulation: np.ndarray, timesteps: int, rng: np.random.Generator) -> np.ndarray:
    """PopSAN's probabilistic encoder: S_t ~ Bernoulli(A) at every step → (T, D) bool."""
    return rng.random((timesteps, stimulation.size)) < np.clip(stimulation, 0, 1)


def two_neuron_input(state: np.ndarray, clip: float) -> np.ndarray:
    """Akl et al.'s analog input (max(s, 0), max(−s, 0)) / clip → (2N,) float32."""
    return (np.concatenate([np.maximum(state, 0), np.maximum(-state, 0)]) / np.float32(clip)).astype(np.float32)


def encode(kind: str, state: np.ndarray, timesteps: int, mu: np.ndarray | None = None,
           sigma: np.ndarray | None = None, threshold: float = 0.999, clip: float = 3.0,
           rng: np.random.Generator | None = None) -> np.ndarray:
    """Encoder ``kind`` (ilcsan.config.ENCODERS) on a normalised state (N,) → FC1's input (T, D) float32;
    an analog input is repeated at every step."""
    if kind == "layer":
        analog = state
    elif kind == "two-neuron":
        analog = two_neuron_input(state, clip)
    elif kind in ("pop", "pop-det", "pop-prob"):
        analog = gaussian_stimulation(state, mu, sigma)
        if kind == "pop-det":
            return deterministic_spike_train(analog, timesteps, threshold).astype(np.float32)
        if kind == "pop-prob":
            rng = np.random.default_rng() if rng is None else rng
            return bernoulli_spike_train(analog, timesteps, rng).astype(np.float32)
    else:
        raise UserError(f"unknown encoder {kind!r}")
    return np.repeat(np.asarray(analog, np.float32)[None], timesteps, axis=0)


def li_voltages(inputs: np.ndarray, alpha: float) -> np.ndarray:
    """LI neuron (Eq. (7), V_reset = 0): V_t = α V_{t−1} + X_t over inputs (T, M) → (T, M)."""
    if alpha == 1.0:  # an integrator: the running sum, added in the same order
        return np.add.accumulate(inputs, axis=0, dtype=np.float32)  # np.cumsum, without its overhead
    voltages = np.empty_like(inputs)
    voltage = np.zeros(inputs.shape[1], inputs.dtype)
    for t in range(inputs.shape[0]):
        voltage = np.float32(alpha) * voltage + inputs[t]
        voltages[t] = voltage
    return voltages


def select_statistic(voltages: np.ndarray, statistic: str) -> np.ndarray:
    """O = Stat(V_1..V_T) of (T, M) voltages (Eq. (8)): last, max (largest |V|, first on ties), mean."""
    if statistic == "last":
        return voltages[-1]
    if statistic == "mean":
        return voltages.mean(axis=0, dtype=np.float32)
    index = np.abs(voltages).argmax(axis=0)
    return voltages[index, np.arange(voltages.shape[1])]


def squash(output: np.ndarray, scale: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """action = offset + scale · tanh(O), float32."""
    return (np.asarray(offset, np.float32) + np.asarray(scale, np.float32) * np.tanh(output)).astype(np.float32,
                                                                                                   copy=False)
