"""Command-line options shared by the commands: argument types, seed lists, and the actor, run and TD3
switches, generated from the fields of :mod:`ilcsan.config` (flag, type, default, choices and help)."""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path
from typing import Any

from ..arguments import int_at_least, positive_int
from ..config import ActorConfig, RunConfig, actor_config, method_settings, td3_config_class
from ..errors import UserError
from ..settings import check_settings, flag_of, help_text, renamed_note, setting_type

# ------------------------------------------------------------------------------------ helpers
MAX_SEEDS = 1000


def parse_seeds(text: str) -> tuple[int, ...]:
    """'3' → (3,), '0-9' → (0..9), '0,2,5' → (0, 2, 5)."""
    seeds: list[int] = []
    try:
        for part in text.split(","):
            part = part.strip()
            if "-" in part[1:]:
                first, last = part.split("-", 1) if not part.startswith("-") else (part, part)
                low, high = int(first), int(last)
                if high < low:
                    raise ValueError
                if high - low >= MAX_SEEDS:
                    raise UserError(f"--seeds {text!r} gives {high - low + 1} seeds; one run trains at most "
                                    f"{MAX_SEEDS} together")
                seeds.extend(range(low, high + 1))
            else:
                seeds.append(int(part))
    except UserError:
        raise
    except ValueError:
        raise UserError(f"--seeds {text!r} is not a seed list; write e.g. 0, 0-9 or 0,2,5") from None
    if any(seed < 0 for seed in seeds) or len(set(seeds)) != len(seeds):
        raise UserError(f"--seeds {text!r}: seeds must be distinct non-negative integers")
    if len(seeds) > MAX_SEEDS:
        raise UserError(f"--seeds {text!r} gives {len(seeds)} seeds; one run trains at most {MAX_SEEDS} together")
    return tuple(seeds)


def _finite_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} must be finite")
    return value


# ------------------------------------------------------------------- switches generated from the config
def _argparse_type(config_class: type, setting_field) -> Any:
    """The argparse type of a field: whole numbers of at least its minimum, finite floats, strings as given."""
    kind = setting_type(config_class, setting_field)
    if kind is int:
        return int_at_least(setting_field.metadata.get("minimum") or 0)
    if kind is float:
        return _finite_float
    return None


def _help(text: str, default: str | None) -> str:
    """Help text with its default, ``%`` escaped for argparse."""
    return (text if default is None else f"{text} ({default})").replace("%", "%%")


def _metavar(setting_field) -> str:
    """``{a,b,c}`` for a choice, else the flag's name in capitals."""
    choices = setting_field.metadata["choices"]
    if choices is not None:
        return "{" + ",".join(choices) + "}"
    return flag_of(setting_field)[2:].upper().replace("-", "_")


def add_setting(parser, config_class: type, name: str, *, default: Any = dataclasses.MISSING,
                default_text: str | None = None) -> None:
    """Add the option of one field of a config class: flag, type, choices, help and default from the field.

    ``default`` replaces the field's default (e.g. None where another layer decides); ``default_text`` then
    says what that means in the help, ``{paper}`` standing for the field's default (the paper's value)."""
    setting_field = next(item for item in dataclasses.fields(config_class) if item.name == name)
    meta = setting_field.metadata
    value = setting_field.default if default is dataclasses.MISSING else default
    if default_text is not None:
        shown = default_text.format(paper=setting_field.default)
    else:
        shown = None if value is None else f"default: {value}"
    parser.add_argument(flag_of(setting_field), *meta["aliases"], dest=name, default=value,
                        type=_argparse_type(config_class, setting_field), metavar=_metavar(setting_field),
                        help=_help(help_text(setting_field), shown))


def actor_switches() -> list[tuple[str, tuple[str, ...], dict[str, Any]]]:
    """(flag, aliases, argparse options) of every actor switch, generated from :class:`ActorConfig`'s fields.

    The preset's switch defaults to ILC-SAN; every other switch defaults to None (the preset decides) and its
    help names the paper's value, which is the field's default. A field with ``switches`` in its metadata is
    offered through those switches instead (``hidden`` as ``--hidden-layers`` and ``--hidden-width``)."""
    switches = []
    for item in dataclasses.fields(ActorConfig):
        meta = item.metadata
        for part in meta["switches"]:
            switches.append(("--" + part.flag, (), {
                "dest": part.flag.replace("-", "_"), "type": positive_int,
                "help": _help(part.help, f"paper: {part.default_of(item.default)}")}))
        if not meta["switches"]:
            is_preset = item.name == "preset"
            switches.append((flag_of(item), meta["aliases"], {
                "dest": item.name, "default": item.default if is_preset else None, "metavar": _metavar(item),
                "type": _argparse_type(ActorConfig, item),
                "help": _help(help_text(item), f"{'default' if is_preset else 'paper'}: {item.default}")}))
    return switches


def _add_actor_switches(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("actor (a preset, then any switch overrides it; see `ilcsan actors`)")
    for flag, aliases, options in actor_switches():
        group.add_argument(flag, *aliases, **options)


def actor_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The actor switches given on the command line (None: the preset's value)."""
    return {options["dest"]: getattr(args, options["dest"], None) for _, _, options in actor_switches()
            if options["dest"] != "preset"}


RUN_SETTINGS = ("algorithm", "contact_forces", "eval_every", "eval_episodes", "device", "engine", "threads", "compile",
                "matmul", "checkpoint_minutes")
"""The :class:`~ilcsan.config.RunConfig` fields ``train`` offers besides the task, seeds and steps."""
PROTOCOL_SETTINGS = ("start_steps", "update_after", "update_every", "batch_size")
"""The fields of the :class:`~ilcsan.config.TrainingProtocol` that ``train`` offers."""


def td3_settings() -> tuple[str, ...]:
    """The training settings ``train`` offers: :data:`PROTOCOL_SETTINGS` and every method's and algorithm's
    (:func:`~ilcsan.config.method_settings`)."""
    return PROTOCOL_SETTINGS + method_settings()


def _add_run_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seeds", "--seed", dest="seeds", default="0",
                        help="seed or seeds: 0, 0-9 or 0,2,5; several seeds train together in one process")
    add_setting(parser, RunConfig, "steps")
    for name in RUN_SETTINGS:
        add_setting(parser, RunConfig, name)
    for name in td3_settings():
        add_setting(parser, td3_config_class(), name)


def build_run_config(args: argparse.Namespace, task: str | None = None):
    """A :class:`~ilcsan.config.RunConfig` from parsed ``train`` arguments; with ``--like``, TD3 settings that have
    no flag (γ, τ, the critic, ...) are the liked run's."""
    like = getattr(args, "like_config", None)
    td3 = {name: getattr(args, name) for name in td3_settings()}
    note = renamed_note(td3_config_class(), td3)
    if note:
        print(note, file=sys.stderr)
    config = RunConfig(
        task=task or args.task, seeds=parse_seeds(args.seeds), steps=args.steps,
        actor=actor_config(args.preset, **_actor_settings(args, like)),
        td3=dataclasses.replace(like.td3, **td3) if like is not None else td3_config_class()(**td3),
        label=getattr(args, "label", None), **{name: getattr(args, name) for name in RUN_SETTINGS},
    )
    check_settings(config)
    check_settings(config.td3)
    return config


# ------------------------------------------------------------------------------- train --like RUN
def _actor_settings(args: argparse.Namespace, like: RunConfig | None) -> dict[str, Any]:
    """The actor switches given; with ``--like``, a field offered through several switches (``hidden``) that none
    of them changed is the liked run's own value, which those switches may not express (widths 256, 128)."""
    settings = actor_overrides(args)
    if like is None:
        return settings
    for item in dataclasses.fields(ActorConfig):
        liked = getattr(like.actor, item.name)
        parts = {part.flag.replace("-", "_"): part.default_of(liked) for part in item.metadata["switches"]}
        if parts and all(settings.get(name) == value for name, value in parts.items()):
            for name in parts:
                settings.pop(name)
            settings[item.name] = liked
    return settings


def liked_run_config(path: str) -> RunConfig:
    """The settings of the run at ``path`` (a run folder, a folder of stacked seeds, which share their settings, or
    a run's config.json), for ``train --like``; one-line UserError when there is none."""
    from ..runs.directory import CONFIG, RunDirectory, RunFileError

    if "\0" in path:
        raise UserError(f"--like {path!r} is not a path")
    given = Path(path)
    try:
        if given.is_file() and given.name != CONFIG:
            raise UserError(f"--like {path}: pass a run folder or its {CONFIG}")
        folder = given.parent if given.is_file() else given
        if given.is_dir() and not RunDirectory(given).file(CONFIG).is_file():
            seeds = sorted(p for p in given.glob("seed*") if RunDirectory(p).file(CONFIG).is_file())
            folder = seeds[0] if seeds else given
        return RunConfig.from_dict(RunDirectory(folder).config_object())
    except RunFileError as error:
        raise UserError(f"--like {path}: {error}; pass a run folder (it holds config.json)") from None
    except UserError:
        raise
    except (KeyError, TypeError, ValueError) as error:
        raise UserError(f"--like {path}: its config.json is not an ilcsan run's ({error})") from None


def like_defaults(config: RunConfig) -> dict[str, Any]:
    """``train``'s option values that give ``config``: defaults for ``--like``, which the flags given override. The
    seeds are not taken (give --seeds), nor a grid's table and row: the new run is a ``train`` run, which
    ``ilcsan report`` places by its label, or with ``--table`` by its settings."""
    values: dict[str, Any] = {"task": config.task, "steps": config.steps, "label": config.label,
                              "preset": config.actor.preset}
    values |= {name: getattr(config, name) for name in RUN_SETTINGS}  # contact_forces None (the task's default)
    # stays None, so that --like with another --task takes that task's default
    values |= {name: getattr(config.td3, name) for name in td3_settings()}
    for item in dataclasses.fields(ActorConfig):
        value = getattr(config.actor, item.name)
        for part in item.metadata["switches"]:
            values[part.flag.replace("-", "_")] = part.default_of(value)
        if not item.metadata["switches"] and item.name != "preset":
            values[item.name] = value
    return values


def choices_help(choices: dict[str, str], default: str) -> str:
    """The help of an option with declared choices: ``a (what a; default) | b (what b)``."""
    return " | ".join(f"{name} ({what}{'; default' if name == default else ''})" for name, what in choices.items())
