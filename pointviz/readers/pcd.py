"""PCD (Point Cloud Library): header forensics (Open3D reads garbage sizes, allocates without
bound or crashes on crafted headers) and the reader."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import _core
from ..cloud import PointCloud
from ..errors import FileFormatError
from ..validate import check_points_fit
from . import table
from .common import point_cloud, read_o3d_points

# Largest PCD header (text lines before DATA) we accept.
_PCD_MAX_HEADER = 1 << 16
# PCD v0.7 header lines: all known ones, and those the format requires (Open3D reads garbage
# sizes, and may allocate without bound, when one is missing).
_PCD_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT",
             "POINTS", "DATA")
_PCD_REQUIRED = ("FIELDS", "SIZE", "TYPE", "WIDTH", "HEIGHT", "POINTS", "DATA")
# Most values one PCD field may hold: descriptors reach a few hundred (VFH: 308); Open3D's reader
# overflows (and crashes) on counts near 2^31.
_PCD_MAX_COUNT = 1 << 16
# LZF's largest expansion: a three-byte back reference copies at most 264 bytes (checked before
# anything allocates for the expanded block).
_LZF_MAX_RATIO = 88
# An organised cloud is in its camera's coordinates (up -y) when this fraction of its points lies
# in a frustum about +z of the VIEWPOINT origin (the four PCL frames here: all of them).
CAMERA_FRAME_FRACTION = 0.95


def _pcd_header(path: Path) -> dict | None:
    """Parse a PCD header; None if the file does not look like PCD (Open3D will then fail)."""
    with open(path, "rb") as fh:
        head = fh.read(_PCD_MAX_HEADER)
    fields: dict[str, list[str]] = {}
    offset = 0
    for raw in head.split(b"\n"):
        offset += len(raw) + 1
        line = raw.decode("latin-1").strip()
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        fields[key.upper()] = values
        if key.upper() == "DATA":
            fields["_offset"] = [str(offset)]
            return fields
    return None


def _check_pcd(path: Path) -> dict:
    """Check a PCD header's counts against the file before anything allocates for them.

    Returns
    -------
    dict
        ``fields`` (names), ``sizes``, ``types``, ``counts`` (one per field), ``points``,
        ``mode`` ("ascii", "binary", "binary_compressed") and ``offset`` of the data.
    """
    h = _pcd_header(path)
    if h is None:
        raise FileFormatError(f"{path}: not a PCD file (no DATA line in the header)")

    unknown = sorted(set(h) - set(_PCD_KEYS) - {"_offset"})
    if unknown:
        raise FileFormatError(f"{path}: PCD header: unknown line(s) {', '.join(unknown)!r}")
    missing = [k for k in _PCD_REQUIRED if k not in h]
    if missing:
        raise FileFormatError(f"{path}: PCD header: missing {' '.join(missing)} line(s)")

    def ints(key, default=None):
        if key not in h:
            if default is None:
                raise FileFormatError(f"{path}: PCD header has no {key} line")
            return default
        try:
            vals = [int(v) for v in h[key]]
        except ValueError:
            raise FileFormatError(f"{path}: PCD header: {key} must be integers, got {h[key]}") from None
        if any(v < 0 for v in vals):
            raise FileFormatError(f"{path}: PCD header: negative {key} {h[key]}")
        return vals

    width, height = ints("WIDTH", [0])[0], ints("HEIGHT", [1])[0]
    points = ints("POINTS", [width * height])[0]
    nfields = len(h.get("FIELDS", []))
    sizes = ints("SIZE", [4] * nfields)
    counts = ints("COUNT", [1] * len(sizes))
    types = h.get("TYPE", ["F"] * len(sizes))
    if not (len(sizes) == len(counts) == len(types) == nfields) or nfields == 0:
        raise FileFormatError(
            f"{path}: PCD header: FIELDS, SIZE, TYPE and COUNT must have the same, non-zero "
            f"length, got {nfields}, {len(sizes)}, {len(types)} and {len(counts)}"
        )
    if any(sz not in (1, 2, 4, 8) for sz in sizes) or any(t.upper() not in "FIU" for t in types):
        raise FileFormatError(f"{path}: PCD header: bad SIZE {sizes} or TYPE {types}")
    if any(not 1 <= c <= _PCD_MAX_COUNT for c in counts):
        raise FileFormatError(f"{path}: PCD header: COUNT values must be in 1..{_PCD_MAX_COUNT}, got {counts}")
    if width * height != points:
        raise FileFormatError(
            f"{path}: PCD header: WIDTH x HEIGHT = {width * height} but POINTS = {points}"
        )
    row = sum(s * c for s, c in zip(sizes, counts))
    mode = (h.get("DATA") or ["?"])[0].lower()
    start = int(h["_offset"][0])
    size = path.stat().st_size
    if mode == "binary":
        need = start + points * row
        if size < need:
            raise FileFormatError(
                f"{path}: truncated PCD: the header declares {points} points ({need} bytes), "
                f"the file has {size}"
            )
    elif mode == "ascii":  # every value takes at least two bytes ("0 ")
        if 2 * points * sum(counts) > size - start + 1:
            raise FileFormatError(
                f"{path}: truncated PCD: the header declares {points} points, the file has only "
                f"{size - start} bytes of data"
            )
    elif mode == "binary_compressed":
        with open(path, "rb") as fh:
            fh.seek(start)
            sizes_raw = fh.read(8)
        if len(sizes_raw) < 8:
            raise FileFormatError(f"{path}: truncated PCD: no compressed data")
        compressed, uncompressed = np.frombuffer(sizes_raw, dtype="<u4")
        if int(uncompressed) != points * row:
            raise FileFormatError(
                f"{path}: corrupt PCD: the compressed block expands to {int(uncompressed)} bytes, "
                f"the header's {points} points need {points * row}"
            )
        if int(uncompressed) > _LZF_MAX_RATIO * int(compressed) + _LZF_MAX_RATIO:
            raise FileFormatError(
                f"{path}: corrupt PCD: {int(compressed)} compressed bytes cannot expand to "
                f"{int(uncompressed)}"
            )
        if start + 8 + int(compressed) > size:
            raise FileFormatError(
                f"{path}: truncated PCD: the compressed block needs {int(compressed)} bytes, "
                f"the file has {size - start - 8}"
            )
    else:
        raise FileFormatError(f"{path}: PCD header: unknown DATA mode {mode!r}")
    check_points_fit(points, str(path))
    viewpoint = h.get("VIEWPOINT", ["0"] * 7)
    try:
        origin = [float(v) for v in viewpoint[:3]]
    except ValueError:
        origin = [np.nan]
    if len(viewpoint) != 7 or not np.isfinite(origin).all():
        raise FileFormatError(
            f"{path}: PCD header: VIEWPOINT must be 7 finite numbers, got {' '.join(viewpoint)}")
    return {"fields": list(h["FIELDS"]), "sizes": sizes, "types": [t.upper() for t in types],
            "counts": counts, "points": points, "mode": mode, "offset": start,
            "width": width, "height": height, "origin": np.asarray(origin)}


def depth_frame(path: Path, h: dict, points: np.ndarray, has_normals: bool) -> dict:
    """What an organised cloud (HEIGHT > 1) tells beyond its points: it is one depth-camera
    frame, so without normals the fit and the normals treat it as a raw scan, and either way the
    default view is the camera's (:meth:`pointviz.camera.Camera.fit`).

    PCL's grabbers write such frames in the camera's coordinates (x right, y down, z forward)
    with the camera at the VIEWPOINT's origin; its rotation is not applied (the OpenNI grabber
    writes a half turn about x over points still in the camera's frame). Returns the
    PointCloud keywords: ``viewpoints`` (that origin), ``scan_index`` (one scan), ``scan_grid``
    (each point's row and column: the frame's pixel grid gives its neighbours) and ``up`` (-y,
    when CAMERA_FRAME_FRACTION of the points lie in a frustum in front of the camera, i.e. the
    frame is the camera's), and a note.
    Empty for unorganised clouds.
    """
    width, height = h["width"], h["height"]
    if height <= 1 or width <= 1 or width * height != len(points):
        return {}
    index = np.arange(len(points), dtype=np.int32)
    grid = np.column_stack([index // width, index % width]).astype(np.int32)
    origin = h["origin"]
    rel = points - origin
    rel = rel[np.isfinite(rel).all(axis=1)]
    z = rel[:, 2]
    # a camera's frame: nearly every point inside a frustum about +z narrower than 127 degrees
    # (depth cameras: 57-90); a spinning LiDAR's organised frame (z up, all around) is not
    in_view = (z > 0) & (np.abs(rel[:, 0]) < 2 * z) & (np.abs(rel[:, 1]) < 2 * z)
    in_front = float(np.mean(in_view)) if len(rel) else 0.0
    extra = {"viewpoints": origin, "scan_index": np.zeros(len(points), np.int32),
             "scan_grid": grid}
    note = (f"organised cloud ({width} x {height}): read as one depth-camera frame, the camera at "
            f"({origin[0]:g}, {origin[1]:g}, {origin[2]:g})")
    if in_front >= CAMERA_FRAME_FRACTION:
        extra["up"] = np.array([0.0, -1.0, 0.0])
        note += " looking along +z, up -y (PCL's camera frame)"
    if not has_normals:
        note += "; normals face the camera and its pixel grid gives neighbours"
    extra["notes"] = [note]
    return extra


def _packed_colour(name: str, size: int, count: int) -> bool:
    """Whether a PCD field is a packed colour: one 4-byte value (declared F or U) whose bits are
    0xAARRGGBB, read as an unsigned integer."""
    return name in ("rgb", "rgba") and size == 4 and count == 1


def _decompressed_values(path: Path, h: dict, want: list[str]) -> np.ndarray:
    """The ``want`` columns (field names, ``name#k`` for the k-th value of a field) of a
    binary_compressed PCD file as float64, like the table reader's: its LZF block is expanded in
    the core, then each field is one contiguous block of every point's values (PCL's layout)."""
    n = h["points"]
    with open(path, "rb") as fh:
        fh.seek(h["offset"])
        compressed, expanded = (int(v) for v in np.frombuffer(fh.read(8), dtype="<u4"))
        data = fh.read(compressed)
    if len(data) < compressed:  # (checked against the file's size already)
        raise FileFormatError(f"{path}: truncated PCD: the compressed block ends early")
    try:
        raw = _core.lzf_decompress(data, expanded)
    except table.MalformedData as exc:
        raise FileFormatError(f"{path}: corrupt PCD compressed block ({exc})") from None
    out = np.empty((n, len(want)), dtype=np.float64)
    start = 0
    for name, size, typ, count in zip(h["fields"], h["sizes"], h["types"], h["counts"]):
        block = n * size * count
        dtype = np.dtype(f"<{'f' if typ == 'F' else typ.lower()}{size}")
        if _packed_colour(name, size, count):
            dtype = np.dtype("<u4")
        for k in range(count):
            column = name if k == 0 else f"{name}#{k}"
            if column in want:
                field = np.frombuffer(raw, dtype=dtype, count=n * count, offset=start)
                out[:, want.index(column)] = field[k::count]
        start += block
    return out


def read_pcd(path: Path, sample, rng) -> PointCloud:
    """A PCD file: ASCII, binary and binary_compressed data in the core (Open3D's reader only for
    compressed files with padding fields, ``_``)."""
    h = _check_pcd(path)
    if h["mode"] == "binary_compressed" and "_" in h["fields"]:
        return read_o3d_points(path, sample, rng,
                               frame=lambda pts, normals: depth_frame(path, h, pts, normals))
    columns, names = [], []
    for name, size, typ, count in zip(h["fields"], h["sizes"], h["types"], h["counts"]):
        scalar = table.PCD_SCALARS.get((typ, size))
        if scalar is None:  # 8-byte integers: not a coordinate type; read as raw bytes
            scalar = "u8"
            count *= size
        if _packed_colour(name, size, count):
            scalar = "u32"
        columns += [scalar] * count
        names += [name] + [f"{name}#{k}" for k in range(1, count)]
    want = [n for n in ("x", "y", "z") if n in names]
    if len(want) < 3:
        raise FileFormatError(f"{path}: the PCD file has no x, y and z fields")
    if all(n in names for n in ("normal_x", "normal_y", "normal_z")):
        want += ["normal_x", "normal_y", "normal_z"]
    packed = next((n for n in ("rgb", "rgba") if n in names and f"{n}#1" not in names), None)
    if packed is not None:
        want.append(packed)
    mode = "ascii" if h["mode"] == "ascii" else "binary_little_endian"
    if h["mode"] == "binary_compressed":
        values = _decompressed_values(path, h, want)
    else:
        spec = table.spec(path, offset=h["offset"], encoding=mode, columns=columns,
                          rows=h["points"], wanted=[names.index(n) for n in want])
        try:
            values = table.read([spec])[0].values
        except table.TruncatedData as exc:
            raise FileFormatError(f"{path}: truncated PCD: {exc}") from None
        except table.MalformedData as exc:
            raise FileFormatError(f"{path}: malformed ASCII PCD: {exc}") from None
        except RuntimeError as exc:
            raise FileFormatError(f"{path}: could not read the PCD file ({exc})") from None
    normals = values[:, 3:6] if "normal_x" in want else None
    colors = None
    if packed is not None:
        raw = values[:, -1]
        if mode == "ascii" and h["types"][h["fields"].index(packed)] == "F":
            bits = raw.astype(np.float32).view(np.uint32)  # written as the float of the bits
        else:
            bits = np.nan_to_num(raw).astype(np.uint32)
        rgb = np.column_stack([(bits >> 16) & 255, (bits >> 8) & 255, bits & 255])
        colors = rgb.astype(np.float32) / 255.0
    return point_cloud(path, values[:, :3], normals, colors, sample=sample, rng=rng,
                       **depth_frame(path, h, values[:, :3], normals is not None))
