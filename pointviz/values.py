"""Checks of the small values a scene and a camera are described with: colours, directions,
bounded numbers and image sizes (InputError naming the field and what is wrong)."""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np

from .errors import InputError

#: Largest accepted image width or height, in pixels.
MAX_IMAGE_SIZE = 16384


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


#: The world axes by name, and each with its sign: what ``--up`` and the viewer's Up control accept.
AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
_SIGNED_AXES = {f"{sign}{name}": tuple(0.0 if v == 0 else (v if sign == "+" else -v) for v in axis)
                for sign in "+-" for name, axis in AXES.items()}


def axis(text: str) -> tuple[float, float, float] | None:
    """The unit vector an axis name stands for: ``x``, ``+y``, ``-Z`` (one optional sign, any
    case, surrounding blanks ignored); None when ``text`` is not one."""
    word = text.strip().lower()
    return _SIGNED_AXES.get(word if word[:1] in ("+", "-") else "+" + word)


def in_range(value, name: str, lo: float, hi: float) -> float:
    v = float(value)
    if not (np.isfinite(v) and lo <= v <= hi):
        raise InputError(f"{name}: expected a number in [{lo}, {hi}], got {value!r}")
    return v


def check_vec3(value: Any, name: str) -> np.ndarray:
    """Return ``value`` as a finite float64 array of shape (3,) or raise InputError naming it."""
    try:
        arr = np.asarray(value)
    except Exception as exc:  # ragged lists and the like
        raise InputError(f"{name} must be 3 numbers, got {value!r}") from exc
    if arr.dtype.kind not in "iuf" or arr.shape != (3,):
        raise InputError(f"{name} must be 3 numbers, got {value!r}")
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name} contains NaN or inf: {value!r}")
    return arr


def check_real(value: Any, name: str) -> float:
    """Return ``value`` as a finite float or raise InputError naming it."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise InputError(f"{name} must be a number, got {value!r}")
    out = float(value)
    if not math.isfinite(out):
        raise InputError(f"{name} must be finite, got {value!r}")
    return out


def check_image_size(value: Any, name: str) -> int:
    """Return a validated image size (positive int <= MAX_IMAGE_SIZE)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise InputError(f"{name} must be an integer, got {value!r}")
    out = int(value)
    if not 0 < out <= MAX_IMAGE_SIZE:
        raise InputError(f"{name} must be in 1..{MAX_IMAGE_SIZE}, got {out}")
    return out


def check_fov(value: Any, name: str = "fov_deg") -> float:
    """Return a validated vertical field of view in degrees, in (0, 180) exclusive."""
    out = check_real(value, name)
    if not 0.0 < out < 180.0:
        raise InputError(f"{name} must be in (0, 180) degrees exclusive, got {out}")
    return out
