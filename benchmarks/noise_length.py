"""NoisySAN's per-episode noise series: time to draw one at the length an episode needs (Hopper: 1 001 actions × T = 5
= 5 005 samples, prime factors 5·7·11·13) against the next length with prime factors up to 7 (5 040), which the runs
use (``ilcsan.rl.methods.coloured_noise.fft_length``). One thread, the rounds alternating; prints min and median ms
and their ratio.

    python benchmarks/noise_length.py [--rounds 15] [--channels 5435]
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
from speed import cpu_model

from ilcsan.rl.methods.coloured_noise import coloured_noise, fft_length


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--channels", type=int, default=5435, help="noise channels of Hopper's ILC-SAN (2·ΣD_l + M)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    needed = 1001 * 5
    lengths = {"needed": needed, "fft_length": fft_length(needed)}
    generator = torch.Generator().manual_seed(0)
    times: dict[str, list[float]] = {name: [] for name in lengths}
    for length in lengths.values():  # warm-up
        coloured_noise(1.0, (args.channels, length), generator)
    for _ in range(args.rounds):
        for name, length in lengths.items():
            start = time.perf_counter()
            coloured_noise(1.0, (args.channels, length), generator)
            times[name].append(1e3 * (time.perf_counter() - start))
    print(f"CPU: {cpu_model()}; torch {torch.__version__}; one thread; {args.channels} channels, {args.rounds} rounds")
    print("| length | samples | min ms | median ms |")
    print("|---|---|---|---|")
    for name, length in lengths.items():
        print(f"| {name} | {length} | {min(times[name]):.1f} | {statistics.median(times[name]):.1f} |")
    ratio = statistics.median(times["fft_length"]) / statistics.median(times["needed"])
    print(f"median fft_length / needed: {ratio:.2f}")


if __name__ == "__main__":
    main()
