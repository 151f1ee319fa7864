"""User-facing errors.

Every mistake a user can make (unknown task, bad switch value, corrupt checkpoint, observation of the
wrong shape, ...) raises :class:`UserError` with one sentence that says what is wrong and how to fix it.
The command line prints that sentence and exits with code 2, without a traceback.
"""

from __future__ import annotations


class UserError(ValueError):
    """A mistake in the user's input: printed as one line, exit code 2."""


class TrainingDiverged(RuntimeError):
    """Training produced a non-finite value (observation, reward or loss).

    The run stops at once and keeps its last good checkpoint.
    """
