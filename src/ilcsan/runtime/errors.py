"""The runtime's error type: :class:`ilcsan.errors.UserError` inside the package, an equivalent local class
when this folder is copied on its own (then the relative import has no package above it)."""

try:
    from ..errors import UserError
except ImportError:  # copied standalone: no ilcsan package around this folder

    class UserError(ValueError):  # type: ignore[no-redef]
        """A mistake in the user's input (the package's ilcsan.errors.UserError when installed)."""


__all__ = ["UserError"]
