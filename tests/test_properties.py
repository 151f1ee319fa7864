"""Hostile and mistaken input, generated: every case ends in a result or one clear line, never a
traceback or a hang.

* command lines drawn from the real parser's options with hostile values, run through
  `ilcsan.cli.main` with the heavy parts stubbed (no training loop, no network weights, one action
  per "episode", no grid execution): exit 0, or exit 2 with exactly one line on stderr;
* grids as mappings (`grid_from_dict`) and as files (`load_grid`): a TableSpec equal to the input, or
  a UserError;
* `Policy.predict` on any object: an action of the right shape, inside the action bounds, or a
  UserError; real numbers of the right shape are always accepted;
* damaged files: random byte damage to a policy.pt / checkpoint.pt (`ilcsan.load`, `train --resume`)
  and random damage to a deploy bundle: a working policy or one clear line.

The number of examples scales with ``ILCSAN_PROPERTY_SCALE`` (1 in CI; benchmarks/faults.py raises
it), and with ``ILCSAN_PROPERTY_COUNTS=path`` the examples run per property are written there as JSON.
"""

from __future__ import annotations

import collections
import contextlib
import datetime
import io
import json
import os
import shutil
import signal
import types
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import ilcsan
from ilcsan.cli import build_parser, main
from ilcsan.config import DECODERS, ENCODERS, INTRA_TIMINGS, INTRA_VARIANTS, PRESET_NAMES
from ilcsan.errors import UserError
from ilcsan.experiments.grid_files import OVERRIDE_KEYS, grid_from_dict, load_grid
from ilcsan.paper.layouts import TableSpec

SCALE = max(1, int(os.environ.get("ILCSAN_PROPERTY_SCALE", "1")))
EXAMPLES: collections.Counter[str] = collections.Counter()
OUTCOMES: collections.Counter[str] = collections.Counter()  # how the cases ended, per property


def hostile(examples: int, seconds: float = 30.0):
    """Settings: ``examples`` × SCALE examples, a deadline, no example database; fixed examples in CI."""
    return settings(max_examples=examples * SCALE, deadline=datetime.timedelta(seconds=seconds), database=None,
                    derandomize=SCALE == 1, print_blob=True,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                           HealthCheck.data_too_large, HealthCheck.filter_too_much])


@pytest.fixture(scope="module", autouse=True)
def _write_counts():
    yield
    path = os.environ.get("ILCSAN_PROPERTY_COUNTS")
    if path:
        Path(path).write_text(json.dumps({"examples": dict(EXAMPLES), "outcomes": dict(OUTCOMES)},
                                         indent=2, sort_keys=True))


@contextlib.contextmanager
def time_limit(seconds: int, what: str):
    """A hang is a failure: SIGALRM after ``seconds``."""
    def alarm(_signum, _frame):
        raise TimeoutError(f"{what} did not finish in {seconds} s")

    previous = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


# ------------------------------------------------------------------------------------------------
# Command lines

PARSER = build_parser()
COMMANDS = {name: sub for name, sub in PARSER._subparsers._group_actions[0].choices.items()}
HELP_TOKENS = {"-h", "--help", "--version"}


def command_options(name: str) -> list[tuple[str, bool, bool]]:
    """(flag, takes a value, value is a number) for every option of a sub-command of the real parser."""
    return [(flag, action.nargs != 0, action.type is not None) for action in COMMANDS[name]._actions
            if action.option_strings for flag in action.option_strings if flag not in HELP_TOKENS]


def positionals(name: str) -> int:
    return sum(1 for action in COMMANDS[name]._actions if not action.option_strings)


NUMBERS = st.sampled_from(["0", "1", "2", "3", "-1", "-0", "16", "150", "1_000", "1e3", "0.5", "1.0", "-0.25",
                           "nan", "inf", "-inf", "1e309", "99999999999999999999", "0x10", " 7 ", "1,2", "0-3",
                           "3-1", "0-99999999999999"])
WORDS = st.sampled_from(["ilc-san", "popsan", "mdc-san", "akl", "dan", "snn", "pop-det", "pop-prob", "pop",
                         "layer", "two-neuron", "clif", "dynamic", "intra", "self", "lateral+bias", "none", "last",
                         "max", "fr", "cpu", "cuda", "cuda:1", "meta", "fast", "reference", "auto", "on", "off",
                         "Pendulum-v1", "pendulum-v1", "Hopper", "hopper", "CartPole-v1", "MountainCarContinuous-v0",
                         "NoSuchTask-v9", "npz", "nir", "onnx", "int8", "float32", "perf", "intra", "tiny", "local",
                         "ray", "127.0.0.1:1", "--", "-", "", " "])
TEXT = st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=10)
PATHS = st.sampled_from(["<run>", "<checkpoint>", "<policy>", "<file>", "<missing>", "<grid>", "<fresh>", "."])
VALUES = st.one_of(NUMBERS, WORDS, TEXT, PATHS)
COMMAND_EXAMPLES = {"train": 40, "evaluate": 15, "export": 15, "energy": 10, "report": 10, "reproduce": 15,
                    "demo": 10, "others": 10}
OTHERS = ["actors", "tasks", "", "frobnicate", "--version", "-h"]


PLAUSIBLE = {
    "--task": ["Pendulum-v1", "Hopper", "hopper", "MountainCarContinuous-v0", "BipedalWalker"],
    "--actor": ["ilc-san", "popsan", "mdc-san", "akl", "dan"], "--preset": ["popsan", "dan"],
    "--encoder": ["pop-det", "pop", "pop-prob", "layer", "two-neuron"], "--neuron": ["clif", "dynamic"],
    "--intra": ["intra", "self", "lateral", "bias", "none"], "--decoder": ["last", "max", "mean", "fr"],
    "--device": ["cpu"], "--engine": ["fast", "reference"], "--compile": ["auto", "off"],
    "--matmul": ["float32", "aten", "onednn", "bf16"],
    "--seeds": ["0", "1", "0-2", "0,3"], "--seed": ["0", "5"], "--format": ["npz", "nir"],
    "--weights": ["float32", "int8"], "--backend": ["local", "ray"], "--table": ["perf", "intra", "<grid>"],
    "--tasks": ["Hopper", "Pendulum-v1"], "--rows": ["dan", "intra"], "--out": ["<fresh>", "<fresh>", "."],
    "--label": ["mine", "ILC-SAN 16"], "--workers": ["1", "2"], "--address": ["auto"],
}
PLAUSIBLE_NUMBERS = ["1", "2", "3", "16", "150", "0.5", "0.75", "1e-3"]


@st.composite
def command_lines(draw, command: str) -> list[str]:
    """Command lines of the real commands and options. Half are plausible (the right positionals, values of
    the right kind) with a hostile value slipped in now and then; half carry hostile values throughout;
    sometimes a value is missing or an unknown word or option is added."""
    name = draw(st.sampled_from(OTHERS)) if command == "others" else command
    if name not in COMMANDS:
        return [name] if name else []
    plausible = draw(st.booleans())

    def value(pool) -> str:
        return draw(VALUES if draw(st.integers(0, 7 if plausible else 1)) == 0 else st.sampled_from(pool))

    count = positionals(name) if draw(st.integers(0, 9)) else draw(st.integers(0, 3))
    if name == "energy":
        count = max(count, draw(st.integers(1, 2)))
    positional_pool = ["<run>", "<policy>", "<checkpoint>"] if plausible else ["<run>", "<file>", "<missing>",
                                                                                "<grid>", "perf", "x"]
    argv = [name] + [value(["<grid>", "intra"] if name == "reproduce" else positional_pool) for _ in range(count)]
    options = command_options(name)
    for _ in range(draw(st.integers(0, 8)) if options else 0):
        flag, takes_value, numeric = draw(st.sampled_from(options))
        argv.append(flag)
        if takes_value and draw(st.integers(0, 19)):  # sometimes the value is missing
            if plausible:
                argv.append(value(PLAUSIBLE.get(flag, PLAUSIBLE_NUMBERS if numeric else ["x"])))
            else:
                argv.append(draw((NUMBERS if numeric else (PATHS if flag == "--out" else WORDS))
                                 if draw(st.integers(0, 3)) else VALUES))
    if draw(st.integers(0, 9)) == 0:
        argv.insert(draw(st.integers(1, len(argv))), draw(TEXT | st.sampled_from(["--no-such-option", "-x"])))
    return argv


class _StubAgent:
    """Stands in for the algorithm: no weights are allocated, whatever the sizes."""

    def __init__(self, *_args, **_kwargs):
        self.actor = types.SimpleNamespace(engine=None)
        self.actor_target = types.SimpleNamespace(engine=None)


def _stub_train(config, out, resume=False, progress=None, log=print):
    """Everything `train` checks and prepares (settings, folders, lock, environments, memory), no loop."""
    from ilcsan.rl.training import Trainer

    trainer = Trainer(config, out, resume=resume, progress=progress, log=lambda *_: None)
    trainer.close()
    return [dict(result, best_return=-1.0, best_step=config.eval_every) for result in trainer.results()]


def _one_action_episodes(act, task, episodes, seed=0, batched=False, video=None, progress=False, contact_forces=None):
    """Stands in for evaluation.run_episodes: the real environment and one real action, not whole episodes (no video,
    no progress bar)."""
    from ilcsan.rl.tasks import make_env

    env = make_env(task, contact_forces=contact_forces)
    try:
        observation, _ = env.reset(seed=seed)
        action = np.asarray(act(observation[None])[0] if batched else act(observation))
        assert action.shape == env.action_space.shape and np.all(np.isfinite(action))
    finally:
        env.close()
    return [0.0], [1]


def _stub_grid(grid, *_args, **_kwargs):
    from ilcsan.experiments.coordinator import GridSummary

    assert grid.runs
    return GridSummary(len(grid.runs), 0, 0, (), False, False, None, 0.0)


@pytest.fixture(scope="module")
def workspace(trained_run, tmp_path_factory):
    """A folder with a copy of a trained run, its files, a grid, a plain file; cwd for relative paths."""
    base = tmp_path_factory.mktemp("hostile")
    shutil.copytree(trained_run, base / "run")
    (base / "file").write_text("not a run")
    (base / "grid.toml").write_text('name = "tiny"\ntasks = ["Pendulum-v1"]\nseeds = 1\nsteps = 300\n'
                                    '[[rows]]\nslug = "ilc"\npreset = "ilc-san"\noverrides = { hidden_width = 16 }\n')
    return base


@pytest.fixture
def stubbed(monkeypatch, workspace):
    import ilcsan.analysis.report
    import ilcsan.experiments.coordinator
    import ilcsan.rl.evaluation
    import ilcsan.rl.run_setup
    import ilcsan.rl.training

    monkeypatch.setattr(ilcsan.rl.run_setup, "build_algorithm", _StubAgent)
    monkeypatch.setattr(ilcsan.rl.training, "train", _stub_train)
    monkeypatch.setattr(ilcsan.rl.evaluation, "run_episodes", _one_action_episodes)
    monkeypatch.setattr(ilcsan.rl.evaluation, "random_policy_return", lambda *_a, **_k: 0.0)
    monkeypatch.setattr(ilcsan.analysis.report, "plot_curves", lambda *_a, **_k: None)
    monkeypatch.setattr(ilcsan.experiments.coordinator, "run_grid", _stub_grid)
    monkeypatch.chdir(workspace)
    threads = torch.get_num_threads()
    yield workspace
    torch.set_num_threads(threads)


def _materialise(argv: list[str], workspace: Path, index: int) -> list[str]:
    places = {"<run>": workspace / "run", "<checkpoint>": workspace / "run" / "checkpoint.pt",
              "<policy>": workspace / "run" / "policy.pt", "<file>": workspace / "file",
              "<missing>": workspace / "missing" / "nowhere", "<grid>": workspace / "grid.toml",
              "<fresh>": workspace / f"fresh{index}"}
    return [str(places.get(arg, arg)) for arg in argv]


@pytest.mark.parametrize("command", list(COMMAND_EXAMPLES))
def test_any_command_line_ends_in_success_or_one_line(stubbed, capsys, command):
    @hostile(examples=COMMAND_EXAMPLES[command], seconds=60)
    @given(argv=command_lines(command))
    def check(argv):
        _run_command_line(stubbed, capsys, argv)

    check()


def _run_command_line(stubbed, capsys, argv):
    EXAMPLES["command lines"] += 1
    argv = _materialise(argv, stubbed, EXAMPLES["command lines"])
    # the training loop, grid execution and full episodes are stubbed: nothing below may take long
    with time_limit(60, f"ilcsan {argv}"):
        try:
            code = main(argv)
        except SystemExit as stop:  # argparse's own --help / --version
            assert stop.code == 0 and HELP_TOKENS & set(argv), (argv, stop.code)
            capsys.readouterr()
            return
    torch.set_num_threads(1)
    captured = capsys.readouterr()
    OUTCOMES[f"{argv[0] if argv else '(none)'}: exit {code}"] += 1
    assert "Traceback" not in captured.err, (argv, captured.err)
    if not argv:
        assert code == 2 and "usage" in captured.out  # no command: the help, exit 2
    elif code == 2:
        lines = [line for line in captured.err.splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].startswith("ilcsan: error: "), (argv, captured.err)
    else:
        assert code == 0, (argv, code, captured.err)


def test_invalid_utf8_in_arguments_is_one_line(tmp_path):
    # a shell passes raw bytes; Python hands them over as surrogate escapes, which stderr must survive
    import subprocess
    import sys

    result = subprocess.run([os.fsencode(sys.executable), b"-m", b"ilcsan.cli", b"train", b"--task", b"\xff\xfe",
                             b"--out", os.fsencode(tmp_path / "run")], capture_output=True, timeout=120)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and b"unknown task" in lines[0] and b"Traceback" not in result.stderr


# ------------------------------------------------------------------------------------------------
# Grids

SCALARS = st.one_of(st.none(), st.booleans(), st.integers(-3, 2**63 - 1), st.floats(allow_nan=True), TEXT, WORDS)
TOML_VALUES = st.recursive(SCALARS, lambda inner: st.lists(inner, max_size=3)
                           | st.dictionaries(TEXT | st.sampled_from(OVERRIDE_KEYS), inner, max_size=3), max_leaves=8)


@st.composite
def rows(draw):
    row = {"slug": draw(st.sampled_from(["ilc", "pop", "a.b+c-1", "Bad Slug", ""]) | TEXT),
           "preset": draw(st.sampled_from(PRESET_NAMES) | TOML_VALUES)}
    if draw(st.booleans()):
        row["label"] = draw(TEXT | TOML_VALUES)
    if draw(st.booleans()):
        overrides = {}
        for key in draw(st.lists(st.sampled_from(OVERRIDE_KEYS) | TEXT, max_size=3)):
            overrides[key] = draw(st.sampled_from(["none", "mean", "layer", "intra"]) | st.integers(-2, 9)
                                  | st.floats(-1, 2) | TOML_VALUES)
        row["overrides"] = overrides
    for key in draw(st.lists(TEXT, max_size=1)):
        row[key] = draw(TOML_VALUES)
    return row


@st.composite
def grids(draw):
    data = {"name": draw(st.sampled_from(["tiny", "perf", "x-1"]) | TEXT | TOML_VALUES),
            "tasks": draw(st.lists(st.sampled_from(["Hopper", "Pendulum-v1", "hopper", "NoSuch", "ns/Env-v0", ""])
                                   | TEXT, max_size=3) | TOML_VALUES),
            "rows": draw(st.lists(rows(), max_size=3) | TOML_VALUES)}
    for key in draw(st.lists(st.sampled_from(["caption", "seeds", "steps", "eval_every", "eval_episodes"])
                             | TEXT, max_size=3)):
        data[key] = draw(st.integers(-1, 10**6) | TOML_VALUES)
    for key in draw(st.lists(st.sampled_from(["name", "tasks", "rows"]), max_size=1)):
        data.pop(key, None)
    return data


VALID_OVERRIDES = {"encoder": ENCODERS, "decoder": DECODERS, "intra": INTRA_VARIANTS, "intra_timing": INTRA_TIMINGS,
                   "alpha_v_li": (0.0, 0.5, 1.0), "hidden_layers": (1, 2, 4), "hidden_width": (1, 16, 256),
                   "timesteps": (1, 5), "v_th": (0.25, 0.5)}
"""Valid values of some of the switches a grid row may override (each key is one of OVERRIDE_KEYS)."""
assert set(VALID_OVERRIDES) <= set(OVERRIDE_KEYS)


@st.composite
def valid_grids(draw):
    """Grids the documentation says are valid (load_grid's docstring), then 0-2 damaged values."""
    rows_ = []
    for slug in draw(st.lists(st.sampled_from(["ilc", "pop", "no-intra.mean", "a+b", "x_1"]), min_size=1,
                              max_size=3, unique=True)):
        preset = draw(st.sampled_from(PRESET_NAMES))
        keys = ("hidden_layers", "hidden_width") if preset == "dan" else tuple(VALID_OVERRIDES)
        row = {"slug": slug, "preset": preset,
               "overrides": {key: draw(st.sampled_from(VALID_OVERRIDES[key]))
                             for key in draw(st.lists(st.sampled_from(keys), max_size=3, unique=True))}}
        if draw(st.booleans()):
            row["label"] = draw(st.sampled_from(["ILC-SAN", "No I_intra, D_mean", "ünï"]))
        rows_.append(row)
    data = {"name": draw(st.sampled_from(["tiny", "my-grid", "g.1"])), "rows": rows_,
            "tasks": draw(st.lists(st.sampled_from(["Hopper", "Pendulum-v1", "Walker2d", "ns/Env-v3"]), min_size=1,
                                   max_size=3, unique=True))}
    for key in draw(st.lists(st.sampled_from(["seeds", "steps", "eval_every", "eval_episodes"]), unique=True)):
        data[key] = draw(st.integers(1, 10**6))
    damaged = 0
    for _ in range(draw(st.integers(0, 2))):
        targets = [data, *rows_, *(row["overrides"] for row in rows_)]
        target = draw(st.sampled_from([t for t in targets if isinstance(t, dict)]))
        key = draw(st.sampled_from(sorted(target)) | TEXT) if target else draw(TEXT)
        target[key] = draw(TOML_VALUES)
        damaged += 1
    return data, damaged


@hostile(examples=300)
@given(case=st.one_of(grids().map(lambda data: (data, None)), valid_grids()))
def test_any_grid_mapping_is_a_grid_or_one_user_error(case):
    EXAMPLES["grid mappings"] += 1
    data, damaged = case
    try:
        spec = grid_from_dict(data)
    except UserError as error:
        OUTCOMES["grid mapping: refused"] += 1
        assert "\n" not in str(error)
        assert damaged != 0, f"a valid grid was refused: {error}"
        return
    OUTCOMES["grid mapping: grid"] += 1
    assert isinstance(spec, TableSpec)
    assert spec.name == data["name"] and list(spec.tasks) == data["tasks"]
    assert [row.slug for row in spec.rows] == [row["slug"] for row in data["rows"]]
    assert all(isinstance(value, int) and value >= 1 for value in (spec.seeds, spec.steps, spec.eval_every,
                                                                   spec.eval_episodes))


GRID_TEXT = st.one_of(
    st.binary(max_size=200).map(lambda b: b),
    st.text(max_size=200).map(lambda t: t.encode("utf-8", "surrogatepass")),
    st.sampled_from([b'name = "g"\ntasks = ["Hopper"]\n[[rows]]\nslug = "a"\npreset = "dan"\n',
                     b"a = " + b"[" * 3000 + b"]" * 3000, b'name = "g"\nname = "h"\n', b"\xef\xbb\xbfname = 1",
                     b'tasks = ["Hopper"]\n[[rows]]\nslug = "a"\npreset = "dan"\noverrides = {encoder = "layer"}\n']),
)


@hostile(examples=150)
@given(content=GRID_TEXT, cut=st.integers(0, 300))
def test_any_grid_file_is_a_grid_or_one_user_error(tmp_path_factory, content, cut):
    EXAMPLES["grid files"] += 1
    path = tmp_path_factory.mktemp("grid") / "grid.toml"
    path.write_bytes(content[:cut] if cut < len(content) else content)
    try:
        spec = load_grid(path)
    except UserError as error:
        OUTCOMES["grid file: refused"] += 1
        assert "\n" not in str(error)
        return
    OUTCOMES["grid file: grid"] += 1
    assert isinstance(spec, TableSpec) and spec.rows


# ------------------------------------------------------------------------------------------------
# predict

@pytest.fixture(scope="module")
def policy(trained_run):
    return ilcsan.load(trained_run)


DTYPES = st.sampled_from(["float64", "float32", "float16", "int8", "int64", "uint64", "bool", "complex64", "U3",
                          "S2", "datetime64[s]", "object"])


def arrays_of_any_kind():
    def build(dtype):
        if dtype in ("U3", "S2", "datetime64[s]", "object"):
            return hnp.arrays(np.dtype(dtype) if dtype != "object" else object,
                              hnp.array_shapes(min_dims=0, max_dims=3, max_side=4),
                              elements=st.one_of(st.integers(-5, 5), st.floats(-5, 5), TEXT.map(str))
                              if dtype == "object" else None)
        return hnp.arrays(np.dtype(dtype), hnp.array_shapes(min_dims=0, max_dims=3, max_side=4))
    return DTYPES.flatmap(build)


OBSERVATIONS = st.one_of(
    arrays_of_any_kind(),
    hnp.arrays(np.float64, st.sampled_from([(3,), (1, 3), (5, 3), (0, 3), (3, 1), (2, 3, 1)]),
               elements=st.floats(allow_nan=True, allow_infinity=True)),
    st.lists(st.one_of(st.floats(), st.integers(-10**400, 10**400), st.booleans(), TEXT, st.none(),
                       st.lists(st.floats(), max_size=4)), max_size=5),
    st.recursive(st.floats() | st.integers() | TEXT, lambda inner: st.lists(inner, max_size=4), max_leaves=12),
    st.builds(lambda values: torch.tensor(values), st.lists(st.floats(-1e6, 1e6), min_size=3, max_size=3)),
    st.none(), st.dictionaries(TEXT, st.floats(), max_size=3), st.binary(max_size=24), TEXT,
)


def _is_real_observation(value) -> bool:
    """Real numbers (not strings, complex, dates), all finite, shape (3,) or (B, 3) with B >= 1."""
    if isinstance(value, torch.Tensor):
        value = value.numpy()
    if isinstance(value, np.ndarray):
        ok_kind = value.dtype.kind in "biuf"
    else:
        try:
            value = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            return False
        ok_kind = True
    with np.errstate(all="ignore"):
        finite = ok_kind and value.size > 0 and bool(np.all(np.isfinite(value.astype(np.float64))))
    return finite and value.ndim in (1, 2) and value.shape[-1] == 3


@hostile(examples=400)
@given(observation=OBSERVATIONS)
def test_predict_returns_a_bounded_action_or_one_user_error(policy, observation):
    EXAMPLES["predict inputs"] += 1
    try:
        action = policy.predict(observation)
    except UserError as error:
        OUTCOMES["predict: refused"] += 1
        assert "\n" not in str(error)
        assert not (isinstance(observation, np.ndarray | torch.Tensor) and _is_real_observation(observation)), \
            f"a valid observation was refused: {error}"
        return
    OUTCOMES["predict: action"] += 1
    single = np.asarray(observation).ndim == 1
    assert action.shape == ((1,) if single else (np.asarray(observation).shape[0], 1))
    assert np.all(np.isfinite(action)) and np.all(np.abs(action) <= 2.0)


@pytest.fixture(scope="module")
def deployed_actor(policy):
    from ilcsan.deploy import DeployedActor
    from ilcsan.deploy.bundle import bundle_arrays, bundle_meta

    return DeployedActor.from_arrays(bundle_arrays(policy), bundle_meta(policy))


@hostile(examples=200)
@given(observation=OBSERVATIONS)
def test_the_deployed_runtime_refuses_exactly_what_predict_refuses(policy, deployed_actor, observation):
    """One check of what a robot passes in, for the PyTorch policy and the numpy runtime alike (no string or
    complex number slips through one of them)."""
    outcomes = []
    for call in (policy.predict, deployed_actor.act):
        try:
            outcomes.append(call(observation).shape)
        except UserError as error:
            assert "\n" not in str(error)
            outcomes.append("refused")
    assert outcomes[0] == outcomes[1], f"predict: {outcomes[0]}, deployed act: {outcomes[1]}"


# ------------------------------------------------------------------------------------------------
# Damaged files

def _damage(data: bytes, draw_ops) -> bytes:
    damaged = bytearray(data)
    for kind, where, value in draw_ops:
        where = where % max(len(damaged), 1)
        if kind == "flip" and damaged:
            damaged[where] ^= 1 << (value % 8)
        elif kind == "byte" and damaged:
            damaged[where] = value % 256
        elif kind == "zero":
            damaged[where:where + value] = bytes(len(damaged[where:where + value]))
        elif kind == "cut":
            damaged = damaged[:where]
    return bytes(damaged)


DAMAGE = st.lists(st.tuples(st.sampled_from(["flip", "byte", "zero", "cut"]), st.integers(0, 10**7),
                            st.integers(0, 4096)), min_size=1, max_size=6)


@hostile(examples=120)
@given(which=st.sampled_from(["policy.pt", "checkpoint.pt"]), operations=DAMAGE)
def test_damaged_policy_or_checkpoint_loads_or_is_one_user_error(trained_run, tmp_path_factory, which, operations):
    EXAMPLES["damaged policy/checkpoint files"] += 1
    path = tmp_path_factory.mktemp("damaged") / which
    path.write_bytes(_damage((trained_run / which).read_bytes(), operations))
    try:
        with time_limit(30, f"loading a damaged {which}"):
            policy = ilcsan.load(path)
    except UserError as error:
        OUTCOMES["damaged policy/checkpoint: refused"] += 1
        assert "\n" not in str(error)
        return
    OUTCOMES["damaged policy/checkpoint: loaded and acted"] += 1
    action = policy.predict(np.zeros(3))  # what loaded is a working policy
    assert action.shape == (1,) and np.all(np.isfinite(action))


@hostile(examples=25, seconds=60)
@given(operations=DAMAGE)
def test_resume_from_a_damaged_checkpoint_resumes_or_is_one_line(trained_run, tmp_path_factory, monkeypatch,
                                                                 operations):
    from ilcsan.rl.training import Trainer

    EXAMPLES["damaged checkpoints resumed"] += 1
    monkeypatch.setattr(Trainer, "train", lambda self: (self.close(), self.results())[1])
    run = tmp_path_factory.mktemp("resume") / "run"
    shutil.copytree(trained_run, run)
    (run / "checkpoint.pt").write_bytes(_damage((run / "checkpoint.pt").read_bytes(), operations))
    stderr = io.StringIO()
    with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()), \
            time_limit(60, "resuming a damaged checkpoint"):
        code = main(["train", "--task", "Pendulum-v1", "--steps", "300", "--eval-every", "150", "--eval-episodes",
                     "1", "--start-steps", "150", "--update-after", "100", "--update-every", "25", "--batch-size",
                     "16", "--hidden-width", "16", "--threads", "1", "--no-progress", "--out", str(run), "--resume"])
    torch.set_num_threads(1)
    OUTCOMES[f"damaged checkpoint resumed: exit {code}"] += 1
    lines = [line for line in stderr.getvalue().splitlines() if line.strip()]
    assert code in (0, 2) and "Traceback" not in stderr.getvalue(), stderr.getvalue()
    assert (code == 0 and not lines) or (code == 2 and len(lines) == 1), stderr.getvalue()


@pytest.fixture(scope="module")
def bundle_arrays(trained_run, tmp_path_factory):
    from ilcsan.deploy.export import export

    path = export(trained_run, "npz", tmp_path_factory.mktemp("bundle") / "actor.npz")
    with np.load(path, allow_pickle=False) as data:
        return {name: data[name] for name in data.files}


@st.composite
def damaged_bundles(draw, arrays):
    arrays = dict(arrays)
    meta = json.loads(str(arrays["meta"]))
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["drop", "reshape", "dtype", "values", "meta-key", "meta-value", "extra"]))
        names = sorted(arrays)
        name = draw(st.sampled_from(names))
        if kind == "drop":
            arrays.pop(name)
        elif kind == "reshape" and name != "meta":
            arrays[name] = arrays[name].reshape(-1)[: draw(st.integers(0, arrays[name].size))]
        elif kind == "dtype" and name != "meta":
            with contextlib.suppress(ValueError, TypeError), np.errstate(all="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore")  # e.g. complex to float drops the imaginary part
                arrays[name] = arrays[name].astype(draw(st.sampled_from(["float64", "int8", "int64", "complex64",
                                                                          "U4", "bool"])))
        elif kind == "values" and name != "meta" and arrays[name].size:
            value = draw(st.sampled_from([np.nan, np.inf, -np.inf, 1e30, 0.0, -1e30]))
            arrays[name] = np.full_like(arrays[name], value) if arrays[name].dtype.kind == "f" else arrays[name]
        elif kind == "meta-key" and meta:
            meta.pop(draw(st.sampled_from(sorted(meta))))
        elif kind == "meta-value" and meta:
            meta[draw(st.sampled_from(sorted(meta)))] = draw(TOML_VALUES)
        elif kind == "extra":
            arrays[draw(TEXT.filter(lambda t: t and "/" not in t and "\x00" not in t))] = np.zeros(2)
    if "meta" in arrays:
        arrays["meta"] = np.array(json.dumps(meta, allow_nan=True))
    return arrays


@hostile(examples=150)
@given(data=st.data())
def test_damaged_deploy_bundle_acts_or_is_one_user_error(bundle_arrays, tmp_path_factory, data):
    from ilcsan.deploy import DeployedActor

    EXAMPLES["damaged deploy bundles"] += 1
    arrays = data.draw(damaged_bundles(bundle_arrays))
    path = tmp_path_factory.mktemp("bundle") / "damaged.npz"
    np.savez(path, **arrays)
    try:
        with time_limit(30, "a damaged bundle"):
            action = DeployedActor.load(path).act(np.zeros(3))
    except UserError as error:
        OUTCOMES["damaged bundle: refused"] += 1
        assert "\n" not in str(error)
        return
    OUTCOMES["damaged bundle: acted"] += 1
    assert action.shape == (1,) and np.all(np.isfinite(action))  # meta may rescale it: finite is the promise
