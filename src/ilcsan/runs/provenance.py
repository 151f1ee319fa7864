"""What code, libraries and machine computed a run: ``provenance.json``, one segment per start or resume.

A run may be trained in several stretches (``--resume``), on other commits or other machines. Each stretch is a
*segment*: the facts of the process that trained it (:func:`collect`) and the step it began at. A seed's run folder
keeps the segments that produced its current state, oldest first::

    {"segments": [{"step": 0, "commit": "7040e47...", "cpu": "AMD EPYC 9R14 96-Core Processor", ...},
                  {"step": 200000, "commit": "5590cb3...", "cpu": "Intel(R) Xeon(R) Platinum 8488C", ...}]}

A resumed run continues from its checkpoint's step and discards whatever was computed after it, so a segment that
began at or after that step is dropped when the new one is added (:func:`extend`): a crash before the first
checkpoint leaves no trace, and a new run in a folder that never reached one starts a new list.

Collecting never fails a run: a fact that cannot be found (no git, not a git checkout, a library not installed)
is None. :func:`differences` tells which of these facts set the runs of one report cell apart.
"""

from __future__ import annotations

import importlib.metadata
import os
import platform
import re
import subprocess
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from ..compute.matmul import FLOAT32_PATHS
from ..version import __version__

GIT_TIMEOUT_SECONDS = 5.0
LIBRARIES = ("torch", "gymnasium", "mujoco")
"""The libraries whose versions a segment records (their distribution names)."""


def collect(step: int, matmul: str, matmul_path: str, device: str = "cpu") -> dict[str, Any]:
    """The facts of this process for a segment that begins at ``step``, as plain JSON values.

    ``matmul`` is the run's ``--matmul`` precision and ``matmul_path`` the path it computes its products on
    (:func:`~ilcsan.rl.matmul_choice.choose_matmul_path`: ``aten`` (MKL), ``onednn`` or ``bf16``); ``threads`` is
    torch's intra-op thread count now, so collect after the run has applied ``--threads``."""
    import torch

    commit, dirty = source_revision(Path(__file__).resolve().parents[1])
    return {
        "step": int(step),
        "started": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "ilcsan": __version__, "commit": commit, "dirty": dirty,
        "python": platform.python_version(),
        **{name: library_version(name) for name in LIBRARIES},
        "cpu": cpu_model(), "cpu_flags": cpu_flags(), "cores": os.cpu_count(), "threads": torch.get_num_threads(),
        "device": device, "matmul": matmul, "matmul_path": matmul_path,
    }


def extend(segments: Sequence[Mapping[str, Any]], segment: Mapping[str, Any]) -> list[dict[str, Any]]:
    """``segments`` followed by ``segment``, without the segments that began at or after its step (nothing they
    computed survives a resume from that step)."""
    kept = [dict(old) for old in segments if isinstance(old, Mapping) and _step(old) < segment["step"]]
    return [*kept, dict(segment)]


def _step(segment: Mapping[str, Any]) -> float:
    step = segment.get("step")
    return step if isinstance(step, int | float) and not isinstance(step, bool) else float("inf")


# --------------------------------------------------------------------------------------- the facts
def source_revision(folder: Path) -> tuple[str | None, bool | None]:
    """The git commit of the checkout that holds the package folder ``folder``, and whether the files under
    ``folder`` differ from it (changed tracked files or new untracked ones; changes elsewhere in the checkout, such
    as docs or tests, do not count). (None, None) when git is missing, too slow, or ``folder`` is not tracked in a
    git checkout (an installed wheel, or a folder inside some other repository, such as a virtualenv in one)."""
    if git(folder, "ls-files", "--error-unmatch", "--", "__init__.py") is None:
        return None, None
    commit = git(folder, "rev-parse", "HEAD")
    if commit is None:
        return None, None
    status = git(folder, "status", "--porcelain", "--untracked-files=normal", "--", ".")
    return commit.strip(), None if status is None else bool(status.strip())


def git(folder: Path, *arguments: str) -> str | None:
    """The output of ``git -C folder ARGUMENTS``; None when it fails, times out or git is not installed. Git's own
    environment variables (``GIT_DIR``, ...) are left out, so the folder alone decides the repository."""
    environment = {key: value for key, value in os.environ.items() if not key.startswith("GIT_")}
    try:
        done = subprocess.run(["git", "-C", str(folder), *arguments], capture_output=True, text=True,
                              timeout=GIT_TIMEOUT_SECONDS, env=environment, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout if done.returncode == 0 else None


def library_version(name: str) -> str | None:
    """The installed version of distribution ``name``, None when it is not installed."""
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return None


def cpu_model(cpuinfo: Path = Path("/proc/cpuinfo")) -> str | None:
    """The CPU's model name (Linux's ``/proc/cpuinfo``), else what :func:`platform.processor` says, else None."""
    try:
        for line in cpuinfo.read_text(encoding="utf-8", errors="replace").splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name" and value.strip():
                return value.strip()
    except OSError:
        pass
    return platform.processor() or None


MATMUL_FLAGS = ("avx2", "avx512f", "avx512_bf16", "amx_bf16")
"""The CPU features that decide the matmul paths' speed (:mod:`ilcsan.compute.matmul`): a virtual machine may name its
CPU only "Intel(R) Xeon(R) Processor", and these tell such CPUs apart where bf16 and float32 speeds differ."""


def cpu_flags(cpuinfo: Path = Path("/proc/cpuinfo")) -> list[str] | None:
    """Which of :data:`MATMUL_FLAGS` the CPU has (the first ``flags`` line of ``/proc/cpuinfo``); None where the file
    is unreadable or has no such line."""
    try:
        for line in cpuinfo.read_text(encoding="utf-8", errors="replace").splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "flags":
                present = set(value.split())
                return [flag for flag in MATMUL_FLAGS if flag in present]
    except OSError:
        pass
    return None


# ---------------------------------------------------------------------------------- comparing runs
def short_cpu(model: str) -> str:
    """A CPU model without trademarks and filler: ``Intel(R) Xeon(R) Platinum 8488C`` → ``Intel Xeon Platinum
    8488C``, ``AMD EPYC 9R14 96-Core Processor`` → ``AMD EPYC 9R14 96-Core``."""
    text = re.sub(r"\((R|TM|r|tm)\)|\bCPU\b|\bProcessor\b|@.*$", " ", model)
    return " ".join(text.split()) or model


def _code(segment: Mapping[str, Any]) -> str:
    commit = segment.get("commit")
    if not isinstance(commit, str):
        return f"ilcsan {segment.get('ilcsan')} (no commit)"
    return commit[:7] + ("+dirty" if segment.get("dirty") else "")


def _precision(segment: Mapping[str, Any]) -> str:
    """``--matmul`` and the path, e.g. ``float32 (aten)``: a path named (``--matmul aten``) reads as the same path
    measured, since both compute alike."""
    matmul, path = segment.get("matmul"), segment.get("matmul_path")
    matmul = "float32" if matmul in FLOAT32_PATHS else matmul
    text = str(matmul) if path in (None, matmul) else f"{matmul} ({path})"
    device = segment.get("device", "cpu")
    return text if device == "cpu" else f"{text} on {device}"


def _cpu(segment: Mapping[str, Any]) -> str:
    model, flags = segment.get("cpu"), segment.get("cpu_flags")
    text = short_cpu(model) if isinstance(model, str) else "unknown"
    return f"{text} [{' '.join(map(str, flags))}]" if isinstance(flags, list) and flags else text


def _version(name: str) -> Callable[[Mapping[str, Any]], str]:
    return lambda segment: "not installed" if segment.get(name) is None else str(segment.get(name))


ASPECTS: dict[str, Callable[[Mapping[str, Any]], str]] = {
    "CPU": _cpu, "code": _code, "precision": _precision, "Python": _version("python"),
    **{name: _version(name) for name in LIBRARIES}}
"""What :func:`differences` compares, each as the text a segment shows for it: the CPU model, the code (commit and
dirty flag), the precision (``--matmul`` and the matmul path), and the versions of Python and each library."""


def differences(runs: Sequence[Sequence[Mapping[str, Any]] | None]) -> str | None:
    """What sets apart the runs of one cell, given each run's segments (None: a run without ``provenance.json``),
    e.g. ``runs differ in CPU (Intel Xeon ×5, AMD EPYC 9R14 96-Core ×5) and code (7040e47 ×8, 5590cb3 ×2)``:
    each aspect of :data:`ASPECTS` that takes more than one value, with how many runs have a segment with each
    value; then how many runs did not record their provenance, when some did. None when nothing differs, or when no
    run recorded it."""
    recorded = [segments for segments in runs if segments]
    if not recorded:
        return None
    parts = []
    for aspect, show in ASPECTS.items():
        counts = Counter(value for segments in recorded for value in {show(segment) for segment in segments})
        if len(counts) > 1:
            ordered = sorted(counts.items(), key=lambda item: (-item[1], item[0]))
            parts.append(f"{aspect} ({', '.join(f'{value} ×{count}' for value, count in ordered)})")
    notes = ["runs differ in " + (parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " and " + parts[-1])
             ] if parts else []
    if len(recorded) < len(runs):
        notes.append(f"provenance not recorded for {len(runs) - len(recorded)} of {len(runs)} runs")
    return "; ".join(notes) or None
