"""The commands about one actor besides ``train`` (:mod:`ilcsan.cli.train`): evaluate, demo, export, lava, and the
listings (actors, tasks)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from .. import methods
from ..config import PRESET_SUMMARIES, RunConfig, actor_config, training_config_class
from .train import print_results


def _print_table(rows: list[dict[str, Any]], columns: list[str]) -> None:
    widths = {c: max(len(c), *(len(str(r.get(c, ""))) for r in rows)) for c in columns}
    print("  ".join(c.ljust(widths[c]) for c in columns))
    for row in rows:
        print("  ".join(str(row.get(c, "")).ljust(widths[c]) for c in columns))


# ----------------------------------------------------------------------------------- commands
def cmd_evaluate(args: argparse.Namespace) -> int:
    import numpy as np

    from ..rl.evaluation import episode_seed, evaluate_policy

    actor = _evaluated_actor(Path(args.run))
    task = args.task or actor.task
    video = Path(args.video) if args.video else None
    returns, lengths = evaluate_policy(actor, episodes=args.episodes, seed=args.seed, task=task, video=video,
                                       progress=sys.stderr.isatty(), contact_forces=args.contact_forces)
    episodes = f"{args.episodes} episode" + ("s" if args.episodes != 1 else "")
    print(f"{task} · {actor.label} · {episodes}: average return "
          f"{np.mean(returns):.1f} ± {np.std(returns):.1f} (std over the episodes; min {np.min(returns):.1f}, "
          f"max {np.max(returns):.1f}), "
          f"average length {np.mean(lengths):.0f}")
    if getattr(actor, "inferences", 0):  # the numpy runtime counts every accumulate it performs
        print(f"synaptic operations per action: {actor.total_sop / actor.inferences:.0f} on average over "
              f"{actor.inferences} actions (additions only; energy estimates: `ilcsan energy RUN`)")
    if video is not None:
        from ..rl.video import video_path

        first, last = (video_path(video, task, episode_seed(args.seed, e)) for e in (0, args.episodes - 1))
        print(f"video of each episode: {first}" + (f" … {last.name}" if last != first else ""))
    return 0


def _evaluated_actor(path: Path):
    """What ``ilcsan evaluate`` plays: a deploy bundle (``.npz``) in the numpy runtime, anything else as a Policy."""
    if path.suffix == ".npz":
        from ..deploy import DeployedActor

        return DeployedActor.load(path)
    from ..deploy.policy import load

    return load(path)


def cmd_export(args: argparse.Namespace) -> int:
    from ..deploy import export

    path = export.export(args.run, args.format, Path(args.out) if args.out else None, weights=args.weights,
                         target=args.target)
    print(f"wrote {path}")
    return 0


def cmd_lava(args: argparse.Namespace) -> int:
    """Export the run's bundle (unless given one) and run it in the Lava environment's Python."""
    import subprocess
    import tempfile

    from ..deploy import export
    from ..deploy.lava import lava_python, run_arguments

    python = lava_python()
    with tempfile.TemporaryDirectory(prefix="ilcsan-lava-") as folder:
        bundle = Path(args.run)
        if bundle.suffix != ".npz":
            bundle = export.export(args.run, "npz", Path(folder) / "actor.npz")
        command = [str(python), "-m", "ilcsan.deploy.lava", str(bundle), *run_arguments(args)]
        return subprocess.run(command, check=False).returncode


LISTED_KINDS = ("algorithm", "target_actor", "exploration", "normalization", "loss_term")
"""The order in which ``ilcsan actors`` lists the registered declarations (:mod:`ilcsan.methods`)."""


def cmd_actors(args: argparse.Namespace) -> int:
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
    print("\nalgorithms and training methods (actors: which it trains; DAN keeps TD3's own target and action noise):")
    listed = [{"option": method.option(), "actors": "spiking" if method.spiking_only else "all", "what": method.paper}
              for kind in LISTED_KINDS for method in methods.registered(kind).values()]
    _print_table(listed, ["option", "actors", "what"])
    return 0


def cmd_tasks(args: argparse.Namespace) -> int:
    from ..rl.tasks import CONTACT_FORCES_NOTE, VERSION_NOTE, describe_tasks

    rows = describe_tasks()
    for row in rows:
        row["kwargs"] = ",".join(f"{k}={v}" for k, v in row["kwargs"].items()) or "-"
    _print_table(rows, ["task", "gym_id", "N", "M", "paper_id", "kwargs", "contact_forces", "note"])
    print(VERSION_NOTE)
    print(CONTACT_FORCES_NOTE)
    print("Any other registered Gymnasium id with a Box action space works too, e.g. Pendulum-v1, and so does a task "
          "of your own as module:id (the module that registers it is imported first), e.g. my_robot.envs:Arm-v0.")
    return 0


DEMO_TASK = "Pendulum-v1"
"""The demo's task: small, learnt in a few thousand steps, and it stays learnt (InvertedPendulum often collapses
after solving, so its score depends on where a short run stops)."""
DEMO_STEPS = 12_000
DEMO_EVALUATIONS = 12


def demo_config(task: str, steps: int, seed: int, threads: int | None):
    """The demo's run: ILC-SAN, evaluated every ``steps / 12`` steps on 5 episodes, updates from step 1000."""
    return RunConfig(task=task, seeds=(seed,), steps=steps, eval_every=max(1, steps // DEMO_EVALUATIONS),
                     eval_episodes=5, actor=actor_config("ilc-san"),
                     training=training_config_class()(start_steps=1000, update_after=1000), threads=threads)


def cmd_demo(args: argparse.Namespace) -> int:
    from ..rl.training import train

    out = Path(args.out)
    config = demo_config(args.task, args.steps, args.seed, args.threads)
    print(f"ilcsan demo: training ILC-SAN on {config.task} for {config.steps} steps (a short run, not the paper's "
          f"1M-step protocol); results in {out}")
    # running the quick start again continues (or just reports) the demo instead of refusing
    from ..runs.directory import RunDirectory

    results = train(config, out, resume=RunDirectory(out).holds_run(), progress=None)
    print_results(results, out)
    from ..analysis.report import collect_runs, plot_curves

    runs = collect_runs(out)
    picture = out / "learning_curve.png"
    plot_curves(runs, picture)
    from ..rl.evaluation import random_policy_return

    baseline = random_policy_return(config.task, episodes=5, seed=args.seed,
                                    contact_forces=config.task_contact_forces())
    best, step = results[0]["best_return"], results[0]["best_step"]
    last = runs[0].returns[-1] if runs and runs[0].returns else None
    if best is not None:
        ending = "" if last is None else f", its last {last:.1f}"
        print(f"{config.task}: a random policy scores {baseline:.1f}; the trained spiking actor's best evaluation "
              f"scored {best:.1f} (step {step}){ending} (higher is better)")
    print(f"learning curve: {picture}; deploy it with `ilcsan export {out} --format npz`, "
          f"or in Python: ilcsan.load('{out}').predict(obs)")
    print(f"watch it: `ilcsan evaluate {out} --episodes 1 --video {out}/videos` writes an MP4 of one episode")
    return 0
