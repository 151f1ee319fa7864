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

import numpy as np
import torch
from speed import cpu_model, seconds_per_training_step

from ilcsan.config import RunConfig, TrainingConfig, actor_config
from ilcsan.paper.layouts import TABLES
from ilcsan.rl.evaluation import replay_diagnostics
from ilcsan.rl.training import Trainer

PRECISIONS = ("float32", "bf16")
EVAL_EVERY = 10_000
EVAL_EPISODES = 10


def measure(actor: str, task: str, matmul: str, steps: int, warmup: int) -> dict[str, float | str]:
    """One actor preset, task and precision: seconds per training step, per evaluation, and the matmul choice."""
    torch.set_num_threads(1)
    training = TrainingConfig(start_steps=0, update_after=100)
    config = RunConfig(task=task, seeds=(0,), steps=warmup + steps + 1, eval_every=EVAL_EVERY,
                       eval_episodes=EVAL_EPISODES, actor=actor_config(actor), training=training, threads=1,
                       compile="on", matmul=matmul)
    train, (evaluation, limit, chosen) = seconds_per_training_step(config, warmup, steps, evaluation_and_path)
    return {"actor": actor, "task": task, "matmul": matmul, "train": train, "evaluation": evaluation,
            "limit": limit, "path": chosen}


def evaluation_and_path(trainer: Trainer) -> tuple[float, int, str]:
    """:func:`evaluation_seconds` and the matmul path the run chose, in words."""
    chosen = trainer.matmul_choice["path"]
    if chosen == "bf16":
        chosen = f"bf16 on {len(trainer.matmul_choice['bf16_products'])} of {trainer.matmul_choice['products']} shapes"
    return (*evaluation_seconds(trainer), chosen)


def evaluation_seconds(trainer: Trainer, lockstep_steps: int = 100, warmup: int = 20) -> tuple[float, int]:
    """Seconds of one evaluation with every episode at the task's time limit, and that limit: the time of
    ``lockstep_steps`` lockstep steps (one batched action, then each episode's environment step; an ended episode
    restarts so that every step steps all of them), scaled to the limit, plus one pass of the actor diagnostics;
    each after ``warmup`` untimed calls (the acting pass compiles for the evaluation's shape on its first)."""
    envs = trainer.eval_envs[0]
    limit = envs[0].spec.max_episode_steps
    observations = np.stack([env.reset(seed=index)[0] for index, env in enumerate(envs)])[None]

    def lockstep() -> None:
        actions = trainer._act(observations)
        for index, env in enumerate(envs):
            observation, _, terminated, truncated, _ = env.step(actions[0, index])
            observations[0, index] = env.reset()[0] if terminated or truncated else observation

    def diagnostics() -> None:
        replay_diagnostics(trainer.agent, trainer.replay, trainer.normalizer, trainer.config.seeds, trainer.step)

    per_step = seconds_per_call(lockstep, lockstep_steps, warmup)
    return limit * per_step + seconds_per_call(diagnostics, 3, 1), limit


def seconds_per_call(function, calls: int, warmup: int) -> float:
    """Mean seconds of ``calls`` calls of ``function`` after ``warmup`` untimed ones."""
    for _ in range(warmup):
        function()
    start = time.perf_counter()
    for _ in range(calls):
        function()
    return (time.perf_counter() - start) / calls


def protocol_speed(row: dict) -> float:
    """Steps/s of the protocol after the random phase, evaluations included."""
    return EVAL_EVERY / (EVAL_EVERY * row["train"] + row["evaluation"])


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
        speed = protocol_speed(row)
        hopper = rows.get(("ilc-san", "Hopper", matmul))
        relative = f"{protocol_speed(hopper) / speed:.2f}" if hopper else "–"
        float32 = rows.get((actor, task, "float32"))
        gain = f"{speed / protocol_speed(float32):.2f}" if matmul == "bf16" and float32 else "–"
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
