"""The ``ilcsan`` command: train, evaluate, reproduce, report, energy, export, and listings.

User mistakes (unknown task or option, bad values, corrupt files) print one line and exit with code 2;
a training run that diverges prints one line and exits with code 3, keeping its last checkpoint.
"""

from __future__ import annotations

import argparse
import os
import sys

from .. import __version__
from ..analysis.comparison import BOOTSTRAP_REPS, BOOTSTRAP_SEED
from ..arguments import non_negative_int, positive_int
from ..config import BACKENDS, COLLAPSE_RETURN, EXPORT_FORMATS, NIR_TARGETS, WEIGHT_FORMATS, RunConfig, TrainingProtocol
from ..deploy.lava import run_options
from ..errors import TrainingDiverged, UserError
from ..paper.layouts import SEEDS, TABLES
from . import commands, grid_commands
from .options import add_setting, choices_help
from .train import add_train_command, like_defaults, liked_run_config

EXIT_USER_ERROR = 2
EXIT_DIVERGED = 3


_GRIDS = "default: the grid's; paper: {paper}"


class _Parser(argparse.ArgumentParser):
    """argparse whose errors are one line and exit code 2."""

    commands: dict[str, argparse.ArgumentParser]
    """The sub-commands' parsers by name (on the top-level parser)."""

    def error(self, message: str):  # noqa: D102
        raise UserError(f"{self.prog}: {message} (see `{self.prog} --help`)")


# ------------------------------------------------------------------------------------- parser
def build_parser() -> argparse.ArgumentParser:
    """The ``ilcsan`` parser: one sub-command per ``add_*_command``, ``train``'s in :mod:`ilcsan.cli.train`, the
    others' below."""
    parser = _Parser(prog="ilcsan", description="Fully spiking actor networks (ILC-SAN) for continuous control.")
    parser.add_argument("--version", action="version", version=f"ilcsan {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for add_command in (add_train_command, _add_evaluate_command, _add_export_command, _add_reproduce_command,
                        _add_report_command, _add_energy_command, _add_actors_command, _add_tasks_command,
                        _add_demo_command, _add_lava_command):
        add_command(subparsers)
    parser.commands = subparsers.choices
    return parser


def _add_evaluate_command(subparsers) -> None:
    """``ilcsan evaluate RUN``: deterministic episodes with a trained actor."""
    evaluate = subparsers.add_parser("evaluate", help="evaluate a trained actor",
                                   description="Run deterministic episodes with a trained actor, or with its deploy "
                                               "bundle in the numpy runtime (what a robot runs; int8 included).")
    evaluate.add_argument("run", help="run directory, policy.pt, checkpoint.pt, or a deploy bundle (.npz from "
                                      "`ilcsan export`)")
    evaluate.add_argument("--episodes", type=positive_int, default=10, help="episodes (paper: 10)")
    evaluate.add_argument("--seed", type=non_negative_int, default=0, help="environment seed of the first episode")
    evaluate.add_argument("--task", help="evaluate on another task of the same shape (default: the training task)")
    add_setting(evaluate, RunConfig, "contact_forces", default=None,
                default_text="default: as in training; a run saved before this setting existed: simulated")
    evaluate.add_argument("--video", metavar="DIR", help="also write each episode to DIR/<task>-seed<S>.mp4 "
                          "(rendered off-screen; needs imageio-ffmpeg, which scripts/setup installs)")
    evaluate.set_defaults(handler=commands.cmd_evaluate)


def _add_export_command(subparsers) -> None:
    """``ilcsan export RUN``: an npz deploy bundle or a NIR graph."""
    export = subparsers.add_parser("export", help="export a trained actor (npz bundle or NIR graph)",
                                 description="Export a trained actor for deployment.")
    export.add_argument("run", help="run directory, policy.pt or checkpoint.pt")
    export.add_argument("--format", default="npz", help=choices_help(EXPORT_FORMATS, "npz"))
    export.add_argument("--out", help="output file (default: <run>/actor.<format>)")
    export.add_argument("--weights", default="float32", help=choices_help(WEIGHT_FORMATS, "float32"))
    export.add_argument("--target", default="portable", help="NIR profile: " + choices_help(NIR_TARGETS, "portable"))
    export.set_defaults(handler=commands.cmd_export)


def _add_reproduce_command(subparsers) -> None:
    """``ilcsan reproduce TABLE|GRID.toml``: a paper table or a TOML grid as a grid of runs."""
    reproduce = subparsers.add_parser("reproduce", help="run a table of the paper as a grid of runs",
                                    description="Run the grid of a paper table (or your own TOML grid).")
    reproduce.add_argument("table", nargs="?", help=" | ".join([*TABLES, "path/to/grid.toml"]))
    reproduce.add_argument("--list", action="store_true",
                           help="list the tables and their grids, with run counts and hours estimated from this "
                                "machine's speed (measured once, about a minute, and kept; ILCSAN_STEPS_PER_SECOND "
                                "sets it instead)")
    reproduce.add_argument("--seeds", default=None, help=f"seeds (default: the grid's; paper: 0-{SEEDS - 1})")
    add_setting(reproduce, RunConfig, "steps", default=None, default_text=_GRIDS)
    reproduce.add_argument("--tasks", default=None, help="comma-separated tasks: the table's, or any other "
                           "(a paper task, a Gymnasium id or module:id, with Box actions; no paper numbers)")
    reproduce.add_argument("--rows", default=None, help="comma-separated subset of the table's rows")
    for name in ("eval_every", "eval_episodes"):
        add_setting(reproduce, RunConfig, name, default=None, default_text=_GRIDS)
    add_setting(reproduce, TrainingProtocol, "start_steps", default=None, default_text=_GRIDS)
    reproduce.add_argument("--out", default="runs/reproduce", help="grid directory (default runs/reproduce)")
    reproduce.add_argument("--backend", default="local", help=choices_help(BACKENDS, "local"))
    reproduce.add_argument("--address", default=None,
                           help="join the Ray cluster at HOST:PORT, or auto (this machine's, or RAY_ADDRESS's), "
                           "sending this machine's Ray token if it has one (docs/cluster.md); default: start a "
                           "private local Ray")
    reproduce.add_argument("--workers", type=positive_int, default=None, help="parallel runs (default: cores)")
    add_setting(reproduce, RunConfig, "contact_forces")
    add_setting(reproduce, RunConfig, "device")
    add_setting(reproduce, RunConfig, "matmul")
    reproduce.add_argument("--dashboard", action="store_true",
                           help="start the Ray dashboard (on 127.0.0.1) with the local Ray")
    reproduce.set_defaults(handler=grid_commands.cmd_reproduce)


def _add_report_command(subparsers) -> None:
    """``ilcsan report DIR``: the paper's tables and learning curves from runs on disk."""
    report = subparsers.add_parser("report", help="tables and learning curves from runs",
                                 description="Build the paper's tables and learning curves from runs on disk.")
    report.add_argument("directory", nargs="+",
                        help="folder holding runs (searched recursively); several folders are reported together "
                             "(then give --out)")
    report.add_argument("--table", default=None,
                        help="table layout to use (default: from the runs' tags); runs not written by `reproduce` "
                             "land in the row with their label, else in the row with their actor settings and "
                             "training method; runs of another table's grid in the row with their settings and "
                             "method")
    report.add_argument("--out", default=None, help="where to write report.md/.tex/.csv and curves.png")
    report.add_argument("--seeds", default=None,
                        help="only the runs of these seeds, e.g. 1-3 or 0,2,5: rows compared on the same seeds "
                             "(default: every run found; the report's title names the seeds)")
    report.add_argument("--collapse", default=None, metavar="STEPS",
                        help="comma-separated steps, e.g. 30000,50000: also count each row's seeds still in the "
                             "collapsed start there (return below --collapse-return), with 95 %% intervals and "
                             "Fisher's exact test between rows, and draw diagnostics.png")
    report.add_argument("--collapse-return", type=float, default=COLLAPSE_RETURN,
                        help=f"the return below which a seed counts as collapsed (default {COLLAPSE_RETURN:g}, "
                             "Hopper's falls)")
    report.add_argument("--bootstrap-reps", type=positive_int, default=BOOTSTRAP_REPS,
                        help="replicates of the stratified bootstrap whose 95 %% intervals tell rows apart (IQM, "
                             f"P(improvement), APR; default {BOOTSTRAP_REPS})")
    report.add_argument("--bootstrap-seed", type=non_negative_int, default=BOOTSTRAP_SEED,
                        help=f"seed of the bootstrap's draws (default {BOOTSTRAP_SEED}): the same report each time")
    report.set_defaults(handler=grid_commands.cmd_report)


def _add_energy_command(subparsers) -> None:
    """``ilcsan energy RUN...``: firing rates, operation counts and energy per inference."""
    energy = subparsers.add_parser("energy", help="firing rates, operation counts and energy per inference",
                                 description="Energy analysis of trained actors (Section V-F).")
    energy.add_argument("runs", nargs="+", help="run directories or policy.pt files")
    energy.add_argument("--episodes", type=positive_int, default=1, help="episodes to measure (paper: 1)")
    energy.add_argument("--seed", type=non_negative_int, default=0, help="environment seed")
    energy.add_argument("--json", action="store_true", help="print JSON instead of tables")
    energy.set_defaults(handler=grid_commands.cmd_energy)


def _add_actors_command(subparsers) -> None:
    """``ilcsan actors``: the presets and their settings."""
    actors = subparsers.add_parser("actors", help="list the actor presets and their settings")
    actors.add_argument("--json", action="store_true", help="every switch of every preset as JSON")
    actors.set_defaults(handler=commands.cmd_actors)


def _add_tasks_command(subparsers) -> None:
    """``ilcsan tasks``: the paper's tasks and the Gymnasium versions used."""
    tasks = subparsers.add_parser("tasks", help="list the paper's tasks and their sizes")
    tasks.set_defaults(handler=commands.cmd_tasks)


def _add_lava_command(subparsers) -> None:
    """``ilcsan lava RUN|BUNDLE``: the actor in Lava's simulator of Loihi 2, closed loop."""
    lava = subparsers.add_parser("lava", help="run a trained actor in Lava (Loihi 2's SDK), closed loop",
                                 parents=[run_options()],
                                 description="Run a trained actor as Lava processes in Lava's simulator of Loihi 2, "
                                             "closed loop on its task (needs `bash scripts/setup-lava`).")
    lava.add_argument("run", help="run directory, policy.pt, checkpoint.pt or a deploy bundle (.npz)")
    lava.set_defaults(handler=commands.cmd_lava)


def _add_demo_command(subparsers) -> None:
    """``ilcsan demo``: a short ILC-SAN run with its learning curve."""
    demo = subparsers.add_parser("demo", help="train ILC-SAN briefly on a small task and plot its learning curve",
                               description="A short ILC-SAN run that shows the whole pipeline in minutes.")
    demo.add_argument("--task", default=commands.DEMO_TASK, help=f"task (default {commands.DEMO_TASK})")
    demo.add_argument("--steps", type=positive_int, default=commands.DEMO_STEPS,
                      help=f"steps (default {commands.DEMO_STEPS})")
    demo.add_argument("--seed", type=non_negative_int, default=0, help="seed of the run (default 0)")
    demo.add_argument("--out", default="runs/demo", help="run directory (default runs/demo)")
    add_setting(demo, RunConfig, "threads")
    demo.set_defaults(handler=commands.cmd_demo)



def _one_line(error: Exception) -> str:
    """The message on one line whatever the user typed: line breaks and other control characters escaped."""
    return "".join(char if char.isprintable() else repr(char)[1:-1] for char in str(error))


def parse_arguments(parser: _Parser, argv: list[str] | None) -> argparse.Namespace:
    """Parse ``argv``; for ``train --like RUN``, once more with that run's settings as the defaults, so that only the
    flags given change it (``args.like_config`` is the liked run's RunConfig)."""
    args = parser.parse_args(argv)
    if getattr(args, "like", None):
        like = liked_run_config(args.like)
        parser.commands["train"].set_defaults(**like_defaults(like))
        args = parser.parse_args(argv)
        args.like_config = like
        if args.preset != like.actor.preset:
            raise UserError(f"--like {args.like} copies that run's actor ({like.actor.preset} with its switches); to "
                            f"train {args.preset}, start from its preset without --like")
    return args


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``ilcsan`` console script."""
    parser = build_parser()
    args = None
    try:
        args = parse_arguments(parser, argv)
        if args.command is None:
            parser.print_help()
            return EXIT_USER_ERROR
        return int(args.handler(args) or 0)
    except UserError as error:
        print(f"ilcsan: error: {_one_line(error)}", file=sys.stderr)
        return EXIT_USER_ERROR
    except TrainingDiverged as error:
        print(f"ilcsan: stopped: {_one_line(error)}", file=sys.stderr)
        return EXIT_DIVERGED
    except KeyboardInterrupt:
        hint = "run the same command again" if getattr(args, "command", None) == "reproduce" else \
            "continue with the same command and --resume"
        print(f"ilcsan: interrupted; {hint}", file=sys.stderr)
        return 130
    except BrokenPipeError:
        os._exit(0)

