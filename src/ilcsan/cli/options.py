"""Command-line options shared by the commands: argument types, seed lists, an option generated from a field of
:mod:`ilcsan.config` (flag, type, default, choices and help) and the actor switches. The options of ``train`` and the
run configuration they make are :mod:`ilcsan.cli.train`'s."""

from __future__ import annotations

import argparse
import dataclasses
import math
from typing import Any

from ..arguments import int_at_least, positive_int
from ..config import ActorConfig
from ..errors import UserError
from ..settings import flag_of, help_text, setting_type

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


def add_actor_switches(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("actor (a preset, then any switch overrides it; see `ilcsan actors`)")
    for flag, aliases, options in actor_switches():
        group.add_argument(flag, *aliases, **options)


def actor_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The actor switches given on the command line (None: the preset's value)."""
    return {options["dest"]: getattr(args, options["dest"], None) for _, _, options in actor_switches()
            if options["dest"] != "preset"}


def choices_help(choices: dict[str, str], default: str) -> str:
    """The help of an option with declared choices: ``a (what a; default) | b (what b)``."""
    return " | ".join(f"{name} ({what}{'; default' if name == default else ''})" for name, what in choices.items())
