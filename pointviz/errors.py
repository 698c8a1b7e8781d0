"""Exceptions raised by pointviz.

Every error a user can cause (a bad file, a bad argument) is a :class:`PointvizError`; its message
names the file or argument and what is wrong, so the CLI can print it as one readable line.
"""

from __future__ import annotations


class PointvizError(Exception):
    """Base class of every error pointviz raises on purpose."""


class InputError(PointvizError, ValueError):
    """An argument or array has the wrong shape, type or value (NaN, negative radius, ...)."""


class FileFormatError(PointvizError, ValueError):
    """A file cannot be read: missing, unsupported extension, truncated or malformed."""


class MissingDependencyError(PointvizError, ImportError):
    """An optional dependency is not installed; the message names the extra to install."""


class CancelledError(PointvizError):
    """A long operation (render, path, comparison) was cancelled by the caller."""


def require(module: str, extra: str):
    """Import an optional dependency or raise :class:`MissingDependencyError` naming the extra."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise MissingDependencyError(
            f"{module} is needed for this; install it with: pip install 'pointviz[{extra}]'"
        ) from exc
