"""Training speed, measured side by side in one run: prints one Markdown table (and writes it with --out).

What it measures, on this machine, in this order:
  1. the float32 GEMM peak (2048² matmul) for 1 and for --threads threads: the machine's matmul limit;
  2. environment steps per second including TD3 updates, for DAN, PopSAN and ILC-SAN on Hopper and Ant,
     with the reference engine (Algorithm 1's time-step loop, eager, as the authors' code) and the fast
     engine (layer-major, torch.compile of the spiking actor, fused Adam), in float32 and with bf16 matmuls
     (``--matmul bf16``: AMX on this CPU), as a fraction of the float32 matmul limit in two ways: of the
     GEMM peak, and of the step's own matmul-only floor (its recorded matrix products replayed back to back);
  3. Stable-Baselines3's TD3 (MLP actor 256-256, batch 100, one update per step) when it is installed;
  4. K seeds trained together in one process vs the same cores running separate single-seed processes;
  5. batch-1 action latency of ``Policy.predict``.

Steps/s are measured after a warm-up (compilation happens there), with updates from the start (no
random-action phase), and without evaluations. Run it on an otherwise idle machine:

    .venv/bin/python benchmarks/speed.py --out benchmarks/RESULTS.md
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from ilcsan.config import RunConfig, TD3Config, actor_config
from ilcsan.rl.training import Trainer

TASK_SIZES = {"Hopper": (11, 3), "Ant": (111, 8)}


def gemm_peak(threads: int, size: int = 2048, seconds: float = 2.0) -> float:
    """GFLOP/s of a float32 square matmul with ``threads`` threads."""
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    a, b = torch.randn(size, size), torch.randn(size, size)
    for _ in range(3):
        a @ b
    count, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        a @ b
        count += 1
    elapsed = time.perf_counter() - start
    torch.set_num_threads(previous)
    return 2 * size**3 * count / elapsed / 1e9


def actor_forward_flops(preset: str, state_dim: int, action_dim: int, batch: int) -> float:
    """Matmul FLOPs of one actor forward pass over a batch (T steps for spiking layers)."""
    config = actor_config(preset)
    if config.network == "deep":
        sizes = [state_dim, *config.hidden, action_dim]
        return sum(2.0 * batch * a * b for a, b in zip(sizes[:-1], sizes[1:], strict=True))
    first = state_dim * (config.population_in if config.encoder.startswith("pop") else 1)
    sizes = [first, *config.hidden, action_dim * config.population_out]
    analog_first = config.encoder not in ("pop-det", "pop-prob")
    total = 0.0
    for index, (a, b) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
        repeats = 1 if (index == 0 and analog_first) else config.timesteps
        total += 2.0 * batch * repeats * a * b
    if config.intra != "none":
        total += 2.0 * batch * (config.timesteps - 1) * action_dim * config.population_out**2
    return total


def td3_step_flops(preset: str, state_dim: int, action_dim: int, td3: TD3Config) -> float:
    """Matmul FLOPs of one environment step of TD3: one action, one critic update, half an actor update."""
    batch = td3.batch_size
    critic_sizes = [state_dim + action_dim, *td3.critic_hidden, 1]
    critic = 2 * sum(2.0 * batch * a * b for a, b in zip(critic_sizes[:-1], critic_sizes[1:], strict=True))
    actor = actor_forward_flops(preset, state_dim, action_dim, batch)
    update = actor + critic + 3 * critic  # target actor, target critics, critic forward + backward
    update += (3 * actor + 3 * critic) / td3.policy_delay  # actor forward + backward through the critic
    return update + actor_forward_flops(preset, state_dim, action_dim, 1)


def matmul_floor(task: str, preset: str, seeds: tuple[int, ...], threads: int, matmul: str = "float32",
                 repeats: int = 50) -> float:
    """Steps/s if a training step did nothing but its matrix products: the floor no engine can beat.

    Records the operand shapes of every matmul of two TD3 updates (one without and one with the delayed
    actor update) and one action, at the dispatcher (forward and backward), then replays exactly those
    products back to back.
    """
    from torch.utils._python_dispatch import TorchDispatchMode

    from ilcsan.rl.settings import set_matmul_precision
    from ilcsan.rl.td3 import TD3Agent

    matmuls = {torch.ops.aten.bmm.default, torch.ops.aten.baddbmm.default, torch.ops.aten.mm.default,
               torch.ops.aten.addmm.default}
    products = []

    class RecordMatmuls(TorchDispatchMode):
        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            if func in matmuls:
                products.append((func, [torch.randn(arg.shape) for arg in args if isinstance(arg, torch.Tensor)]))
            return func(*args, **(kwargs or {}))

    state_dim, action_dim = TASK_SIZES[task]
    torch.set_num_threads(threads)
    set_matmul_precision(matmul)
    k = len(seeds)
    agent = TD3Agent(actor_config(preset), TD3Config(), state_dim, action_dim, [1.0] * action_dim,
                     [0.0] * action_dim, seeds)
    generator = torch.Generator().manual_seed(0)
    batch = {"obs": torch.randn(k, 100, state_dim, generator=generator),
             "next_obs": torch.randn(k, 100, state_dim, generator=generator),
             "action": torch.rand(k, 100, action_dim, generator=generator) * 2 - 1,
             "reward": torch.randn(k, 100, generator=generator), "terminal": torch.zeros(k, 100)}
    agent.update(batch)  # leaves the update count odd: of the two recorded updates, the second is delayed
    with RecordMatmuls():
        agent.update(batch)
        agent.update(batch)
        agent.act(np.zeros((k, state_dim), dtype=np.float32))

    def replay() -> None:
        for function, operands in products:
            function(*operands)

    for _ in range(5):
        replay()
    start = time.perf_counter()
    for _ in range(repeats):
        replay()
    seconds_per_step = (time.perf_counter() - start) / repeats / 2
    set_matmul_precision("float32")
    return 1.0 / seconds_per_step


def training_speed(task: str, preset: str, engine: str, seeds: tuple[int, ...], threads: int, steps: int,
                   warmup: int, compiled: bool = True, matmul: str = "float32") -> float:
    """Environment steps per second per seed, including updates, after ``warmup`` steps."""
    compile_mode = "on" if engine == "fast" and compiled else "off"
    td3 = TD3Config(start_steps=0, update_after=100, update_every=50)
    config = RunConfig(task=task, seeds=seeds, steps=warmup + steps + 1, eval_every=10**9, eval_episodes=1,
                       actor=actor_config(preset), td3=td3, engine=engine, threads=threads, compile=compile_mode,
                       matmul=matmul)
    with tempfile.TemporaryDirectory() as folder:
        trainer = Trainer(config, Path(folder) / "run", progress=False, log=lambda *_: None)
        try:
            for _ in range(warmup):
                trainer.train_step()
            start = time.perf_counter()
            for _ in range(steps):
                trainer.train_step()
            elapsed = time.perf_counter() - start
        finally:
            trainer.close()
    return steps / elapsed


def sb3_speed(task: str, threads: int, steps: int, warmup: int) -> float | None:
    try:
        from stable_baselines3 import TD3
    except ImportError:
        return None
    from ilcsan.rl.tasks import make_env

    torch.set_num_threads(threads)
    env = make_env(task, seed=0)
    model = TD3("MlpPolicy", env, learning_starts=100, batch_size=100, train_freq=1, gradient_steps=1,
                policy_kwargs={"net_arch": [256, 256]}, device="cpu", seed=0, verbose=0)
    model.learn(total_timesteps=warmup)
    start = time.perf_counter()
    model.learn(total_timesteps=steps, reset_num_timesteps=False)
    return steps / (time.perf_counter() - start)


def predict_latency_us(preset: str, task: str, calls: int = 2000) -> float:
    from ilcsan.runs.policy import Policy
    from ilcsan.snn.actor import build_actor

    state_dim, action_dim = TASK_SIZES[task]
    torch.set_num_threads(1)
    config = actor_config(preset)
    actor = build_actor(config, state_dim, action_dim, [1.0] * action_dim).eval()
    policy = Policy(actor, config, task, np.zeros(state_dim), np.ones(state_dim), 3.0, np.ones(action_dim),
                    np.zeros(action_dim), {})
    observation = np.random.default_rng(0).normal(size=state_dim)
    for _ in range(100):
        policy.predict(observation)
    times = []
    for _ in range(calls):
        start = time.perf_counter()
        policy.predict(observation)
        times.append(time.perf_counter() - start)
    return float(np.median(times) * 1e6)


def separate_runs_speed(task: str, preset: str, processes: int, steps: int, warmup: int, matmul: str,
                        seeds_per_process: int = 1) -> float:
    """Aggregate steps/s of ``processes`` runs at once, one torch thread each, each of ``seeds_per_process``
    stacked seeds (``ilcsan reproduce`` runs its workers this way)."""
    job = {"task": task, "preset": preset, "steps": steps, "warmup": warmup, "matmul": matmul,
           "seeds": seeds_per_process}
    command = [sys.executable, __file__, "--worker", json.dumps(job)]
    workers = [subprocess.Popen(command, stdout=subprocess.PIPE, text=True) for _ in range(processes)]
    speeds = [float(worker.communicate()[0].strip().splitlines()[-1]) for worker in workers]
    return seeds_per_process * sum(speeds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 2, help="torch threads of one run")
    parser.add_argument("--steps", type=int, default=1500, help="measured steps per configuration")
    parser.add_argument("--warmup", type=int, default=400, help="warm-up steps (compilation happens here)")
    parser.add_argument("--seeds", type=int, default=10, help="K for the many-seeds measurement")
    parser.add_argument("--tasks", default="Hopper,Ant")
    parser.add_argument("--presets", default="dan,popsan,ilc-san")
    parser.add_argument("--out", help="also write the table to this Markdown file")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        job = json.loads(args.worker)
        print(training_speed(job["task"], job["preset"], "fast", tuple(range(job["seeds"])), 1, job["steps"],
                             job["warmup"], matmul=job["matmul"]))
        return

    lines = []

    def emit(text: str = "") -> None:
        print(text, flush=True)
        lines.append(text)

    peak_1, peak_n = gemm_peak(1), gemm_peak(args.threads)
    td3 = TD3Config()
    emit(f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__}, "
         f"{args.threads} threads per run; float32 GEMM peak {peak_1:.0f} GFLOP/s (1 thread), "
         f"{peak_n:.0f} GFLOP/s ({args.threads} threads).")
    emit()
    emit("| task | actor | reference engine, eager (steps/s) | fast engine, eager | fast engine, compiled | "
         "compiled / reference | compiled, bf16 matmuls | bf16 / reference | matmul-only floor (float32) | "
         "compiled as % of floor | GFLOP per step | compiled as % of GEMM peak |")
    emit("|---|---|---|---|---|---|---|---|---|---|---|---|")
    fast_speeds, bf16_speeds = {}, {}
    for task in args.tasks.split(","):
        state_dim, action_dim = TASK_SIZES[task]
        for preset in args.presets.split(","):
            reference = training_speed(task, preset, "reference", (0,), args.threads, args.steps, args.warmup)
            eager = training_speed(task, preset, "fast", (0,), args.threads, args.steps, args.warmup, compiled=False)
            fast = training_speed(task, preset, "fast", (0,), args.threads, args.steps, args.warmup)
            bf16 = training_speed(task, preset, "fast", (0,), args.threads, args.steps, args.warmup, matmul="bf16")
            fast_speeds[(task, preset)], bf16_speeds[(task, preset)] = fast, bf16
            floor = matmul_floor(task, preset, (0,), args.threads)
            flops = td3_step_flops(preset, state_dim, action_dim, td3)
            limit = peak_n * 1e9 / flops
            emit(f"| {task} | {preset} | {reference:.0f} | {eager:.0f} | {fast:.0f} | {fast / reference:.2f}× | "
                 f"{bf16:.0f} | {bf16 / reference:.2f}× | {floor:.0f} | {100 * fast / floor:.0f}% | "
                 f"{flops / 1e9:.3f} | {100 * fast / limit:.0f}% of {limit:.0f} |")
    emit()
    sb3 = sb3_speed("Hopper", args.threads, args.steps, args.warmup)
    if sb3 is None:
        emit("Stable-Baselines3 is not installed (pip install stable-baselines3): no comparison.")
    else:
        ilc, ilc_bf16 = fast_speeds.get(("Hopper", "ilc-san")), bf16_speeds.get(("Hopper", "ilc-san"))
        emit(f"Stable-Baselines3 TD3 (MLP 256-256, float32) on Hopper: {sb3:.0f} steps/s; ILC-SAN fast engine: "
             f"{ilc:.0f} steps/s = {ilc / sb3:.2f}× SB3, with bf16 matmuls {ilc_bf16:.0f} steps/s = "
             f"{ilc_bf16 / sb3:.2f}× SB3 (SB3 trains an MLP actor, ours a spiking one).")
    emit()
    k = args.seeds
    cores = os.cpu_count() or 2
    for matmul in ("float32", "bf16"):
        together = k * training_speed("Hopper", "ilc-san", "fast", tuple(range(k)), args.threads, args.steps // 2,
                                      args.warmup, matmul=matmul)
        separate = separate_runs_speed("Hopper", "ilc-san", cores, args.steps // 2, args.warmup, matmul)
        split = separate_runs_speed("Hopper", "ilc-san", cores, args.steps // 2, args.warmup, matmul,
                                    seeds_per_process=k // cores)
        floor = k * matmul_floor("Hopper", "ilc-san", tuple(range(k)), args.threads, matmul)
        emit(f"Many seeds, ILC-SAN on Hopper, {matmul} matmuls: {k} seeds in one process {together:.0f} steps/s "
             f"in aggregate ({100 * together / floor:.0f}% of its matmul-only floor, {floor:.0f}); {cores} separate "
             f"single-seed processes (1 thread each) {separate:.0f} steps/s in aggregate: "
             f"{together / separate:.2f}× faster together; {cores} processes of {k // cores} stacked seeds "
             f"(1 thread each, as `ilcsan reproduce` runs) {split:.0f} steps/s: {split / separate:.2f}×.")
        emit()
    emit()
    for task in args.tasks.split(","):
        emit(f"Batch-1 action latency, Policy.predict, ILC-SAN on {task} (PyTorch eager, 1 thread): "
             f"{predict_latency_us('ilc-san', task):.0f} µs (median).")
    if args.out:
        Path(args.out).write_text("# Speed benchmark\n\n" + "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
