"""The ``ilcsan`` command: train, evaluate, reproduce, report, energy, export, and listings.

User mistakes (unknown task or option, bad values, corrupt files) print one line and exit with code 2;
a training run that diverges prints one line and exits with code 3, keeping its last checkpoint.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

from .errors import TrainingDiverged, UserError

EXIT_USER_ERROR = 2
EXIT_DIVERGED = 3


class _Parser(argparse.ArgumentParser):
    """argparse whose errors are one line and exit code 2."""

    def error(self, message: str):  # noqa: D102
        raise UserError(f"{self.prog}: {message} (see `{self.prog} --help`)")


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


def _int_at_least(minimum: int):
    """An argparse type: a whole number (underscores allowed) of at least ``minimum``."""

    def parse(text: str) -> int:
        try:
            value = int(text.replace("_", ""))
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"{text!r} must be at least {minimum}")
        return value

    return parse


_positive_int = _int_at_least(1)
_non_negative_int = _int_at_least(0)


def _finite_float(text: str) -> float:
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} must be finite")
    return value


ACTOR_SWITCHES: list[tuple[str, dict[str, Any]]] = [
    ("--encoder", {"help": "input coding: pop-det (fully spiking) | pop-prob | pop | layer | two-neuron"}),
    ("--neuron", {"help": "backbone neuron: clif | dynamic (MDC-SAN)"}),
    ("--hidden-layers", {"type": _positive_int, "help": "number of hidden layers, 1-4 (paper: 2)"}),
    ("--hidden-width", {"type": _positive_int, "help": "neurons per hidden layer (paper: 256)"}),
    ("--intra", {"help": "intra-layer connections: intra | self | lateral | bias | lateral+bias | self+bias | "
                         "self+lateral | none"}),
    ("--decoder", {"help": "decoder statistic: last | max | mean (LI membrane voltage) | fr (firing rate)"}),
    ("--alpha-v-li", {"type": _finite_float, "help": "voltage decay of the decoder's LI neuron (paper: 1.0)"}),
    ("--timesteps", {"type": _positive_int, "help": "simulation time T per action (paper: 5)"}),
    ("--population-in", {"type": _positive_int, "help": "encoder neurons per state dimension (paper: 10)"}),
    ("--population-out", {"type": _positive_int, "help": "output neurons per action dimension (paper: 10)"}),
    ("--alpha-c", {"type": _finite_float, "help": "CLIF current decay (paper: 0.5)"}),
    ("--alpha-v", {"type": _finite_float, "help": "CLIF voltage decay (paper: 0.75)"}),
    ("--v-th", {"type": _finite_float, "help": "CLIF threshold (paper: 0.5)"}),
    ("--surrogate-width", {"type": _finite_float, "help": "rectangular surrogate window (paper: 0.5)"}),
    ("--actor-lr", {"type": _finite_float, "dest": "learning_rate",
                    "help": "actor learning rate (spiking 1e-4, DAN 1e-3)"}),
]
ACTOR_DESTS = ["encoder", "neuron", "hidden_layers", "hidden_width", "intra", "decoder", "alpha_v_li", "timesteps",
               "population_in", "population_out", "alpha_c", "alpha_v", "v_th", "surrogate_width", "learning_rate"]


def _add_actor_switches(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("actor (a preset, then any switch overrides it; see `ilcsan actors`)")
    group.add_argument("--actor", "--preset", dest="preset", default="ilc-san",
                       help="ilc-san (default) | popsan | mdc-san | akl | dan")
    for flag, options in ACTOR_SWITCHES:
        group.add_argument(flag, **options)


def _add_run_options(parser: argparse.ArgumentParser, steps_default: int | None) -> None:
    parser.add_argument("--seeds", "--seed", dest="seeds", default="0",
                        help="seed or seeds: 0, 0-9 or 0,2,5; several seeds train together in one process")
    parser.add_argument("--steps", type=_positive_int, default=steps_default,
                        help=f"environment steps per seed (default {steps_default})")
    parser.add_argument("--eval-every", type=_positive_int, default=None,
                        help="evaluate every this many steps (paper: 10000)")
    parser.add_argument("--eval-episodes", type=_positive_int, default=None,
                        help="episodes per evaluation (paper: 10)")
    parser.add_argument("--start-steps", type=_non_negative_int, default=None,
                        help="uniformly random actions before the actor acts (paper: 10000)")
    parser.add_argument("--update-after", type=_non_negative_int, default=None,
                        help="first TD3 update at this step (paper: 1000)")
    parser.add_argument("--update-every", type=_positive_int, default=None,
                        help="TD3 updates run in chunks of this many, one per step (authors' code: 50)")
    parser.add_argument("--batch-size", type=_positive_int, default=None, help="minibatch size (paper: 100)")
    parser.add_argument("--device", default="cpu", help="cpu (default) | cuda | cuda:N")
    parser.add_argument("--engine", default="fast", help="fast (layer-major, default) | reference (Algorithm 1)")
    parser.add_argument("--threads", type=_positive_int, default=None,
                        help="torch threads (default: torch's own; use 1 when several runs share the cores)")
    parser.add_argument("--compile", default="auto",
                        help="torch.compile the spiking actor and the no-grad target values (the trained critic and "
                             "DAN run eager, faster): auto (default: on for runs of 50000 steps or more) | on | off")
    parser.add_argument("--matmul", default="float32",
                        help="float32 (default) | bf16: matmul inputs rounded to bfloat16 with float32 accumulation, "
                             "on AMX/AVX512-BF16 CPUs (and TF32/bf16 on CUDA); pays on large matmuls (Ant, many seeds)")


def build_run_config(args: argparse.Namespace, task: str | None = None):
    """A :class:`~ilcsan.training.RunConfig` from parsed ``train`` arguments."""
    from .config import TD3Config, actor_config
    from .training import RunConfig

    overrides = {dest: getattr(args, dest, None) for dest in ACTOR_DESTS}
    actor = actor_config(args.preset, **overrides)
    td3_overrides = {name: getattr(args, name) for name in ("start_steps", "update_after", "update_every",
                                                             "batch_size") if getattr(args, name, None) is not None}
    defaults = {"eval_every": 10_000, "eval_episodes": 10}
    return RunConfig(
        task=task or args.task, seeds=parse_seeds(args.seeds), steps=args.steps,
        eval_every=args.eval_every or defaults["eval_every"],
        eval_episodes=args.eval_episodes or defaults["eval_episodes"],
        actor=actor, td3=TD3Config(**td3_overrides), device=args.device, engine=args.engine, threads=args.threads,
        compile=args.compile, matmul=args.matmul, label=getattr(args, "label", None),
    )


def _print_table(rows: list[dict[str, Any]], columns: list[str]) -> None:
    widths = {c: max(len(c), *(len(str(r.get(c, ""))) for r in rows)) for c in columns}
    print("  ".join(c.ljust(widths[c]) for c in columns))
    for row in rows:
        print("  ".join(str(row.get(c, "")).ljust(widths[c]) for c in columns))


# ----------------------------------------------------------------------------------- commands
def cmd_train(args: argparse.Namespace) -> int:
    from .training import train

    config = build_run_config(args)
    out = Path(args.out or f"runs/{config.task}-{config.actor.preset}-s{args.seeds.replace(',', '_')}")
    results = train(config, out, resume=args.resume, progress=None if not args.no_progress else False)
    _print_results(results, out)
    return 0


def _print_results(results: list[dict[str, Any]], out: Path) -> None:
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
        print(f"best average evaluation return {np.mean(bests):.1f} ± {np.std(bests):.1f} over {len(bests)} seeds "
              f"({', '.join(f'{b:.1f}' for b in bests)}); results in {out}/seed*")


def cmd_evaluate(args: argparse.Namespace) -> int:
    from .evaluation import evaluate_policy
    from .policy import load

    policy = load(args.run)
    returns, lengths = evaluate_policy(policy, episodes=args.episodes, seed=args.seed, task=args.task)
    import numpy as np

    print(f"{policy.task} · {policy.actor_config.preset} · {args.episodes} episodes: average return "
          f"{np.mean(returns):.1f} ± {np.std(returns):.1f} (min {np.min(returns):.1f}, max {np.max(returns):.1f}), "
          f"average length {np.mean(lengths):.0f}")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from . import export

    path = export.export(args.run, args.format, Path(args.out) if args.out else None, weights=args.weights)
    print(f"wrote {path}")
    return 0


def cmd_actors(args: argparse.Namespace) -> int:
    from .config import PRESET_SUMMARIES, actor_config

    if args.json:
        print(json.dumps({name: actor_config(name).to_dict() for name in PRESET_SUMMARIES}, indent=2))
        return 0
    rows = []
    for name, summary in PRESET_SUMMARIES.items():
        c = actor_config(name)
        rows.append({"preset": name, "encoder": c.encoder if c.network == "spiking" else "-",
                     "neuron": c.neuron if c.network == "spiking" else "relu",
                     "hidden": "x".join(map(str, c.hidden)), "intra": c.intra if c.network == "spiking" else "-",
                     "decoder": (f"{c.decoder}" + (f" α={c.alpha_v_li}" if c.decoder != "fr" else ""))
                     if c.network == "spiking" else "tanh",
                     "lr": c.learning_rate, "fully spiking": "yes" if c.fully_spiking else "no",
                     "what": summary})
    _print_table(rows, ["preset", "encoder", "neuron", "hidden", "intra", "decoder", "lr", "fully spiking", "what"])
    return 0


def cmd_tasks(args: argparse.Namespace) -> int:
    from .tasks import describe_tasks

    rows = describe_tasks()
    for row in rows:
        row["kwargs"] = ",".join(f"{k}={v}" for k, v in row["kwargs"].items()) or "-"
    _print_table(rows, ["task", "gym_id", "N", "M", "paper_id", "kwargs", "note"])
    print("Any other registered Gymnasium id with a Box action space works too, e.g. Pendulum-v1.")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from .config import TD3Config, actor_config
    from .training import RunConfig, train

    out = Path(args.out)
    config = RunConfig(task=args.task, seeds=(args.seed,), steps=args.steps, eval_every=max(1, args.steps // 6),
                       eval_episodes=5, actor=actor_config("ilc-san"),
                       td3=TD3Config(start_steps=1000, update_after=1000), threads=args.threads)
    print(f"ilcsan demo: training ILC-SAN on {config.task} for {config.steps} steps (a short run, not the paper's "
          f"1M-step protocol); results in {out}")
    # always resume: running the quick start again continues (or just reports) the demo instead of refusing
    results = train(config, out, resume=True, progress=None)
    _print_results(results, out)
    from .report import collect_runs, plot_curves

    picture = out / "learning_curve.png"
    plot_curves(collect_runs(out), picture)
    from .evaluation import random_policy_return

    baseline = random_policy_return(config.task, episodes=5, seed=args.seed)
    best = results[0]["best_return"]
    print(f"a random policy scores {baseline:.1f} on {config.task}; the trained spiking actor scored {best:.1f}")
    print(f"learning curve: {picture}; deploy it with `ilcsan export {out} --format npz`, "
          f"or in Python: ilcsan.load('{out}').predict(obs)")
    return 0


def _lazy(module: str, function: str):
    def run(args: argparse.Namespace) -> int:
        import importlib

        return importlib.import_module(f".{module}", __package__).__dict__[function](args)

    return run


# ------------------------------------------------------------------------------------- parser
def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="ilcsan", description="Fully spiking actor networks (ILC-SAN) for continuous control.")
    from . import __version__

    parser.add_argument("--version", action="version", version=f"ilcsan {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    train = commands.add_parser("train", help="train an actor with TD3",
                                description="Train an actor with TD3 and a deep twin critic.")
    train.add_argument("--task", default="Hopper", help="paper short name (see `ilcsan tasks`) or a Gymnasium id")
    _add_actor_switches(train)
    _add_run_options(train, steps_default=1_000_000)
    train.add_argument("--out", help="run directory (default runs/<task>-<actor>-s<seeds>)")
    train.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    train.add_argument("--label", help="row label for reports (default: the preset)")
    train.add_argument("--no-progress", action="store_true", help="no progress bar (one line per evaluation)")
    train.set_defaults(handler=cmd_train)

    evaluate = commands.add_parser("evaluate", help="evaluate a trained actor",
                                   description="Run deterministic episodes with a trained actor.")
    evaluate.add_argument("run", help="run directory, policy.pt or checkpoint.pt")
    evaluate.add_argument("--episodes", type=_positive_int, default=10, help="episodes (paper: 10)")
    evaluate.add_argument("--seed", type=_non_negative_int, default=0, help="environment seed of the first episode")
    evaluate.add_argument("--task", help="evaluate on another task of the same shape (default: the training task)")
    evaluate.set_defaults(handler=cmd_evaluate)

    export = commands.add_parser("export", help="export a trained actor (npz bundle or NIR graph)",
                                 description="Export a trained actor for deployment.")
    export.add_argument("run", help="run directory, policy.pt or checkpoint.pt")
    export.add_argument("--format", default="npz", help="npz (deploy bundle) | nir (neuromorphic graph)")
    export.add_argument("--out", help="output file (default: <run>/actor.<format>)")
    export.add_argument("--weights", default="float32", help="float32 (default) | int8 (per-layer scales)")
    export.set_defaults(handler=cmd_export)

    reproduce = commands.add_parser("reproduce", help="run a table of the paper as a grid of runs",
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
    reproduce.set_defaults(handler=_lazy("experiments", "cmd_reproduce"))

    report = commands.add_parser("report", help="tables and learning curves from runs",
                                 description="Build the paper's tables and learning curves from runs on disk.")
    report.add_argument("directory", help="folder holding runs (searched recursively)")
    report.add_argument("--table", default=None, help="table layout to use (default: from the runs' tags)")
    report.add_argument("--out", default=None, help="where to write report.md/.tex/.csv and curves.png")
    report.set_defaults(handler=_lazy("report", "cmd_report"))

    energy = commands.add_parser("energy", help="firing rates, operation counts and energy per inference",
                                 description="Energy analysis of trained actors (Section V-F).")
    energy.add_argument("runs", nargs="+", help="run directories or policy.pt files")
    energy.add_argument("--episodes", type=_positive_int, default=1, help="episodes to measure (paper: 1)")
    energy.add_argument("--seed", type=_non_negative_int, default=0, help="environment seed")
    energy.add_argument("--json", action="store_true", help="print JSON instead of tables")
    energy.set_defaults(handler=_lazy("energy", "cmd_energy"))

    actors = commands.add_parser("actors", help="list the actor presets and their settings")
    actors.add_argument("--json", action="store_true", help="every switch of every preset as JSON")
    actors.set_defaults(handler=cmd_actors)

    tasks = commands.add_parser("tasks", help="list the paper's tasks and their sizes")
    tasks.set_defaults(handler=cmd_tasks)

    demo = commands.add_parser("demo", help="train ILC-SAN briefly on a small task and plot its learning curve",
                               description="A short ILC-SAN run that shows the whole pipeline in minutes.")
    demo.add_argument("--task", default="InvertedPendulum-v4", help="task (default InvertedPendulum-v4)")
    demo.add_argument("--steps", type=_positive_int, default=12_000, help="steps (default 12000)")
    demo.add_argument("--seed", type=_non_negative_int, default=0)
    demo.add_argument("--out", default="runs/demo", help="run directory (default runs/demo)")
    demo.add_argument("--threads", type=_positive_int, default=None)
    demo.set_defaults(handler=cmd_demo)
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


if __name__ == "__main__":
    sys.exit(main())
