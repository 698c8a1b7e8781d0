"""Checks of the array arguments of a point cloud: each returns the array in the dtype the core
wants, or raises :class:`~pointviz.errors.InputError` naming the argument and the first bad row.

Used by :class:`~pointviz.cloud.PointCloud` and by the estimation functions, which accept the
same arrays without a cloud.
"""

from __future__ import annotations

import numpy as np

from .errors import InputError



def numeric(name: str, value, *, allow_int: bool = True) -> np.ndarray:
    """``np.asarray(value)`` checked to be a real numeric array (not bool/object/complex/str)."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: cannot be converted to an array ({exc})") from None
    kinds = "iuf" if allow_int else "f"
    if arr.dtype.kind not in kinds:
        raise InputError(f"{name}: expected a real numeric array, got dtype {arr.dtype}")
    return arr


def check_finite(name: str, arr: np.ndarray) -> None:
    """Raise :class:`InputError` naming the rows of ``arr`` that contain NaN or inf."""
    if arr.dtype.kind != "f":
        return
    finite = np.isfinite(arr)
    if finite.all():
        return
    bad = ~finite if arr.ndim == 1 else ~finite.all(axis=1)
    rows = np.flatnonzero(bad)
    what = "rows contain" if arr.ndim > 1 else "values are"
    raise InputError(f"{name}: {rows.size} {what} NaN or inf (first at row {rows[0]})")


def rows3(name: str, value, n: int | None) -> np.ndarray:
    """Validate an (n, 3) real array; return it as float64 (not yet copied)."""
    arr = numeric(name, value)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"{name}: expected shape (n, 3), got {arr.shape}")
    if n is not None and arr.shape[0] != n:
        raise InputError(f"{name}: has {arr.shape[0]} rows but points has {n}")
    check_finite(name, arr)
    return arr


def unit_vector(name: str, value) -> np.ndarray:
    arr = numeric(name, value)
    if arr.shape != (3,):
        raise InputError(f"{name}: expected shape (3,), got {arr.shape}")
    check_finite(name, arr)
    norm = float(np.linalg.norm(arr))
    if norm == 0.0:
        raise InputError(f"{name}: must not be the zero vector")
    return np.ascontiguousarray(arr / norm, dtype=np.float64)


#: Rows per block of the checks that compute on a whole array: bounds their temporaries (a
#: 100M-point cloud's normals in float64 at once would be 2.4 GB beside the cloud).
CHECK_BLOCK = 1 << 18


def normals(value, n: int) -> np.ndarray:
    arr = rows3("normals", value, n)
    out = np.empty(arr.shape, np.float32)
    zeros, first = 0, -1
    for b in range(0, len(arr), CHECK_BLOCK):
        blk = arr[b:b + CHECK_BLOCK].astype(np.float64)
        # the same sums as np.linalg.norm(blk, axis=1), without its temporaries
        length = np.sqrt(blk[:, 0] * blk[:, 0] + blk[:, 1] * blk[:, 1] + blk[:, 2] * blk[:, 2])
        zero = np.flatnonzero(length == 0.0)
        if zero.size:
            first = first if zeros else b + int(zero[0])
            zeros += zero.size
        elif not zeros:  # in float64, then rounded
            np.divide(blk, length[:, None], out=out[b:b + CHECK_BLOCK], casting="unsafe")
    if zeros:
        raise InputError(
            f"normals: {zeros} rows have zero length (first at row {first}); "
            "give a direction for every point or leave normals out to estimate them"
        )
    return out


def radii(value, n: int) -> np.ndarray:
    arr = numeric("radii", value)
    if arr.ndim == 0:
        arr = np.full(n, arr, dtype=np.float64)
    if arr.shape != (n,):
        raise InputError(f"radii: expected shape ({n},) or a scalar, got {arr.shape}")
    check_finite("radii", arr)
    bad = np.flatnonzero(~(arr > 0))
    if bad.size:
        raise InputError(
            f"radii: {bad.size} values are zero or negative (first at row {bad[0]}: {arr[bad[0]]})"
        )
    with np.errstate(over="ignore"):
        out = np.ascontiguousarray(arr, dtype=np.float32)
    if not (out > 0).all():  # positive float64 values that underflow float32
        raise InputError("radii: values too small for float32 (underflow to 0)")
    if not np.isfinite(out).all():
        bad = np.flatnonzero(~np.isfinite(out))
        raise InputError(f"radii: {bad.size} values overflow float32 (first at row {bad[0]}: {arr[bad[0]]})")
    return out


def colors(value, n: int) -> np.ndarray:
    arr = numeric("colors", value)
    if arr.ndim != 2 or arr.shape[1] not in (3, 4):
        raise InputError(f"colors: expected shape (n, 3), got {arr.shape}")
    if arr.shape[0] != n:
        raise InputError(f"colors: has {arr.shape[0]} rows but points has {n}")
    arr = arr[:, :3]  # RGBA: alpha is dropped, surfels are opaque
    if arr.dtype.kind in "iu":
        lo, hi = (int(arr.min()), int(arr.max())) if arr.size else (0, 0)
        if arr.dtype == np.uint16:
            scale = 65535.0
        elif lo >= 0 and hi <= 255:
            scale = 255.0
        else:
            raise InputError(
                f"colors: integer colours must be 8-bit (0..255) or uint16, got range {lo}..{hi}"
            )
        return np.ascontiguousarray(arr / scale, dtype=np.float32)
    check_finite("colors", arr)
    outside = np.flatnonzero(((arr < 0) | (arr > 1)).any(axis=1))
    if outside.size:
        raise InputError(
            f"colors: {outside.size} rows are outside [0, 1] (first at row {outside[0]}); "
            "float colours must be in [0, 1], integer ones 0..255"
        )
    return np.ascontiguousarray(arr, dtype=np.float32)


def viewpoints(value, n: int) -> np.ndarray:
    arr = numeric("viewpoints", value)
    if arr.shape == (3,):
        check_finite("viewpoints", arr)
        return np.ascontiguousarray(arr, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] != n:
        raise InputError(f"viewpoints: expected shape (3,) or ({n}, 3), got {arr.shape}")
    check_finite("viewpoints", arr)
    return np.ascontiguousarray(arr, dtype=np.float64)


def per_point(name: str, value, n: int, dtype) -> np.ndarray:
    arr = numeric(name, value)
    if arr.shape != (n,):
        raise InputError(f"{name}: expected shape ({n},), got {arr.shape}")
    check_finite(name, arr)
    return np.ascontiguousarray(arr, dtype=dtype)
