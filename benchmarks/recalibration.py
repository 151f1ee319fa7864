"""What CaRe-BN's recalibration costs: the package's (each layer's pass stops at that layer) against whole passes
through the actor per layer (its definition), side by side in one run, alternating rounds.

A recalibration replays RECALIBRATION_BATCHES minibatches of RECALIBRATION_BATCH_SIZE states and pools each layer's
statistics over them, layer by layer (:func:`ilcsan.rl.methods.care_bn.recalibrated_statistics`). The actor is
ILC-SAN's (2×256, T = 5) on a task's state and action sizes, float32, one torch thread, eager as in training. Run it on
an otherwise idle machine:

    .venv/bin/python benchmarks/recalibration.py --task Hopper --seeds 1 --rounds 5
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import torch
from speed import cpu_model

from ilcsan.actors import build_actor
from ilcsan.config import actor_config
from ilcsan.rl.methods.care_bn import (
    RECALIBRATION_BATCH_SIZE,
    RECALIBRATION_BATCHES,
    pool_statistics,
    recalibrated_statistics,
)
from ilcsan.rl.tasks import TASK_SPECS
from ilcsan.snn.output import PassOptions


def whole_passes(actor, batches):
    """The definition: for layer l, a whole pass per batch with the layers before l normalised by their pooled
    statistics, layer l's batch statistics pooled."""
    found = []
    for index in range(len(actor.layers)):
        options = PassOptions(statistics=tuple(found))
        parts = [actor.run(batch, options=options).norm_statistics[index] for batch in batches]
        found.append(pool_statistics(parts, [batch.shape[1] for batch in batches]))
    return tuple(found)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="Hopper")
    parser.add_argument("--seeds", type=int, default=1, help="seeds stacked in one actor (K)")
    parser.add_argument("--rounds", type=int, default=5, help="alternating rounds of each")
    args = parser.parse_args()
    torch.set_num_threads(1)
    spec = TASK_SPECS[args.task]
    actor = build_actor(actor_config("ilc-san", normalization="care-bn"), spec.state_dim, spec.action_dim,
                        [1.0] * spec.action_dim, seeds=tuple(range(args.seeds)))
    generator = torch.Generator().manual_seed(0)
    batches = [torch.randn(args.seeds, RECALIBRATION_BATCH_SIZE, spec.state_dim, generator=generator)
               for _ in range(RECALIBRATION_BATCHES)]
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    ways = {"whole passes": whole_passes, "stopping at the layer": recalibrated_statistics}
    times: dict[str, list[float]] = {name: [] for name in ways}
    results = {}
    with torch.no_grad():
        for run in ways.values():
            run(actor, batches[:2])  # warm-up
        for _ in range(args.rounds):
            for name, run in ways.items():
                begin = time.perf_counter()
                results[name] = run(actor, batches)
                times[name].append(time.perf_counter() - begin)
    same = all(torch.equal(a.mean, b.mean) and torch.equal(a.var, b.var)
               for a, b in zip(*results.values(), strict=True))
    print(f"Machine: {cpu_model()}, {os.cpu_count()} cores, torch {torch.__version__}; 1 thread. {args.task}, "
          f"K = {args.seeds}, {RECALIBRATION_BATCHES} batches × {RECALIBRATION_BATCH_SIZE} states, {args.rounds} "
          f"alternating rounds, from {started}.\n")
    print("| recalibration | s, min / median / max | × whole passes (median) |")
    print("|---|---|---|")
    reference = statistics.median(times["whole passes"])
    for name, values in times.items():
        print(f"| {name} | {min(values):.2f} / {statistics.median(values):.2f} / {max(values):.2f} | "
              f"{statistics.median(values) / reference:.2f}× |")
    print(f"\nThe same statistics (torch.equal): {same}.")


if __name__ == "__main__":
    main()
