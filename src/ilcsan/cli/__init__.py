"""The ``ilcsan`` command: train, evaluate, reproduce, report, energy, export, and listings.

User mistakes (unknown task or option, bad values, corrupt files) print one line and exit with code 2;
a training run that diverges prints one line and exits with code 3, keeping its last checkpoint.
"""

from __future__ import annotations

import argparse
import os
import sys

from ..errors import TrainingDiverged, UserError
from . import commands, grid_commands
from .options import _add_actor_switches, _add_run_options, _non_negative_int, _positive_int

EXIT_USER_ERROR = 2
EXIT_DIVERGED = 3


class _Parser(argparse.ArgumentParser):
    """argparse whose errors are one line and exit code 2."""

    def error(self, message: str):  # noqa: D102
        raise UserError(f"{self.prog}: {message} (see `{self.prog} --help`)")


# ------------------------------------------------------------------------------------- parser
def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="ilcsan", description="Fully spiking actor networks (ILC-SAN) for continuous control.")
    from .. import __version__

    parser.add_argument("--version", action="version", version=f"ilcsan {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    train = subparsers.add_parser("train", help="train an actor with TD3",
                                description="Train an actor with TD3 and a deep twin critic.")
    train.add_argument("--task", default="Hopper", help="paper short name (see `ilcsan tasks`) or a Gymnasium id")
    _add_actor_switches(train)
    _add_run_options(train, steps_default=1_000_000)
    train.add_argument("--out", help="run directory (default runs/<task>-<actor>-s<seeds>)")
    train.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    train.add_argument("--label", help="row label for reports (default: the preset)")
    train.add_argument("--no-progress", action="store_true", help="no progress bar (one line per evaluation)")
    train.set_defaults(handler=commands.cmd_train)

    evaluate = subparsers.add_parser("evaluate", help="evaluate a trained actor",
                                   description="Run deterministic episodes with a trained actor.")
    evaluate.add_argument("run", help="run directory, policy.pt or checkpoint.pt")
    evaluate.add_argument("--episodes", type=_positive_int, default=10, help="episodes (paper: 10)")
    evaluate.add_argument("--seed", type=_non_negative_int, default=0, help="environment seed of the first episode")
    evaluate.add_argument("--task", help="evaluate on another task of the same shape (default: the training task)")
    evaluate.set_defaults(handler=commands.cmd_evaluate)

    export = subparsers.add_parser("export", help="export a trained actor (npz bundle or NIR graph)",
                                 description="Export a trained actor for deployment.")
    export.add_argument("run", help="run directory, policy.pt or checkpoint.pt")
    export.add_argument("--format", default="npz", help="npz (deploy bundle) | nir (neuromorphic graph)")
    export.add_argument("--out", help="output file (default: <run>/actor.<format>)")
    export.add_argument("--weights", default="float32", help="float32 (default) | int8 (per-layer scales)")
    export.set_defaults(handler=commands.cmd_export)

    reproduce = subparsers.add_parser("reproduce", help="run a table of the paper as a grid of runs",
                                    description="Run the grid of a paper table (or your own TOML grid).")
    reproduce.add_argument("table", nargs="?", help="perf | decode | dec_intra | intra | layer | path/to/grid.toml")
    reproduce.add_argument("--list", action="store_true", help="list the tables and their grids")
    reproduce.add_argument("--seeds", default=None, help="seeds (paper: 0-9)")
    reproduce.add_argument("--steps", type=_positive_int, default=None, help="steps per run (paper: 1000000)")
    reproduce.add_argument("--tasks", default=None, help="comma-separated subset of the table's tasks")
    reproduce.add_argument("--rows", default=None, help="comma-separated subset of the table's rows")
    reproduce.add_argument("--eval-every", type=_positive_int, default=None, help="(paper: 10000)")
    reproduce.add_argument("--eval-episodes", type=_positive_int, default=None, help="(paper: 10)")
    reproduce.add_argument("--start-steps", type=_non_negative_int, default=None, help="(paper: 10000)")
    reproduce.add_argument("--out", default="runs/reproduce", help="grid directory (default runs/reproduce)")
    reproduce.add_argument("--backend", default="local", help="local (default) | ray")
    reproduce.add_argument("--address", default=None, help="Ray cluster address (default: start a local Ray)")
    reproduce.add_argument("--workers", type=_positive_int, default=None, help="parallel runs (default: cores)")
    reproduce.add_argument("--device", default="cpu", help="cpu | cuda")
    reproduce.add_argument("--matmul", default="float32", help="float32 (default) | bf16 (see train --matmul)")
    reproduce.add_argument("--dashboard", action="store_true",
                           help="start the Ray dashboard (on 127.0.0.1) with the local Ray")
    reproduce.set_defaults(handler=grid_commands.cmd_reproduce)

    report = subparsers.add_parser("report", help="tables and learning curves from runs",
                                 description="Build the paper's tables and learning curves from runs on disk.")
    report.add_argument("directory", help="folder holding runs (searched recursively)")
    report.add_argument("--table", default=None, help="table layout to use (default: from the runs' tags)")
    report.add_argument("--out", default=None, help="where to write report.md/.tex/.csv and curves.png")
    report.set_defaults(handler=grid_commands.cmd_report)

    energy = subparsers.add_parser("energy", help="firing rates, operation counts and energy per inference",
                                 description="Energy analysis of trained actors (Section V-F).")
    energy.add_argument("runs", nargs="+", help="run directories or policy.pt files")
    energy.add_argument("--episodes", type=_positive_int, default=1, help="episodes to measure (paper: 1)")
    energy.add_argument("--seed", type=_non_negative_int, default=0, help="environment seed")
    energy.add_argument("--json", action="store_true", help="print JSON instead of tables")
    energy.set_defaults(handler=grid_commands.cmd_energy)

    actors = subparsers.add_parser("actors", help="list the actor presets and their settings")
    actors.add_argument("--json", action="store_true", help="every switch of every preset as JSON")
    actors.set_defaults(handler=commands.cmd_actors)

    tasks = subparsers.add_parser("tasks", help="list the paper's tasks and their sizes")
    tasks.set_defaults(handler=commands.cmd_tasks)

    demo = subparsers.add_parser("demo", help="train ILC-SAN briefly on a small task and plot its learning curve",
                               description="A short ILC-SAN run that shows the whole pipeline in minutes.")
    demo.add_argument("--task", default="InvertedPendulum-v4", help="task (default InvertedPendulum-v4)")
    demo.add_argument("--steps", type=_positive_int, default=12_000, help="steps (default 12000)")
    demo.add_argument("--seed", type=_non_negative_int, default=0)
    demo.add_argument("--out", default="runs/demo", help="run directory (default runs/demo)")
    demo.add_argument("--threads", type=_positive_int, default=None)
    demo.set_defaults(handler=commands.cmd_demo)
    return parser


def _one_line(error: Exception) -> str:
    """The message on one line whatever the user typed: line breaks and other control characters escaped."""
    return "".join(char if char.isprintable() else repr(char)[1:-1] for char in str(error))


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``ilcsan`` console script."""
    parser = build_parser()
    args = None
    try:
        args = parser.parse_args(argv)
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

