"""Checks of the small values a scene is described with: colours, directions and bounded
numbers (InputError naming the field and what is wrong)."""

from __future__ import annotations

import numpy as np

from .errors import InputError


def rgb(value, name: str) -> tuple[float, float, float]:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape != (3,) or not np.isfinite(arr).all() or (arr < 0).any():
        raise InputError(f"{name}: expected three finite non-negative numbers, got {value!r}")
    return tuple(float(v) for v in arr)


def unit(value, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape != (3,) or not np.isfinite(arr).all():
        raise InputError(f"{name}: expected three finite numbers, got {value!r}")
    n = np.linalg.norm(arr)
    if not n > 0:
        raise InputError(f"{name}: must not be the zero vector")
    return arr / n


def in_range(value, name: str, lo: float, hi: float) -> float:
    v = float(value)
    if not (np.isfinite(v) and lo <= v <= hi):
        raise InputError(f"{name}: expected a number in [{lo}, {hi}], got {value!r}")
    return v
