"""One clear line for every impossible run setting, before anything is built."""

from __future__ import annotations

import os

import torch

from ..config import RunConfig, check_settings
from ..errors import UserError
from .algorithms import algorithm_class


def validate_run(config: RunConfig) -> None:
    """One clear sentence for every impossible run setting: the ranges and choices declared with the settings
    (:func:`~ilcsan.config.check_settings`), then what needs this process (seeds, threads, the device)."""
    check_settings(config)
    check_settings(config.training)
    algorithm_class(config.algorithm).check(config)
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
