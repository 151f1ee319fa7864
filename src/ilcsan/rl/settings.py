"""What a run's settings mean for this process: one clear line for every impossible setting, the matmul
precision, and whether to compile."""

from __future__ import annotations

import os

import torch

from ..config import MATMUL_PRECISIONS, RunConfig, check_settings
from ..errors import UserError

COMPILE_PAYS_AFTER_UPDATES = {"spiking": 2_000, "deep": 10_000}
"""``--compile auto`` compiles a run with at least this many TD3 updates (steps − update_after), by network.

Measured on a 2-core AMD EPYC (Hopper, one thread): compiling the update program takes 10-20 s; it then saves
about 12 ms per ILC-SAN update (eager 18.5 → 6.5 ms per step) and about 2 ms per DAN update (5.5 → 3.6 ms),
so compiling repays itself after ~1 300 and ~9 000 updates."""


def validate_run(config: RunConfig) -> None:
    """One clear sentence for every impossible run setting: the ranges and choices declared with the settings
    (:func:`~ilcsan.config.check_settings`), then what needs this process (seeds, threads, the device)."""
    check_settings(config)
    check_settings(config.td3)
    if config.td3.target_actor == "proxy" and config.actor.network != "spiking":
        raise UserError("--target-actor proxy replaces a spiking actor's target by a continuous proxy; DAN is "
                        "continuous already and keeps TD3's own target: drop --target-actor for DAN")
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


def apply_to_process(config: RunConfig) -> None:
    """``--threads`` and ``--matmul`` for this process."""
    if config.threads is not None:
        torch.set_num_threads(config.threads)
    set_matmul_precision(config.matmul)


def use_compile(config: RunConfig) -> bool:
    """Compile when asked, or (auto) when the run has enough updates to repay the compilation
    (:data:`COMPILE_PAYS_AFTER_UPDATES`); the reference engine (the literal Algorithm 1 oracle) stays eager."""
    if config.compile == "auto":
        updates = max(0, config.steps - config.td3.update_after)
        return config.engine == "fast" and updates >= COMPILE_PAYS_AFTER_UPDATES[config.actor.network]
    return config.compile == "on"
