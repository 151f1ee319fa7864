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

Every setting is a dataclass field whose metadata describes it once (:func:`~ilcsan.settings.setting`): its help, its
choice list, its command-line flag where that differs from the field name. :mod:`ilcsan.cli.options` generates the
command line from this metadata and :func:`~ilcsan.settings.check_settings` validates against it, so a switch, its
default and its help cannot drift apart. The training methods and algorithms (:mod:`ilcsan.methods`) declare their
own settings, choices and help; the settings that choose them and the training settings of a run
(:func:`training_config_class`) are made from those declarations.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from . import methods
from .errors import UserError
from .settings import Switch as Switch
from .settings import check_settings as check_settings
from .settings import current_spellings as current_spellings
from .settings import described_fields as described_fields
from .settings import flag_of as flag_of
from .settings import renamed_note as renamed_note
from .settings import setting as setting
from .settings import setting_type as setting_type

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
# --matmul: "float32" measures at the start of a run which float32 path (MKL through aten, or oneDNN) is faster on its
# products; "aten" and "onednn" name the path instead, so that every run of a configuration computes the same way
# (two runs that measured differently round differently, and their curves part after the first update); "bf16"
# computes in bfloat16 (float32 accumulation) the products that run faster so, measured at the start of a run (AMX /
# AVX512-BF16 CPUs; ilcsan.compute.matmul), and on CUDA lets torch use TF32/bf16 tensor cores. Neuron states, spikes,
# losses and optimiser stay float32 either way.
MATMUL_CHOICES: tuple[str, ...] = ("float32", "aten", "onednn", "bf16")
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

# ------------------------------------------------------------------------- choosing a method or algorithm
SELECTOR_HELP: dict[str, str] = {
    "target_actor": "actor in TD3's and DDPG's target values",
    "exploration": "how the actor explores",
    "normalization": "normalisation of each spiking layer's synaptic current before its neurons",
    "algorithm": "the off-policy algorithm that trains the actor",
}
"""What the setting that chooses among a kind's declarations (:data:`ilcsan.methods.KINDS`) sets; its help goes on
with each choice's ``option_help``."""


def _selector(kind: str) -> Any:
    """The setting that chooses among the registered declarations of ``kind``: their names (the mapping, which
    registering changes), the first as default, their earlier names renamed, their phrases as help."""
    renamed = {old: name for name, method in methods.registered(kind).items() for old in method.renamed}
    return setting(methods.default(kind), lambda: f"{SELECTOR_HELP[kind]}: {methods.either(kind)}",
                   choices=methods.registered(kind), renamed=renamed)


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
    normalization: str = _selector("normalization")

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
    if config.normalization != methods.NO_NORMALIZATION and config.network != "spiking":
        raise UserError(f"--normalization {config.normalization} normalises a spiking actor's synaptic currents; "
                        f"DAN (--network deep) has none: use --normalization {methods.NO_NORMALIZATION}")
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
class TrainingProtocol:
    """The training settings every algorithm and method shares: TD3's hyper-parameters of the paper (Section IV-A)
    and the authors' code. The training settings of a run (:func:`training_config_class`, ``TrainingConfig``) are these
    and every registered method's and algorithm's own (:mod:`ilcsan.methods`)."""

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

    def __post_init__(self) -> None:
        current_spellings(self)

    def to_dict(self) -> dict[str, Any]:
        data = dataclasses.asdict(self)
        data["critic_hidden"] = list(self.critic_hidden)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainingProtocol:
        """The settings a config.json or checkpoint holds; a UserError when it holds settings no registered method
        declares (a run made with a method of the user's own, read where it is not registered)."""
        values = dict(data)
        unknown = sorted(set(values) - {item.name for item in dataclasses.fields(cls)})
        if unknown:
            raise UserError(f"the run's training settings {', '.join(unknown)} belong to no registered method: "
                            "register the method that declares them (ilcsan.methods.register) before reading it")
        if "critic_hidden" in values:
            values["critic_hidden"] = tuple(values["critic_hidden"])
        return cls(**values)


_ASSEMBLED: dict[tuple[type, ...], type[TrainingProtocol]] = {}


def training_config_class() -> type[TrainingProtocol]:
    """The training settings of a run (``TrainingConfig``, the ``training`` of a :class:`RunConfig` and of
    config.json), a frozen dataclass: the :class:`TrainingProtocol` and, kind by kind (:data:`ilcsan.methods.KINDS`),
    the setting that chooses among a kind's declarations (``target_actor``, ``exploration``) and each registered
    declaration's ``Settings``. Made once per set of registered declarations (the same class while they do not
    change)."""
    registered = methods.every()
    if registered not in _ASSEMBLED:
        fields: list[tuple[str, Any, Any]] = []
        for kind in methods.KINDS:
            if kind in methods.KINDS_CHOSEN_BY_TRAINING:
                fields.append((kind, str, _selector(kind)))
            for method in methods.registered(kind).values():
                fields += method.setting_fields()
        clashes = sorted({name for name, _, _ in fields} & {item.name for item in dataclasses.fields(TrainingProtocol)})
        if clashes:
            raise ValueError(f"declared settings {', '.join(clashes)} are the protocol's")
        assembled = dataclasses.make_dataclass("TrainingConfig", fields, bases=(TrainingProtocol,), frozen=True)
        assembled.__module__, assembled.__doc__ = __name__, training_config_class.__doc__
        _ASSEMBLED[registered] = assembled
    return _ASSEMBLED[registered]


def method_settings() -> tuple[str, ...]:
    """The training settings that choose or tune how the actor is trained — the choosing settings and every
    declaration's own (a grid row's own settings, part of a run's identity in reports); the others, the
    :class:`TrainingProtocol`, every row shares."""
    protocol = {item.name for item in dataclasses.fields(TrainingProtocol)}
    return tuple(item.name for item in dataclasses.fields(training_config_class()) if item.name not in protocol)


OLD_TRAINING_KEY = "td3"
"""What config.json, checkpoints, policy.pt and grid rows written before the name ``training`` call the training
settings; read still."""


def saved_training(data: dict[str, Any]) -> Any:
    """The training settings of a saved run configuration ``data``: its ``training``, or its ``td3``
    (:data:`OLD_TRAINING_KEY`); None when it has neither."""
    return data["training"] if "training" in data else data.get(OLD_TRAINING_KEY)


def deprecated(old: str, new: str) -> None:
    """Warn that the Python name ``old`` is now ``new`` (a :class:`DeprecationWarning` at the caller's caller)."""
    warnings.warn(f"{old} is deprecated: use {new}", DeprecationWarning, stacklevel=3)


def td3_config_class() -> type[TrainingProtocol]:
    """Deprecated: :func:`training_config_class`."""
    deprecated("ilcsan.config.td3_config_class", "training_config_class")
    return training_config_class()


def __getattr__(name: str) -> Any:
    """``TrainingConfig``: the training settings of the methods registered now (:func:`training_config_class`);
    ``TD3Config``, its deprecated name."""
    if name == "TrainingConfig":
        return training_config_class()
    if name == "TD3Config":
        deprecated("TD3Config", "TrainingConfig")
        return training_config_class()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


@dataclass(frozen=True)
class RunConfig:
    """Everything that defines a training run."""

    task: str = "Hopper"
    seeds: tuple[int, ...] = (0,)
    steps: int = setting(1_000_000, "environment steps per seed", minimum=1)
    eval_every: int = setting(10_000, "evaluate every this many steps", minimum=1)
    eval_episodes: int = setting(10, "episodes per evaluation", minimum=1)
    actor: ActorConfig = field(default_factory=ActorConfig)
    training: TrainingProtocol = field(default_factory=lambda: training_config_class()())
    algorithm: str = _selector("algorithm")
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
    matmul: str = setting("float32", "matmul precision and path. float32: the faster of MKL and oneDNN on this "
                                     "run's own matrix shapes, each as often as a training step computes it, measured "
                                     "at start (printed, and kept in config.json); aten / onednn: float32 on that "
                                     "path, not measured, so that two runs of a seed compute alike (runs that "
                                     "measured differently round differently and their curves part); bf16: "
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
            updates = max(0, self.steps - self.training.update_after)
            return self.engine == "fast" and updates >= COMPILE_PAYS_AFTER_UPDATES[self.actor.network]
        return self.compile == "on"

    def task_contact_forces(self) -> str:
        """The contact forces this run's task uses (:func:`contact_forces_of`)."""
        return contact_forces_of(self.task, self.contact_forces)

    @property
    def td3(self) -> TrainingProtocol:
        """Deprecated: :attr:`training`."""
        deprecated("RunConfig.td3", "RunConfig.training")
        return self.training

    def recorded(self) -> RunConfig:
        """This configuration as its config.json records it (:meth:`for_seed`) and :meth:`from_dict` reads it back:
        the training settings its algorithm does not use (:func:`ilcsan.methods.unused_settings`) at their defaults."""
        unused = methods.unused_settings(self.algorithm)
        defaults = type(self.training)()
        return dataclasses.replace(self, training=dataclasses.replace(
            self.training, **{name: getattr(defaults, name) for name in unused}))

    def for_seed(self, seed: int) -> dict[str, Any]:
        """The config.json of one seed's run; its training settings without those its algorithm does not use (SAC's
        have no target actor and no exploration method: :func:`ilcsan.methods.unused_settings`)."""
        data = dataclasses.asdict(self)
        unused = methods.unused_settings(self.algorithm)
        training = {name: value for name, value in self.training.to_dict().items() if name not in unused}
        data.update(seed=seed, seeds=[seed], actor=self.actor.to_dict(), training=training,
                    label=self.label or self.actor.preset, contact_forces=self.task_contact_forces())
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RunConfig:
        """The config of a saved config.json; recorded contact forces that are the task's default read as unset
        (None), as a config made with that default holds them. The training settings are its ``training`` or, as
        files written before that name hold them, its ``td3``; those it lacks (unused by its algorithm, or declared
        since) take their defaults."""
        values = {key: value for key, value in data.items() if key in {f.name for f in dataclasses.fields(cls)}}
        values["actor"] = ActorConfig.from_dict(data["actor"])
        values["training"] = training_config_class().from_dict(saved_training(data))
        values["seeds"] = tuple(data.get("seeds", [data.get("seed", 0)]))
        recorded, task = data.get("contact_forces", RECORDED_BEFORE_CONTACT_FORCES), values.get("task", cls.task)
        values["contact_forces"] = None if recorded == contact_forces_of(task, None) else recorded
        return cls(**values)


_dataclass_init = RunConfig.__init__


@functools.wraps(_dataclass_init)
def _init_taking_td3(self: RunConfig, *args: Any, td3: TrainingProtocol | None = None, **kwargs: Any) -> None:
    """:class:`RunConfig`'s own ``__init__``, which takes the deprecated ``td3=`` for ``training=``."""
    if td3 is not None:
        deprecated("RunConfig(td3=...)", "RunConfig(training=...)")
        if "training" in kwargs:
            raise TypeError("RunConfig() takes training= or its deprecated name td3=, not both")
        kwargs["training"] = td3
    _dataclass_init(self, *args, **kwargs)


RunConfig.__init__ = _init_taking_td3  # type: ignore[method-assign]
