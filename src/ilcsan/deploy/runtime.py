"""Additions-only runtime for a deployed spiking actor: numpy only, no PyTorch.

``DeployedActor.load("actor.npz").act(observation)`` runs the ``.npz`` bundle written by
:mod:`ilcsan.export` and returns the same action as ``ilcsan.load(run).predict(observation)`` (float
rounding aside, tested to 1e-4). It proves the paper's "fully spiking" claim (Section III): every
synaptic operation is an **accumulate** of a weight selected by a 0/1 spike, never a multiply.

What runs where
---------------
Synaptic layers, event-driven (counted as SOP, Section V-F):

* FC1 … FC(L+1) (Algorithm 1, W^l S_t^{l-1}): at every step t, the rows of Wᵀ (outgoing weights) of
  the presynaptic neurons that spiked are selected and added into the layer's input current; silent
  neurons cost nothing. One spike = fan-out accumulates.
* Intra FC (Eq. (10), I_{t+1}^m = W_intra^m S_t^{L,m} + b_intra^m): a spike of output neuron q at
  t = 1..T−1 adds column q of W_intra^m onto its own population. A chip holds only the synapses the
  ablation mask keeps (full: P_out, ``self``: 1, ``lateral``: P_out − 1, ``bias``/``none``: 0 per spike)
  and that is what is counted; numpy adds the whole block-diagonal column (zeros elsewhere), because one
  vectorised add is cheaper here than a scatter.
* Group FC (population decoder, X_t^m = W_D^m S_t^{L,m} + b_D^m): a spike adds one weight into the LI
  neuron of its population (one ``bincount`` over the spike train's events).

The layers run pipelined (:class:`Workspace`): at tick τ layer l computes its step τ − l, so the neuron
updates of all active layers are one vector operation per tick; the result is Algorithm 1's. Buffers
are preallocated per actor: use one :class:`DeployedActor` per thread.

Neuron-local state updates (the neuron core's work, not synaptic operations; no spike multiplies a
weight): the CLIF (or MDC-SAN dynamic) neuron's decay, threshold and hard reset, the constant biases
b^l, b_intra, b_D injected as currents, and the LI neuron V_t = α_V^LI V_{t−1} + X_t (Eq. (7)).

Host (dense floating point, no NIR/neuromorphic primitive, as in the paper): the frozen observation
normaliser clip((s − mean)/std, ±clip); the Gaussian receptive fields A = exp(−½((s−μ)/σ)²) (Eq. (9));
the encoder's deterministic soft-reset IF neurons (v ← v + A; S = [v > 0.999]; v ← v − 0.999·S);
the statistic O = Stat(V_1..V_T) (``last``/``max``/``mean``, Eq. (8)); and action = offset +
scale·tanh(O).

Counting
--------
``last_sop`` is the exact number of accumulates of the last inference (the sum over layers of
spikes × fan-out; ``last_sop_by_layer`` splits it with the layer names of :mod:`ilcsan.energy`);
``total_sop``, ``total_sop_by_layer`` and ``inferences`` add up over calls. Bias currents are not
counted (a bias is a constant per-neuron current, not a synaptic event; the paper does not count it
either). Averaged over the same observations this equals the energy model's T·fr·Din·Dout exactly.

int8 bundles
------------
A bundle written with ``--weights int8`` (:mod:`ilcsan.quantize`) stores every synaptic weight matrix
as int8 ``q`` with a float32 per-layer scale ``s`` (array ``<name>.scale``), W ≈ s·q. The runtime
accumulates the integers exactly (int32 for the backbone and intra rows, exact integer-valued float64
bins for the decoder) and multiplies the integer sum by ``s`` once per neuron and step, as a chip's
neuron core would (integer synapses, one scale per layer); biases stay float32.

Scope and refusals
------------------
Fully spiking actors only: encoder ``pop-det``, neurons ``clif`` or ``dynamic``, decoders ``last``,
``max``, ``mean`` with any α_V^LI, every intra-layer mask, 1-4 hidden layers (any widths). Refused with
:class:`UserError`: ``pop-prob`` (stochastic Bernoulli encoding; the runtime is deterministic, re-train
or fine-tune with ``pop-det``), analog encoders ``pop``/``layer``/``two-neuron`` and the firing-rate
decoder ``fr`` (floating-point matrix operations: not fully spiking), deep actors (DAN), and a
non-zero reset voltage.

Standalone use
--------------
This file depends on numpy only. Copy it next to a robot program and import it by path; inside the
package it raises :class:`ilcsan.errors.UserError`, standalone an equivalent local class.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

try:
    from ..errors import UserError
except ImportError:  # loaded as a standalone file: no package around it

    class UserError(ValueError):  # type: ignore[no-redef]
        """A mistake in the user's input (the package's ilcsan.errors.UserError when installed)."""


SCALE_SUFFIX = ".scale"
"""An int8 weight array ``<name>`` has its float32 scale in ``<name>.scale`` (W ≈ scale · int8)."""

STATISTICS = ("last", "max", "mean")
NEURONS = ("clif", "dynamic")
REQUIRED_META = ("T", "alpha_c", "alpha_v", "v_th", "v_reset", "alpha_v_li", "v_reset_li", "statistic",
                 "encoder", "enc_v_th", "obs_mean", "obs_std", "obs_clip", "action_scale", "action_offset",
                 "neuron", "network", "population_out", "population_in")
INTRA_MASKS = {  # name → (self, lateral, bias), as ilcsan.intra.INTRA_VARIANTS
    "intra": (True, True, True), "self": (True, False, False), "lateral": (False, True, False),
    "bias": (False, False, True), "lateral+bias": (False, True, True), "self+bias": (True, False, True),
    "self+lateral": (True, True, False), "none": (False, False, False),
}


# ------------------------------------------------------------------------------------ synapses
class Synapses(NamedTuple):
    """An event-driven synaptic layer: presynaptic neuron i projects with the weights in row ``weights[i]``.

    ``weights`` is (Din, F) float32 (or int8 with ``scale``): row i holds neuron i's outgoing weights.
    ``targets`` is None for a row over all ``out_dim`` postsynaptic neurons in order (F = out_dim), else
    (Din, F) postsynaptic indices. ``fan_out`` is the number of synapses a spike drives — one spike =
    ``fan_out`` SOP. It is F, except for the intra-layer connections, whose rows are the block-diagonal
    columns over the whole output layer (zeros outside the population and outside the ablation mask) while
    ``fan_out`` counts only the kept synapses of the population.
    """

    name: str
    weights: np.ndarray
    targets: np.ndarray | None
    scale: float | None
    bias: np.ndarray
    out_dim: int
    fan_out: int


def dense_accumulator(synapses: Synapses):
    """``add(spikes, out)``: out ← Σ_{i: spikes[i]} weights[i] for a dense layer, spikes a 0/1 (bool) vector.

    The weight rows of the neurons that spiked are selected (``compress``) and added; nothing is
    multiplied by a spike. int8 rows are added in int32 (exact) and the sum scaled once.
    """
    weights = synapses.weights
    if synapses.scale is None:
        def add(spikes: np.ndarray, out: np.ndarray) -> None:
            np.add.reduce(weights.compress(spikes, axis=0), axis=0, out=out)
        return add
    scale = np.float32(synapses.scale)
    integer_sum = np.empty(synapses.out_dim, np.int32)

    def add_int8(spikes: np.ndarray, out: np.ndarray) -> None:
        np.add.reduce(weights.compress(spikes, axis=0), axis=0, dtype=np.int32, out=integer_sum)
        np.multiply(integer_sum, scale, out=out, casting="same_kind")
    return add_int8


def accumulate_steps(synapses: Synapses, spikes: np.ndarray) -> tuple[np.ndarray, int]:
    """Sparse layer over all T steps at once: (T, Din) 0/1 spikes → ((T, out_dim) float32 incl. bias, SOP).

    Every event (t, i) adds each of neuron i's weights into bin (t, target); one ``bincount`` serves the
    whole spike train (used for the population decoder's Group FC).
    """
    timesteps = spikes.shape[0]
    step_index, neuron_index = np.nonzero(spikes)
    bins = (step_index[:, None] * synapses.out_dim + synapses.targets[neuron_index]).ravel()
    sums = np.bincount(bins, weights=synapses.weights[neuron_index].ravel(),
                       minlength=timesteps * synapses.out_dim)
    if synapses.scale is not None:
        sums = sums * synapses.scale
    currents = sums.astype(np.float32).reshape(timesteps, synapses.out_dim) + synapses.bias
    return currents, int(neuron_index.size) * synapses.fan_out


# ------------------------------------------------------------------------------------- neurons
class CLIF(NamedTuple):
    """Current-based LIF with hard reset to 0 (Algorithm 1; PopSAN's constants by default)."""

    alpha_current: float = 0.5
    alpha_voltage: float = 0.75
    threshold: float = 0.5


class Dynamic(NamedTuple):
    """MDC-SAN's dynamic neuron (ilcsan.neurons.dynamic_step), constants of the authors' comparison."""

    alpha_current: float = 0.5
    threshold: float = 0.5
    theta_v: float = -0.172
    theta_u: float = 0.529
    theta_r: float = 0.021
    theta_s: float = 0.132


def initial_state(neuron: CLIF | Dynamic, size: int) -> dict[str, np.ndarray]:
    """C_0 = 0, V_0 = V_reset = 0 (and u_0 = 0 for the dynamic neuron), float32."""
    names = ("current", "voltage") if isinstance(neuron, CLIF) else ("current", "voltage", "recovery")
    return {name: np.zeros(size, np.float32) for name in names}


def neuron_step(neuron: CLIF | Dynamic, state: dict[str, np.ndarray], drive: np.ndarray, previous: np.ndarray,
                fired: np.ndarray) -> None:
    """One step of the neurons whose state arrays (views) are ``state``, in place; writes S_t into ``fired``.

    CLIF (Algorithm 1, V_reset = 0): C = α_C C + X; H = α_V V + C; S = [H ≥ V_th]; V = H (1 − S).
    Dynamic (ilcsan.neurons.dynamic_step, same operation order): ``previous`` holds S_{t−1}.
    Same float32 operations, in the same order, as the PyTorch actor.
    """
    current, voltage = state["current"], state["voltage"]
    if isinstance(neuron, CLIF):
        current *= np.float32(neuron.alpha_current)
        current += drive
        voltage *= np.float32(neuron.alpha_voltage)
        voltage += current
        np.greater_equal(voltage, np.float32(neuron.threshold), out=fired)
        voltage[fired] = 0.0
        return
    recovery = state["recovery"]
    current[...] = np.float32(neuron.alpha_current) * current + drive
    reset_voltage = np.where(previous, np.float32(neuron.theta_r), voltage)
    reset_recovery = np.where(previous, recovery + np.float32(neuron.theta_s), recovery)
    voltage[...] = reset_voltage + (reset_voltage * reset_voltage - reset_voltage - reset_recovery + current)
    recovery[...] = reset_recovery + (np.float32(neuron.theta_v) * reset_voltage
                                      - np.float32(neuron.theta_u) * reset_recovery)
    np.greater_equal(voltage, np.float32(neuron.threshold), out=fired)


class Tick(NamedTuple):
    """What one tick of the pipelined backbone touches: views into the :class:`Workspace` buffers.

    ``synapses``: (accumulate, presynaptic spikes, drive slice) for every active layer; ``intra``: (output
    spikes of the previous step, output drive slice) when the intra-layer current applies.
    """

    synapses: tuple
    drive: np.ndarray
    bias: np.ndarray
    state: dict[str, np.ndarray]
    previous: np.ndarray
    fired: np.ndarray
    intra: tuple[np.ndarray, np.ndarray] | None


class Workspace:
    """Preallocated buffers of one actor and the plan of its T + L − 1 ticks (so an action allocates little).

    Pipelining: at tick τ, layer l (0-based) computes its step t = τ − l. Layer l at step t needs only
    layer l−1 at step t (computed at tick τ − 1) and its own state, so the result is Algorithm 1's; the
    neuron updates of all active layers are one vector operation per tick. ``history`` row τ holds the
    spikes every active layer emitted at tick τ; layer l's train is rows l .. l+T−1 of its columns.
    """

    def __init__(self, actor: DeployedActor):
        timesteps, layers = actor.timesteps, actor.layers
        widths = [layer.out_dim for layer in layers]
        self.offsets = np.concatenate([[0], np.cumsum(widths)]).astype(int)
        last, total = len(layers) - 1, int(self.offsets[-1])
        self.encoded = np.zeros((timesteps, layers[0].weights.shape[0]), dtype=bool)
        self.history = np.zeros((timesteps + last, total), dtype=bool)
        self.state = initial_state(actor.neuron, total)
        drive = np.empty(total, np.float32)
        bias = np.concatenate([layer.bias for layer in layers]).astype(np.float32)
        accumulators = [dense_accumulator(layer) for layer in layers]
        columns = [slice(self.offsets[index], self.offsets[index + 1]) for index in range(last + 1)]
        self.ticks = []
        for tick in range(timesteps + last):
            first, final = max(0, tick - timesteps + 1), min(tick, last)
            synapses = tuple(
                (accumulators[index],
                 self.encoded[tick] if index == 0 else self.history[tick - 1, columns[index - 1]],
                 drive[columns[index]])
                for index in range(first, final + 1))
            window = slice(self.offsets[first], self.offsets[final + 1])
            intra = None
            if actor.intra is not None and final == last and tick > last:
                intra = (self.history[tick - 1, columns[last]], drive[columns[last]])
            self.ticks.append(Tick(synapses, drive[window], bias[window],
                                   {name: value[window] for name, value in self.state.items()},
                                   self.history[tick - 1, window], self.history[tick, window], intra))
        self.trains = [self.encoded] + [self.history[index:index + timesteps, columns[index]]
                                        for index in range(last + 1)]
        self.intra_current = np.empty(widths[-1], np.float32)
        self.add_intra = dense_accumulator(actor.intra) if actor.intra is not None else None

    def reset(self) -> None:
        """V_0 = C_0 = 0, no spikes yet."""
        self.history.fill(False)
        for value in self.state.values():
            value.fill(0.0)


# ------------------------------------------------------------------------------------- host side
def gaussian_stimulation(state: np.ndarray, mu: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Eq. (9), host: A = exp(−½((s_i − μ)/σ)²), state (N,), μ/σ (N, P_in) → (N·P_in,) float32."""
    z = (state[:, None] - mu) / sigma
    return np.exp(-0.5 * z * z).reshape(-1)


def deterministic_spike_train(stimulation: np.ndarray, timesteps: int, threshold: float,
                              out: np.ndarray | None = None) -> np.ndarray:
    """E_pop_det's soft-reset IF neurons on the host: v ← v + A; S = [v > V_th]; v ← v − V_th S → (T, D)."""
    voltage = np.zeros_like(stimulation)
    spikes = np.empty((timesteps, stimulation.size), dtype=bool) if out is None else out
    for t in range(timesteps):
        voltage += stimulation
        np.greater(voltage, np.float32(threshold), out=spikes[t])
        np.subtract(voltage, np.float32(threshold), out=voltage, where=spikes[t])
    return spikes


def li_voltages(inputs: np.ndarray, alpha: float) -> np.ndarray:
    """LI neuron (Eq. (7), V_reset = 0): V_t = α V_{t−1} + X_t over inputs (T, M) → (T, M)."""
    if alpha == 1.0:  # an integrator: the running sum, added in the same order
        return np.cumsum(inputs, axis=0, dtype=np.float32)
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


# ------------------------------------------------------------------------------------- the actor
@dataclass
class DeployedActor:
    """A fully spiking actor loaded from a deploy bundle; ``act`` is the deployed call."""

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
        self.workspace = Workspace(self)

    # ---------------------------------------------------------------------------- construction
    @classmethod
    def load(cls, path: str | Path) -> DeployedActor:
        """Read a bundle (``np.load(allow_pickle=False)``: data only) and check every array and key."""
        path = Path(path)
        if not path.is_file():
            raise UserError(f"{path} does not exist; export one with `ilcsan export RUN --format npz`")
        try:
            with np.load(path, allow_pickle=False) as bundle:
                arrays = {name: bundle[name] for name in bundle.files}
        except (OSError, ValueError, EOFError) as error:
            raise UserError(f"{path} is not a readable .npz deploy bundle ({error})") from None
        if "meta" not in arrays:
            raise UserError(f"{path} has no 'meta' entry: it is not an ilcsan deploy bundle")
        try:
            meta = json.loads(str(arrays.pop("meta")))
        except json.JSONDecodeError as error:
            raise UserError(f"{path}: the bundle's meta is not valid JSON ({error})") from None
        return cls.from_arrays(arrays, meta, source=str(path))

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray], meta: Mapping[str, Any],
                    source: str = "bundle") -> DeployedActor:
        """Build the runtime from bundle arrays and metadata (what :mod:`ilcsan.export` writes)."""
        meta = _checked_meta(meta, source)
        state_dim, action_dim = len(meta["obs_mean"]), len(meta["action_scale"])
        population_in, population_out = int(meta["population_in"]), int(meta["population_out"])
        mu = _array(arrays, "encoder.mu", (state_dim, population_in), source)
        sigma = _array(arrays, "encoder.sigma", (state_dim, population_in), source)
        layers = _backbone(arrays, state_dim * population_in, action_dim * population_out, source)
        intra = _intra(arrays, meta, action_dim, population_out, source)
        decoder = _decoder(arrays, action_dim, population_out, source)
        if meta["neuron"] == "clif":
            neuron: CLIF | Dynamic = CLIF(float(meta["alpha_c"]), float(meta["alpha_v"]), float(meta["v_th"]))
        else:
            defaults = Dynamic()
            neuron = Dynamic(float(meta["alpha_c"]), float(meta["v_th"]),
                             *(float(meta.get(name, getattr(defaults, name)))
                               for name in ("theta_v", "theta_u", "theta_r", "theta_s")))
        return cls(dict(meta), mu, sigma, layers, intra, decoder, neuron,
                   np.asarray(meta["obs_mean"], np.float64), np.asarray(meta["obs_std"], np.float64),
                   float(meta["obs_clip"]), np.asarray(meta["action_scale"], np.float32),
                   np.asarray(meta["action_offset"], np.float32))

    # -------------------------------------------------------------------------------- properties
    @property
    def state_dim(self) -> int:
        return int(self.obs_mean.shape[0])

    @property
    def action_dim(self) -> int:
        return int(self.action_scale.shape[0])

    @property
    def timesteps(self) -> int:
        return int(self.meta["T"])

    @property
    def last_sop(self) -> int:
        """Synaptic operations (accumulates) of the last inference."""
        return sum(self.last_sop_by_layer.values())

    # ------------------------------------------------------------------------------------- acting
    def act(self, observation: Any) -> np.ndarray:
        """Deterministic action for one observation (N,) → (M,), or a batch (B, N) → (B, M), float32."""
        batch, single = self._checked_observation(observation)
        if single:
            return self._act_one(batch[0])
        return np.stack([self._act_one(row) for row in batch])

    def normalize(self, observation: np.ndarray) -> np.ndarray:
        """Host: the frozen normaliser clip((s − mean)/std, ±clip) → float32 (as Policy.normalize)."""
        return np.clip((observation - self.obs_mean) / self.obs_std, -self.obs_clip,
                       self.obs_clip).astype(np.float32)

    def spike_trains(self, observation: Any) -> list[np.ndarray]:
        """Encoder output and every layer's spikes (T, D) for one raw observation (copies, for analysis)."""
        batch, _ = self._checked_observation(observation)
        self._forward(self.normalize(batch[0]))
        return [train.copy() for train in self.workspace.trains]

    def _act_one(self, observation: np.ndarray) -> np.ndarray:
        output = self._forward(self.normalize(observation))
        return self.action_offset + self.action_scale * np.tanh(output)

    def _forward(self, state: np.ndarray) -> np.ndarray:
        """Normalised state (N,) → O (M,); the spike trains stay in ``workspace.trains`` until the next call."""
        workspace = self.workspace
        stimulation = gaussian_stimulation(state, self.mu, self.sigma)
        deterministic_spike_train(stimulation, self.timesteps, float(self.meta["enc_v_th"]), out=workspace.encoded)
        self._backbone()
        trains = workspace.trains
        counts = {layer.name: int(np.count_nonzero(spikes)) * layer.fan_out
                  for layer, spikes in zip(self.layers, trains, strict=False)}
        if self.intra is not None:  # output spikes of steps 1..T−1 feed I_2..I_T
            counts[self.intra.name] = int(np.count_nonzero(trains[-1][:-1])) * self.intra.fan_out
        drive, counts[self.decoder.name] = accumulate_steps(self.decoder, trains[-1])
        voltages = li_voltages(drive, float(self.meta["alpha_v_li"]))
        self.last_sop_by_layer = counts
        for name, count in counts.items():
            self.total_sop_by_layer[name] = self.total_sop_by_layer.get(name, 0) + count
        self.total_sop += sum(counts.values())
        self.inferences += 1
        return select_statistic(voltages, self.meta["statistic"])

    def _backbone(self) -> None:
        """Run the L spiking layers tick by tick (:class:`Workspace`): accumulate the spikes of the previous
        layer into each active layer's drive, add the biases and the intra-layer current, update neurons."""
        workspace, neuron, intra = self.workspace, self.neuron, self.intra
        workspace.reset()
        for tick in workspace.ticks:
            for add, presynaptic, layer_drive in tick.synapses:
                add(presynaptic, layer_drive)
            drive = tick.drive
            drive += tick.bias
            if tick.intra is not None:  # I_t = W_intra S_{t−1} + b_intra, then X_t + I_t
                previous_output, output_drive = tick.intra
                intra_current = workspace.intra_current
                workspace.add_intra(previous_output, intra_current)
                intra_current += intra.bias
                output_drive += intra_current
            neuron_step(neuron, tick.state, drive, tick.previous, tick.fired)

    def _checked_observation(self, observation: Any) -> tuple[np.ndarray, bool]:
        try:
            array = np.asarray(observation, dtype=np.float64)
        except (TypeError, ValueError):
            raise UserError(f"observation must be numbers of shape ({self.state_dim},) or "
                            f"(B, {self.state_dim})") from None
        if array.ndim not in (1, 2) or array.shape[-1] != self.state_dim or array.size == 0:
            raise UserError(f"observation has shape {array.shape}; this actor expects ({self.state_dim},) "
                            f"or (B, {self.state_dim})")
        if not np.all(np.isfinite(array)):
            raise UserError("observation contains NaN or inf; check the sensor readings before acting")
        return (array[None] if array.ndim == 1 else array), array.ndim == 1


# ----------------------------------------------------------------------------- bundle checking
def _checked_meta(meta: Mapping[str, Any], source: str) -> dict[str, Any]:
    if not isinstance(meta, Mapping):
        raise UserError(f"{source}: the bundle's meta must be a JSON object")
    missing = [key for key in REQUIRED_META if key not in meta]
    if missing:
        raise UserError(f"{source}: the bundle's meta lacks {', '.join(missing)}; re-export it with this "
                        "version of ilcsan")
    if meta["network"] != "spiking":
        raise UserError(f"{source} holds a {meta['network']!r} actor (DAN); the additions-only runtime runs "
                        "spiking actors only: use ilcsan.load(run).predict for a deep actor")
    if meta["encoder"] == "pop-prob":
        raise UserError(f"{source}: encoder 'pop-prob' draws Bernoulli spikes, so its actions are random; the "
                        "deployed runtime is deterministic: train (or fine-tune) with --encoder pop-det")
    if meta["encoder"] != "pop-det":
        raise UserError(f"{source}: encoder {meta['encoder']!r} feeds analog values to FC1 (floating-point "
                        "matrix operations), so the actor is not fully spiking; the runtime needs pop-det")
    if meta["statistic"] not in STATISTICS:
        raise UserError(f"{source}: decoder {meta['statistic']!r} is not fully spiking (a floating-point FC "
                        f"on firing rates); the runtime runs the membrane-voltage decoders {STATISTICS}")
    if meta["neuron"] not in NEURONS:
        raise UserError(f"{source}: unknown neuron {meta['neuron']!r}; expected one of {NEURONS}")
    numbers = ("T", "alpha_c", "alpha_v", "v_th", "v_reset", "alpha_v_li", "v_reset_li", "enc_v_th",
               "obs_clip", "population_out", "population_in")
    for key in numbers:
        value = meta[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise UserError(f"{source}: meta {key!r} must be a finite number, got {value!r}")
    for key in ("T", "population_out", "population_in"):
        if int(meta[key]) != meta[key] or meta[key] < 1:
            raise UserError(f"{source}: meta {key!r} must be a positive integer, got {meta[key]!r}")
    if meta["v_reset"] != 0 or meta["v_reset_li"] != 0:
        raise UserError(f"{source}: the runtime implements reset voltages of 0 (the paper's); got "
                        f"v_reset={meta['v_reset']}, v_reset_li={meta['v_reset_li']}")
    vectors = {}
    for key in ("obs_mean", "obs_std", "action_scale", "action_offset"):
        try:
            vectors[key] = np.asarray(meta[key], dtype=np.float64)
        except (TypeError, ValueError):
            raise UserError(f"{source}: meta {key!r} must be a list of numbers") from None
        if vectors[key].ndim != 1 or vectors[key].size == 0 or not np.all(np.isfinite(vectors[key])):
            raise UserError(f"{source}: meta {key!r} must be a non-empty list of finite numbers")
    if vectors["obs_std"].shape != vectors["obs_mean"].shape or np.any(vectors["obs_std"] <= 0):
        raise UserError(f"{source}: meta 'obs_std' must be positive and as long as 'obs_mean'")
    if vectors["action_offset"].shape != vectors["action_scale"].shape:
        raise UserError(f"{source}: meta 'action_offset' and 'action_scale' differ in length")
    intra = meta.get("intra")
    if intra is not None and (not isinstance(intra, str) or intra not in INTRA_MASKS):
        raise UserError(f"{source}: meta 'intra' {intra!r} is not one of {', '.join(INTRA_MASKS)}")
    return dict(meta)


def _array(arrays: Mapping[str, np.ndarray], name: str, shape: tuple[int, ...], source: str) -> np.ndarray:
    """A float32 array of the given shape (an int8 weight with its scale is returned as int8)."""
    if name not in arrays:
        raise UserError(f"{source} has no array {name!r}: it is incomplete or from another exporter")
    array = np.asarray(arrays[name])
    if tuple(array.shape) != tuple(shape):
        raise UserError(f"{source}: array {name!r} has shape {tuple(array.shape)}, expected {tuple(shape)}")
    if array.dtype == np.int8:
        return array
    if not np.issubdtype(array.dtype, np.floating):
        raise UserError(f"{source}: array {name!r} has dtype {array.dtype}, expected float32 or int8")
    array = array.astype(np.float32)
    if not np.all(np.isfinite(array)):
        raise UserError(f"{source}: array {name!r} contains NaN or inf")
    return array


def _weight(arrays: Mapping[str, np.ndarray], name: str, shape: tuple[int, ...],
            source: str) -> tuple[np.ndarray, float | None]:
    """A synaptic weight matrix and its int8 scale (None for float weights)."""
    weight = _array(arrays, name, shape, source)
    if weight.dtype != np.int8:
        return weight, None
    scale_name = name + SCALE_SUFFIX
    if scale_name not in arrays:
        raise UserError(f"{source}: int8 array {name!r} has no scale {scale_name!r}")
    scale = np.asarray(arrays[scale_name])
    if scale.size != 1 or not np.isfinite(scale).all() or float(scale.reshape(-1)[0]) <= 0:
        raise UserError(f"{source}: scale {scale_name!r} must be one positive finite number")
    return weight, float(scale.reshape(-1)[0])


def _backbone(arrays: Mapping[str, np.ndarray], input_dim: int, output_dim: int,
              source: str) -> tuple[Synapses, ...]:
    """FC1 … FC(L+1) as dense event-driven layers, rows = presynaptic neurons (Wᵀ)."""
    count = 0
    while f"layers.{count}.weight" in arrays:
        count += 1
    if not 2 <= count <= 5:
        raise UserError(f"{source} has {count} synaptic layers; a spiking actor has 1-4 hidden layers + output")
    layers, fan_in = [], input_dim
    for index in range(count):
        name = f"layers.{index}.weight"
        if name not in arrays or np.ndim(arrays[name]) != 2:
            raise UserError(f"{source}: array {name!r} must be a 2-D (out, in) matrix")
        out_dim = int(np.shape(arrays[name])[0])
        if index == count - 1 and out_dim != output_dim:
            raise UserError(f"{source}: the output layer has {out_dim} neurons, expected M·P_out = {output_dim}")
        weight, scale = _weight(arrays, name, (out_dim, fan_in), source)
        bias = _array(arrays, f"layers.{index}.bias", (out_dim,), source)
        layers.append(Synapses(f"FC{index + 1}", np.ascontiguousarray(weight.T), None, scale, bias, out_dim,
                               out_dim))
        fan_in = out_dim
    return tuple(layers)


def _intra(arrays: Mapping[str, np.ndarray], meta: Mapping[str, Any], populations: int, size: int,
           source: str) -> Synapses | None:
    """Intra FC as block-diagonal rows over the output layer, counting the synapses the ablation mask keeps.

    The mask comes from meta ``intra`` when present, else from the weights (a part whose weights are all
    exactly zero is absent; masked weights are stored as exact zeros). Row j (a presynaptic output neuron
    of population m) holds column j of the block-diagonal W_intra: W_intra^m[:, q] on population m's
    slots, zeros elsewhere — one vectorised add per step is cheaper in numpy than a scatter; the SOP
    count is spikes × the kept synapses of one population (P_out, 1, P_out − 1 or 0).
    """
    if "intra.weight" not in arrays and "intra.bias" not in arrays:
        if meta.get("intra") not in (None, "none"):
            raise UserError(f"{source}: meta says intra {meta['intra']!r} but the bundle has no intra arrays")
        return None
    weight, scale = _weight(arrays, "intra.weight", (populations, size, size), source)
    bias = _array(arrays, "intra.bias", (populations, size), source).reshape(-1)
    eye = np.eye(size, dtype=bool)
    if meta.get("intra") is not None:
        keep_self, keep_lateral, _ = INTRA_MASKS[meta["intra"]]
    else:
        keep_self = bool(np.any(weight[:, eye]))
        keep_lateral = bool(np.any(weight[:, ~eye]))
    keep = (eye & keep_self) | (~eye & keep_lateral)  # keep[post, pre]
    width = populations * size
    rows = np.zeros((width, width), weight.dtype)  # rows[pre, post]
    for m in range(populations):
        block = slice(m * size, (m + 1) * size)
        rows[block, block] = np.where(keep, weight[m], 0).T
    return Synapses("Intra FC", rows, None, scale, bias, width, int(keep[:, 0].sum()))


def _decoder(arrays: Mapping[str, np.ndarray], populations: int, size: int, source: str) -> Synapses:
    """Group FC: output neuron j of population m = j // P_out adds W_D[m, j mod P_out] into LI neuron m."""
    weight, scale = _weight(arrays, "decoder.weight", (populations, size), source)
    bias = _array(arrays, "decoder.bias", (populations,), source)
    targets = np.repeat(np.arange(populations), size)[:, None]
    return Synapses("Group FC", weight.reshape(-1, 1), targets, scale, bias, populations, 1)
