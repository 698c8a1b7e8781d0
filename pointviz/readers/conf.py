"""Stanford ``.conf`` registrations: several range scans placed in one frame, read in parallel."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..cloud import PointCloud
from ..errors import FileFormatError, PointvizError
from . import ply, table
from .common import point_cloud

# Stanford (Cyberware) range scans are stored in the scanner's frame with the sensor looking down
# its -z axis from +z: measured on bun000 against the bunny reconstruction, 97% of the outward
# normals have n_z > 0, and orienting toward the local origin (which lies inside the object)
# makes 78-97% of the normals of every bunny scan point inward. The viewpoint of a scan is put on
# the +z axis above the scan's centroid, this many scan diagonals away; 1 m and 10 m away give
# the same orientation on 99.9% of the points, so the exact standoff does not matter.
RANGE_SCAN_VIEW_DISTANCE = 10.0


def quaternion_matrix(q) -> np.ndarray:
    """Rotation matrix of a unit quaternion ``(x, y, z, w)`` (Hamilton convention).

    Returns
    -------
    (3, 3) float64
        ``R`` with ``R @ v`` rotating column vectors.
    """
    x, y, z, w = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def parse_conf(path) -> list[tuple[Path, np.ndarray, np.ndarray, int]]:
    """Read the ``bmesh`` lines of a Stanford ``.conf`` file.

    Returns
    -------
    list of (scan_path, t, q, line_number)
        ``t`` (3,) float64 translation, ``q`` (4,) float64 quaternion ``(x, y, z, w)``; scan
        paths are resolved relative to the ``.conf``'s folder. Other lines are ignored.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="latin-1")
    except OSError as exc:
        raise FileFormatError(f"{path}: cannot be read ({exc})") from exc
    scans = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        f = line.split()
        if not f or f[0] != "bmesh":
            continue
        bad = (
            f"{path}: line {lineno}: malformed bmesh line, "
            "expected 'bmesh FILE tx ty tz qx qy qz qw'"
        )
        if len(f) != 9:
            raise FileFormatError(f"{bad}, got {len(f) - 1} fields: {line.strip()!r}")
        try:
            values = np.array([float(v) for v in f[2:]])
        except ValueError:
            raise FileFormatError(f"{bad}, got non-numbers: {line.strip()!r}") from None
        if not np.isfinite(values).all() or np.linalg.norm(values[3:]) == 0:
            raise FileFormatError(f"{bad}, got non-finite values or a zero quaternion")
        scans.append((path.parent / f[1], values[:3], values[3:], lineno))
    if not scans:
        raise FileFormatError(f"{path}: no 'bmesh' lines: not a Stanford .conf registration")
    return scans


def read_conf(path: Path, sample, rng, read_scan) -> PointCloud:
    """Registered Stanford range scans: every scan is moved into the common frame.

    The conf file stores, per scan, a translation ``t`` and a quaternion ``q = (x, y, z, w)``.
    The scan is placed with ``p' = R(q)^T p + t`` where ``R(q)`` is the Hamilton rotation matrix
    for column vectors (scanalyze multiplies row vectors, ``p' = p R + t``). Measured: with this
    convention the median distance from each scan's points to the other scans is 0.23-0.34 mm on
    the bunny (its sample spacing is ~0.5 mm), while ``R(q) p + t`` leaves 4-12 mm.
    """
    entries = parse_conf(path)
    for scan_path, _, _, lineno in entries:
        if not scan_path.exists():
            raise FileFormatError(f"{path}: line {lineno}: scan {scan_path} does not exist")
        if scan_path.suffix.lower() == ".conf":
            raise FileFormatError(
                f"{path}: line {lineno}: scan {scan_path.name} is a .conf file; a registration "
                "lists point files"
            )
    scans, joined = _read_scans(path, entries, read_scan)
    parts, grids = [], []
    for (scan_path, t, q, lineno), scan in zip(entries, scans):
        if scan.finite == 0:
            raise FileFormatError(f"{path}: line {lineno}: {scan_path}: no finite points")
        rot = quaternion_matrix(q)
        # the scan's points are already placed (p R + t, rows: (R^T p)^T); its viewpoint is
        # placed from the scan's own frame. NaN rows are dropped below, with a note.
        eye_local = scan.mean + [0.0, 0.0, RANGE_SCAN_VIEW_DISTANCE * np.linalg.norm(scan.hi - scan.lo)]
        eye = eye_local @ rot + t
        parts.append((scan_path.name, scan.points, scan.colors, eye))
        grids.append(scan.grid)
    # the core read the scans into one array: their points are its rows (else joined here)
    points = joined if joined is not None else np.concatenate([w for _, w, _, _ in parts])
    sizes = [len(w) for _, w, _, _ in parts]
    colors = None
    if all(c is not None for _, _, c, _ in parts):
        colors = np.concatenate([c for _, _, c, _ in parts])
    viewpoints = _rows_per_scan([e for _, _, _, e in parts], sizes)
    scan_index = np.repeat(np.arange(len(parts), dtype=np.int32), sizes)
    # the scanner's grid of each scan (its range_grid): neighbours within a scan come from it
    scan_grid = np.concatenate(grids) if all(g is not None for g in grids) else None
    notes = [
        (
            f"registered {len(parts)} scans ({', '.join(name for name, _, _, _ in parts)}); "
            "normals are oriented toward each scan's scanner (+z of its frame)"
        )
    ]
    return point_cloud(path, points, None, colors, sample=sample, rng=rng, viewpoints=viewpoints,
                       scan_index=scan_index, scan_grid=scan_grid, notes=notes)


def _rows_per_scan(values, sizes) -> np.ndarray:
    """(sum(sizes), 3) float64: ``values[k]`` on each of scan k's ``sizes[k]`` rows (written by
    blocks: ``np.repeat`` along rows copies 24 bytes at a time)."""
    out = np.empty((sum(sizes), 3))
    at = 0
    for value, size in zip(values, sizes):
        out[at:at + size] = value
        at += size
    return out


@dataclass
class _Scan:
    """One scan placed in the registration's frame, with its bounds and mean in its own."""

    points: np.ndarray  # (n, 3) float64, placed; non-finite rows kept
    colors: np.ndarray | None
    lo: np.ndarray
    hi: np.ndarray
    mean: np.ndarray
    finite: int
    grid: np.ndarray | None = None  # (n, 2) int32 cell of each point in the scan's grid


def _read_scans(path: Path, entries, read_scan) -> tuple[list[_Scan], np.ndarray | None]:
    """Every scan of a registration, placed, and the registration's (n, 3) points when the
    core read them into one array (else None). PLY point scans (the usual case) are read and
    placed by one core call, in parallel; anything else by ``read_scan(path)`` (the registry's
    reader of its format), then placed here."""

    def named(lineno, exc):
        return FileFormatError(f"{path}: line {lineno}: {exc}")

    plans = {}
    for i, (scan_path, t, q, lineno) in enumerate(entries):
        if scan_path.suffix.lower() != ".ply":
            continue
        try:
            plan = ply.points_plan(scan_path, affine=(quaternion_matrix(q), t))
        except PointvizError as exc:
            raise named(lineno, exc if str(scan_path) in str(exc) else f"{scan_path}: {exc}") from exc
        if plan is not None:
            plans[i] = plan
    specs = [plan.spec for plan in plans.values()]
    # every scan a planned PLY file: all read into one array, the registration's points
    join = len(plans) == len(entries) and table.joinable(specs)
    joined = None
    try:
        if join:
            values, tables = table.read_joined(specs)
            tables = dict(zip(plans, tables))
            joined = values if values.shape[1] == 3 else None
        else:
            tables = dict(zip(plans, table.read(specs)))
    except (table.TruncatedData, table.MalformedData, RuntimeError):
        for i, plan in plans.items():  # which scan: read them one by one
            try:
                table.read([plan.spec])
            except (table.TruncatedData, table.MalformedData, RuntimeError) as exc:
                err = ply.core_error(plan.path, plan.header["format"], exc)
                raise named(entries[i][3], err) from None
        raise
    scans = []
    for i, (scan_path, t, q, lineno) in enumerate(entries):
        try:
            if i in plans:
                data = tables[i]
                arrays = ply.points_from_table(plans[i], data)
                scans.append(_Scan(arrays["points"], arrays["colors"], data.lo, data.hi,
                                   data.mean, data.finite, arrays["grid"]))
            else:
                cloud = read_scan(scan_path)  # finite rows only
                local = cloud.points
                scans.append(_Scan(local @ quaternion_matrix(q) + t, cloud.colors,
                                   local.min(axis=0), local.max(axis=0), local.mean(axis=0),
                                   len(local)))
        except PointvizError as exc:
            raise named(lineno, exc if str(scan_path) in str(exc) else f"{scan_path}: {exc}") from exc
    return scans, joined
