"""Atomic writes and safe reads: nothing half-written, nothing executed.

Every result and checkpoint is written to a temporary file in the same folder, flushed to disk, then
renamed over the target (``os.replace`` is atomic on POSIX), so a crash leaves the previous version
intact. Checkpoints load with ``torch.load(weights_only=True)`` and bundles with
``numpy.load(allow_pickle=False)``: a shared file is data, never code.

Fault-injection hook (tests only): with ``ILCSAN_FAULT_DELAY_WRITE=SECONDS`` in the environment, every
atomic write pauses for that long halfway through its data, so a test can kill the process while a
half-written temporary file exists (``tests/faults``, ``benchmarks/faults.py``).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from .errors import UserError

_UMASK = os.umask(0)
os.umask(_UMASK)


@contextlib.contextmanager
def replacing(path: Path):
    """Yield a temporary file beside ``path`` (a new file's permissions); when the block succeeds, flush it to
    disk and rename it over ``path``; when it fails, remove it. The one atomic write of the package."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(handle, 0o666 & ~_UMASK)
        os.close(handle)
        yield temporary
        descriptor = os.open(temporary, os.O_RDONLY)
        try:
            os.fsync(descriptor)
        finally:
            os.close(descriptor)
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.remove(temporary)
        raise


FAULT_DELAY_VARIABLE = "ILCSAN_FAULT_DELAY_WRITE"


def atomic_write_file(path: Path, write) -> None:
    """Atomically create ``path`` with ``write(temporary_path)``, for libraries that write files themselves."""
    with replacing(path) as temporary:
        write(temporary)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    delay = float(os.environ.get(FAULT_DELAY_VARIABLE) or 0)
    with replacing(path) as temporary, open(temporary, "wb") as stream:
        if delay > 0:  # fault injection: a half-written temporary file exists while we sleep
            stream.write(data[: len(data) // 2])
            stream.flush()
            time.sleep(delay)
            data = data[len(data) // 2:]
        stream.write(data)


def atomic_write_text(path: Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: Path, data: Any) -> None:
    atomic_write_text(path, json_text(data) + "\n")


def json_text(value: Any, indent: int = 0) -> str:
    """``value`` as JSON, keys sorted, objects one key per line (two spaces a level), and a list of numbers or
    strings, or of such lists, on one line: hidden widths ``[256, 256]`` and a matrix product's shapes
    ``[[1, 5, 3760], [1, 256, 3760]]`` read as one value each."""
    if isinstance(value, dict) and value:
        inner = " " * (indent + 2)
        items = [f"{inner}{json.dumps(str(key))}: {json_text(item, indent + 2)}" for key, item in sorted(value.items())]
        return "{\n" + ",\n".join(items) + "\n" + " " * indent + "}"
    if isinstance(value, (list, tuple)) and value and not _flat(value):
        inner = " " * (indent + 2)
        return "[\n" + ",\n".join(inner + json_text(item, indent + 2) for item in value) + "\n" + " " * indent + "]"
    return json.dumps(value)


def _flat(items: list | tuple) -> bool:
    """Whether ``items`` holds only scalars, or only lists of scalars: written on one line."""
    def scalar(item: Any) -> bool:
        return not isinstance(item, (dict, list, tuple))
    return all(scalar(item) or (isinstance(item, (list, tuple)) and all(map(scalar, item))) for item in items)


def atomic_savez(path: Path, **arrays: Any) -> None:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    atomic_write_bytes(path, buffer.getvalue())


def atomic_torch_save(path: Path, obj: Any) -> None:
    import torch

    buffer = io.BytesIO()
    torch.save(obj, buffer)
    atomic_write_bytes(path, buffer.getvalue())


def safe_torch_load(path: Path, what: str = "checkpoint") -> dict:
    """Load a checkpoint as data only; any failure is one clear :class:`UserError`."""
    import pickle

    import torch

    path = Path(path)
    if not path.is_file():
        raise UserError(f"{what} {path} does not exist")
    try:
        with warnings.catch_warnings():  # torch warns about pickle protocols of foreign files: one line only
            warnings.simplefilter("ignore")
            data = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as error:
        raise UserError(
            f"{what} {path} was refused: it is corrupt or contains code, which is never executed "
            f"({_unpickler_reason(error)})") from None
    except Exception as error:  # a damaged file fails in many ways (zip, storage, pickle): all mean corrupt
        raise UserError(f"{what} {path} is corrupt or truncated and cannot be read ({type(error).__name__})") \
            from None
    if not isinstance(data, dict) or "format" not in data:
        raise UserError(f"{path} is not an ilcsan {what}")
    return data


def _unpickler_reason(error: Exception) -> str:
    """The useful part of torch's weights-only refusal (not its advice to load the file unsafely)."""
    text = str(error)
    marker = "WeightsUnpickler error:"
    if marker in text:
        text = text.split(marker, 1)[1]
    lines = [line.strip() for line in text.strip().splitlines() if line.strip()]
    return (lines[0] if lines else "unpickling failed")[:120]


def read_json(path: Path, what: str = "file") -> Any:
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UserError(f"{what} {path} does not exist") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise UserError(f"{what} {path} is corrupt: {error}") from None
