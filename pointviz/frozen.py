"""Frozen dataclasses whose fields include numpy vectors (:class:`~pointviz.camera.Camera`,
:class:`~pointviz.path.Keyframe`): value equality and hashing, a short repr, ``replace()`` that
validates again, and pickling through the constructor.

Use with ``@dataclass(frozen=True, eq=False, repr=False)``; ``__post_init__`` normalises the
fields with :func:`set_fields` and makes the vectors read-only.
"""

from __future__ import annotations

from dataclasses import fields, replace
from typing import Any

import numpy as np


def set_fields(obj: Any, **values: Any) -> None:
    """Set fields of a frozen dataclass from its ``__post_init__``; arrays become read-only."""
    for name, value in values.items():
        if isinstance(value, np.ndarray):
            value.setflags(write=False)
        object.__setattr__(obj, name, value)


def _fmt(value: Any) -> str:
    if isinstance(value, np.ndarray):
        return "(" + ", ".join(f"{x:.6g}" for x in value) + ")"
    if isinstance(value, float):
        return f"{value:.6g}"
    return repr(value)


class ArrayValue:
    """Mixin of the value behaviour; the constructor's fields (``init=True``) are the value."""

    def _values(self) -> tuple:
        return tuple(getattr(self, f.name) for f in fields(self) if f.init)

    def _key(self) -> tuple:
        return tuple(tuple(v.tolist()) if isinstance(v, np.ndarray) else v
                     for v in self._values())

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    def __repr__(self) -> str:
        parts = (f"{f.name}={_fmt(getattr(self, f.name))}" for f in fields(self) if f.repr)
        return f"{type(self).__name__}({', '.join(parts)})"

    def replace(self, **changes: Any):
        """A copy with some fields replaced, validated like a new value (TypeError for names
        that are not fields)."""
        return replace(self, **changes)

    def __reduce__(self):
        return (type(self), tuple(v.copy() if isinstance(v, np.ndarray) else v
                                  for v in self._values()))
