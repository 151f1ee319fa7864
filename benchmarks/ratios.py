"""Our training speed against Stable-Baselines3's TD3 and against the matmul-only floor, over interleaved rounds.

One ``speed.py`` run gives each figure once, and on a shared or virtual machine a figure moves by 10-20 %
between runs (SB3 on Hopper measured 154-181 steps/s in three runs): a ratio near a target (1.5× SB3, 2× SB3)
cannot be judged from one measurement. This script measures the same configurations in R rounds, each round
every configuration once, back to back (so slow phases of the machine hit all of them), and prints every
round's ratios with their median, min and max:

- ILC-SAN compiled, float32 and bf16 (per product), and DAN compiled, in steps/s (``speed.training_speed``);
- SB3's TD3 (MLP 256-256) with denormals flushed as our runs do, in a fresh process (``speed.sb3_speed``);
- the float32 matmul-only floor of ILC-SAN and DAN (``speed.best_float32_floor``): their recorded products
  replayed back to back on the fastest float32 path — an upper bound of what the design can reach in float32.

The floor's own ratio to SB3 tells whether a float32 target is reachable at all: if ILC-SAN's matmuls alone are
slower than 1.5× SB3's whole step, no engine computing those products in float32 reaches 1.5× SB3.

    .venv/bin/python benchmarks/ratios.py --rounds 3 --tasks Hopper,Ant,HalfCheetah --threads 1
"""

from __future__ import annotations

import argparse
import importlib.util
import platform
import statistics
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).parent))
import speed  # noqa: E402  (the measurements this script repeats)

CONFIGURATIONS = (("ILC-SAN float32", "ilc-san", "float32"), ("ILC-SAN bf16", "ilc-san", "bf16"),
                  ("DAN float32", "dan", "float32"))
"""(label, preset, matmul) of our measured configurations, all compiled, fast engine, one seed."""


SB3 = "SB3 (denormals flushed)"


def floor_label(preset: str) -> str:
    return f"{preset} float32 floor"


def one_round(task: str, threads: int, steps: int, warmup: int) -> dict[str, float]:
    """Every configuration once, back to back: steps/s by label, the floors included."""
    figures = {label: speed.training_speed(task, preset, "fast", (0,), threads, steps, warmup, True, matmul)
               for label, preset, matmul in CONFIGURATIONS}
    figures[SB3] = speed.sb3_speed(task, threads, steps, warmup, flush=True)
    for preset in ("ilc-san", "dan"):
        figures[floor_label(preset)] = speed.best_float32_floor(task, preset, (0,), threads)[0]
    return figures


RATIOS = (("ILC-SAN float32 / SB3", "ILC-SAN float32", SB3),
          ("ILC-SAN bf16 / SB3", "ILC-SAN bf16", SB3),
          ("DAN / SB3", "DAN float32", SB3),
          ("ILC-SAN float32 floor / SB3", floor_label("ilc-san"), SB3),
          ("DAN float32 floor / SB3", floor_label("dan"), SB3),
          ("ILC-SAN float32 / its floor", "ILC-SAN float32", floor_label("ilc-san")),
          ("DAN / its floor", "DAN float32", floor_label("dan")))
"""(label, numerator, denominator) of each printed ratio."""


def print_task(task: str, threads: int, rounds: list[dict[str, float]]) -> None:
    print(f"\n**{task}, {threads} thread{'s' if threads > 1 else ''}, {len(rounds)} rounds**\n")
    header = " | ".join(f"round {index + 1}" for index in range(len(rounds)))
    print(f"| figure | {header} | median | min–max |")
    print("|---" * (len(rounds) + 3) + "|")
    for name in rounds[0]:
        values = [figures[name] for figures in rounds]
        cells = " | ".join(f"{value:.0f}" for value in values)
        print(f"| {name}, steps/s | {cells} | {statistics.median(values):.0f} | {min(values):.0f}–{max(values):.0f} |")
    for label, numerator, denominator in RATIOS:
        values = [figures[numerator] / figures[denominator] for figures in rounds]
        cells = " | ".join(f"{value:.2f}" for value in values)
        print(f"| {label} | {cells} | **{statistics.median(values):.2f}** | {min(values):.2f}–{max(values):.2f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3, help="rounds of every configuration, interleaved")
    parser.add_argument("--tasks", default="Hopper,Ant,HalfCheetah")
    parser.add_argument("--threads", default="1", help="torch threads of one run, comma-separated")
    parser.add_argument("--steps", type=int, default=1000, help="measured steps per configuration")
    parser.add_argument("--warmup", type=int, default=300, help="warm-up steps (compilation happens here)")
    args = parser.parse_args()
    if importlib.util.find_spec("stable_baselines3") is None:
        parser.error("Stable-Baselines3 is not installed: pip install stable-baselines3")
    print(f"CPU: {speed.cpu_model()} · {platform.machine()} · torch {torch.__version__}")
    for threads in (int(text) for text in args.threads.split(",")):
        for task in args.tasks.split(","):
            rounds = []
            for index in range(args.rounds):
                rounds.append(one_round(task, threads, args.steps, args.warmup))
                print(f"  {task}, {threads} thread(s): round {index + 1} of {args.rounds} done", file=sys.stderr)
            print_task(task, threads, rounds)


if __name__ == "__main__":
    main()
