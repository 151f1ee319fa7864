"""Two checkouts of ilcsan, the same fixed-seed compiled runs: are their curves identical, and their processes as fast?

For a change that must not alter behaviour or speed (a refactor), this trains each configuration once per checkout
with ``ilcsan train`` as a whole process (``PYTHONPATH=<checkout>/src``, one torch thread, compiled, float32), then
compares the two ``metrics.csv`` files column by column, all but wall time and steps/s, which must match to the last
digit; then it times R more rounds of both, A and B back to back in each round (so a slow phase of the machine hits
both), and prints per configuration the median wall time of each and B / A with its min and max over rounds.

Configurations: plain TD3, SAC, Proxy Target, NoisySAN, CaRe-BN (the preset --actor, ILC-SAN by default, on --task;
``--actor dan --only td3,sac`` for the deep actor, which takes no spiking method). Run it on an otherwise idle machine
(the identity part alone is valid on a busy one, with --rounds 0):

    git worktree add /tmp/before main~3
    .venv/bin/python benchmarks/refactor_check.py /tmp/before . --task Hopper --steps 3000 --rounds 3
"""

from __future__ import annotations

import argparse
import csv
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from speed import cpu_model

CONFIGURATIONS = {
    "td3": ("plain TD3", []),
    "sac": ("SAC", ["--algorithm", "sac"]),
    "proxy": ("TD3 + Proxy Target", ["--target-actor", "proxy"]),
    "noisy": ("TD3 + NoisySAN", ["--exploration", "noisy"]),
    "care-bn": ("TD3 + CaRe-BN", ["--normalization", "care-bn"]),
}
TIMING_COLUMNS = {"wall_seconds", "steps_per_second"}
"""The columns of metrics.csv that measure the machine, not the run."""


def train(checkout: Path, extra: list[str], options: argparse.Namespace, out: Path) -> float:
    """Train one configuration from ``checkout`` into ``out``; returns the process's wall time in seconds."""
    command = [sys.executable, "-c", "import sys; from ilcsan.cli import main; sys.exit(main())", "train",
               "--task", options.task, "--actor", options.actor, "--seed", "0", "--steps", str(options.steps),
               "--eval-every", str(options.steps // 3), "--eval-episodes", "2", "--start-steps",
               str(options.steps // 3), "--update-after", str(options.steps // 3), "--threads", "1",
               "--compile", "on", "--matmul", "float32", "--no-progress", "--out", str(out), *extra]
    env = {**os.environ, "PYTHONPATH": str(checkout.resolve() / "src")}
    started = time.perf_counter()
    done = subprocess.run(command, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{checkout}: {' '.join(extra) or 'td3'} failed:\n{done.stderr[-2000:]}")
    return time.perf_counter() - started


def curve(out: Path) -> list[dict[str, str]]:
    """metrics.csv without the columns that measure the machine."""
    with open(out / "metrics.csv") as stream:
        return [{key: value for key, value in row.items() if key not in TIMING_COLUMNS}
                for row in csv.DictReader(stream)]


def first_difference(a: list[dict[str, str]], b: list[dict[str, str]]) -> str:
    if len(a) != len(b):
        return f"{len(a)} rows against {len(b)}"
    for row_a, row_b in zip(a, b, strict=True):
        for key in row_a:
            if row_a[key] != row_b.get(key):
                return f"step {row_a['step']}, {key}: {row_a[key]} against {row_b.get(key)}"
    return "identical"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("before", type=Path, help="checkout A (e.g. a git worktree of the commit before the change)")
    parser.add_argument("after", type=Path, help="checkout B")
    parser.add_argument("--task", default="Hopper")
    parser.add_argument("--actor", default="ilc-san", help="the actor preset every configuration trains")
    parser.add_argument("--steps", type=int, default=3000, help="steps per run (evaluations at each third)")
    parser.add_argument("--rounds", type=int, default=3, help="timed rounds after the identity run (0: none)")
    parser.add_argument("--only", default=",".join(CONFIGURATIONS), help="comma-separated configurations")
    options = parser.parse_args()
    names = options.only.split(",")
    print(f"CPU: {cpu_model()} · {os.cpu_count()} cores · task {options.task}, actor {options.actor}, "
          f"{options.steps} steps, compiled, float32, one thread · A = {options.before}, B = {options.after}")
    print(f"{'configuration':22} {'metrics.csv A vs B':40} {'A s (median)':>12} {'B s (median)':>12} "
          f"{'B / A median (min-max)':>24}")
    with tempfile.TemporaryDirectory() as scratch:
        for name in names:
            label, extra = CONFIGURATIONS[name]
            times: dict[str, list[float]] = {"A": [], "B": []}
            curves = {}
            for round_ in range(1 + options.rounds):
                for side, checkout in (("A", options.before), ("B", options.after)):
                    out = Path(scratch) / f"{name}-{side}-{round_}"
                    seconds = train(checkout, extra, options, out)
                    if round_ == 0:
                        curves[side] = curve(out)
                    else:
                        times[side].append(seconds)
            verdict = first_difference(curves["A"], curves["B"])
            if options.rounds:
                ratios = [b / a for a, b in zip(times["A"], times["B"], strict=True)]
                timing = (f"{statistics.median(times['A']):12.1f} {statistics.median(times['B']):12.1f} "
                          f"{statistics.median(ratios):10.3f} ({min(ratios):.3f}-{max(ratios):.3f})")
            else:
                timing = f"{'-':>12} {'-':>12} {'-':>24}"
            print(f"{label:22} {verdict[:40]:40} {timing}", flush=True)


if __name__ == "__main__":
    main()
