"""What one seed of the paper's protocol costs on each task and actor: steps/s per core, measured side by side.

For each actor preset (ILC-SAN, DAN, PopSAN, ...: ``--actors``), task and matmul precision, one run (the preset, TD3,
one torch thread, compiled, the run's own matmul choice as ``ilcsan train`` makes it) measures, after a warm-up in
which the update program compiles:

- ``train``: seconds per environment step with TD3's updates (one update per step, in chunks of 50), no evaluation;
- ``evaluation``: seconds of one evaluation of the protocol (10 deterministic episodes in lockstep, every 10 000
  steps), taken as episodes at their full length (1 000 steps; BipedalWalker 1 600), as a trained actor plays them:
  the time limit × (one batched action of the 10 episodes + 10 environment steps), plus the actor diagnostics on
  replayed states that every evaluation computes.

``protocol steps/s`` = 10 000 / (10 000 × train + evaluation): the speed of a run after its random-action phase,
evaluations included; ``h per 1M`` follows from it (the random phase's 10 000 steps are cheaper, episodes of an
untrained actor shorter, so a real run takes somewhat less). ``× ILC-SAN's Hopper`` is the run's time per step over
ILC-SAN's on Hopper in the same precision: the per-actor, per-task factors
:data:`ilcsan.experiments.estimate.ACTOR_STEP_COST` holds (float32).

With ``--jobs 2`` the measurements run two at a time, one process per core, as the paper's runs do (one seed per
core, both cores busy). Run it on an otherwise idle machine:

    .venv/bin/python benchmarks/task_cost.py --jobs 2
    .venv/bin/python benchmarks/task_cost.py --jobs 2 --actors ilc-san,dan,popsan --precisions float32
"""

from __future__ import annotations

import argparse
import os
import time
from concurrent.futures import ProcessPoolExecutor

import torch
from speed import cpu_model

from ilcsan.experiments.machine_speed import (
    evaluation_seconds,
    protocol_config,
    protocol_speed,
    seconds_per_training_step,
)
from ilcsan.paper.layouts import TABLES
from ilcsan.rl.training import Trainer

PRECISIONS = ("float32", "bf16")


def measure(actor: str, task: str, matmul: str, steps: int, warmup: int) -> dict[str, float | str]:
    """One actor preset, task and precision: seconds per training step, per evaluation, and the matmul choice."""
    torch.set_num_threads(1)
    config = protocol_config(actor, task, matmul, steps=steps, warmup=warmup)
    train, (evaluation, limit, chosen) = seconds_per_training_step(config, warmup, steps, evaluation_and_path)
    return {"actor": actor, "task": task, "matmul": matmul, "train": train, "evaluation": evaluation,
            "limit": limit, "path": chosen}


def evaluation_and_path(trainer: Trainer) -> tuple[float, int, str]:
    """:func:`~ilcsan.experiments.machine_speed.evaluation_seconds` and the matmul path the run chose, in words."""
    chosen = trainer.matmul_choice["path"]
    if chosen == "bf16":
        chosen = f"bf16 on {len(trainer.matmul_choice['bf16_products'])} of {trainer.matmul_choice['products']} shapes"
    return (*evaluation_seconds(trainer), chosen)


def row_speed(row: dict) -> float:
    """Steps/s of the protocol after the random phase, evaluations included."""
    return protocol_speed(row["train"], row["evaluation"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--actors", default="ilc-san", help="actor presets, comma-separated (ilc-san first: the "
                        "ratios are to its Hopper step)")
    parser.add_argument("--tasks", default=",".join(TABLES["perf"].tasks))
    parser.add_argument("--precisions", default=",".join(PRECISIONS))
    parser.add_argument("--steps", type=int, default=500, help="measured training steps per configuration")
    parser.add_argument("--warmup", type=int, default=250, help="warm-up steps (the update compiles here)")
    parser.add_argument("--jobs", type=int, default=1, help="measurements at a time, one process per core")
    parser.add_argument("--out", help="also append the table to this Markdown file")
    args = parser.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    actors, tasks, precisions = args.actors.split(","), args.tasks.split(","), args.precisions.split(",")
    jobs = [(actor, task, matmul) for actor in actors for task in tasks for matmul in precisions]
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futures = [pool.submit(measure, *job, args.steps, args.warmup) for job in jobs]
        rows = {(row["actor"], row["task"], row["matmul"]): row for row in (future.result() for future in futures)}
    lines = [f"CPU: {cpu_model()}, {os.cpu_count()} cores, torch {torch.__version__}; {started}; one thread per "
             f"run, {args.jobs} run(s) at a time; {args.steps} measured steps after {args.warmup}.", "",
             "| actor | task | matmul (path) | train steps/s | evaluation s | protocol steps/s | h per 1M | "
             "× ILC-SAN's Hopper | bf16 × float32 |", "|---|---|---|---|---|---|---|---|---|"]
    for actor, task, matmul in jobs:
        row = rows[(actor, task, matmul)]
        speed = row_speed(row)
        hopper = rows.get(("ilc-san", "Hopper", matmul))
        relative = f"{row_speed(hopper) / speed:.2f}" if hopper else "–"
        float32 = rows.get((actor, task, "float32"))
        gain = f"{speed / row_speed(float32):.2f}" if matmul == "bf16" and float32 else "–"
        lines.append(f"| {actor} | {task} | {matmul} ({row['path']}) | {1 / row['train']:.0f} | "
                     f"{row['evaluation']:.1f} (limit {row['limit']}) | {speed:.0f} | {1e6 / speed / 3600:.2f} | "
                     f"{relative} | {gain} |")
    text = "\n".join(lines)
    print(text)
    if args.out:
        with open(args.out, "a", encoding="utf-8") as stream:
            stream.write("\n" + text + "\n")


if __name__ == "__main__":
    main()
