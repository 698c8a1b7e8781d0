"""LAS/LAZ airborne LiDAR through laspy (LAZ through the lazrs backend)."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from ..errors import FileFormatError, require
from ..validate import check_points_fit
from .common import point_cloud

# LAS public header: the 1.0-1.2 size (fields up to the point count); each VLR header is 54 bytes.
_LAS_HEADER_MIN = 227
_LAS_VLR_HEADER = 54


def _check_las_size(path: Path, laspy) -> None:
    """An uncompressed LAS file must hold the points its header declares (before allocating)."""
    with open(path, "rb") as fh:
        raw = fh.read(_LAS_HEADER_MIN)
    if len(raw) < _LAS_HEADER_MIN or raw[:4] != b"LASF":
        raise FileFormatError(f"{path}: not a LAS/LAZ file (no 'LASF' signature)")
    header_size, offset, n_vlrs = struct.unpack_from("<HII", raw, 94)
    if n_vlrs * _LAS_VLR_HEADER > max(0, offset - header_size):
        raise FileFormatError(
            f"{path}: corrupt LAS header: {n_vlrs} variable-length records do not fit in the "
            f"{max(0, offset - header_size)} bytes before the points"
        )
    try:
        with laspy.open(str(path)) as reader:
            header = reader.header
            compressed = bool(getattr(header, "are_points_compressed", False))
            count = int(header.point_count)
            record = int(header.point_format.size)
            offset = int(header.offset_to_point_data)
            evlrs = int(getattr(header, "number_of_evlrs", 0) or 0)
    except Exception as exc:  # laspy raises LaspyException, ValueError, OSError, ...
        raise FileFormatError(f"{path}: could not read the LAS/LAZ header ({exc or type(exc).__name__})") from exc
    if compressed:  # LAZ: sizes cannot be checked, memory can
        check_points_fit(count, str(path))
        return
    size = path.stat().st_size
    need = offset + count * record
    if size < need:
        raise FileFormatError(
            f"{path}: truncated LAS or wrong point count: the header declares {count} points of "
            f"{record} bytes ({need} bytes), the file has {size}"
        )
    if evlrs == 0 and size - need >= record:
        raise FileFormatError(
            f"{path}: wrong point count in the LAS header: it declares {count} points, the file "
            f"holds {(size - offset) // record}"
        )
    check_points_fit(count, str(path))


def _laz_backend(laspy):
    """lazrs decompressing chunks on all cores when installed (the ``io`` extra installs it);
    else laspy's own choice."""
    available = laspy.LazBackend.detect_available()
    for backend in (laspy.LazBackend.LazrsParallel, laspy.LazBackend.Lazrs):
        if backend in available:
            return backend
    return None


def read_las(path: Path, sample, rng) -> PointCloud:
    laspy = require("laspy", "io")
    _check_las_size(path, laspy)
    try:
        las = laspy.read(str(path), laz_backend=_laz_backend(laspy))
    except Exception as exc:  # laspy raises LaspyException, ValueError, OSError, ...
        raise FileFormatError(f"{path}: could not read the LAS/LAZ file ({exc})") from exc
    n = len(las.points)
    if n == 0:
        raise FileFormatError(f"{path}: the LAS/LAZ file has no points")
    points = np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)])
    dims = set(las.point_format.dimension_names)
    notes: list[str] = []
    colors = None
    if {"red", "green", "blue"} <= dims:
        rgb = np.column_stack([np.asarray(las.red), np.asarray(las.green), np.asarray(las.blue)])
        # LAS stores 16-bit colour; some writers put 8-bit values in it
        scale = 255.0 if rgb.max() <= 255 else 65535.0
        if scale == 255.0:
            notes.append("colour values are all <= 255: read as 8-bit")
        colors = (rgb / scale).astype(np.float32)
    intensity = np.asarray(las.intensity, dtype=np.float32) if "intensity" in dims else None
    return point_cloud(path, points, None, colors, sample=sample, rng=rng, intensity=intensity,
                       up=(0.0, 0.0, 1.0), seen_from_above=True, notes=notes)


