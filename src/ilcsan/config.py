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

Every setting is a dataclass field whose metadata describes it once: its help, its choice list, its command-line
flag where that differs from the field name. :mod:`ilcsan.cli.options` generates the command line from this
metadata and :func:`check_settings` validates against it, so a switch, its default and its help cannot drift
apart.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Callable, Mapping
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
COMPILE_PAYS_AFTER_UPDATES: dict[str, int] = {"spiking": 4_000, "deep": 25_000}
"""``--compile auto`` compiles a run with at least this many TD3 updates (steps − update_after), by network: compiling
the update program and the acting pass costs tens of seconds once (less when inductor's cache holds them) and then
saves most of each update's time, so it repays itself after a few thousand updates of a spiking actor, and after more
of DAN's much cheaper ones (``benchmarks/RESULTS.md`` has the measurements behind these thresholds)."""
# --matmul: "bf16" computes in bfloat16 (float32 accumulation) the products that run faster so, measured at the
# start of a run (AMX / AVX512-BF16 CPUs; ilcsan.compute.matmul), and on CUDA lets torch use TF32/bf16 tensor cores.
# Neuron states, spikes, losses and optimiser stay float32 either way.
MATMUL_CHOICES: tuple[str, ...] = ("float32", "bf16")
EXPORT_FORMATS: dict[str, str] = {"npz": "deploy bundle for the numpy runtime",
                                  "nir": "a NIR graph for neuromorphic toolchains"}
"""``ilcsan export --format``, each with what it writes."""
WEIGHT_FORMATS: dict[str, str] = {"float32": "float32 weights", "int8": "int8 weights with a float32 scale per layer"}
"""``ilcsan export --weights``: the weight formats of a deploy bundle."""
NIR_TARGETS: dict[str, str] = {
    "portable": "the decoder's LI integrator on the host; runs in snnTorch, Norse and SpikingJelly",
    "generic": "the LI integrator in the graph",
    "sinabs": "for Sinabs 3.1.3 (nir <= 1.0.4): each CubaLIF as LI + LIF in steps; load with "
              "ilcsan.deploy.nir.consumers.sinabs_module",
}
"""``ilcsan export --target``: the profiles of a NIR graph."""
COLLAPSE_RETURN = 100.0
"""``ilcsan report --collapse``: an evaluation below this return counts as the collapsed start (Hopper's falls score
about 40)."""
BACKENDS: dict[str, str] = {"local": "a pool of worker processes on this machine", "ray": "a Ray cluster"}
"""``ilcsan reproduce --backend``: where a grid's runs execute."""
ALGORITHM_PAPERS: dict[str, str] = {
    "td3": "TD3 (Fujimoto, van Hoof, Meger, ICML 2018): twin critics, target policy smoothing, delayed actor "
           "updates; how the ILC-SAN paper trains every actor",
    "ddpg": "DDPG (Lillicrap et al., ICLR 2016) as TD3's paper re-implements it: one critic, no target policy "
            "smoothing, the actor and targets updated at every critic update",
    "sac": "SAC (Haarnoja et al. 2018, arXiv 1812.05905): the output populations decode a mean and a log-std of a "
           "tanh-squashed Gaussian, twin critics, automatic entropy tuning; acts deterministically when evaluated",
}
"""The off-policy algorithms that train an actor (``--algorithm``), each with its paper
(:mod:`ilcsan.rl.algorithms`)."""
TARGET_ACTOR_PAPERS: dict[str, str] = {
    "polyak": "the Polyak-averaged (soft-updated) copy of the actor (TD3, Fujimoto et al. 2018; the ILC-SAN paper)",
    "proxy": "Proxy Target: a continuous proxy fitted to the online actor (Xu et al., NeurIPS 2025, arXiv 2505.24161)",
}
"""The actor in TD3's target values (``--target-actor``), each with its paper; a registered method
(:func:`ilcsan.rl.methods.register_target_actor`) adds itself."""
EXPLORATION_PAPERS: dict[str, str] = {
    "gaussian": "Gaussian noise on the action (TD3, Fujimoto et al. 2018; the ILC-SAN paper)",
    "noisy": "NoisySAN: coloured noise in every spiking layer's charge and spike transmission and in the decoder, "
             "with a learned decoder noise scale (Chen et al., arXiv 2403.04162)",
}
"""How the actor explores during training (``--exploration``), each with its paper; evaluation is deterministic. A
registered method (:func:`ilcsan.rl.methods.register_exploration`) adds itself."""
CONTACT_FORCES: dict[str, str] = {
    "zeroed": "as the paper's simulator (mujoco-py 2.1) read them: zeros, in the state and in the reward terms "
              "computed from them",
    "simulated": "MuJoCo's computed forces (Gymnasium's default)",
}
"""``--contact-forces``: how a MuJoCo task's external contact forces ``cfrc_ext`` read (:mod:`ilcsan.rl.tasks`)."""
CONTACT_FORCE_TASKS: tuple[str, ...] = ("Ant", "Humanoid", "HumanoidStandup")
"""The paper's tasks whose state holds contact forces (84 values each); by short name they default to ``zeroed``."""


RECORDED_BEFORE_CONTACT_FORCES = "simulated"
"""A run recorded before ``contact_forces`` existed ran MuJoCo's computed forces."""


def contact_forces_of(task: str, choice: str | None) -> str:
    """The contact forces a run of ``task`` uses: ``choice`` if given, else ``zeroed`` for the paper's tasks of
    :data:`CONTACT_FORCE_TASKS` named by short name (any case) and ``simulated`` for every other task."""
    if choice is not None:
        return choice
    return "zeroed" if task.lower() in {name.lower() for name in CONTACT_FORCE_TASKS} else "simulated"


NOISY_RETURN_REFERENCE: dict[str, float] = {
    "Ant": 6000.0, "HalfCheetah": 12000.0, "Hopper": 4000.0, "Walker2d": 6000.0, "Humanoid": 6000.0,
    "HumanoidStandup": 180000.0, "InvertedDoublePendulum": 10000.0, "BipedalWalker": 320.0,
}
"""NoisySAN's per-task return R* (``SUP_R`` in the authors' TD3 script in SpikingJelly's ``noisy_san`` example):
the weight of the noise penalty is k = max(0, R)/R*, R the latest evaluation's mean return."""
PROXY_HIDDEN: tuple[int, ...] = (512, 512)
"""The proxy actor's hidden widths (ReLU MLP, tanh output): the default ``--proxy_hidden_sizes 512 512`` of the
Proxy Target code as reproduced in ``madao2333/Proxy-Target-with-PLIF`` (main.py)."""


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


def intra_label(variant: str) -> str:
    """The paper's name of an intra-layer variant (Table intra's rows): ``No I_intra`` for ``none``, else each kept
    part as a current, e.g. ``I_intra``, ``I_self``, ``I_self+I_lateral``."""
    if variant not in INTRA_MASKS:
        raise KeyError(f"no intra-layer variant {variant!r}; the variants are {', '.join(INTRA_VARIANTS)}")
    return "No I_intra" if variant == "none" else "+".join(f"I_{part}" for part in variant.split("+"))
INTRA_TIMING_SOURCES: dict[str, str] = {
    "paper": "Algorithm 1: I_t = W_intra S_{t-1} + b_intra from t = 2 on, nothing at t = 1",
    "authors": "the authors' released code (popsan.py): W_intra S_{t-1} + b_intra at every t = 1..T, so b_intra "
               "also arrives at t = 1 (S_0 = 0)",
}
"""When the intra-layer current starts (``--intra-timing``), each with where it comes from."""
INTRA_TIMINGS: tuple[str, ...] = tuple(INTRA_TIMING_SOURCES)
SAVED_WITHOUT_INTRA_TIMING = "paper"
"""The timing of an actor saved before ``intra_timing`` existed (a config.json, checkpoint or policy without it): every
such actor ran Algorithm 1's."""

NORMALIZATION_PAPERS: dict[str, str] = {
    "none": "the synaptic current W S + b reaches the neurons as it is (the ILC-SAN paper)",
    "care-bn": "CaRe-BN (Xu et al., ICLR 2026): batch normalisation of each synaptic layer's current, pooled over "
               "the batch and the T steps; batch statistics in the actor's loss, running statistics (Kalman-style "
               "gain, periodic recalibration) when acting; folded into the weights at export",
}
"""How a spiking actor normalises each synaptic layer's current before its neurons (``--normalization``), each with
its paper. An actor saved before this setting existed has ``none``, the default."""
NORMALIZATIONS: tuple[str, ...] = tuple(NORMALIZATION_PAPERS)



# ------------------------------------------------------------------ settings described once
class Switch(NamedTuple):
    """A command-line switch that sets part of a field (``hidden`` is offered as a layer count and a width)."""

    flag: str
    help: str
    default_of: Callable[[Any], Any]
    """The switch's value implied by the field's value, e.g. ``len`` of the hidden widths."""


def setting(default: Any, help: str, *, choices: tuple[str, ...] | Mapping[str, Any] | None = None,
            flag: str | None = None, aliases: tuple[str, ...] = (), minimum: int | None = None,
            bounds: str | None = None, switches: tuple[Switch, ...] = (),
            renamed: Mapping[str, str] | None = None) -> Any:
    """A dataclass field described once for the command line and for :func:`check_settings`.

    ``flag`` is the CLI name when it is not the field name with dashes; ``minimum`` bounds whole numbers;
    ``bounds`` is ``"decay"`` (a factor in [0, 1]), ``"positive"`` or ``"non-negative"`` for real numbers (None,
    where a field allows it, passes); ``switches`` replace
    the field's own switch by switches that each set part of it; ``renamed`` maps the old spellings of choices to
    today's (:func:`current_spellings`).
    """
    metadata = {"help": help, "choices": choices, "flag": flag, "aliases": aliases, "minimum": minimum,
                "bounds": bounds, "switches": switches, "renamed": dict(renamed or {})}
    return field(default=default, metadata=metadata)


def current_spellings(config: Any) -> None:
    """Replace, in a frozen config just made, every choice written in an old spelling by today's (a config file,
    grid or script of an earlier version keeps working; :func:`renamed_note` tells a user who typed one)."""
    for item in described_fields(type(config)):
        value = getattr(config, item.name)
        if isinstance(value, str) and value in item.metadata["renamed"]:
            object.__setattr__(config, item.name, item.metadata["renamed"][value])


def renamed_note(config_class: type, values: Mapping[str, Any]) -> str | None:
    """One line for the old spellings among ``values`` (by field name) as a user gave them, or None."""
    notes = [f"{flag_of(item)} {values[item.name]} is now called {item.metadata['renamed'][values[item.name]]}"
             for item in described_fields(config_class)
             if isinstance(values.get(item.name), str) and values[item.name] in item.metadata["renamed"]]
    return f"note: {'; '.join(notes)} (the old name still works)" if notes else None


def flag_of(setting_field: dataclasses.Field) -> str:
    """The command-line flag of a field: ``--`` and its metadata ``flag``, or its name with dashes."""
    return "--" + (setting_field.metadata.get("flag") or setting_field.name.replace("_", "-"))


def described_fields(config_class: type) -> list[dataclasses.Field]:
    """The fields of a config class that carry a description (help) in their metadata."""
    return [item for item in dataclasses.fields(config_class) if "help" in item.metadata]


def setting_type(config_class: type, setting_field: dataclasses.Field) -> Any:
    """The Python type of a field's value (``int | None`` → int)."""
    hint = typing.get_type_hints(config_class)[setting_field.name]
    if isinstance(hint, types.UnionType):
        hint = next(arg for arg in typing.get_args(hint) if arg is not type(None))
    return hint


def check_settings(config: Any) -> None:
    """Raise :class:`UserError` naming the flag for any field whose value its metadata does not allow."""
    for item in described_fields(type(config)):
        value, meta, name = getattr(config, item.name), item.metadata, flag_of(item)
        optional = value is None and item.default is None  # None: another layer decides (the field's help says)
        if meta["choices"] is not None and not optional and value not in meta["choices"]:
            raise UserError(f"{name} {value!r} is not one of: {', '.join(meta['choices'])}")
        if meta["minimum"] is not None and value is not None and value < meta["minimum"]:
            raise UserError(f"{name} must be at least {meta['minimum']}, got {value}")
        if meta["bounds"] is not None and value is None:
            continue
        if meta["bounds"] == "non-negative" and not (math.isfinite(value) and value >= 0):
            raise UserError(f"{name} must be a number of at least 0, got {value}")
        if meta["bounds"] == "decay" and not (math.isfinite(value) and 0.0 <= value <= 1.0):
            raise UserError(f"{name} is a decay factor in [0, 1], got {value}")
        if meta["bounds"] == "positive" and not (math.isfinite(value) and value > 0):
            raise UserError(f"{name} must be a positive number, got {value}")


# ------------------------------------------------------------------------------------ the actor
PRESETS: dict[str, dict[str, Any]] = {
    "ilc-san": {},
    "popsan": {"intra": "none", "decoder": "fr"},
    "mdc-san": {"encoder": "pop", "neuron": "dynamic", "intra": "none", "decoder": "fr"},
    "akl": {"encoder": "two-neuron", "hidden": (400, 300), "alpha_c": 0.5, "alpha_v": 0.5,
            "intra": "none", "decoder": "last", "alpha_v_li": 1.0},
    "dan": {"network": "deep", "learning_rate": 1e-3, "encoder": "layer", "intra": "none",
            "decoder": "last"},
}
"""Each preset as its differences from :class:`ActorConfig`'s defaults (which are ILC-SAN's)."""

PRESET_NAMES: tuple[str, ...] = tuple(PRESETS)

PRESET_SUMMARIES = {
    "ilc-san": "ILC-SAN (the paper): E_pop_det, CLIF, intra-layer connections, LI decoder D_last",
    "popsan": "PopSAN (Tang et al. 2021): E_pop_det, CLIF, firing-rate decoder",
    "mdc-san": "MDC-SAN (Zhang et al. 2022): E_pop analog input, dynamic neurons, firing-rate decoder",
    "akl": "Akl et al. 2023 (variant): two-neuron analog input, CLIF 400-300, integrator readout",
    "dan": "DAN: TD3's deep actor (N, 256, ReLU, 256, ReLU, M, tanh)",
}

MAX_HIDDEN_LAYERS = 4


@dataclass(frozen=True)
class ActorConfig:
    """Every switch of an actor; the defaults are the paper's ILC-SAN. Field metadata is the CLI's help."""

    preset: str = setting("ilc-san", "the preset; any switch below overrides it (see `ilcsan actors`)",
                          choices=PRESET_NAMES, flag="actor", aliases=("--preset",))
    network: str = setting("spiking", "spiking actor, or TD3's deep actor network (DAN)", choices=NETWORKS)
    encoder: str = setting("pop-det", "input coding; pop-det and pop-prob keep the actor fully spiking",
                           choices=ENCODERS)
    neuron: str = setting("clif", "backbone neuron: CLIF, or MDC-SAN's dynamic neuron", choices=NEURONS)
    hidden: tuple[int, ...] = setting((256, 256), "hidden layer widths", switches=(
        Switch("hidden-layers", f"number of hidden layers, 1-{MAX_HIDDEN_LAYERS}", len),
        Switch("hidden-width", "neurons per hidden layer", lambda widths: widths[0])))
    intra: str = setting("intra", "intra-layer connections kept (Eq. (10)): all, one part, or none",
                         choices=INTRA_VARIANTS)
    intra_timing: str = setting("paper", "when the intra-layer current starts: paper (Algorithm 1, from t = 2) or "
                                         "authors (their released code: b_intra also at t = 1)",
                                choices=INTRA_TIMINGS)
    decoder: str = setting("last", "decoder statistic: the LI membrane voltage's last, max or mean, or the firing "
                                   "rate (fr)", choices=DECODERS)
    alpha_v_li: float = setting(1.0, "voltage decay α_V^LI of the decoder's LI neuron", bounds="decay")
    timesteps: int = setting(5, "simulation time T per action", minimum=1)
    population_in: int = setting(10, "encoder neurons per state dimension P_in", minimum=1)
    population_out: int = setting(10, "output neurons per action dimension P_out", minimum=1)
    alpha_c: float = setting(0.5, "CLIF current decay α_C", bounds="decay")
    alpha_v: float = setting(0.75, "CLIF voltage decay α_V^CLIF", bounds="decay")
    v_th: float = setting(0.5, "CLIF threshold V_th", bounds="positive")
    surrogate_width: float = setting(0.5, "rectangular surrogate window w", bounds="positive")
    enc_v_th: float = setting(0.999, "threshold of the encoder's soft-reset IF neurons", bounds="positive")
    learning_rate: float = setting(1e-4, "actor learning rate; DAN's is 1e-3", flag="actor-lr", bounds="positive")
    normalization: str = setting("none", "normalisation of each spiking layer's synaptic current before its neurons: "
                                         "none (the paper), or care-bn (CaRe-BN, Xu et al. 2026: batch statistics "
                                         "in the actor's loss, running statistics moved by a Kalman-style gain after "
                                         "each actor step and recalibrated from the replay every 5000 steps when "
                                         "acting; on the output populations the feed-forward current only; folded "
                                         "into the weights on export; spiking actors only)",
                                 choices=NORMALIZATIONS)

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
        values = {"intra_timing": SAVED_WITHOUT_INTRA_TIMING, **data}
        if "hidden" in values:
            values["hidden"] = tuple(int(width) for width in values["hidden"])
        return validate(cls(**values))


def validate(config: ActorConfig) -> ActorConfig:
    """Raise :class:`UserError` with one sentence for any impossible switch value."""
    check_settings(config)
    if not 1 <= len(config.hidden) <= MAX_HIDDEN_LAYERS:
        raise UserError(f"the backbone needs 1 to {MAX_HIDDEN_LAYERS} hidden layers, got {len(config.hidden)}")
    if any(width < 1 for width in config.hidden):
        raise UserError(f"hidden layer widths must be at least 1, got {list(config.hidden)}")
    if config.normalization != "none" and config.network != "spiking":
        raise UserError(f"--normalization {config.normalization} normalises a spiking actor's synaptic currents; "
                        "DAN (--network deep) has none: use --normalization none")
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
        if layers < 1 or layers > MAX_HIDDEN_LAYERS:
            raise UserError(f"--hidden-layers must be 1 to {MAX_HIDDEN_LAYERS}, got {layers}")
        overrides["hidden"] = (width,) * layers
    known = {f.name for f in dataclasses.fields(ActorConfig)}
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise UserError(f"unknown actor switch(es) {', '.join(unknown)}")
    values.update(overrides)
    if "hidden" in values:
        values["hidden"] = tuple(int(w) for w in values["hidden"])
    return validate(ActorConfig(**values))


# ------------------------------------------------------------------------------------ TD3 and the run
@dataclass(frozen=True)
class TD3Config:
    """TD3 hyper-parameters of the paper (Section IV-A) and the authors' code."""

    gamma: float = 0.99  # reward discount
    tau: float = 0.005  # soft target update factor
    batch_size: int = setting(100, "minibatch size", minimum=1)
    replay_size: int = 1_000_000
    critic_lr: float = 1e-3
    critic_hidden: tuple[int, ...] = (256, 256)
    exploration_noise: float = 0.1  # stddev, relative to the action half-range
    target_noise: float = 0.2  # target policy smoothing stddev, relative to the action half-range
    noise_clip: float = 0.5
    policy_delay: int = setting(2, "actor and target updates once every this many critic updates", minimum=1)
    start_steps: int = setting(10_000, "uniformly random actions before the actor acts", minimum=0)
    update_after: int = setting(1_000, "first TD3 update at this step", minimum=0)
    update_every: int = setting(50, "TD3 updates run in chunks of this many, one per environment step, "
                                    "as in the authors' code", minimum=1)
    target_actor: str = setting("polyak", "actor in TD3's and DDPG's target values: polyak, the Polyak-averaged copy "
                                          "of the actor (the paper), or proxy, Proxy Target's continuous proxy "
                                          "imitating the online actor (Xu et al. 2025; spiking actors only)",
                                choices=TARGET_ACTOR_PAPERS, renamed={"spiking": "polyak"})
    proxy_iterations: int = setting(3, "Proxy Target: regression steps of the proxy per TD3 update (K; 1 with "
                                       "--proxy-lr 3e-3 is the cheap setting)", minimum=1)
    proxy_lr: float = setting(1e-3, "Proxy Target: the proxy's Adam learning rate", bounds="positive")
    exploration: str = setting("gaussian", "how the actor explores: TD3's Gaussian action noise (the paper), or "
                                           "NoisySAN's coloured noise inside the spiking neurons (Chen et al. "
                                           "2024; spiking actors only)", choices=EXPLORATION_PAPERS)
    preaction_penalty: float = setting(0.0, "weight λ of a penalty λ·mean(O²) on the actor's pre-tanh output O, added "
                                            "to the actor's loss (0: the paper; > 0 pulls a saturated actor back "
                                            "into tanh's range)", bounds="non-negative")
    noisy_sigma: float = setting(0.5, "NoisySAN: sigma_init; a layer of D neurons gets the fixed noise scale "
                                      "sigma_init/sqrt(D) on charge and transmission, the decoder's learned "
                                      "scale starts at sigma_init/sqrt(M)", bounds="positive")
    noisy_beta: float = setting(1.0, "NoisySAN: spectral exponent of the noise, power ~ 1/f^beta (0 white, 1 "
                                     "pink: the paper's choice, 2 brown)", bounds="non-negative")
    entropy_lr: float = setting(3e-4, "SAC: Adam learning rate of the entropy coefficient's logarithm log α (SAC's "
                                      "paper: 3e-4)", bounds="positive")
    initial_entropy_coefficient: float = setting(1.0, "SAC: the entropy coefficient α at the start; it then tunes "
                                                      "itself toward the target entropy −M", bounds="positive")
    noisy_return_reference: float | None = setting(
        None, "NoisySAN: the return R* at which the noise penalty's weight max(0, R)/R* reaches 1 (default per "
              "paper task: Hopper 4000, Walker2d/Ant/Humanoid 6000, HalfCheetah 12000, ...; needed for other "
              "tasks)", bounds="positive")

    def __post_init__(self) -> None:
        current_spellings(self)

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


METHOD_SETTINGS: tuple[str, ...] = ("target_actor", "proxy_iterations", "proxy_lr", "exploration", "noisy_sigma",
                                    "noisy_beta", "noisy_return_reference", "preaction_penalty", "entropy_lr",
                                    "initial_entropy_coefficient")
"""The :class:`TD3Config` fields that choose or tune how the actor is trained (a grid row's own settings, part of a
run's identity in reports); the others are the protocol every row shares."""


@dataclass(frozen=True)
class RunConfig:
    """Everything that defines a training run."""

    task: str = "Hopper"
    seeds: tuple[int, ...] = (0,)
    steps: int = setting(1_000_000, "environment steps per seed", minimum=1)
    eval_every: int = setting(10_000, "evaluate every this many steps", minimum=1)
    eval_episodes: int = setting(10, "episodes per evaluation", minimum=1)
    actor: ActorConfig = field(default_factory=ActorConfig)
    td3: TD3Config = field(default_factory=TD3Config)
    algorithm: str = setting("td3", "the off-policy algorithm that trains the actor: td3 (the paper's), ddpg (one "
                                    "critic, no target smoothing or delay) or sac (squashed Gaussian actor: the "
                                    "output populations decode a mean and a log-std; entropy tuned)",
                             choices=ALGORITHM_PAPERS)
    contact_forces: str | None = setting(None, "a MuJoCo task's external contact forces. zeroed: as the paper's "
                                               "simulator read them (mujoco-py 2.1): zeros in the state and in the "
                                               "rewards computed from them; simulated: MuJoCo's. Default: zeroed for "
                                               f"the paper's {', '.join(CONTACT_FORCE_TASKS)} by short name, "
                                               "simulated otherwise", choices=tuple(CONTACT_FORCES))
    device: str = setting("cpu", "cpu, cuda or cuda:N")
    engine: str = setting("fast", "the spiking actor's forward pass: fast (layer-major) or reference (the literal "
                                  "time loop of Algorithm 1)", choices=ENGINES)
    threads: int | None = setting(None, "torch threads (default: torch's own; use 1 when several runs share the "
                                        "cores)", minimum=1)
    compile: str = setting("auto", "run each TD3 update as one compiled program (and the actor's acting pass "
                                   "compiled); auto: on when the run has enough updates to repay the compilation "
                                   f"({COMPILE_PAYS_AFTER_UPDATES['spiking']} for spiking actors, "
                                   f"{COMPILE_PAYS_AFTER_UPDATES['deep']} for DAN)", choices=COMPILE_MODES)
    matmul: str = setting("float32", "matmul precision. float32: the faster of MKL and oneDNN on this run's own "
                                     "matrix shapes, each as often as a training step computes it, measured at start "
                                     "(printed, and kept in config.json); bf16: "
                                     "operands and products rounded to bfloat16 for the product shapes it computes "
                                     "faster on this CPU (AMX/AVX512-BF16), timed at start, float32 for the rest "
                                     "(TF32/bf16 on CUDA)", choices=MATMUL_CHOICES)
    checkpoint_minutes: float = setting(10.0, "also checkpoint after this many minutes of training since the last "
                                              "checkpoint, between evaluations (0: at evaluations only), so that an "
                                              "interrupted run loses at most that much", bounds="non-negative")
    label: str | None = None  # row label in reports (default: the preset)
    table: str | None = None  # set by `ilcsan reproduce`
    row: str | None = None  # set by `ilcsan reproduce`

    def compiles(self) -> bool:
        """Whether the run compiles: when asked, or (auto) when it has enough updates to repay the compilation
        (:data:`COMPILE_PAYS_AFTER_UPDATES`); the reference engine (the literal Algorithm 1 oracle) stays eager."""
        if self.compile == "auto":
            updates = max(0, self.steps - self.td3.update_after)
            return self.engine == "fast" and updates >= COMPILE_PAYS_AFTER_UPDATES[self.actor.network]
        return self.compile == "on"

    def task_contact_forces(self) -> str:
        """The contact forces this run's task uses (:func:`contact_forces_of`)."""
        return contact_forces_of(self.task, self.contact_forces)

    def for_seed(self, seed: int) -> dict[str, Any]:
        """The config.json of one seed's run."""
        data = dataclasses.asdict(self)
        data.update(seed=seed, seeds=[seed], actor=self.actor.to_dict(), td3=self.td3.to_dict(),
                    label=self.label or self.actor.preset, contact_forces=self.task_contact_forces())
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RunConfig:
        """The config of a saved config.json; recorded contact forces that are the task's default read as unset
        (None), as a config made with that default holds them."""
        values = {key: value for key, value in data.items() if key in {f.name for f in dataclasses.fields(cls)}}
        values["actor"] = ActorConfig.from_dict(data["actor"])
        values["td3"] = TD3Config.from_dict(data["td3"])
        values["seeds"] = tuple(data.get("seeds", [data.get("seed", 0)]))
        recorded, task = data.get("contact_forces", RECORDED_BEFORE_CONTACT_FORCES), values.get("task", cls.task)
        values["contact_forces"] = None if recorded == contact_forces_of(task, None) else recorded
        return cls(**values)
