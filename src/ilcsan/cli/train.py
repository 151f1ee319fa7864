"""``ilcsan train``: its options, generated from the fields of :mod:`ilcsan.config`, the run configuration they make
(``--like RUN`` starts from another run's), and the handler that trains it (:func:`ilcsan.rl.training.train`)."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

from ..config import ActorConfig, RunConfig, actor_config, method_settings, training_config_class
from ..errors import UserError
from ..settings import check_settings, renamed_note
from .options import actor_overrides, add_actor_switches, add_setting, parse_seeds

RUN_SETTINGS = ("algorithm", "contact_forces", "eval_every", "eval_episodes", "device", "engine", "threads", "compile",
                "matmul", "checkpoint_minutes")
"""The :class:`~ilcsan.config.RunConfig` fields ``train`` offers besides the task, seeds and steps."""
PROTOCOL_SETTINGS = ("start_steps", "update_after", "update_every", "batch_size")
"""The fields of the :class:`~ilcsan.config.TrainingProtocol` that ``train`` offers."""


def training_settings() -> tuple[str, ...]:
    """The training settings ``train`` offers: :data:`PROTOCOL_SETTINGS` and every method's and algorithm's
    (:func:`~ilcsan.config.method_settings`)."""
    return PROTOCOL_SETTINGS + method_settings()


# ---------------------------------------------------------------------------------- the command
def add_train_command(subparsers) -> None:
    """``ilcsan train``: the task, the actor switches and the run and training options, all from the config."""
    train = subparsers.add_parser("train", help="train an actor (TD3, DDPG or SAC)",
                                description="Train an actor with a deep critic: TD3 (the paper's), DDPG or SAC.")
    train.add_argument("--task", default=RunConfig.task,
                       help=f"paper short name (see `ilcsan tasks`), a Gymnasium id, or your own task as "
                            f"module:id (its module is imported first; default: {RunConfig.task})")
    add_actor_switches(train)
    _add_run_options(train)
    train.add_argument("--out", help="run directory (default runs/<task>-<actor>-s<seeds>)")
    train.add_argument("--resume", action="store_true",
                       help="continue the run in --out from its last checkpoint (a larger --steps extends it)")
    train.add_argument("--like", metavar="RUN", help="start from every setting of the run in RUN (task, actor, TD3 "
                       "and run options, --steps, --label; not its seeds): each flag given here changes that one")
    train.add_argument("--label", help="row label for reports (default: the preset)")
    train.add_argument("--no-progress", action="store_true", help="no progress bar (one line per evaluation)")
    train.set_defaults(handler=cmd_train)


def cmd_train(args: argparse.Namespace) -> int:
    """Train the run the arguments describe (:func:`build_run_config`) into ``--out`` and print each seed's best
    evaluation."""
    from ..rl.tasks import task_file_name
    from ..rl.training import train

    config = build_run_config(args)
    if args.like:
        _note_a_kept_label(config, args.like_config, args.like)
    seeds = args.seeds.replace(",", "_")
    out = Path(args.out or f"runs/{task_file_name(config.task)}-{config.actor.preset}-s{seeds}")
    results = train(config, out, resume=args.resume, progress=None if not args.no_progress else False)
    print_results(results, out)
    return 0


def build_run_config(args: argparse.Namespace, task: str | None = None):
    """A :class:`~ilcsan.config.RunConfig` from parsed ``train`` arguments; with ``--like``, training settings that have
    no flag (γ, τ, the critic, ...) are the liked run's."""
    like = getattr(args, "like_config", None)
    training = {name: getattr(args, name) for name in training_settings()}
    note = renamed_note(training_config_class(), training)
    if note:
        print(note, file=sys.stderr)
    config = RunConfig(
        task=task or args.task, seeds=parse_seeds(args.seeds), steps=args.steps,
        actor=actor_config(args.preset, **_actor_settings(args, like)),
        training=(dataclasses.replace(like.training, **training) if like is not None
                  else training_config_class()(**training)),
        label=getattr(args, "label", None), **{name: getattr(args, name) for name in RUN_SETTINGS},
    )
    check_settings(config)
    check_settings(config.training)
    return config


def _add_run_options(parser: argparse.ArgumentParser) -> None:
    """The seeds, the steps, :data:`RUN_SETTINGS` and the training settings (:func:`training_settings`)."""
    parser.add_argument("--seeds", "--seed", dest="seeds", default="0",
                        help="seed or seeds: 0, 0-9 or 0,2,5; several seeds train together in one process")
    add_setting(parser, RunConfig, "steps")
    for name in RUN_SETTINGS:
        add_setting(parser, RunConfig, name)
    for name in training_settings():
        add_setting(parser, training_config_class(), name)


def print_results(results: list[dict[str, Any]], out: Path) -> None:
    """Each seed's best evaluation (the mean and spread over several seeds) and where the results are."""
    import numpy as np

    bests = [r["best_return"] for r in results if r["best_return"] is not None]
    if not bests:
        print(f"no evaluation was made; results are in {out}")
        return
    if len(results) == 1:
        r = results[0]
        print(f"best average evaluation return {r['best_return']:.1f} at step {r['best_step']} "
              f"(seed {r['seed']}, {r['steps_done']} steps); results in {out}")
    else:
        from ..analysis.reward_tables import seed_std

        spread = seed_std(bests)
        stat = f"{np.mean(bests):.1f}" + (f" ± {spread:.1f}" if spread is not None else "")
        print(f"best average evaluation return {stat} over {len(bests)} seeds (sample std) "
              f"({', '.join(f'{b:.1f}' for b in bests)}); results in {out}/seed*")


def _note_a_kept_label(config: RunConfig, like: RunConfig, path: str) -> None:
    """``train --like``: say so when the run keeps the liked run's label but not its actor or training method, so
    that a report does not put the two in one row unknowingly."""
    from ..analysis.collect import configuration_key

    def key(run: RunConfig) -> str:
        return configuration_key(run.actor.to_dict(), run.training.to_dict(), run.algorithm)

    custom = like.label not in (None, like.actor.preset)  # a preset's own name is every such run's default label
    if custom and config.label == like.label and key(config) != key(like):
        print(f"note: this run keeps the label {config.label!r} of {path}, whose actor or training method differs; "
              "give --label to report it in a row of its own")


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
    values |= {name: getattr(config.training, name) for name in training_settings()}
    for item in dataclasses.fields(ActorConfig):
        value = getattr(config.actor, item.name)
        for part in item.metadata["switches"]:
            values[part.flag.replace("-", "_")] = part.default_of(value)
        if not item.metadata["switches"] and item.name != "preset":
            values[item.name] = value
    return values
