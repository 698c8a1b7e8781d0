"""Guards that turn impossible requests into clear errors before any memory is allocated.

A file header or an argument may ask for billions of points. Allocating first and failing later
means an out-of-memory kill (no message at all) or minutes of swapping; these checks compare the
request with the memory the machine has and raise :class:`~pointviz.errors.InputError` instead.
"""

from __future__ import annotations

import math
import os

from .errors import InputError

#: Bytes one point costs from loading to a built surfel tree: float64 position (24), float32
#: normal (12), radius (4) and colour (12), the tree's surfel (32) and node share (~11), and the
#: neighbour queries of normal/radius estimation (~16 neighbours x 8 bytes of index, done in
#: blocks but with a full-size distance array, ~32). Rounded up to leave room for copies.
BYTES_PER_POINT = 192


#: Largest coordinate magnitude accepted from a file. float64 resolves 0.1 units up to about 1e15,
#: so larger values are not measurements (a georeferenced coordinate in millimetres is ~1e10);
#: and squared distances of values beyond ~1e154 overflow in neighbour searches.
MAX_ABS_COORDINATE = 1e15


def check_coordinates(points, what: str) -> None:
    """Raise :class:`InputError` if finite coordinates exceed :data:`MAX_ABS_COORDINATE`.

    Parameters
    ----------
    points : (n, 3) float64
        Positions; non-finite rows are ignored (callers drop or reject them separately).
    what : str
        Names the source in the message.
    """
    import numpy as np

    a = np.asarray(points, dtype=np.float64)
    if a.size == 0:
        return
    # the usual case in two passes without a copy: the extremes are finite and in range
    lo, hi = float(a.min()), float(a.max())
    if math.isfinite(lo) and math.isfinite(hi) and max(-lo, hi) <= MAX_ABS_COORDINATE:
        return
    a = np.abs(a)
    if not np.isfinite(a).all():  # only then the slower per-row selection
        a = a[np.isfinite(a).all(axis=1)] if a.ndim == 2 else a[np.isfinite(a)]
    if a.size and a.max() > MAX_ABS_COORDINATE:
        rows = np.flatnonzero((a > MAX_ABS_COORDINATE).any(axis=-1)) if a.ndim == 2 else []
        raise InputError(
            f"{what}: {len(rows)} points have coordinates beyond +-{MAX_ABS_COORDINATE:g} "
            f"(largest {a.max():.3g}): not a plausible measurement (corrupt file or wrong scale?)"
        )


def available_memory_bytes() -> int | None:
    """Memory the process may still use: ``MemAvailable`` from /proc/meminfo, else total RAM.

    Returns None when neither can be read (then no limit is enforced).
    """
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return None


def check_points_fit(n_points: int, what: str, bytes_per_point: int = BYTES_PER_POINT) -> None:
    """Raise :class:`InputError` if ``n_points`` points cannot fit in the available memory.

    Parameters
    ----------
    n_points : int
        Points about to be allocated (a header's count, a ``sample=`` argument).
    what : str
        Names the source in the message: a file name or an argument.
    bytes_per_point : int
        Memory one point costs; default :data:`BYTES_PER_POINT`.
    """
    n = int(n_points)
    if n < 0:
        raise InputError(f"{what}: negative point count {n}")
    need = n * int(bytes_per_point)
    have = available_memory_bytes()
    if have is not None and need > have:
        raise InputError(
            f"{what}: {n:,} points need about {need / 1e9:.1f} GB, more than the "
            f"{have / 1e9:.1f} GB of memory available; load a subset (sample=) or a smaller file"
        )
