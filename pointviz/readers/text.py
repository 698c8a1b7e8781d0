"""XYZ-style text: one point per line, values separated by blanks, commas or semicolons.

=========== ==============================================
``.xyz``    ``x y z`` (further values on a line ignored)
``.xyzn``   ``x y z nx ny nz``
``.xyzrgb`` ``x y z r g b``, colours in [0, 1] (or 0-255)
``.pts``    Open3D's reader (a count line, then the points)
=========== ==============================================

Blank lines and comment lines (``#`` or ``//``) are skipped; any other line that does not start
with the values its format needs is an error naming the row.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..cloud import PointCloud
from ..errors import FileFormatError
from . import table
from .common import float_color_scale, point_cloud, read_o3d_points

#: Values a line must start with, per extension.
TEXT_COLUMNS = {".xyz": 3, ".xyzn": 6, ".xyzrgb": 6}


def read_text(path: Path, sample, rng) -> PointCloud:
    ext = path.suffix.lower()
    if ext not in TEXT_COLUMNS:
        return read_o3d_points(path, sample, rng)
    ncols = TEXT_COLUMNS[ext]
    spec = table.spec(path, offset=0, encoding="ascii", columns=["f64"] * ncols, rows=-1,
                      wanted=list(range(ncols)), exact_columns=False, commas=True)
    try:
        values = table.read([spec])[0].values
    except table.MalformedData as exc:
        raise FileFormatError(
            f"{path}: malformed {ext} text: data {exc} (each line needs {ncols} numbers)"
        ) from None
    except (table.TruncatedData, RuntimeError) as exc:
        raise FileFormatError(f"{path}: could not read the text file ({exc})") from None
    if len(values) == 0:
        raise FileFormatError(f"{path}: no points could be read (no data lines)")
    normals = values[:, 3:6] if ext == ".xyzn" else None
    colors = None
    if ext == ".xyzrgb":
        rgb = values[:, 3:6]
        colors = np.clip(rgb / float_color_scale(rgb), 0.0, 1.0)
    return point_cloud(path, values[:, :3], normals, colors, sample=sample, rng=rng)
