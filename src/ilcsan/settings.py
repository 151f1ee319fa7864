"""Settings described once: a dataclass field's help, choices, bounds and command-line flag in its metadata
(:func:`setting`), and what reads them — the command line (:mod:`ilcsan.cli.options`), :func:`check_settings`, the
renamed spellings of choices. The configuration (:mod:`ilcsan.config`) and every training method and algorithm
(:mod:`ilcsan.methods`) declare their settings with :func:`setting`."""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import field
from typing import Any, NamedTuple

from .errors import UserError


class Switch(NamedTuple):
    """A command-line switch that sets part of a field (``hidden`` is offered as a layer count and a width)."""

    flag: str
    help: str
    default_of: Callable[[Any], Any]
    """The switch's value implied by the field's value, e.g. ``len`` of the hidden widths."""


def setting(default: Any, help: str | Callable[[], str], *, choices: tuple[str, ...] | Mapping[str, Any] | None = None,
            flag: str | None = None, aliases: tuple[str, ...] = (), minimum: int | None = None,
            bounds: str | None = None, switches: tuple[Switch, ...] = (),
            renamed: Mapping[str, str] | None = None) -> Any:
    """A dataclass field described once for the command line and for :func:`check_settings`.

    ``help`` may be a function that says it when asked (:func:`help_text`: a choice among registered methods names
    them as they are then); ``flag`` is the CLI name when it is not the field name with dashes; ``minimum`` bounds
    whole numbers; ``bounds`` is ``"decay"`` (a factor in [0, 1]), ``"positive"`` or ``"non-negative"`` for real
    numbers (None, where a field allows it, passes); ``switches`` replace the field's own switch by switches that each
    set part of it; ``renamed`` maps the old spellings of choices to today's (:func:`current_spellings`).
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


def help_text(setting_field: dataclasses.Field) -> str:
    """The help of a described field, made now when it is a function."""
    text = setting_field.metadata["help"]
    return text() if callable(text) else text


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
