"""Firing rates, operation counts and energy per inference (Section V-F; Tables fr, op and power).

The model
---------
For a fully-connected layer (Din, Dout) the paper counts Din·Dout FLOP for an ANN and
T·fr_in·Din·Dout SOP for an SNN, with fr_in the average firing rate of the neuronal layer feeding
it, measured by running the trained actor for one episode (batch 1, the deterministic policy).
Energy = FLOP · 12.5 pJ (FPGA, Intel Stratix 10 TX) + SOP · 77 fJ (ROLLS). A second column uses the
45 nm CMOS figures (Horowitz 2014: 4.6 pJ per 32-bit float multiply-accumulate, 0.9 pJ per float
accumulate), counting one FLOP as one MAC and one SOP as one AC.

Layers: FC1 (N·P_in, H_1), FC2 … FC_L (hidden), FC_{L+1} (H_L, M·P_out) — FC3 for the paper's 2×256 —
Group FC (M groups of (P_out, 1): M·P_out synapses) and Intra FC (M groups of (P_out, P_out)).

What each input costs (our choices, following the paper):

* spikes in (encoder ``pop-det``/``pop-prob``, every CLIF/dynamic layer): SOP = T·fr_in·synapses,
  i.e. exactly the accumulates of the spikes (each spike reaches its fan-out once). Measured rates
  averaged over an episode make this the average number of accumulates per inference; the
  additions-only runtime (:mod:`ilcsan.deploy`) counts the same number event by event (tested).
* analog input to a spiking layer (encoders ``pop``, ``layer``, ``two-neuron`` feed FC1 the same real
  vector at every step): FLOP = T·Din·Dout. The paper does not print this case, but Section V-F argues
  that MDC-SAN's FC1 "considering the simulation time T" costs more than DAN, i.e. FC1 is charged at
  every step (as the authors' code computes it). A host that caches the product would pay Din·Dout once.
* firing rates in (PopSAN's decoder ``fr``: group FC on (1/T)·Σ_t S_t): FLOP = Din·Dout = M·P_out,
  evaluated once per inference — the stated formula and what Table power charges (see below).
* DAN: Din·Dout FLOP per layer, 256·(N + 256 + M) for the paper's actor; Ant 96 000 FLOP = 1200.0 nJ.
* Intra FC: synapses = the connections its ablation mask keeps (full M·P², ``self`` M·P, ``lateral``
  M·P(P−1), ``bias``/``none`` 0; a bias is a constant current, never a synaptic operation — biases
  are not counted anywhere, as in the paper).

The Intra FC rate (verified against the authors' released code)
---------------------------------------------------------------
The intra-layer connections act on the output spikes of steps t = 1..T−1 (they feed I_2..I_T). The
authors' ``get_each_layer_fire_rate_and_forward`` (lucifer2859/ILC-SAN, ``popsan.py``) adds
mean(S_t)/T for t ≠ T only, so Table fr's Intra FC rate is *spikes of steps 1..T−1 divided by
T·M·P_out* — not divided by (T−1)·M·P_out. With that rate T·fr·M·P² is the exact accumulate count,
and Table op's Intra FC entries follow: Ant 5 · 0.315 · 8 · 10 · 10 = 1260 SOP (HalfCheetah 921,
Hopper 492, Walker2d 1110, all exact). We report the rate in the same convention
(:attr:`MeasuredRates.rates` ``"Intra FC"``); the rate over the T−1 steps it acts on is
fr·T/(T−1) (e.g. 31.5 % → 39.4 %).

Checks against the paper (tests/test_energy.py)
-----------------------------------------------
Feeding Table fr (rounded to 0.1 %) into this model reproduces Table op: ILC-SAN HalfCheetah, Hopper
and Walker2d exactly per layer after rounding to an integer; every other SNN entry within 0.3 % except
ILC-SAN Ant FC1 (formula 39 782 vs printed 40 351, −1.4 %): a 2.8 % rate rounded to 0.1 % is only
known to ±1.8 %, and 40 351 means 2.84 %. Every DAN and ILC-SAN energy of Table power follows to its
printed precision (Ant ILC-SAN 208 278 SOP · 77 fJ = 16.04 → 16.0 nJ).

PopSAN's Group FC discrepancy: Table op prints PopSAN's Group FC as T·fr·Din·Dout "FLOP"
(Ant 336 = 5 · 0.839 · 80, HalfCheetah 208, Hopper 69, Walker2d 158), but Table power charges it as
Din·Dout = M·P_out FLOP: Ant 229 463 SOP · 77 fJ + 80 FLOP · 12.5 pJ = 17.67 + 1.00 = 18.7 nJ as printed,
whereas the Table op figure would give 17.67 + 4.20 = 21.9 nJ. Likewise HalfCheetah 15.5 (vs 17.4),
Hopper 22.6 (vs 23.1), Walker2d 20.8 (vs 22.0). The firing rate is a real number computed once per
inference, so its FC is Din·Dout FLOP: we follow the stated formula and Table power.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from ..config import INTRA_MASKS, SPIKING_ENCODERS, ActorConfig, actor_config
from ..errors import UserError
from ..paper.published import ENERGY_PER_FLOP_PJ, ENERGY_PER_SOP_PJ, FIRING_RATES, TASKS
from ..rl import evaluation
from ..rl.tasks import trained_contact_forces
from ..runtime.synapses import GROUP_FC, INTRA_FC, fc_name

INTRA_SYNAPSES_PER_POPULATION = {  # (self, lateral) kept → synapses of one P×P block
    (True, True): lambda p: p * p, (True, False): lambda p: p, (False, True): lambda p: p * (p - 1),
    (False, False): lambda p: 0,
}


class EnergyCosts(NamedTuple):
    """Energy of one FLOP (a multiply-accumulate) and one SOP (an accumulate), in picojoule."""

    name: str
    flop_pj: float
    sop_pj: float


PAPER_COSTS = EnergyCosts("FPGA 12.5 pJ/FLOP + ROLLS 77 fJ/SOP (paper)", ENERGY_PER_FLOP_PJ, ENERGY_PER_SOP_PJ)
CMOS_45NM = EnergyCosts("45 nm CMOS: 4.6 pJ/MAC, 0.9 pJ/AC", 4.6, 0.9)
COSTS = (PAPER_COSTS, CMOS_45NM)


class SynapticLayer(NamedTuple):
    """One fully-connected layer of Section V-F.

    ``input_kind``: ``spikes`` (SOP = T·fr·synapses), ``analog`` (real vector at every step:
    FLOP = T·synapses), ``rates`` (firing rates once: FLOP = synapses), ``dense`` (ANN: FLOP = synapses).
    """

    name: str
    shape: str
    synapses: int
    input_kind: str


class LayerCount(NamedTuple):
    """Operations per inference of one layer, and the firing rate of its input (None if not spikes)."""

    name: str
    shape: str
    input_kind: str
    rate: float | None
    sop: float
    flop: float


class MeasuredRates(NamedTuple):
    """Average firing rate of the neuronal layer feeding each synaptic layer, and how many inferences."""

    rates: dict[str, float]
    inferences: int


@dataclass(frozen=True)
class EnergyReport:
    """Operation counts and energy per inference of one actor on one task."""

    label: str
    task: str
    state_dim: int
    action_dim: int
    timesteps: int
    layers: tuple[LayerCount, ...]
    inferences: int = 0
    source: str = ""
    runs: int = 1
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def total_sop(self) -> float:
        return float(sum(layer.sop for layer in self.layers))

    @property
    def total_flop(self) -> float:
        return float(sum(layer.flop for layer in self.layers))

    def energy_nj(self, costs: EnergyCosts = PAPER_COSTS) -> float:
        """Energy per inference in nanojoule: (FLOP · E_FLOP + SOP · E_SOP) / 1000."""
        return (self.total_flop * costs.flop_pj + self.total_sop * costs.sop_pj) / 1000.0

    def to_dict(self) -> dict[str, Any]:
        return {"label": self.label, "task": self.task, "state_dim": self.state_dim,
                "action_dim": self.action_dim, "timesteps": self.timesteps, "inferences": self.inferences,
                "source": self.source, "runs": self.runs,
                "layers": [layer._asdict() for layer in self.layers],
                "total_sop": self.total_sop, "total_flop": self.total_flop,
                "energy_nj": {costs.name: self.energy_nj(costs) for costs in COSTS}}


# ------------------------------------------------------------------------------------ structure
def fc_names(count: int) -> list[str]:
    """FC1 … FC<count> (the paper's names for the backbone's synaptic layers)."""
    return [fc_name(index) for index in range(count)]


def intra_synapses(intra: str, populations: int, population_size: int) -> int:
    """Synapses of the Intra FC under an ablation mask (biases are not synapses)."""
    mask = INTRA_MASKS[intra]
    per_population = INTRA_SYNAPSES_PER_POPULATION[(mask.self_weights, mask.lateral_weights)]
    return populations * per_population(population_size)


def synaptic_layers(config: ActorConfig, state_dim: int, action_dim: int) -> tuple[SynapticLayer, ...]:
    """The synaptic layers of an actor, with shapes and input kinds, in the paper's order; the backbone's
    widths are :meth:`ActorConfig.layer_sizes` (the encoder's output width first)."""
    sizes = config.layer_sizes(state_dim, action_dim)
    if config.network == "deep":
        return tuple(SynapticLayer(name, f"({a}, {b})", a * b, "dense")
                     for name, a, b in zip(fc_names(len(sizes) - 1), sizes[:-1], sizes[1:], strict=True))
    out = sizes[-1]
    layers = []
    for index, (name, a, b) in enumerate(zip(fc_names(len(sizes) - 1), sizes[:-1], sizes[1:], strict=True)):
        kind = "spikes" if index > 0 or config.encoder in SPIKING_ENCODERS else "analog"
        layers.append(SynapticLayer(name, f"({a}, {b})", a * b, kind))
    p = config.population_out
    layers.append(SynapticLayer(GROUP_FC, f"{action_dim}×({p}, 1)", out,
                                "rates" if config.decoder == "fr" else "spikes"))
    if config.intra != "none":
        layers.append(SynapticLayer(INTRA_FC, f"{action_dim}×({p}, {p})",
                                    intra_synapses(config.intra, action_dim, p), "spikes"))
    return tuple(layers)


def count_operations(layers: Sequence[SynapticLayer], rates: Mapping[str, float | None],
                     timesteps: int) -> tuple[LayerCount, ...]:
    """Section V-F per layer: SOP = T·fr·synapses for spikes, FLOP = T·synapses for analog input,
    FLOP = synapses for firing-rate input and ANN layers."""
    counts = []
    for layer in layers:
        rate = rates.get(layer.name)
        if layer.input_kind == "spikes":
            if rate is None:
                raise UserError(f"no firing rate for {layer.name}: measure the actor first")
            counts.append(LayerCount(layer.name, layer.shape, layer.input_kind, float(rate),
                                     timesteps * float(rate) * layer.synapses, 0.0))
        elif layer.input_kind == "analog":
            counts.append(LayerCount(layer.name, layer.shape, layer.input_kind, None, 0.0,
                                     float(timesteps * layer.synapses)))
        else:  # rates (PopSAN's group FC on firing rates) or dense (ANN)
            counts.append(LayerCount(layer.name, layer.shape, layer.input_kind, rate, 0.0, float(layer.synapses)))
    return tuple(counts)


# ---------------------------------------------------------------------------------- measurement
class _SpikeTally:
    """Running sums of spikes and neuron-steps per layer over many forward passes."""

    def __init__(self, names: Sequence[str], has_intra: bool):
        self.names, self.has_intra = list(names), has_intra
        self.spikes: dict[str, float] = {}
        self.slots: dict[str, float] = {}
        self.inferences = 0

    def _add(self, name: str, spikes: float, slots: float) -> None:
        self.spikes[name] = self.spikes.get(name, 0.0) + spikes
        self.slots[name] = self.slots.get(name, 0.0) + slots

    def add(self, output) -> None:
        """Add one :class:`~ilcsan.snn.actor.ActorOutput` of ensemble size 1 (any batch)."""
        for name, inputs in zip(self.names, output.layer_inputs, strict=True):
            if inputs.dim() == 4:  # (K, T, B, D) spikes; (K, B, D) is an analog input
                self._add(name, float(inputs[0].double().sum()), float(inputs[0].numel()))
        spikes = output.output_spikes[0].double()  # (T, B, M·P)
        self._add(GROUP_FC, float(spikes.sum()), float(spikes.numel()))
        if self.has_intra:  # steps 1..T−1 feed I_2..I_T; ÷ T·B·M·P as the authors' code (module doc)
            self._add(INTRA_FC, float(spikes[:-1].sum()), float(spikes.numel()))
        self.inferences += int(spikes.shape[1])

    def rates(self) -> MeasuredRates:
        return MeasuredRates({name: self.spikes[name] / self.slots[name] for name in self.spikes},
                             self.inferences)


def _tally_for(policy) -> _SpikeTally:
    config = policy.actor_config
    if config.network == "deep":
        raise UserError("a deep actor (DAN) has no spikes: its cost is FLOP only, no firing rates to measure")
    return _SpikeTally(fc_names(len(config.hidden) + 1), config.intra != "none")


def measure_firing_rates(policy, observations: np.ndarray) -> MeasuredRates:
    """Average firing rates of a spiking policy over the given raw observations (B, N), one batch."""
    tally = _tally_for(policy)
    tally.add(policy.run(np.asarray(observations, dtype=np.float64)))
    return tally.rates()


def firing_rates(policy, task: str | None = None, episodes: int = 1, seed: int = 0) -> MeasuredRates:
    """Table fr: run the deterministic policy for ``episodes`` episodes at batch 1 and average the firing
    rate of every neuronal layer feeding a synaptic layer over all steps (the paper: one episode)."""
    if episodes < 1:
        raise UserError(f"--episodes must be at least 1, got {episodes}")
    tally = _tally_for(policy)

    def act(observation: np.ndarray) -> np.ndarray:
        output = policy.run(observation)
        tally.add(output)
        return output.action[0, 0].numpy()

    evaluation.run_episodes(act, task or policy.task, episodes, seed,
                            contact_forces=trained_contact_forces(policy))
    return tally.rates()


def energy_report(policy, rates: MeasuredRates | None = None, source: str = "") -> EnergyReport:
    """Operation counts and energy of ``policy`` from measured ``rates`` (None for a DAN)."""
    config = policy.actor_config
    layers = synaptic_layers(config, policy.state_dim, policy.action_dim)
    measured = {} if rates is None else rates.rates
    counts = count_operations(layers, measured, config.timesteps)
    return EnergyReport(config.preset, policy.task, policy.state_dim, policy.action_dim, config.timesteps,
                        counts, 0 if rates is None else rates.inferences, source)


def measure_energy(policy, episodes: int = 1, seed: int = 0, task: str | None = None,
                   source: str = "") -> EnergyReport:
    """Firing rates over ``episodes`` episodes (none for a DAN), then :func:`energy_report`."""
    rates = None if policy.actor_config.network == "deep" else firing_rates(policy, task, episodes, seed)
    return energy_report(policy, rates, source)


# -------------------------------------------------------------------------------- paper figures
def analytic_report(preset: str, task: str, state_dim: int, action_dim: int,
                    rates: Mapping[str, float] | None = None, source: str = "") -> EnergyReport:
    """A report from given rates (or none for DAN) for a preset's paper configuration."""
    config = actor_config(preset)
    layers = synaptic_layers(config, state_dim, action_dim)
    counts = count_operations(layers, dict(rates or {}), config.timesteps)
    return EnergyReport(preset, task, state_dim, action_dim, config.timesteps, counts, 0, source)


def paper_report(preset: str, task: str) -> EnergyReport:
    """The paper's Table fr rates for ``preset`` (popsan, ilc-san; dan needs none) on a paper task."""
    dims = TASKS[task]
    if preset == "dan":
        return analytic_report("dan", task, dims.n, dims.m, source="paper")
    row = FIRING_RATES[preset][task]
    rates = {fc_name(0): row.fc1, fc_name(1): row.fc2, fc_name(2): row.fc3, GROUP_FC: row.group_fc}
    if row.intra_fc is not None:
        rates[INTRA_FC] = row.intra_fc
    return analytic_report(preset, task, dims.n, dims.m, rates, source="paper")
