"""Batch-1 action latency: the additions-only numpy runtime (ilcsan.runtime) vs PyTorch ``Policy.predict``.

Usage:
    python benchmarks/deploy_latency.py                 # ILC-SAN, Hopper- and Ant-sized random actors
    python benchmarks/deploy_latency.py --runs RUN ...  # trained runs (observations from one episode)
    python benchmarks/deploy_latency.py --baseline DIR  # also time another copy of the runtime folder (e.g. an
                                                        # older commit's), interleaved

A random actor is calibrated to the paper's firing rates (Table fr): one bias shift of the backbone is
bisected until the mean hidden-layer rate matches the task's FC2 rate, because latency grows with
activity (an event-driven layer costs spikes × fan-out). Each latency is the median of many calls
cycling over a fixed set of observations, one torch thread; the 10th percentile is printed too (on a
shared machine it is the closest to an idle core). Prints a table: firing rates, SOP per inference,
runtime µs (float32 and int8 weights), the float32 accumulates alone (the inference's own
spiking rows added with their indices given: what remains of the runtime without neuron updates, host and
bookkeeping), PyTorch µs, PyTorch / runtime, and the largest action difference.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

TASKS = {"Hopper": (11, 3), "Ant": (111, 8)}


def latency_microseconds(call, inputs, calls: int) -> tuple[float, float]:
    """(median, 10th percentile) of ``calls`` timed calls, µs; the percentile is what an idle core gives."""
    for observation in inputs[:20]:
        call(observation)
    times = []
    for index in range(calls):
        observation = inputs[index % len(inputs)]
        start = time.perf_counter()
        call(observation)
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1e6, float(np.percentile(times, 10)) * 1e6


def calibrated_policy(task: str, seed: int = 0):
    """A random ILC-SAN with the mean rate of its hidden layers near the paper's FC2 rate for ``task``."""
    from spiking_policies import observations, random_policy

    from ilcsan.analysis.energy import measure_firing_rates
    from ilcsan.paper.published import FIRING_RATES

    state_dim, action_dim = TASKS[task]
    target = FIRING_RATES["ilc-san"][task].fc2
    low, high = -1.0, 1.0
    for _ in range(12):
        shift = (low + high) / 2
        policy = random_policy(state_dim=state_dim, action_dim=action_dim, seed=seed, gain=2.0, bias_shift=shift)
        rate = measure_firing_rates(policy, observations(policy, 64)).rates["FC2"]
        low, high = (shift, high) if rate < target else (low, shift)
    return policy, observations(policy, 200, seed=seed + 7)


def trained_policy(run: str, seed: int = 0):
    """A trained run's policy and the observations of one deterministic episode."""
    import ilcsan
    from ilcsan.rl.evaluation import run_episodes

    policy = ilcsan.load(run)
    seen = []

    def act(observation):
        seen.append(np.asarray(observation, np.float64))
        return policy.predict(observation)

    run_episodes(act, policy.task, 1, seed)
    return policy, np.array(seen[:500])


def load_runtime_copy(folder: str):
    """``DeployedActor`` of another copy of the runtime folder (it is standalone: numpy and the standard library),
    imported under a private name so that both versions run in this process."""
    import importlib.util

    init = Path(folder) / "__init__.py"
    spec = importlib.util.spec_from_file_location("baseline_runtime", init, submodule_search_locations=[folder])
    module = importlib.util.module_from_spec(spec)
    sys.modules["baseline_runtime"] = module
    spec.loader.exec_module(module)
    return module.DeployedActor


def interleaved(calls: dict, inputs, rounds: int, per_round: int = 300) -> dict[str, float]:
    """Median µs of each call, timed in alternating blocks so that both see the same machine load."""
    times: dict[str, list[float]] = {name: [] for name in calls}
    for call in calls.values():
        for observation in inputs[:20]:
            call(observation)
    for _ in range(rounds):
        for name, call in calls.items():
            for index in range(per_round):
                observation = inputs[index % len(inputs)]
                start = time.perf_counter()
                call(observation)
                times[name].append(time.perf_counter() - start)
    return {name: statistics.median(values) * 1e6 for name, values in times.items()}


def accumulates_only_microseconds(runtime, inputs, calls: int) -> float:
    """Median µs of the float32 accumulates alone of an inference — every layer's and step's spiking rows
    selected with their indices given (``take``) and added (``np.add.reduce``), the intra rows included: the
    synaptic work the runtime cannot skip, without its neuron updates, host or Python bookkeeping."""
    work = []
    for observation in inputs[:50]:
        trains = runtime.spike_trains(observation)
        layers = list(runtime.layers)
        presynaptic = trains[:-1]
        if runtime.intra is not None:
            layers.append(runtime.intra)
            presynaptic.append(trains[-1][:-1])
        work.append([(layer.weights, np.flatnonzero(step)) for layer, train in zip(layers, presynaptic, strict=True)
                     for step in train])
    out = np.empty(max(layer.weights.shape[1] for layer in layers), np.float32)

    def accumulate(pairs):
        for weights, rows in pairs:
            np.add.reduce(weights.take(rows, 0), 0, None, out[:weights.shape[1]])
    return latency_microseconds(accumulate, work, calls)[0]


def measure(label: str, policy, inputs, calls: int, baseline=None) -> dict:
    from ilcsan.analysis.energy import measure_firing_rates
    from ilcsan.deploy import DeployedActor
    from ilcsan.deploy.bundle import bundle_arrays, bundle_meta
    from ilcsan.deploy.quantize import quantize_bundle

    arrays, meta = bundle_arrays(policy), bundle_meta(policy)
    runtime = DeployedActor.from_arrays(arrays, meta)
    int8_runtime = DeployedActor.from_arrays(*quantize_bundle(arrays, meta))
    error = max(float(np.abs(runtime.act(o) - policy.predict(o)).max()) for o in inputs[:50])
    rates = measure_firing_rates(policy, inputs).rates
    runtime_us, runtime_p10 = latency_microseconds(runtime.act, inputs, calls)
    int8_us, _ = latency_microseconds(int8_runtime.act, inputs, calls)
    torch_us, torch_p10 = latency_microseconds(policy.predict, inputs, max(200, calls // 4))
    compared = {}
    if baseline is not None:
        old = baseline.from_arrays(arrays, meta)
        old.act(inputs[0])
        runtime.act(inputs[0])
        if old.last_sop_by_layer != runtime.last_sop_by_layer:
            raise SystemExit(f"the baseline counts {old.last_sop_by_layer}, this runtime {runtime.last_sop_by_layer}")
        medians = interleaved({"baseline": old.act, "this": runtime.act}, inputs, max(1, calls // 300))
        compared = {"baseline µs (A/B)": f"{medians['baseline']:.0f}", "this µs (A/B)": f"{medians['this']:.0f}"}
    return {"actor": label, "N, M": f"{policy.state_dim}, {policy.action_dim}",
            "fr FC1/FC2/FC3": "/".join(f"{100 * rates[name]:.0f}%" for name in ("FC1", "FC2", "FC3")),
            "SOP/inference": f"{runtime.total_sop / runtime.inferences:,.0f}",
            "runtime µs": f"{runtime_us:.0f} (p10 {runtime_p10:.0f})",
            "accumulates only µs": f"{accumulates_only_microseconds(runtime, inputs, calls):.0f}",
            "int8 µs": f"{int8_us:.0f}",
            "PyTorch µs": f"{torch_us:.0f} (p10 {torch_p10:.0f})", "PyTorch/runtime": f"{torch_us / runtime_us:.1f}×",
            "max |Δaction|": f"{error:.1e}", **compared}


def print_table(rows: list[dict]) -> None:
    header = list(rows[0])
    widths = [max(len(h), *(len(row[h]) for row in rows)) for h in header]
    print("  ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)))
    print("  ".join("-" * w for w in widths))
    for row in rows:
        print("  ".join(row[h].ljust(w) for h, w in zip(header, widths, strict=True)))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", nargs="*", default=[], help="trained run directories (default: random actors)")
    parser.add_argument("--calls", type=int, default=3000, help="calls per latency median (runtime)")
    parser.add_argument("--baseline", help="another copy of the runtime folder to time against this one (A/B)")
    args = parser.parse_args(argv)
    baseline = load_runtime_copy(args.baseline) if args.baseline else None
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import torch

    torch.set_num_threads(1)
    rows = []
    if args.runs:
        for run in args.runs:
            policy, inputs = trained_policy(run)
            rows.append(measure(f"{policy.actor_config.preset} {policy.task} ({run})", policy, inputs, args.calls,
                                baseline))
    else:
        for task in TASKS:
            policy, inputs = calibrated_policy(task)
            rows.append(measure(f"ILC-SAN {task}-sized (random, rates ≈ Table fr)", policy, inputs, args.calls,
                                baseline))
    print_table(rows)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"\nmedian (10th percentile) of {args.calls} runtime calls per cell; 1 torch thread; "
          f"{os.cpu_count()} CPUs, load average {load:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
