"""Typed configuration of an actor and its presets (one mechanism with switches).

An :class:`ActorConfig` describes an actor completely; saved with a checkpoint it is enough to rebuild
the actor anywhere, including in the deploy runtime. Presets set every switch at once:

``ilc-san``  the paper's final configuration: E_pop_det, CLIF 2×256, full intra-layer connections,
             D_last with α_V^LI = 1.0 (Tables perf/dec_intra/intra).
``popsan``   Tang et al. 2021: E_pop_det, CLIF, no intra-layer connections, firing-rate decoder D_fr.
``mdc-san``  Zhang et al. 2022: E_pop (analog), MDC-SAN's dynamic neurons, D_fr.
``akl``      Akl et al. 2023 (a faithful-enough variant, see README): two-neuron analog input,
             hidden (400, 300), α_C = α_V = 0.5, output populations read by a non-leaky integrator
             (D_last, α_V^LI = 1) and tanh.
``dan``      TD3's deep actor network: (N, 256, ReLU, 256, ReLU, M, tanh), learning rate 1e-3.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from .errors import UserError

# ------------------------------------------------------------------------------ the choice lists
ENCODERS: tuple[str, ...] = ("pop-det", "pop-prob", "pop", "layer", "two-neuron")
SPIKING_ENCODERS: tuple[str, ...] = ("pop-det", "pop-prob")
DECODERS: tuple[str, ...] = ("last", "max", "mean", "fr")
NEURONS: tuple[str, ...] = ("clif", "dynamic")
NETWORKS: tuple[str, ...] = ("spiking", "deep")
ENGINES: tuple[str, ...] = ("fast", "reference")
"""The actor's forward passes: layer-major (fast, default) and the literal Algorithm-1 time loop (reference)."""
COMPILE_MODES: tuple[str, ...] = ("auto", "on", "off")
# --matmul → torch's float32 matmul precision. "bf16" lets oneDNN round a float32 matmul's inputs to bfloat16
# and accumulate in float32 (AMX / AVX512-BF16 CPUs; elsewhere it stays float32); on CUDA torch then uses
# TF32/bf16 tensor cores. Neuron states, spikes, losses and optimiser stay float32 either way.
MATMUL_PRECISIONS = {"float32": "highest", "bf16": "medium"}


class IntraMask(NamedTuple):
    """Which parts of I_intra = I_self + I_lateral + I_bias are kept (Eq. (10), Table intra)."""

    self_weights: bool
    lateral_weights: bool
    bias: bool


INTRA_MASKS: dict[str, IntraMask] = {
    "intra": IntraMask(True, True, True),
    "self": IntraMask(True, False, False),
    "lateral": IntraMask(False, True, False),
    "bias": IntraMask(False, False, True),
    "lateral+bias": IntraMask(False, True, True),
    "self+bias": IntraMask(True, False, True),
    "self+lateral": IntraMask(True, True, False),
    "none": IntraMask(False, False, False),
}
"""Every intra-layer variant as a mask on one mechanism; ``none`` keeps nothing (no intra-layer module)."""
INTRA_VARIANTS: tuple[str, ...] = tuple(INTRA_MASKS)


@dataclass(frozen=True)
class ActorConfig:
    """Every switch of an actor. Field docs double as the CLI's help text."""

    preset: str = "ilc-san"
    network: str = "spiking"  # spiking | deep (DAN)
    encoder: str = "pop-det"  # pop-det | pop-prob | pop | layer | two-neuron
    neuron: str = "clif"  # clif | dynamic (MDC-SAN)
    hidden: tuple[int, ...] = (256, 256)  # hidden layer widths (1-4 layers)
    intra: str = "intra"  # intra | self | lateral | bias | lateral+bias | self+bias | self+lateral | none
    decoder: str = "last"  # last | max | mean | fr
    alpha_v_li: float = 1.0  # voltage decay α_V^LI of the decoder's LI neuron
    timesteps: int = 5  # simulation time T per action
    population_in: int = 10  # encoder neurons per state dimension P_in
    population_out: int = 10  # output neurons per action dimension P_out
    alpha_c: float = 0.5  # CLIF current decay α_C
    alpha_v: float = 0.75  # CLIF voltage decay α_V^CLIF
    v_th: float = 0.5  # CLIF threshold V_th
    surrogate_width: float = 0.5  # rectangular surrogate window w
    enc_v_th: float = 0.999  # threshold of the encoder's soft-reset IF neurons
    learning_rate: float = 1e-4  # actor learning rate (DAN 1e-3)

    @property
    def fully_spiking(self) -> bool:
        """True when no floating-point matrix operation is needed at inference (Section III)."""
        return self.network == "spiking" and self.encoder in SPIKING_ENCODERS and self.decoder != "fr"

    def encoded_width(self, state_dim: int) -> int:
        """What the encoder hands to FC1 for an N-dimensional state: N·P_in neurons for the population
        encoders (Eq. (9)), 2N channels for the two-neuron input, N for E_layer and DAN."""
        if self.network == "spiking" and self.encoder.startswith("pop"):
            return state_dim * self.population_in
        return state_dim * (2 if self.network == "spiking" and self.encoder == "two-neuron" else 1)

    def layer_sizes(self, state_dim: int, action_dim: int) -> list[int]:
        """Input and output widths of the synaptic layers in order: [FC1 in, hidden..., last out], the last
        being the M·P_out output neurons of a spiking actor or the M actions of DAN."""
        outputs = action_dim * (self.population_out if self.network == "spiking" else 1)
        return [self.encoded_width(state_dim), *self.hidden, outputs]

    def to_dict(self) -> dict[str, Any]:
        data = dataclasses.asdict(self)
        data["hidden"] = list(self.hidden)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ActorConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise UserError(f"unknown actor setting(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
        values = dict(data)
        if "hidden" in values:
            values["hidden"] = tuple(int(width) for width in values["hidden"])
        return validate(cls(**values))


PRESETS: dict[str, dict[str, Any]] = {
    "ilc-san": {},
    "popsan": {"intra": "none", "decoder": "fr"},
    "mdc-san": {"encoder": "pop", "neuron": "dynamic", "intra": "none", "decoder": "fr"},
    "akl": {"encoder": "two-neuron", "hidden": (400, 300), "alpha_c": 0.5, "alpha_v": 0.5,
            "intra": "none", "decoder": "last", "alpha_v_li": 1.0},
    "dan": {"network": "deep", "learning_rate": 1e-3, "encoder": "layer", "intra": "none",
            "decoder": "last"},
}

PRESET_NAMES: tuple[str, ...] = tuple(PRESETS)

PRESET_SUMMARIES = {
    "ilc-san": "ILC-SAN (the paper): E_pop_det, CLIF, intra-layer connections, LI decoder D_last",
    "popsan": "PopSAN (Tang et al. 2021): E_pop_det, CLIF, firing-rate decoder",
    "mdc-san": "MDC-SAN (Zhang et al. 2022): E_pop analog input, dynamic neurons, firing-rate decoder",
    "akl": "Akl et al. 2023 (variant): two-neuron analog input, CLIF 400-300, integrator readout",
    "dan": "DAN: TD3's deep actor (N, 256, ReLU, 256, ReLU, M, tanh)",
}


def _choice(name: str, value: Any, choices: tuple[str, ...] | dict) -> None:
    if value not in choices:
        raise UserError(f"--{name.replace('_', '-')} {value!r} is not one of: {', '.join(choices)}")


def validate(config: ActorConfig) -> ActorConfig:
    """Raise :class:`UserError` with one sentence for any impossible switch value."""
    _choice("preset", config.preset, PRESETS)
    _choice("network", config.network, NETWORKS)
    _choice("encoder", config.encoder, ENCODERS)
    _choice("neuron", config.neuron, NEURONS)
    _choice("intra", config.intra, INTRA_VARIANTS)
    _choice("decoder", config.decoder, DECODERS)
    if not 1 <= len(config.hidden) <= 4:
        raise UserError(f"the backbone needs 1 to 4 hidden layers, got {len(config.hidden)}")
    if any(width < 1 for width in config.hidden):
        raise UserError(f"hidden layer widths must be at least 1, got {list(config.hidden)}")
    for name in ("timesteps", "population_in", "population_out"):
        if getattr(config, name) < 1:
            raise UserError(f"--{name.replace('_', '-')} must be at least 1, got {getattr(config, name)}")
    for name in ("alpha_c", "alpha_v", "alpha_v_li"):
        value = getattr(config, name)
        if not (math.isfinite(value) and 0.0 <= value <= 1.0):
            raise UserError(f"--{name.replace('_', '-')} is a decay factor in [0, 1], got {value}")
    for name in ("v_th", "surrogate_width", "enc_v_th", "learning_rate"):
        value = getattr(config, name)
        if not (math.isfinite(value) and value > 0):
            raise UserError(f"--{name.replace('_', '-')} must be a positive number, got {value}")
    return config


def actor_config(preset: str = "ilc-san", **overrides: Any) -> ActorConfig:
    """The preset's configuration with ``overrides`` applied (None values are ignored).

    ``hidden_layers`` and ``hidden_width`` are accepted as a shorthand for ``hidden``.
    """
    if preset not in PRESETS:
        raise UserError(f"unknown actor preset {preset!r}; choose one of: {', '.join(PRESETS)}")
    values: dict[str, Any] = {"preset": preset, **PRESETS[preset]}
    overrides = {key: value for key, value in overrides.items() if value is not None}
    layers = overrides.pop("hidden_layers", None)
    width = overrides.pop("hidden_width", None)
    if layers is not None or width is not None:
        base = overrides.get("hidden", values.get("hidden", ActorConfig.hidden))
        layers = len(base) if layers is None else int(layers)
        width = base[0] if width is None else int(width)
        if layers < 1 or layers > 4:
            raise UserError(f"--hidden-layers must be 1 to 4, got {layers}")
        overrides["hidden"] = (width,) * layers
    known = {f.name for f in dataclasses.fields(ActorConfig)}
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise UserError(f"unknown actor switch(es) {', '.join(unknown)}")
    values.update(overrides)
    if "hidden" in values:
        values["hidden"] = tuple(int(w) for w in values["hidden"])
    return validate(ActorConfig(**values))


@dataclass(frozen=True)
class TD3Config:
    """TD3 hyper-parameters of the paper (Section IV-A) and the authors' code."""

    gamma: float = 0.99  # reward discount
    tau: float = 0.005  # soft target update factor
    batch_size: int = 100
    replay_size: int = 1_000_000
    critic_lr: float = 1e-3
    critic_hidden: tuple[int, ...] = (256, 256)
    exploration_noise: float = 0.1  # stddev, relative to the action half-range
    target_noise: float = 0.2  # target policy smoothing stddev, relative to the action half-range
    noise_clip: float = 0.5
    policy_delay: int = 2
    start_steps: int = 10_000  # uniformly random actions before the actor acts
    update_after: int = 1_000  # first update at this step
    update_every: int = 50  # updates run in chunks of this many (one per environment step)

    def to_dict(self) -> dict[str, Any]:
        data = dataclasses.asdict(self)
        data["critic_hidden"] = list(self.critic_hidden)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TD3Config:
        values = dict(data)
        if "critic_hidden" in values:
            values["critic_hidden"] = tuple(values["critic_hidden"])
        return cls(**values)


@dataclass(frozen=True)
class RunConfig:
    """Everything that defines a training run."""

    task: str = "Hopper"
    seeds: tuple[int, ...] = (0,)
    steps: int = 1_000_000  # environment steps per seed
    eval_every: int = 10_000
    eval_episodes: int = 10
    actor: ActorConfig = field(default_factory=ActorConfig)
    td3: TD3Config = field(default_factory=TD3Config)
    device: str = "cpu"
    engine: str = "fast"  # fast | reference
    threads: int | None = None  # torch threads; None: torch's default
    compile: str = "auto"  # torch.compile the networks: on | off | auto (on for runs of 50 000 steps or more)
    matmul: str = "float32"  # float32 | bf16 (matmul inputs rounded to bfloat16, float32 accumulation; see below)
    label: str | None = None  # row label in reports (default: the preset)
    table: str | None = None  # set by `ilcsan reproduce`
    row: str | None = None  # set by `ilcsan reproduce`

    def for_seed(self, seed: int) -> dict[str, Any]:
        """The config.json of one seed's run."""
        data = dataclasses.asdict(self)
        data.update(seed=seed, seeds=[seed], actor=self.actor.to_dict(), td3=self.td3.to_dict(),
                    label=self.label or self.actor.preset)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RunConfig:
        values = {key: value for key, value in data.items() if key in {f.name for f in dataclasses.fields(cls)}}
        values["actor"] = ActorConfig.from_dict(data["actor"])
        values["td3"] = TD3Config.from_dict(data["td3"])
        values["seeds"] = tuple(data.get("seeds", [data.get("seed", 0)]))
        return cls(**values)
