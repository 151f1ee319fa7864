"""Training speed, measured side by side in one run: prints Markdown tables (and writes them with --out).

What it measures, on this machine, in this order:
  1. the CPU, the float32 GEMM peak (2048² matmul) and each matmul path's GFLOP/s on a run's own products, each
     as often as a training step computes it (MKL through aten, oneDNN, bf16), one thread;
  2. for each task and for 1 and 2 torch threads, environment steps per second including TD3 updates: ILC-SAN
     with the reference engine (Algorithm 1's time-step loop, eager, about the authors' code), the fast engine
     eager, the update compiled as one program (float32 on the path the run chooses, and bf16); DAN eager and
     compiled; Stable-Baselines3's TD3 (MLP 256-256) when installed, as shipped and with denormal floats flushed
     to zero as our runs do (``ilcsan.compute.process.flush_denormals``). Each figure is also given as a ratio to the
     reference engine and to both SB3 rows, and as a fraction of the step's matmul-only floor: its recorded matrix
     products replayed back to back on the fastest float32 path (bf16 rows: each product as a bf16 run computes it,
     in bfloat16 with the casts excluded where that is faster, else in float32); and the ceiling of any float32
     engine: the step's matmul FLOPs at the CPU's float32 GEMM peak, nothing else costing;
  3. K seeds trained together in one process against K times the floor of one;
  4. batch-1 action latency: the training loop's compiled acting pass and ``Policy.predict``, eager and compiled.

Steps/s are measured after a warm-up (compilation happens there), with updates from the start (no random-action
phase), and without evaluations. Run it on an otherwise idle machine:

    .venv/bin/python benchmarks/speed.py --out benchmarks/RESULTS.md
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

from ilcsan.compute.process import flush_denormals
from ilcsan.config import RunConfig, TrainingConfig, actor_config
from ilcsan.experiments.estimate import cpu_field
from ilcsan.experiments.machine_speed import seconds_per_training_step

TASK_SIZES = {"Hopper": (11, 3), "Ant": (111, 8), "HalfCheetah": (17, 6)}


def gemm_peak(threads: int, size: int = 2048, windows: int = 8, seconds: float = 0.3) -> float:
    """GFLOP/s of a float32 square matmul with ``threads`` threads: the best of ``windows`` timed windows of about
    ``seconds`` each, so that a slow phase of a shared machine does not lower the ceiling it stands for."""
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    a, b = torch.randn(size, size), torch.randn(size, size)
    for _ in range(3):
        a @ b
    best = 0.0
    for _ in range(windows):
        count, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds:
            a @ b
            count += 1
        best = max(best, 2 * size**3 * count / (time.perf_counter() - start) / 1e9)
    torch.set_num_threads(previous)
    return best


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


def td3_step_flops(preset: str, state_dim: int, action_dim: int, training: TrainingConfig) -> float:
    """Matmul FLOPs of one environment step of TD3: one action, one critic update, half an actor update."""
    batch = training.batch_size
    critic_sizes = [state_dim + action_dim, *training.critic_hidden, 1]
    critic = 2 * sum(2.0 * batch * a * b for a, b in zip(critic_sizes[:-1], critic_sizes[1:], strict=True))
    actor = actor_forward_flops(preset, state_dim, action_dim, batch)
    update = actor + critic + 3 * critic  # target actor, target critics, critic forward + backward
    update += (3 * actor + 3 * critic) / training.policy_delay  # actor forward + backward through the critic
    return update + actor_forward_flops(preset, state_dim, action_dim, 1)


def matmul_floor(task: str, preset: str, seeds: tuple[int, ...], threads: int, path: str = "aten",
                 repeats: int = 50) -> float:
    """Steps/s if a training step did nothing but its matrix products, on matmul ``path``: the floor no engine
    on that path can beat.

    Records the operand shapes of every matmul of two TD3 updates (one without and one with the delayed
    actor update) and one action, at the dispatcher (forward and backward), then replays exactly those
    products back to back as ``a @ wᵀ`` per ensemble member on ``path`` (:mod:`ilcsan.compute.matmul`). On ``bf16``
    each product runs as a bf16 run computes it: in bfloat16 with its operands already cast (a compiled program
    fuses the casts) where that was measured faster, else in float32 (``aten``).
    """
    from torch.utils._python_dispatch import TorchDispatchMode

    from ilcsan.compute.matmul import gaining_products, product_call, product_times
    from ilcsan.rl.algorithms import TD3, TaskSpace

    matmuls = {torch.ops.aten.bmm.default, torch.ops.aten.baddbmm.default, torch.ops.aten.mm.default,
               torch.ops.aten.addmm.default}
    products = []

    class RecordMatmuls(TorchDispatchMode):
        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            if func in matmuls:
                a, b = [arg for arg in args if isinstance(arg, torch.Tensor)][-2:]  # (bias,) a, b
                a, b = (a, b) if a.dim() == 3 else (a.unsqueeze(0), b.unsqueeze(0))
                products.append((torch.randn(a.shape), torch.randn(b.shape).transpose(1, 2).contiguous()))
            return func(*args, **(kwargs or {}))

    state_dim, action_dim = TASK_SIZES[task]
    torch.set_num_threads(threads)
    k = len(seeds)
    agent = TD3(actor_config(preset), TrainingConfig(), TaskSpace(state_dim, action_dim, [1.0] * action_dim,
                                                            [0.0] * action_dim), seeds)
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

    shapes = [(tuple(a.shape), tuple(w.shape)) for a, w in products]
    if path == "bf16":  # bfloat16 where the run would use it, float32 elsewhere
        bf16 = gaining_products(product_times(shapes, fused_casts=True))
        paths = ["bf16" if shape in bf16 else "aten" for shape in shapes]
    else:
        paths = [path] * len(shapes)
    calls = [product_call(a, w, chosen, fused_casts=True) for (a, w), chosen in zip(products, paths, strict=True)]

    def replay() -> None:
        for call in calls:
            call()

    for _ in range(5):
        replay()
    start = time.perf_counter()
    for _ in range(repeats):
        replay()
    seconds_per_step = (time.perf_counter() - start) / repeats / 2
    return 1.0 / seconds_per_step


def best_float32_floor(task: str, preset: str, seeds: tuple[int, ...], threads: int) -> tuple[float, str]:
    """The matmul-only floor on the fastest float32 path, and that path."""
    from ilcsan.compute.matmul import FLOAT32_PATHS, onednn_available

    floors = {path: matmul_floor(task, preset, seeds, threads, path) for path in FLOAT32_PATHS
              if path != "onednn" or onednn_available()}
    path = max(floors, key=floors.get)
    return floors[path], path


def training_speed(task: str, preset: str, engine: str, seeds: tuple[int, ...], threads: int, steps: int,
                   warmup: int, compiled: bool = True, matmul: str = "float32", algorithm: str = "td3",
                   normalization: str = "none", **training_options) -> float:
    """Environment steps per second per seed, including updates, after ``warmup`` steps; ``training_options`` choose a
    training method (e.g. ``target_actor="proxy"``), ``algorithm`` the off-policy algorithm, ``normalization`` the
    actor's (``care-bn``)."""
    compile_mode = "on" if engine == "fast" and compiled else "off"
    training = TrainingConfig(start_steps=0, update_after=100, update_every=50, **training_options)
    config = RunConfig(task=task, seeds=seeds, steps=warmup + steps + 1, eval_every=10**9, eval_episodes=1,
                       actor=actor_config(preset, normalization=normalization), training=training, engine=engine,
                       threads=threads, compile=compile_mode, matmul=matmul, algorithm=algorithm)
    return 1.0 / seconds_per_training_step(config, warmup, steps)[0]


def sb3_speed(task: str, threads: int, steps: int, warmup: int, flush: bool = False) -> float | None:
    """SB3's TD3 on the same task and budget, in a fresh process (the denormal flag is per thread and inherited
    by the threads a process starts, so it must be set before any of them exist); as shipped SB3 keeps denormal
    floats (``flush=False``), our runs flush them (:func:`ilcsan.compute.process.flush_denormals`): both
    are measured, for a like-for-like ratio. None when Stable-Baselines3 is not installed."""
    if importlib.util.find_spec("stable_baselines3") is None:
        return None
    argv = [sys.executable, __file__, "--sb3-alone", f"{task},{threads},{steps},{warmup},{int(flush)}"]
    done = subprocess.run(argv, capture_output=True, text=True, check=True)
    return float(done.stdout.split()[-1])


def sb3_alone(task: str, threads: int, steps: int, warmup: int, flush: bool) -> float:
    from stable_baselines3 import TD3

    from ilcsan.rl.tasks import make_env

    flush_denormals(flush)
    torch.set_num_threads(threads)
    env = make_env(task, seed=0)
    model = TD3("MlpPolicy", env, learning_starts=100, batch_size=100, train_freq=1, gradient_steps=1,
                policy_kwargs={"net_arch": [256, 256]}, device="cpu", seed=0, verbose=0)
    model.learn(total_timesteps=warmup)
    start = time.perf_counter()
    model.learn(total_timesteps=steps, reset_num_timesteps=False)
    return steps / (time.perf_counter() - start)


def predict_latency_us(preset: str, task: str, calls: int = 2000, compiled: bool = False) -> float:
    """Median µs of ``Policy.predict`` for one observation, one thread: eager, or after ``Policy.compile``."""
    from ilcsan.actors import build_actor
    from ilcsan.deploy.policy import Policy

    state_dim, action_dim = TASK_SIZES[task]
    torch.set_num_threads(1)
    config = actor_config(preset)
    actor = build_actor(config, state_dim, action_dim, [1.0] * action_dim).eval()
    policy = Policy(actor, config, task, np.zeros(state_dim), np.ones(state_dim), 3.0, np.ones(action_dim),
                    np.zeros(action_dim), {})
    if compiled:
        policy.compile()
    observation = np.random.default_rng(0).normal(size=state_dim)
    return median_call_us(lambda: policy.predict(observation), calls)


def median_call_us(function, calls: int, warmup: int = 200) -> float:
    """Median µs of one call of ``function`` over ``calls`` timed calls, after ``warmup`` untimed ones."""
    for _ in range(warmup):
        function()
    times = []
    for _ in range(calls):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return float(np.median(times) * 1e6)


def cpu_model() -> str:
    """The CPU's model name as /proc/cpuinfo gives it (or what platform knows)."""
    return cpu_field("model name") or platform.processor() or platform.machine()


def path_speeds(task: str, preset: str, seeds: tuple[int, ...] = (0,)) -> dict[str, float]:
    """GFLOP/s of every matmul path on the products of a run of ``preset`` on ``task`` (one thread), each product
    weighted by how often a training step computes it (``run_products``): each path on all of them (bf16 casting its
    operands in the call, as eager runs do), and "bf16 per product" as a compiled bf16 run computes them (bfloat16
    with the casts fused where that is faster, float32 elsewhere)."""
    from ilcsan.compute.matmul import MATMUL_PATHS, gaining_products, measure_paths, product_flops, product_times
    from ilcsan.rl.matmul_choice import run_products

    torch.set_num_threads(1)
    config = RunConfig(task=task, seeds=seeds, actor=actor_config(preset))
    products = run_products(config, *TASK_SIZES[task])
    speeds = measure_paths(products, paths=MATMUL_PATHS, seconds=0.02)
    times = product_times(products, fused_casts=True, seconds=0.02)
    bf16 = gaining_products(times)
    seconds = sum(count * times[product][1 if product in bf16 else 0] for product, count in products.items())
    flops = sum(count * product_flops(product) for product, count in products.items())
    speeds["bf16 per product"] = flops / seconds / 1e9
    return speeds


def act_latency_us(task: str, calls: int = 3000) -> float:
    """Median µs of the training loop's batch-1 action (compiled ILC-SAN acting pass), one thread."""
    from ilcsan.rl.algorithms import TD3, ComputeSettings, TaskSpace

    torch.set_num_threads(1)
    state_dim, action_dim = TASK_SIZES[task]
    task_space = TaskSpace(state_dim, action_dim, [1.0] * action_dim, [0.0] * action_dim)
    agent = TD3(actor_config("ilc-san"), TrainingConfig(), task_space, (0,), ComputeSettings(compile=True))
    state = np.random.default_rng(0).normal(size=(1, state_dim)).astype(np.float32)
    return median_call_us(lambda: agent.act(state), calls)


ROWS = (("ILC-SAN, reference engine (Algorithm 1, eager)", "ilc-san", "reference", False, "float32"),
        ("ILC-SAN, fast engine, eager", "ilc-san", "fast", False, "float32"),
        ("ILC-SAN, compiled update program, float32", "ilc-san", "fast", True, "float32"),
        ("ILC-SAN, compiled update program, bf16", "ilc-san", "fast", True, "bf16"),
        ("DAN, eager", "dan", "fast", False, "float32"),
        ("DAN, compiled update program, float32", "dan", "fast", True, "float32"))
"""(label, preset, engine, compiled, matmul) of each measured configuration."""


def peak_bound(task: str, preset: str, peak_gflops: float) -> float:
    """Steps/s if every matrix product of a step ran at the CPU's float32 GEMM peak (:func:`gemm_peak`) and nothing
    else cost anything: the ceiling of any float32 engine computing these products, whatever its matmul path."""
    state_dim, action_dim = TASK_SIZES[task]
    return peak_gflops * 1e9 / td3_step_flops(preset, state_dim, action_dim, TrainingConfig())


def task_table(task: str, threads: int, steps: int, warmup: int, emit, peak_gflops: float) -> dict[str, float]:
    """One task's table for ``threads`` threads (``peak_gflops``: the float32 GEMM peak with as many); returns
    each row's steps/s by label."""
    floors = {preset: best_float32_floor(task, preset, (0,), threads) for preset in ("ilc-san", "dan")}
    bf16_floor = matmul_floor(task, "ilc-san", (0,), threads, "bf16")
    speeds = {label: training_speed(task, preset, engine, (0,), threads, steps, warmup, compiled, matmul)
              for label, preset, engine, compiled, matmul in ROWS}
    sb3 = sb3_speed(task, threads, steps, warmup)
    sb3_flushed = sb3_speed(task, threads, steps, warmup, flush=True)
    reference = speeds[ROWS[0][0]]
    emit(f"**{task}, {threads} thread{'s' if threads > 1 else ''}** — float32 matmul-only floor: ILC-SAN "
         f"{floors['ilc-san'][0]:.0f} steps/s ({floors['ilc-san'][1]}), DAN {floors['dan'][0]:.0f} "
         f"({floors['dan'][1]}); ILC-SAN bf16 floor {bf16_floor:.0f}. Every product at the float32 GEMM peak "
         f"({peak_gflops:.0f} GFLOP/s), nothing else costing: ILC-SAN {peak_bound(task, 'ilc-san', peak_gflops):.0f} "
         f"steps/s, DAN {peak_bound(task, 'dan', peak_gflops):.0f}.")
    emit()
    emit("| configuration | steps/s | × reference engine | × SB3 | × SB3 flushing denormals | % of its floor |")
    emit("|---|---|---|---|---|---|")

    def versus(speed: float, baseline: float | None) -> str:
        return f"{speed / baseline:.2f}×" if baseline else "–"

    for label, preset, _, _, matmul in ROWS:
        speed = speeds[label]
        floor = bf16_floor if matmul == "bf16" else floors[preset][0]
        emit(f"| {label} | {speed:.0f} | {speed / reference:.2f}× | {versus(speed, sb3)} | "
             f"{versus(speed, sb3_flushed)} | {100 * speed / floor:.0f}% |")
    if sb3:
        emit(f"| Stable-Baselines3 TD3 (MLP 256-256, float32), as shipped | {sb3:.0f} | {sb3 / reference:.2f}× | "
             f"1.00× | {versus(sb3, sb3_flushed)} | – |")
        emit(f"| Stable-Baselines3 TD3, denormals flushed as in our runs | {sb3_flushed:.0f} | "
             f"{sb3_flushed / reference:.2f}× | {versus(sb3_flushed, sb3)} | 1.00× | – |")
    emit()
    return speeds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", default="1,2", help="torch threads of one run, comma-separated")
    parser.add_argument("--steps", type=int, default=1000, help="measured steps per configuration")
    parser.add_argument("--warmup", type=int, default=300, help="warm-up steps (compilation happens here)")
    parser.add_argument("--seeds", type=int, default=10, help="K for the many-seeds measurement")
    parser.add_argument("--tasks", default="Hopper,Ant,HalfCheetah")
    parser.add_argument("--out", help="also write the tables to this Markdown file")
    parser.add_argument("--sb3-alone", help=argparse.SUPPRESS)  # task,threads,steps,warmup,flush: one SB3 figure
    args = parser.parse_args()
    if args.sb3_alone:
        task, *numbers = args.sb3_alone.split(",")
        threads, steps, warmup, flush = (int(number) for number in numbers)
        print(sb3_alone(task, threads, steps, warmup, bool(flush)))
        return

    lines = []

    def emit(text: str = "") -> None:
        print(text, flush=True)
        lines.append(text)

    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    flush_denormals()  # before any multi-threaded work, so that the threads torch starts flush them as a run's do
    paths = path_speeds("Hopper", "ilc-san")
    thread_counts = [int(value) for value in args.threads.split(",")]
    peaks = {threads: gemm_peak(threads) for threads in sorted({1, *thread_counts})}
    emit(f"Machine: {cpu_model()}, {os.cpu_count()} cores, torch {torch.__version__}; float32 GEMM peak "
         f"{peaks[1]:.0f} GFLOP/s (1 thread, 2048²). Matmul paths on an ILC-SAN Hopper training step's products, "
         "each as often as a step computes it (1 thread, GFLOP/s): "
         + ", ".join(f"{name} {value:.0f}" for name, value in paths.items()) + ".")
    emit()
    for task in args.tasks.split(","):
        for threads in thread_counts:
            task_table(task, threads, args.steps, args.warmup, emit, peaks[threads])
    k = args.seeds
    together = k * training_speed("Hopper", "ilc-san", "fast", tuple(range(k)), 1, args.steps // 2, args.warmup)
    floor = k * best_float32_floor("Hopper", "ilc-san", tuple(range(k)), 1)[0]
    emit(f"Many seeds, ILC-SAN on Hopper, float32, compiled, 1 thread: {k} seeds in one process {together:.0f} "
         f"steps/s in aggregate, {100 * together / floor:.0f}% of their matmul-only floor ({floor:.0f}).")
    emit()
    for task in args.tasks.split(","):
        emit(f"Batch-1 action latency, ILC-SAN on {task}, 1 thread (median): training loop's compiled acting pass "
             f"{act_latency_us(task):.0f} µs; Policy.predict eager {predict_latency_us('ilc-san', task):.0f} µs, "
             f"compiled {predict_latency_us('ilc-san', task, compiled=True):.0f} µs.")
    emit()
    emit(f"Measured from {started} to {time.strftime('%H:%M UTC', time.gmtime())}.")
    if args.out:
        Path(args.out).write_text("# Speed benchmark\n\n" + "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
