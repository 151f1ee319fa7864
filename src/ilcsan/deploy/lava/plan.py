"""A deployed actor as a network of Lava processes, planned in numpy: what runs on Loihi 2 and when.

Lava (Intel's SDK for Loihi 2) runs processes in lock step. The ones used here, as Lava 0.10's process models define
them (checked against their source):

* ``RingBuffer`` (the host's input): sends column (τ − 1) mod B of its data at step τ.
* ``Dense``: at step τ sends W · s(τ − 1), the spikes it received at the step before (one step of delay).
* ``LIF``: u ← u (1 − du) + a_in; v ← v (1 − dv) + u + bias; s = [v > v_th]; v ← 0 where s.

With du = 1 − α_C, dv = 1 − α_V and V_reset = 0 this is the paper's CLIF (Algorithm 1): C_t = α_C C_{t−1} + X_t,
H_t = α_V V_{t−1} + C_t, S_t = Θ(H_t − V_th), hard reset (Lava fires on v > v_th, Algorithm 1 on H ≥ V_th: equal
unless a voltage lands exactly on the threshold). Lava's floating-point models compute in float64, PyTorch and the
numpy runtime in float32: a voltage within float32 rounding of V_th (≈ 1e-7) can spike in one and not the other.
The LI readout (Eq. (7)) is an LIF with du = 1 (u = a_in, no memory), dv = 1 − α_V^LI and a threshold never
reached.

Timing. Synaptic layer l (1..n, n = L + 1, the output layer last) computes its step t at Lava step τ = t + l: each
Dense adds one step, which only shifts the pipeline. A layer's bias b^l is part of its input current X_t (it decays
in C with α_C), so it cannot be the LIF's ``bias`` (added to v): it arrives as a current through a Dense from a
*clock* channel of the input that is on exactly at the layer's T steps (emitted at τ = t + l − 1). The same clocks
carry b_intra (from the output layer's step 2 with Algorithm 1's timing; from step 1 with the authors', where it
simply joins b^n) and the decoder's b_D. The intra-layer connections are a recurrent Dense from the output layer to
itself: its one step of delay is Eq. (10)'s I_{t+1} = W_intra S_t. The LI neuron's voltage at τ = t + n + 1 is V_t.
One action takes a block of B = T + n + 1 steps, after which every state (u, v and the Dense buffers) is set back to
zero, so each action starts from Algorithm 1's V_0 = C_0 = 0.

Fixed point (Loihi 2's bit-accurate model, :class:`FixedPlan`): each population has a unit q (the float value of one
integer step of its input), chosen from the threshold: V_th = v_th_int · q with v_th_int a power of two as large as
the calibrated range of its states allows (u and v are 24-bit, the input and threshold shifted left by 6); each Dense
has 8-bit weights w (even, in [−256, 254], Lava's mixed-sign format) and an exponent e with W ≈ w · 2^e · q; decays
are 12-bit (du = 2047 gives 1 − (du + 1)/4096 = 0.5, dv = 1024 gives 0.75). :func:`simulate` runs a plan, float or
fixed, with exactly these rules in numpy: the tests hold it against Lava itself where Lava is installed and against
the numpy runtime everywhere.

This module needs numpy only (and Python 3.10, like Lava); :mod:`.network` builds the Lava processes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...runtime import DeployedActor
from ...runtime.errors import UserError
from ...runtime.host import select_statistic, squash

INPUT = "input"
"""The host's source of each block: the encoder's spikes and the clock channels."""
DECODER = "decoder"
"""The LI readout population (M neurons)."""
NEVER = np.inf
"""The threshold of a population that never spikes (the LI readout)."""

# Loihi 2's fixed-point formats, as Lava 0.10's bit-accurate models implement them
DECAY_BITS = 12
STATE_SHIFT = 6
"""Incoming activation and the threshold are shifted left by this many bits before they meet u and v."""
STATE_LIMIT = 2 ** 23
"""u and v are 24-bit signed: |u| wraps, |v| clips below this."""
WEIGHT_LIMITS = (-256, 254)
"""8-bit mixed-sign weights as Lava's Dense stores them: even numbers in this range."""
EXPONENT_LIMITS = (-8, 7)
"""The range of a Dense's weight exponent."""
THRESHOLD_LIMIT = 2 ** 17 - 1
"""v_th is a 17-bit unsigned integer."""


@dataclass(frozen=True)
class Population:
    """A population of LIF neurons: its size, decays (du, dv) and threshold (``NEVER``: the LI readout)."""

    name: str
    size: int
    du: float
    dv: float
    threshold: float


@dataclass(frozen=True)
class Projection:
    """A Dense from ``source`` (a population or :data:`INPUT`) to ``target``: weights (target size, source size)."""

    source: str
    target: str
    weights: np.ndarray


@dataclass(frozen=True)
class Plan:
    """The float network of one actor: populations in pipeline order (layers 1..n, then the decoder), projections,
    the input's clock channels for one block, and where the readout is."""

    populations: tuple[Population, ...]
    projections: tuple[Projection, ...]
    encoded_width: int
    clocks: np.ndarray
    """(clock channels, B) 0/1: the input's rows after the encoder's, the same in every block."""
    timesteps: int
    readout_steps: tuple[int, ...]
    """The Lava steps (1-based, within a block) after which the LI voltage is V_1..V_T."""

    @property
    def block(self) -> int:
        return self.clocks.shape[1]

    @property
    def channels(self) -> int:
        return self.encoded_width + self.clocks.shape[0]

    def source(self, encoded: np.ndarray) -> np.ndarray:
        """The input's data for one block (channels, B): the encoder's spikes (T, D_0) at steps 1..T, then the
        clocks."""
        data = np.zeros((self.channels, self.block), np.float64)
        data[:self.encoded_width, :self.timesteps] = np.asarray(encoded, np.float64).T
        data[self.encoded_width:] = self.clocks
        return data


@dataclass(frozen=True)
class FixedPlan:
    """The same network in Loihi 2's integer formats: per population a unit q, integer decays and threshold; per
    projection 8-bit weights and an exponent (:mod:`this module's docstring <ilcsan.deploy.lava.plan>`)."""

    plan: Plan
    units: dict[str, float]
    du: dict[str, int]
    dv: dict[str, int]
    thresholds: dict[str, int]
    weights: tuple[np.ndarray, ...]
    exponents: tuple[int, ...]
    worst_weight_error: float = field(default=0.0)
    """The largest |W − w·2^e·q| over every projection, relative to that projection's largest |W|."""


# ---------------------------------------------------------------------------------------------------- plan
def plan_actor(actor: DeployedActor) -> Plan:
    """The float network of a deployed actor (a bundle read by the numpy runtime)."""
    meta = actor.meta
    if meta["neuron"] != "clif":
        raise UserError(f"neuron {meta['neuron']!r} (MDC-SAN's dynamic neuron) has no Loihi 2 process; a Lava "
                        "deployment needs CLIF actors")
    timesteps, layers = int(meta["T"]), actor.layers
    n = len(layers)
    neuron = actor.neuron
    populations = [Population(f"layer{index + 1}", layer.out_dim, 1.0 - neuron.alpha_current,
                              1.0 - neuron.alpha_voltage, neuron.threshold) for index, layer in enumerate(layers)]
    action_dim = actor.decoder.out_dim
    populations.append(Population(DECODER, action_dim, 1.0, 1.0 - float(meta["alpha_v_li"]), NEVER))
    block = timesteps + n + 1
    clock_rows: list[np.ndarray] = []
    projections: list[Projection] = []

    def clock(first: int, last: int) -> int:
        """A clock channel on at steps first..last; returns its index among the clocks."""
        row = np.zeros(block)
        row[first - 1:last] = 1.0
        clock_rows.append(row)
        return len(clock_rows) - 1

    biases = [np.asarray(layer.bias, np.float64) for layer in layers]
    intra = actor.intra
    authors_timing = meta.get("intra_timing", "paper") == "authors"
    if intra is not None and authors_timing:
        biases[-1] = biases[-1] + np.asarray(intra.bias, np.float64)
    bias_clocks = [clock(index + 1, index + timesteps) for index in range(n)]  # layer l: τ = t + l − 1
    decoder_clock = clock(n + 1, n + timesteps)  # arrives at τ = t + n + 1
    intra_clock = clock(n + 1, n + timesteps - 1) if intra is not None and not authors_timing else None
    clocks = np.array(clock_rows)
    encoded_width = layers[0].weights.shape[0]
    input_weights = {population.name: np.zeros((population.size, encoded_width + len(clock_rows)))
                     for population in populations}
    input_weights["layer1"][:, :encoded_width] = _dense(layers[0]).T
    for index, channel in enumerate(bias_clocks):
        input_weights[f"layer{index + 1}"][:, encoded_width + channel] = biases[index]
    if intra_clock is not None:
        input_weights[f"layer{n}"][:, encoded_width + intra_clock] = np.asarray(intra.bias, np.float64)
    input_weights[DECODER][:, encoded_width + decoder_clock] = np.asarray(actor.decoder.bias, np.float64)
    for population in populations:
        projections.append(Projection(INPUT, population.name, input_weights[population.name]))
    for index in range(1, n):
        projections.append(Projection(f"layer{index}", f"layer{index + 1}", _dense(layers[index]).T))
    if intra is not None:
        projections.append(Projection(f"layer{n}", f"layer{n}", _dense(intra).T))
    decoder = np.zeros((action_dim, layers[-1].out_dim))
    weights = _dense(actor.decoder)[:, 0]
    decoder[actor.decoder.targets[:, 0], np.arange(layers[-1].out_dim)] = weights
    projections.append(Projection(f"layer{n}", DECODER, decoder))
    readout = tuple(t + n + 1 for t in range(1, timesteps + 1))
    return Plan(tuple(populations), tuple(projections), encoded_width, clocks, timesteps, readout)


def _dense(synapses) -> np.ndarray:
    """A layer's weights as the runtime stores them, as floats (an int8 layer times its scale)."""
    weights = np.asarray(synapses.weights, np.float64)
    return weights * synapses.scale if synapses.scale is not None else weights


# ------------------------------------------------------------------------------------------------ host
def encoder_spikes(actor: DeployedActor, observation: np.ndarray) -> np.ndarray:
    """The host's side before the network: normaliser and encoder (the runtime's own) → spikes (T, D_0) as floats."""
    return actor.spike_trains(observation)[0].astype(np.float64)


def host_action(actor: DeployedActor, voltages: np.ndarray) -> np.ndarray:
    """The host's side after the network: LI voltages (T or 1, M) → the statistic O (Eq. (8)), tanh, the action."""
    output = select_statistic(np.asarray(voltages).astype(np.float32), str(actor.meta["statistic"]))
    return squash(output, actor.action_scale, actor.action_offset)


# ---------------------------------------------------------------------------------------------- simulate
def simulate(plan: Plan, encoded: np.ndarray, fixed: FixedPlan | None = None,
             record: bool = False) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """One block of Lava's rules (module docstring) in numpy, from zero state: encoder spikes (T, D_0) → the LI
    voltages V_1..V_T (T, M) in float units, and with ``record`` every population's spikes (B, size), peak |u|,
    |v| (in float units, ``"<name>.peak"``) and the largest |input| a population received (``"activation.peak"``;
    integer with ``fixed``, where Loihi 2 carries 16 bits). With ``fixed``, Loihi 2's integer formats (bit-accurate
    model)."""
    data = plan.source(encoded)
    names = [population.name for population in plan.populations]
    u = {name: np.zeros(population.size, np.int64 if fixed else np.float64) for name, population in
         zip(names, plan.populations, strict=True)}
    v = {name: value.copy() for name, value in u.items()}
    spikes = {name: np.zeros(population.size, bool) for name, population in zip(names, plan.populations, strict=True)}
    buffers = [np.zeros(projection.weights.shape[0], np.int64 if fixed else np.float64)
               for projection in plan.projections]
    trace: dict[str, np.ndarray] = {name: np.zeros((plan.block, size.size), bool) for name, size in
                                    zip(names, plan.populations, strict=True)}
    peaks = dict.fromkeys(names, 0.0)
    voltages, activation = [], 0.0
    for step in range(1, plan.block + 1):
        arriving = {name: np.zeros_like(u[name]) for name in names}
        for index, projection in enumerate(plan.projections):  # each Dense sends what it took in at the last step
            arriving[projection.target] += buffers[index]
        activation = max(activation, max(float(np.abs(value).max(initial=0)) for value in arriving.values()))
        for name, population in zip(names, plan.populations, strict=True):
            u[name], v[name], spikes[name] = _lif_step(population, u[name], v[name], arriving[name], fixed)
            if record:
                trace[name][step - 1] = spikes[name]
                scale = fixed.units[name] / 2 ** STATE_SHIFT if fixed else 1.0
                peaks[name] = max(peaks[name], float(np.abs(u[name]).max(initial=0)) * scale,
                                  float(np.abs(v[name]).max(initial=0)) * scale)
        emitted = data[:, step - 1] > 0  # the input sends column step − 1 at this step
        for index, projection in enumerate(plan.projections):  # and takes in this step's spikes for the next
            incoming = emitted if projection.source == INPUT else spikes[projection.source]
            buffers[index] = _dense_output(projection, index, incoming, fixed)
        if step in plan.readout_steps:
            scale = fixed.units[DECODER] / 2 ** STATE_SHIFT if fixed else 1.0
            voltages.append(v[DECODER] * scale)
    recorded = {**trace, **{f"{name}.peak": np.array(peak) for name, peak in peaks.items()},
                "activation.peak": np.array(activation)} if record else {}
    return np.array(voltages, np.float64), recorded


def _dense_output(projection: Projection, index: int, incoming: np.ndarray, fixed: FixedPlan | None) -> np.ndarray:
    if fixed is None:
        return projection.weights @ np.asarray(incoming, np.float64)
    accumulated = fixed.weights[index].astype(np.int64) @ np.asarray(incoming, np.int64)
    exponent = fixed.exponents[index]
    return accumulated << exponent if exponent >= 0 else accumulated >> -exponent


def _lif_step(population: Population, u: np.ndarray, v: np.ndarray, arriving: np.ndarray,
              fixed: FixedPlan | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if fixed is None:
        u = u * (1.0 - population.du) + arriving
        v = v * (1.0 - population.dv) + u
        fired = v > population.threshold
        return u, np.where(fired, 0.0, v), fired
    unity = 2 ** DECAY_BITS
    decayed = u * (unity - (fixed.du[population.name] + 1))
    decayed = np.sign(decayed) * (np.abs(decayed) >> DECAY_BITS)
    current = decayed + (arriving << STATE_SHIFT)
    current = np.where(current > STATE_LIMIT, current - 2 * STATE_LIMIT, current)
    current = np.where(current <= -STATE_LIMIT, current + 2 * STATE_LIMIT, current)
    decayed = v * (unity - fixed.dv[population.name])
    decayed = np.sign(decayed) * (np.abs(decayed) >> DECAY_BITS)
    voltage = np.clip(decayed + current, -STATE_LIMIT + 1, STATE_LIMIT - 1)
    fired = voltage > (fixed.thresholds[population.name] << STATE_SHIFT)
    return current, np.where(fired, 0, voltage), fired


# ------------------------------------------------------------------------------------------------- fixed
def fix_plan(plan: Plan, calibration: list[np.ndarray]) -> FixedPlan:
    """The plan in Loihi 2's integer formats. ``calibration``: encoder spike trains (T, D_0) of typical observations,
    whose float states set each population's range (its unit q keeps the largest state at most a quarter of the
    24-bit range)."""
    peaks = dict.fromkeys((population.name for population in plan.populations), 1e-9)
    for encoded in calibration:
        _, recorded = simulate(plan, encoded, record=True)
        for name in peaks:
            peaks[name] = max(peaks[name], float(recorded[f"{name}.peak"]))
    units, du, dv, thresholds = {}, {}, {}, {}
    headroom = (STATE_LIMIT >> STATE_SHIFT) / 4  # the largest state in units of q
    for population in plan.populations:
        name = population.name
        if population.threshold == NEVER:
            units[name] = peaks[name] / headroom
            thresholds[name] = THRESHOLD_LIMIT
        else:
            exponent = int(np.floor(np.log2(min(THRESHOLD_LIMIT, headroom * population.threshold / peaks[name]))))
            thresholds[name] = 2 ** max(exponent, 0)
            units[name] = population.threshold / thresholds[name]
        du[name] = int(round(population.du * 2 ** DECAY_BITS)) - 1  # Lava adds one to du (ds_offset)
        dv[name] = int(round(population.dv * 2 ** DECAY_BITS))
    weights, exponents, worst = [], [], 0.0
    low, high = WEIGHT_LIMITS
    for projection in plan.projections:
        unit = units[projection.target]
        largest = float(np.abs(projection.weights).max(initial=0.0))
        exponent = 0 if largest == 0 else min(EXPONENT_LIMITS[1], max(EXPONENT_LIMITS[0], int(np.ceil(
            np.log2(largest / (unit * high))))))
        step = unit * 2.0 ** exponent
        integers = np.clip(2 * np.round(projection.weights / (2 * step)), low, high).astype(np.int64)
        if largest > 0:
            worst = max(worst, float(np.abs(integers * step - projection.weights).max()) / largest)
        weights.append(integers)
        exponents.append(exponent)
    return FixedPlan(plan, units, du, dv, thresholds, tuple(weights), tuple(exponents), worst)
