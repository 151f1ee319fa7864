"""The command line is generated from the config: every field's switch, type, default, choices and help."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import pytest

from ilcsan.cli import build_parser, main
from ilcsan.cli.options import actor_switches
from ilcsan.cli.train import RUN_SETTINGS, build_run_config, training_settings
from ilcsan.config import ActorConfig, RunConfig, TrainingConfig, actor_config, check_settings, flag_of
from ilcsan.errors import UserError
from ilcsan.settings import help_text

PARSER = build_parser()


def _help(field) -> str:
    """A field's help as its metadata says it (some are made when asked: the choices among registered methods)."""
    return help_text(field)


def _subparser(name):
    return PARSER._subparsers._group_actions[0].choices[name]


@pytest.fixture
def train_help(monkeypatch) -> str:
    """``ilcsan train --help`` on one line per option (no wrapping inside a help text)."""
    monkeypatch.setenv("COLUMNS", "1000")
    return _subparser("train").format_help()


@pytest.mark.parametrize("field", dataclasses.fields(ActorConfig), ids=lambda field: field.name)
def test_every_actor_field_has_help_and_a_switch_in_train_help(field, train_help):
    assert field.metadata.get("help"), f"ActorConfig.{field.name} has no help in its metadata"
    actions = {flag: action for action in _subparser("train")._actions for flag in action.option_strings}
    helps = {"--" + part.flag: part.help for part in field.metadata["switches"]} or {flag_of(field): None}
    shown = " ".join(train_help.split())
    for flag, switch_help in helps.items():
        assert flag in actions, f"ActorConfig.{field.name} has no switch {flag}"
        assert actions[flag].help.startswith(switch_help or _help(field))
        assert actions[flag].help.replace("%%", "%") in shown


@pytest.mark.parametrize("config_class, names", [(RunConfig, RUN_SETTINGS + ("steps",)),
                                                 (TrainingConfig, training_settings())])
def test_run_and_training_options_show_the_configs_help_and_default(config_class, names, train_help):
    text = train_help
    for field in dataclasses.fields(config_class):
        if field.name in names:
            assert " ".join(_help(field).split()) in text
            if field.default is not None:
                assert f"(default: {field.default})" in text


def test_no_switches_parse_to_the_config_defaults():
    args = PARSER.parse_args(["train"])
    assert build_run_config(args) == RunConfig()


def _sample_value(field) -> tuple[str, object]:
    """A command-line value other than the field's default, and what it should become."""
    choices = field.metadata["choices"]
    if choices is not None:
        value = next(choice for choice in choices if choice != field.default and choice != "dan")
        return value, value
    if isinstance(field.default, float):
        return "0.25", 0.25
    return "3", 3


@pytest.mark.parametrize("field", [field for field in dataclasses.fields(ActorConfig)
                                   if not field.metadata["switches"]], ids=lambda field: field.name)
def test_each_actor_switch_sets_its_field(field):
    text, expected = _sample_value(field)
    config = build_run_config(PARSER.parse_args(["train", flag_of(field), text]))
    assert getattr(config.actor, field.name) == expected


def test_hidden_switches_set_the_widths():
    config = build_run_config(PARSER.parse_args(["train", "--hidden-layers", "3", "--hidden-width", "32"]))
    assert config.actor.hidden == (32, 32, 32)


@pytest.mark.parametrize("config_class, names, target", [(RunConfig, RUN_SETTINGS, lambda config: config),
                                                         (TrainingConfig, training_settings(),
                                                          lambda config: config.training)])
def test_each_run_and_training_option_sets_its_field(config_class, names, target):
    for field in dataclasses.fields(config_class):
        if field.name in names and field.name != "device":
            text, expected = _sample_value(field)
            config = build_run_config(PARSER.parse_args(["train", flag_of(field), text]))
            assert getattr(target(config), field.name) == expected, field.name


def test_actor_switch_list_has_no_duplicates_and_is_generated():
    flags = [flag for flag, _aliases, _options in actor_switches()]
    assert len(flags) == len(set(flags))
    assert len(flags) == len(dataclasses.fields(ActorConfig)) + 1  # hidden: --hidden-layers and --hidden-width


@pytest.mark.parametrize("make, flag", [
    (lambda: actor_config(encoder="rate"), "--encoder"),
    (lambda: actor_config(alpha_c=1.5), "--alpha-c"),
    (lambda: actor_config(learning_rate=0.0), "--actor-lr"),
    (lambda: actor_config(timesteps=0), "--timesteps"),
    (lambda: check_settings(RunConfig(engine="turbo")), "--engine"),
    (lambda: check_settings(RunConfig(matmul="fp8")), "--matmul"),
    (lambda: check_settings(TrainingConfig(batch_size=0)), "--batch-size"),
])
def test_settings_are_checked_against_their_metadata(make, flag):
    with pytest.raises(UserError, match=flag):
        make()


@pytest.mark.parametrize("argv, fragment", [(["--actor-lr", "0"], "--actor-lr"), (["--alpha-v", "2"], "--alpha-v"),
                                            (["--compile", "maybe"], "--compile"),
                                            (["--decoder", "median"], "--decoder")])
def test_bad_switch_values_are_one_line(argv, fragment, tmp_path, capsys):
    code = main(["train", *argv, "--steps", "10", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and fragment in err


def test_reproduce_help_names_every_table(monkeypatch):
    from ilcsan.paper.layouts import TABLES

    monkeypatch.setenv("COLUMNS", "1000")
    assert " | ".join([*TABLES, "path/to/grid.toml"]) in _subparser("reproduce").format_help()


def test_building_the_parser_does_not_import_torch():
    probe = ("import sys; from ilcsan.cli import build_parser; build_parser().parse_args(['train']); "
             "print(sorted({m.split('.')[0] for m in sys.modules} & {'torch', 'gymnasium'}))")
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and result.stdout.strip() == "[]", result.stderr


def test_demo_trains_the_documented_run_and_compares_with_random(monkeypatch, tmp_path, capsys):
    import types

    import ilcsan.analysis.report
    import ilcsan.rl.evaluation
    import ilcsan.rl.training
    from ilcsan.cli import commands

    seen = {}

    def fake_train(config, out, resume=False, progress=None):
        seen.update(config=config, resume=resume)
        return [{"seed": 0, "best_return": -150.0, "best_step": 9000, "steps_done": config.steps}]

    monkeypatch.setattr(ilcsan.rl.training, "train", fake_train)
    monkeypatch.setattr(ilcsan.analysis.report, "collect_runs", lambda _out: [types.SimpleNamespace(
        returns=(-1300.0, -160.0))])
    monkeypatch.setattr(ilcsan.analysis.report, "plot_curves", lambda *_args: None)
    monkeypatch.setattr(ilcsan.rl.evaluation, "random_policy_return", lambda *_args, **_kwargs: -1234.5)
    assert main(["demo", "--out", str(tmp_path / "demo")]) == 0
    config = seen["config"]
    assert (config.task, config.steps, config.seeds) == (commands.DEMO_TASK, commands.DEMO_STEPS, (0,))
    assert config.eval_every * commands.DEMO_EVALUATIONS == config.steps
    assert not seen["resume"], "a first demo starts a new run (no 'no checkpoint yet' note)"
    out = capsys.readouterr().out
    assert "random policy scores -1234.5" in out and "-150.0 (step 9000)" in out and "its last -160.0" in out
    (tmp_path / "demo").mkdir()
    (tmp_path / "demo" / "metrics.csv").write_text("step,eval_return_mean\n1000,-1300.0\n")
    assert main(["demo", "--out", str(tmp_path / "demo")]) == 0
    assert seen["resume"], "running the quick start again continues the demo it holds instead of refusing"


# ------------------------------------------------------------------------------- train --like RUN
LIKED = RunConfig(task="Pendulum-v1", steps=300, eval_every=150, eval_episodes=1, label="mine", table="intra",
                  row="self", checkpoint_minutes=0.0,
                  actor=actor_config("ilc-san", hidden=(24, 16), intra="self", decoder="max", alpha_v_li=0.75),
                  training=TrainingConfig(start_steps=150, update_after=100, batch_size=16, gamma=0.98))
"""A run with switches off the preset (widths the switches cannot express among them), a training setting that has no
flag (γ), a label and a grid's tags."""


@pytest.fixture
def liked_run(tmp_path):
    from ilcsan.runs.directory import RunDirectory

    RunDirectory(tmp_path / "liked").write_config(LIKED, seed=7)
    return tmp_path / "liked"


def _like(*argv):
    from ilcsan.cli import parse_arguments

    return build_run_config(parse_arguments(build_parser(), ["train", *argv]))


def test_train_like_a_run_takes_every_setting_but_its_seeds_and_grid_tags(liked_run):
    untagged = dataclasses.replace(LIKED, table=None, row=None)
    assert _like("--like", str(liked_run)) == untagged  # seeds: the flag's default, 0
    assert _like("--like", str(liked_run / "config.json"), "--seeds", "3-4") == dataclasses.replace(untagged,
                                                                                                     seeds=(3, 4))


def test_each_flag_given_with_like_changes_that_one_setting(liked_run):
    changed = _like("--like", str(liked_run), "--intra", "none", "--steps", "1000000", "--hidden-width", "32",
                    "--batch-size", "100")
    expected = dataclasses.replace(
        LIKED, table=None, row=None, steps=1_000_000,  # the default's value given explicitly still counts
        actor=dataclasses.replace(LIKED.actor, intra="none", hidden=(32, 32)),
        training=dataclasses.replace(LIKED.training, batch_size=100))
    assert changed == expected


def test_train_like_trains_that_configuration_and_notes_a_label_kept_for_another_actor(liked_run, tmp_path,
                                                                                      capsys):
    import json

    out = tmp_path / "again"
    assert main(["train", "--like", str(liked_run), "--seeds", "1", "--intra", "none", "--no-progress",
                 "--out", str(out)]) == 0
    assert "note: this run keeps the label 'mine'" in capsys.readouterr().out
    saved = RunConfig.from_dict(json.loads((out / "config.json").read_text()))
    assert saved == dataclasses.replace(LIKED, seeds=(1,), table=None, row=None,
                                        actor=dataclasses.replace(LIKED.actor, intra="none"))


def test_train_like_refuses_another_preset_or_a_folder_without_a_run_in_one_line(liked_run, tmp_path, capsys):
    for argv, fragment in (
            (["--like", str(liked_run), "--actor", "popsan"], "copies that run's actor (ilc-san with its switches)"),
            (["--like", str(tmp_path / "nowhere")], "config.json: cannot be read"),
            (["--like", str(liked_run / "metrics.csv")], "pass a run folder or its config.json")):
        (liked_run / "metrics.csv").write_text("step\n")
        code = main(["train", *argv])
        err = capsys.readouterr().err
        assert code == 2 and len(err.strip().splitlines()) == 1 and fragment in err, err
