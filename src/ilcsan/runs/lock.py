"""One training process per run folder: an exclusive lock on the folder's ``.lock`` file.

Two processes writing one run would interleave their checkpoints and corrupt it, so the trainer holds an
exclusive ``flock`` while it trains; a second process is refused with one line. The kernel drops the lock
when the process dies, even by SIGKILL, so a killed run never needs its lock removed by hand.
"""

from __future__ import annotations

from pathlib import Path
from typing import IO

from ..errors import UserError


class DirectoryLock:
    """An exclusive lock on ``path`` (a file, created if missing), held until :meth:`close`.

    Where the platform has no ``fcntl`` (Windows) nothing is locked."""

    def __init__(self, path: Path, folder: Path):
        self.stream: IO[str] | None = None
        try:
            import fcntl
        except ImportError:
            return
        stream = open(path, "a+")  # noqa: SIM115 - held until close()
        try:
            fcntl.flock(stream.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            stream.close()
            raise UserError(f"another ilcsan process is training in {folder}; wait for it to finish or stop it "
                            "first (two processes writing one run would corrupt it)") from None
        self.stream = stream

    @property
    def held(self) -> bool:
        return self.stream is not None

    def close(self) -> None:
        """Release the lock (closing the file releases ``flock``)."""
        if self.stream is not None:
            self.stream.close()
            self.stream = None
