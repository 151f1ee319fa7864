"""What the training methods and algorithms cost: steps/s of ILC-SAN with each, measured side by side in one run.

Rows: plain ILC-SAN (TD3's target actor and Gaussian action noise), Proxy Target with K = 3 (default) and K = 1
regression steps per update, NoisySAN exploration, CaRe-BN, and the actor trained by DDPG and by SAC instead of TD3;
each compiled (float32) and eager, one torch thread, updates from the start and no evaluations (as
benchmarks/speed.py).
Ratios are to plain ILC-SAN (TD3) of the same execution. Run it on an otherwise idle machine:

    .venv/bin/python benchmarks/methods.py --tasks Hopper
"""

from __future__ import annotations

import argparse
import os
import time

import torch
from speed import cpu_model, training_speed

METHODS = {
    "plain": ("ILC-SAN (TD3 target, Gaussian action noise)", {}),
    "proxy": ("+ Proxy Target, K = 3, lr 1e-3", {"target_actor": "proxy"}),
    "proxy-k1": ("+ Proxy Target, K = 1, lr 3e-3", {"target_actor": "proxy", "proxy_iterations": 1, "proxy_lr": 3e-3}),
    "noisy": ("+ NoisySAN exploration (pink noise in the neurons)", {"exploration": "noisy"}),
    "care-bn": ("+ CaRe-BN (no recalibration in the measured steps: see recalibration.py)",
                {"normalization": "care-bn"}),
    "ddpg": ("trained by DDPG (one critic, actor step every update)", {"algorithm": "ddpg"}),
    "sac": ("trained by SAC (mean and log-std populations, entropy tuning)", {"algorithm": "sac"}),
}
"""(label, training options) of each measured method and algorithm, by a key for ``--methods``."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", default="Hopper")
    parser.add_argument("--steps", type=int, default=1000, help="measured steps per configuration")
    parser.add_argument("--warmup", type=int, default=300, help="warm-up steps (compilation happens here)")
    parser.add_argument("--methods", default=",".join(METHODS),
                        help=f"comma-separated, plain first (default: all of {', '.join(METHODS)})")
    args = parser.parse_args()
    chosen = [METHODS[key] for key in args.methods.split(",")]
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    print(f"Machine: {cpu_model()}, {os.cpu_count()} cores, torch {torch.__version__}; 1 thread.\n")
    for task in args.tasks.split(","):
        print(f"**{task}** (steps/s, and × the plain row of the same execution)\n")
        print("| method | compiled | × | eager | × |")
        print("|---|---|---|---|---|")
        plain = {}
        for label, options in chosen:
            speeds = {compiled: training_speed(task, "ilc-san", "fast", (0,), 1, args.steps, args.warmup, compiled,
                                               **options) for compiled in (True, False)}
            plain = plain or speeds
            print(f"| {label} | {speeds[True]:.0f} | {speeds[True] / plain[True]:.2f}× | {speeds[False]:.0f} | "
                  f"{speeds[False] / plain[False]:.2f}× |", flush=True)
        print()
    print(f"Measured from {started} to {time.strftime('%H:%M UTC', time.gmtime())}.")


if __name__ == "__main__":
    main()
