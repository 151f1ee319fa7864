"""What a run's settings mean for this process: one clear line for every impossible setting, the matmul
precision, and whether to compile."""

from __future__ import annotations

import os

import torch

from ..config import MATMUL_PRECISIONS, RunConfig, check_settings
from ..errors import UserError
from ..snn.matmul import COMPILABLE_PATHS, fastest_float32_path, layer_products, measure_paths, use_matmul_path
from .noisy_exploration import return_reference

COMPILE_PAYS_AFTER_UPDATES = {"spiking": 4_000, "deep": 25_000}
"""``--compile auto`` compiles a run with at least this many TD3 updates (steps − update_after), by network.

Measured on a 2-core AMD EPYC (Hopper, one thread): compiling the update program and the acting pass takes
about 50 s the first time and 10-15 s once inductor's cache holds them; it then saves about 12 ms per ILC-SAN
update (eager 18.5 → 6.5 ms per step) and about 2 ms per DAN update (5.5 → 3.6 ms), so even a first compilation
repays itself after ~4 000 and ~25 000 updates."""


def validate_run(config: RunConfig) -> None:
    """One clear sentence for every impossible run setting: the ranges and choices declared with the settings
    (:func:`~ilcsan.config.check_settings`), then what needs this process (seeds, threads, the device)."""
    check_settings(config)
    check_settings(config.td3)
    config.td3.check_network(config.actor.network)
    if config.td3.exploration == "noisy":
        return_reference(config.task, config.td3)
    if not config.seeds:
        raise UserError("give at least one seed")
    if len(set(config.seeds)) != len(config.seeds):
        raise UserError(f"seeds must be distinct, got {list(config.seeds)}")
    most_threads = 4 * (os.cpu_count() or 1)
    if config.threads is not None and config.threads > most_threads:
        raise UserError(f"--threads {config.threads} is more than 4 per core ({most_threads} here); use at most "
                        f"{os.cpu_count() or 1}")
    _validate_device(config.device)


def _validate_device(name: str) -> None:
    try:
        device = torch.device(name)
    except (RuntimeError, TypeError, ValueError):
        raise UserError(f"--device {name!r} is not a device; use cpu, cuda or cuda:N") from None
    if device.type not in ("cpu", "cuda"):
        raise UserError(f"--device {name!r} is not supported; use cpu, cuda or cuda:N")
    if device.type == "cuda" and not torch.cuda.is_available():
        raise UserError("--device cuda was asked for but no CUDA device is available; use --device cpu")
    if device.type == "cuda" and (device.index or 0) >= torch.cuda.device_count():
        raise UserError(f"--device {name!r}: this machine has {torch.cuda.device_count()} CUDA device(s)")


def set_matmul_precision(name: str) -> None:
    """Apply ``--matmul`` to this process (torch's setting is global)."""
    torch.set_float32_matmul_precision(MATMUL_PRECISIONS[name])


def run_products(config: RunConfig, state_dim: int, action_dim: int) -> list:
    """The (a, w) shapes of every product of one update of this run: each actor layer over T·B rows (B rows for
    DAN and an analog first layer are close enough for timing) and each of the 2K critics' layers over B rows,
    forward and both backward products."""
    seeds, batch = len(config.seeds), config.td3.batch_size
    actor = config.actor
    rows = batch * (actor.timesteps if actor.network == "spiking" else 1)
    sizes = actor.layer_sizes(state_dim, action_dim)
    critic = [state_dim + action_dim, *config.td3.critic_hidden, 1]
    products = [p for d_in, d_out in zip(sizes[:-1], sizes[1:], strict=True)
                for p in layer_products(seeds, rows, d_in, d_out)]
    return products + [p for d_in, d_out in zip(critic[:-1], critic[1:], strict=True)
                       for p in layer_products(2 * seeds, batch, d_in, d_out)]


def choose_matmul_path(config: RunConfig, state_dim: int, action_dim: int) -> dict:
    """Set this process's matmul path for the run (:mod:`ilcsan.snn.matmul`): ``bf16`` when asked, else the
    faster float32 path on the run's own products, measured now (among the compilable paths when the run is
    compiled). Returns what was chosen and the measured GFLOP/s, for config.json and the start-up line."""
    if config.matmul == "bf16" or torch.device(config.device).type != "cpu":
        path = "bf16" if config.matmul == "bf16" and torch.device(config.device).type == "cpu" else "aten"
        use_matmul_path(path)
        return {"path": path, "gflops": {}}
    speeds = measure_paths(run_products(config, state_dim, action_dim), seconds=0.05)
    compiled = use_compile(config)
    path = fastest_float32_path(speeds, compiled)
    use_matmul_path(path)
    return {"path": path, "compiled": compiled, "gflops": {name: round(value, 1) for name, value in speeds.items()}}


def describe_matmul_choice(choice: dict) -> str:
    """One line for the start of a run: the path and, when measured, each path's speed on the run's products."""
    if not choice["gflops"]:
        return f"matmul: {choice['path']}"
    speeds = ", ".join(f"{name} {value:.0f}" + (" (eager runs only)" if choice["compiled"] and name not in
                                                  COMPILABLE_PATHS else "") for name, value in choice["gflops"].items())
    return f"matmul: {choice['path']} (float32 GFLOP/s on this run's products: {speeds})"


def apply_to_process(config: RunConfig) -> None:
    """``--threads``, ``--matmul`` and flushing denormal floats to zero (:func:`flush_denormals`) for this process."""
    flush_denormals()
    if config.threads is not None:
        torch.set_num_threads(config.threads)
    set_matmul_precision(config.matmul)


def denormals_flushed() -> bool:
    """Whether this thread flushes denormal floats to zero now: a float64 → float32 conversion of 1e-39 tells."""
    return float(torch.tensor(1e-39, dtype=torch.float64).to(torch.float32)) == 0.0


def flush_denormals(on: bool = True) -> bool:
    """Treat float32 values below 1.2e-38 (denormals) as zero in this thread (x86 FTZ/DAZ) and in the threads
    it starts later (``on=False``: keep them again); returns whether the CPU supports it.

    The flag is per thread and a new thread inherits it, so it reaches torch's intra-op worker threads only if
    set before the process's first multi-threaded operation creates them (measured with two threads: set
    after, the worker's half of a product kept its denormals and the product took 8 ms instead of 0.02 ms; set
    before, both halves were flushed). A run sets it before any torch work, once its task builds
    (:func:`apply_to_process`), and the trainer gives this thread its earlier setting back when it closes
    (worker threads started meanwhile keep it); from Python, call this before any multi-threaded torch work.

    Why: Adam's moments m and v of a weight whose gradient is (nearly) zero — the input weights of a neuron that
    stays silent, a dead ReLU of Proxy Target's proxy — decay geometrically (×β₁, ×β₂ per update) into the
    denormal range within a few hundred updates and stay there while tiny gradients keep arriving. Each
    arithmetic operation on a denormal then takes a microcode assist: a float32 multiply ran 45× slower here
    (Intel Xeon, one thread), and after about a thousand Proxy Target updates 43 % of the proxy's and 16 % of
    the critic's Adam moments were denormal, which made Proxy Target's regression steps 2.7× slower. Flushing
    them changes an Adam step by less than 1e-30 (m̂ / (√v̂ + ε) with ε = 1e-8 and |m̂| < 1.2e-38), far below a
    weight's last bit.
    """
    return torch.set_flush_denormal(on)


def use_compile(config: RunConfig) -> bool:
    """Compile when asked, or (auto) when the run has enough updates to repay the compilation
    (:data:`COMPILE_PAYS_AFTER_UPDATES`); the reference engine (the literal Algorithm 1 oracle) stays eager."""
    if config.compile == "auto":
        updates = max(0, config.steps - config.td3.update_after)
        return config.engine == "fast" and updates >= COMPILE_PAYS_AFTER_UPDATES[config.actor.network]
    return config.compile == "on"
