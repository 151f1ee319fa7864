"""What a run's settings mean for this process: one clear line for every impossible setting, the matmul
precision, and whether to compile."""

from __future__ import annotations

import os
from dataclasses import dataclass
from itertools import pairwise

import torch

from ..config import PROXY_HIDDEN, SPIKING_ENCODERS, RunConfig, check_settings
from ..errors import UserError
from ..snn.matmul import (
    Product,
    fastest_float32_path,
    gaining_products,
    layer_products,
    matmul_setting,
    measure_paths,
    product_times,
    use_matmul_path,
)
from .noisy_exploration import return_reference

COMPILE_PAYS_AFTER_UPDATES = {"spiking": 4_000, "deep": 25_000}
"""``--compile auto`` compiles a run with at least this many TD3 updates (steps − update_after), by network.

Measured on a 2-core AMD EPYC (Hopper, one thread): compiling the update program and the acting pass takes
about 50 s the first time and 10-15 s once inductor's cache holds them; it then saves about 12 ms per ILC-SAN
update (eager 18.5 → 6.5 ms per step) and about 2 ms per DAN update (5.5 → 3.6 ms), so even a first compilation
repays itself after ~4 000 and ~25 000 updates. On the Intel Xeon (AMX) of ``benchmarks/RESULTS.md``
(2026-12-02, 1 100 steps compiled against eager, empty and warm inductor cache): ILC-SAN's compilation costs ≈ 62 s
the first time and ≈ 12 s cached and saves 12.3 ms per update (16.8 → 4.4-4.7 ms per step), repaid after ≈ 5 000
and ≈ 1 000 updates; DAN's ≈ 34 s and ≈ 7 s, saving 3.4 ms (5.9 → 2.4-2.6 ms), repaid after ≈ 10 000 and ≈ 2 000.
The thresholds are the AMD machine's: ILC-SAN's lies between the Intel machine's first-compilation and cached
break-even points, DAN's above both machines' first-compilation ones."""


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


def set_matmul_precision(name: str, device: str = "cpu") -> None:
    """Apply ``--matmul`` to torch's float32 matmul precision (a global setting): on CUDA, ``bf16`` lets float32
    products use TF32/bf16 tensor cores ("medium"); on a CPU every float32 product stays float32 ("highest"; there
    the bf16 path casts the products it chooses itself, :mod:`ilcsan.snn.matmul`: "medium" would make oneDNN
    round every float32 product, the small ones too, which bfloat16 computes slower)."""
    cuda_bf16 = name == "bf16" and torch.device(device).type == "cuda"
    torch.set_float32_matmul_precision("medium" if cuda_bf16 else "highest")


def run_products(config: RunConfig, state_dim: int, action_dim: int) -> list[Product]:
    """The (a, w) shapes of the products of this run (:data:`~ilcsan.snn.matmul.Product`), repeated as a step
    repeats them: for each actor layer the three products of an update over T·B rows and the forward product of
    acting (T rows), of evaluation (T·E rows) and, with Proxy Target, of the proxy's regression targets (T·B·K_proxy
    rows), T being 1 for DAN and for a first layer whose input is not a spike train; the three products of every
    critic layer for the 2K critics of the critic loss and for the K first critics of the actor loss; and with
    Proxy Target, those of the proxy's layers."""
    seeds, td3, actor = len(config.seeds), config.td3, config.actor
    batch, proxy = td3.batch_size, td3.target_actor == "proxy"
    timesteps = actor.timesteps if actor.network == "spiking" else 1
    forward_rows = [1, config.eval_episodes] + ([batch * td3.proxy_iterations] if proxy else [])
    products = []
    for index, (d_in, d_out) in enumerate(pairwise(actor.layer_sizes(state_dim, action_dim))):
        steps = timesteps if index > 0 or actor.encoder in SPIKING_ENCODERS else 1
        products += layer_products(seeds, steps * batch, d_in, d_out)
        products += [layer_products(seeds, steps * rows, d_in, d_out)[0] for rows in forward_rows]
    critic = [state_dim + action_dim, *td3.critic_hidden, 1]
    for members in (2 * seeds, seeds):
        products += [p for d_in, d_out in pairwise(critic) for p in layer_products(members, batch, d_in, d_out)]
    if proxy:
        sizes = [state_dim, *PROXY_HIDDEN, action_dim]
        products += [p for d_in, d_out in pairwise(sizes) for p in layer_products(seeds, batch, d_in, d_out)]
    return products


def choose_matmul_path(config: RunConfig, state_dim: int, action_dim: int) -> dict:
    """Set this process's matmul path for the run (:mod:`ilcsan.snn.matmul`) and return what was chosen, for
    config.json and the start-up line. float32: the faster float32 path on the run's own products, measured now.
    bf16: bfloat16 for the products it computes faster, measured now as the run will compute them (casts fused
    when compiled), float32 (``aten``) for the others."""
    if torch.device(config.device).type != "cpu":
        use_matmul_path("aten")
        return {"path": "aten", "gflops": {}}
    products, compiled = run_products(config, state_dim, action_dim), use_compile(config)
    if config.matmul == "bf16":
        times = product_times(products, fused_casts=compiled)
        gaining = gaining_products(times)
        use_matmul_path("bf16", gaining)
        float32_seconds, bf16_seconds = (sum(times[product][index] for product in gaining) for index in (0, 1))
        return {"path": "bf16", "compiled": compiled, "gflops": {},
                "bf16_products": sorted([list(a), list(w)] for a, w in gaining), "products": len(times),
                "bf16_speedup": round(float32_seconds / bf16_seconds, 2) if gaining else None}
    speeds = measure_paths(products, seconds=0.05)
    path = fastest_float32_path(speeds)
    use_matmul_path(path)
    return {"path": path, "compiled": compiled, "gflops": {name: round(value, 1) for name, value in speeds.items()}}


def describe_matmul_choice(choice: dict) -> str:
    """One line for the start of a run: the path and, when measured, each path's speed on the run's products."""
    if "bf16_products" in choice:
        chosen, total = len(choice["bf16_products"]), choice["products"]
        gain = f", {choice['bf16_speedup']:.1f}x faster on those" if chosen else ""
        return (f"matmul: bf16 on {chosen} of this run's {total} product shapes (measured{gain}), float32 (aten) "
                f"on the {total - chosen} that bfloat16 does not speed up")
    if not choice["gflops"]:
        return f"matmul: {choice['path']}"
    speeds = ", ".join(f"{name} {value:.0f}" for name, value in choice["gflops"].items())
    return f"matmul: {choice['path']} (float32 GFLOP/s on this run's products: {speeds})"


@dataclass(frozen=True)
class ProcessSettings:
    """What a run changes in its process, as it was before: this thread's denormal flag, torch's thread count and
    float32 matmul precision, and the matmul path with its bf16 products (:mod:`ilcsan.snn.matmul`)."""

    denormals_flushed: bool
    threads: int
    precision: str
    matmul: tuple

    @classmethod
    def now(cls) -> ProcessSettings:
        return cls(denormals_flushed(), torch.get_num_threads(), torch.get_float32_matmul_precision(),
                   matmul_setting())

    def restore(self) -> None:
        """Give the process these settings back (a program compiled meanwhile keeps the path it was traced with)."""
        flush_denormals(self.denormals_flushed)
        torch.set_num_threads(self.threads)
        torch.set_float32_matmul_precision(self.precision)
        use_matmul_path(*self.matmul)


def apply_to_process(config: RunConfig) -> None:
    """``--threads``, ``--matmul`` and flushing denormal floats to zero (:func:`flush_denormals`) for this process."""
    flush_denormals()
    if config.threads is not None:
        torch.set_num_threads(config.threads)
    set_matmul_precision(config.matmul, config.device)


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
