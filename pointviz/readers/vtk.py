"""VTK files (.vtp, .vtk) through pyvista."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..cloud import PointCloud
from ..errors import FileFormatError, require
from ..validate import check_coordinates
from .common import finite_rows

def read_vtk(path: Path, sample, rng) -> PointCloud:
    pv = require("pyvista", "io")
    try:
        data = pv.read(str(path))
    except Exception as exc:  # VTK raises generic errors for bad files
        raise FileFormatError(f"{path}: could not read the VTK file ({exc})") from exc
    if data is None or not isinstance(data, pv.DataSet) or data.n_points == 0:
        raise FileFormatError(f"{path}: no points could be read (empty or unparsable file)")
    check_coordinates(np.asarray(data.points), str(path))
    if not np.isfinite(np.asarray(data.points)).all():
        notes: list[str] = []
        keep = finite_rows(path, np.asarray(data.points, dtype=np.float64), notes)
        cloud = PointCloud.from_pyvista(data.extract_points(keep, adjacent_cells=False))
        cloud.notes.extend(notes)
        return cloud
    return PointCloud.from_pyvista(data, sample=None if sample == "auto" else sample, rng=rng)


