"""What every reader shares: building a PointCloud from loaded arrays (dropping non-finite rows
with a note, sub-sampling), meshes to clouds, and keeping Open3D quiet."""

from __future__ import annotations

import contextlib
import warnings
from pathlib import Path

import numpy as np

from ..cloud import PointCloud
from ..errors import FileFormatError, require
from ..validate import check_coordinates, check_points_fit


@contextlib.contextmanager
def quiet_open3d(o3d):
    """Silence Open3D's printed warnings; failures are detected from the results instead."""
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        yield


def finite_rows(path: Path, points: np.ndarray, notes: list[str]) -> np.ndarray | None:
    """Mask of finite rows, or None if all are finite; notes and warns about the others."""
    if np.isfinite(points).all():  # the usual case, without a slow per-row reduction
        return None
    finite = np.isfinite(points).all(axis=1)
    dropped = int((~finite).sum())
    msg = (
        f"dropped {dropped} of {len(points)} points with NaN/inf coordinates "
        "(holes of an organised cloud?)"
    )
    notes.append(msg)
    warnings.warn(f"{path.name}: {msg}", stacklevel=4)
    if not finite.any():
        raise FileFormatError(f"{path}: all {len(points)} points have NaN/inf coordinates")
    return finite


def usable_normals(normals, keep, notes: list[str]):
    """Drop loaded normals that are unusable (non-finite or zero); they are then estimated."""
    if normals is None:
        return None
    normals = normals if keep is None else normals[keep]
    n = np.asarray(normals, dtype=np.float64)
    length2 = n[:, 0] * n[:, 0] + n[:, 1] * n[:, 1] + n[:, 2] * n[:, 2]  # by columns: fast
    bad = ~np.isfinite(length2) | (length2 == 0)
    if bad.any():
        notes.append(
            f"ignored the file's normals: {int(bad.sum())} are zero or not finite; "
            "normals are estimated instead"
        )
        return None
    return normals


def is_number(token: bytes) -> bool:
    """Whether a text token parses as a float (for naming the bad token in an error)."""
    try:
        float(token)
    except ValueError:
        return False
    return True


def float_color_scale(rgb: np.ndarray) -> float:
    """What float colours are divided by: 1 when written in [0, 1], 255 when some writer put
    0-255 values in them (any finite value above 1)."""
    finite = rgb[np.isfinite(rgb)]
    return 255.0 if finite.size and finite.max() > 1.0 else 1.0


def subsample(cloud_kw: dict, n: int, sample, rng, notes: list[str]) -> dict:
    """Keep a uniformly random subset of ``sample`` rows of every per-point array (``"auto"``:
    all of them; it only samples meshes)."""
    if sample == "auto":
        sample = None
    if sample is None or sample >= n:
        if sample is not None:
            notes.append(f"sample={sample} >= {n} points: kept all points")
        return cloud_kw
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    idx = np.sort(gen.choice(n, size=int(sample), replace=False))
    notes.append(f"kept a random subset of {sample} of {n} points")
    return {
        k: (v[idx] if isinstance(v, np.ndarray) and v.ndim >= 1 and len(v) == n else v)
        for k, v in cloud_kw.items()
    }


def point_cloud(path, points, normals=None, colors=None, *, sample=None, rng=None, **extra):
    """Build a :class:`PointCloud` from loaded arrays, dropping non-finite points."""
    notes = list(extra.pop("notes", []))
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
        raise FileFormatError(f"{path}: no points could be read (empty or unparsable file)")
    keep = finite_rows(path, points, notes)
    check_coordinates(points, str(path))
    normals = usable_normals(normals, keep, notes)
    fields = {"points": points, "normals": normals, "colors": colors, **extra}
    if keep is not None:
        fields = {
            k: (
                v[keep]
                if k != "normals"
                and isinstance(v, np.ndarray)
                and v.ndim >= 1
                and len(v) == len(keep)
                else v
            )
            for k, v in fields.items()
        }
    fields = subsample(fields, len(fields["points"]), sample, rng, notes)
    return PointCloud(**fields, notes=notes)


#: The frame height, in pixels, that :func:`dense_sample_count` plans for (the default frame's;
#: an object fitted to the frame spans about that many pixels).
DENSE_FRAME_PIXELS = 480
#: A mesh whose median edge is longer than this many of those pixels is sampled densely: its
#: vertex disks would show as facets (spot.obj's 3k vertices: 10.6 px; the bunny's 36k: 3.4 px,
#: a fine grain; Lucy's 50k: 2.1 px and the Armadillo's 173k: 1.3 px, smooth).
SPARSE_EDGE_PIXELS = 3.0
#: The dense sampling's spacing, in those pixels, and the most points it draws.
DENSE_SPACING_PIXELS = 1.5
DENSE_MAX_POINTS = 1_000_000


def dense_sample_count(vertices: np.ndarray, faces: np.ndarray) -> int | None:
    """How many surface points a mesh needs so that, framed whole in a DENSE_FRAME_PIXELS
    frame, they lie about DENSE_SPACING_PIXELS apart; None when its vertices already lie within
    SPARSE_EDGE_PIXELS of each other (median edge). Never fewer points than vertices, at most
    DENSE_MAX_POINTS."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    radius = float(np.linalg.norm(vertices - (lo + hi) / 2, axis=1).max())
    if not radius > 0:
        return None
    pixel = 2.0 * radius / DENSE_FRAME_PIXELS
    some = faces[:: max(1, len(faces) // 100_000)]
    edges = np.linalg.norm(vertices[some] - vertices[np.roll(some, 1, axis=1)], axis=2)
    if not np.median(edges) > SPARSE_EDGE_PIXELS * pixel:
        return None
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    area = 0.5 * float(np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())
    want = int(np.ceil(area / (DENSE_SPACING_PIXELS * pixel) ** 2))
    return int(min(DENSE_MAX_POINTS, max(want, len(vertices))))


def mesh_cloud(
    path, vertices, faces, normals=None, colors=None, *, sample=None, rng=None, merge=False, up=None,
    polygons=0,
):
    """A mesh's vertices (normals from the faces unless given) or ``sample`` surface points;
    ``"auto"``: the vertices, or as many surface points as :func:`dense_sample_count` asks for
    when they are too far apart for the picture (seeded: the same points every time).
    ``polygons``: how many faces of more than three corners the reader split into fans (noted)."""
    notes: list[str] = []
    if polygons:
        notes.append(f"split {polygons} polygons of more than three corners into triangles")
    auto = sample == "auto"
    if sample is not None and not auto:
        check_points_fit(sample, "sample")
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(vertices) == 0:
        raise FileFormatError(f"{path}: the mesh has no vertices (empty or unparsable file)")
    if not np.isfinite(vertices).all():
        bad = int((~np.isfinite(vertices).all(axis=1)).sum())
        raise FileFormatError(f"{path}: {bad} mesh vertices have NaN/inf coordinates")
    check_coordinates(vertices, str(path))
    if merge:
        # OBJ/STL/glTF readers split a vertex wherever its texture coordinate or normal changes
        # (STL stores none at all): merge exact duplicates so each surface point is one surfel
        uniq, first, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
        if len(uniq) < len(vertices):
            order = np.argsort(first)  # keep the file's vertex order
            rank = np.empty_like(order)
            rank[order] = np.arange(len(order))
            notes.append(f"merged {len(vertices) - len(uniq)} duplicate vertices (seams)")
            faces = rank[inverse.reshape(-1)][faces]
            keep = first[order]
            vertices = vertices[keep]
            normals = None  # re-derived from the faces: split normals no longer apply
            colors = None if colors is None else np.asarray(colors)[keep]
    if auto and len(faces):
        sample = dense_sample_count(vertices, faces)
        if sample is not None:
            rng = 0 if rng is None else rng
            notes.append(f"{len(vertices)} vertices are sparse for the picture: sampled the "
                         "faces densely (--sample N sets the count, --sample vertices keeps the "
                         "vertices)")
    elif auto:
        sample = None
    if len(faces) == 0:
        return point_cloud(
            path,
            vertices,
            normals,
            colors,
            sample=sample,
            rng=rng,
            up=up,
            notes=notes + ["the mesh has no faces: loaded its vertices"],
        )
    if normals is not None and sample is None:
        normals = usable_normals(np.asarray(normals, dtype=np.float64), None, notes)
        if normals is not None:
            return PointCloud(vertices, normals, colors=colors, up=up, notes=notes)
    cloud = PointCloud.from_mesh(
        vertices, faces, sample=sample, rng=rng, colors=colors, up=up, notes=notes
    )
    if sample is not None:
        cloud.notes.append(f"sampled {sample} points on {len(faces)} faces")
    return cloud


def cloud_from_o3d_points(path, pcd, sample, rng, frame=None) -> PointCloud:
    """``frame(points, has_normals)``: more PointCloud keywords from the file (optional)."""
    points = np.asarray(pcd.points)
    extra = {} if frame is None else frame(points, pcd.has_normals())
    return point_cloud(
        path,
        points,
        np.asarray(pcd.normals) if pcd.has_normals() else None,
        np.asarray(pcd.colors) if pcd.has_colors() else None,
        sample=sample,
        rng=rng,
        **extra,
    )


def mesh_from_o3d(path, mesh, sample, rng, merge=False) -> PointCloud:
    return mesh_cloud(
        path,
        np.asarray(mesh.vertices),
        np.asarray(mesh.triangles),
        np.asarray(mesh.vertex_normals) if mesh.has_vertex_normals() else None,
        np.asarray(mesh.vertex_colors) if mesh.has_vertex_colors() else None,
        sample=sample,
        rng=rng,
        merge=merge,
    )



def read_o3d_points(path: Path, sample, rng, frame=None) -> PointCloud:
    """A point file through Open3D's reader (formats the core does not read); ``frame`` as for
    :func:`cloud_from_o3d_points`."""
    o3d = require("open3d", "io")
    with quiet_open3d(o3d):
        pcd = o3d.io.read_point_cloud(
            str(path), remove_nan_points=False, remove_infinite_points=False
        )
    if len(pcd.points) == 0:
        raise FileFormatError(f"{path}: no points could be read (empty or unparsable file)")
    return cloud_from_o3d_points(path, pcd, sample, rng, frame)
