"""Shared helpers of the pointviz benchmarks: data, surfel models, rays, timing, pointviz probe.

Everything here is deterministic (fixed seeds passed in explicitly) and works without pointviz, so
that the Embree baselines can be developed and run on their own. Where pointviz provides the same
service (radius estimation, camera fitting, loading registered scans) the benchmark prefers it and
records which one was used.
"""

from __future__ import annotations

import importlib
import math
import resource
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parent.parent

# Relative locations inside the shared data folder (see ../shared/data/README.md).
ARMADILLO_MESH = Path("stanford_armadillo/Armadillo.ply")
DRAGON_CONF = Path("stanford_dragon/dragon_stand/dragonStandRight.conf")

# Radius rule for surfels without pointviz: r = RADIUS_SCALE * distance to the RADIUS_NEIGHBOUR-th
# nearest neighbour. Six neighbours is the usual ring around a point on a sampled surface; the
# 1.2 factor makes adjacent discs overlap so a watertight-looking surface has no pinholes.
RADIUS_NEIGHBOUR = 6
RADIUS_SCALE = 1.2

# Normals for raw scans without pointviz: PCA of this many nearest neighbours (enough to average
# out the scanner's noise, few enough to keep thin parts such as the dragon's claws).
NORMAL_NEIGHBOURS = 16

# Camera convention shared with pointviz.Camera: vertical field of view, rows from the top-left.
DEFAULT_FOV_DEGREES = 40.0
# Extra room around the projected bounding box when framing the model, so silhouettes are fully
# visible and some rays miss (misses are part of a real image's cost).
FRAME_MARGIN = 1.05
# The fitted eye is at least this many half-depths of the box from its centre (outside the box).
EYE_OUTSIDE_BOX = 1.5
# Random (incoherent) rays start on a sphere of this many bounding radii around the centre.
RANDOM_RAY_SPHERE = 2.0


class DataMissingError(RuntimeError):
    """The shared data folder (or a file in it) is absent; the message says which and where."""


def default_data_dir() -> Path:
    """Return ``<repo>/../shared/data``, the default location of the shared scans."""
    return REPO_ROOT.parent / "shared" / "data"


def require_data(data_dir: Path, relative: Path) -> Path:
    """Return ``data_dir / relative`` or raise :class:`DataMissingError` naming what is missing.

    Parameters
    ----------
    data_dir : Path
        The shared data folder (``--data``).
    relative : Path
        A file inside it.

    Returns
    -------
    Path
        The existing file.
    """
    path = Path(data_dir) / relative
    if not Path(data_dir).is_dir():
        raise DataMissingError(
            f"shared data folder {data_dir} does not exist; pass --data DIR (the folder described "
            f"by shared/data/README.md)")
    if not path.is_file():
        raise DataMissingError(f"{relative} not found in the shared data folder {data_dir}")
    return path


# ----------------------------------------------------------------------------------------------
# pointviz probe


@dataclass
class PointvizProbe:
    """Whether pointviz's compiled core can be used, and why not when it cannot.

    Attributes
    ----------
    module : module or None
        The imported ``pointviz`` package when its core is importable.
    reason : str
        Empty when usable; otherwise a one-line explanation printed by the benchmarks.
    """

    module: object | None
    reason: str = ""

    @property
    def available(self) -> bool:
        """True when pointviz.SurfelScene can be used."""
        return self.module is not None


def probe_pointviz() -> PointvizProbe:
    """Import pointviz and its compiled core; never raises.

    Returns
    -------
    PointvizProbe
        The module, or None with the reason (missing ``pointviz._core``, missing names, ...).
    """
    try:
        pointviz = importlib.import_module("pointviz")
        importlib.import_module("pointviz._core")
        for name in ("PointCloud", "SurfelScene"):
            getattr(pointviz, name)
    except Exception as exc:  # noqa: BLE001 - any failure means "skip the pointviz columns"
        return PointvizProbe(None, f"pointviz not usable ({type(exc).__name__}: {exc})")
    return PointvizProbe(pointviz)


# ----------------------------------------------------------------------------------------------
# models


@dataclass
class SurfelModel:
    """A surfel cloud plus what the benchmark needs to know about it.

    Attributes
    ----------
    name : str
        Label in tables and JSON.
    points, normals : ndarray, shape (n, 3), float32
        Disc centres and unit normals.
    radii : ndarray, shape (n,), float32
        Disc radii.
    mesh_vertices, mesh_faces : ndarray or None
        The source triangle mesh when there is one (for the triangle anchors).
    notes : dict
        Provenance of normals and radii (pointviz or the local fallback).
    cloud : object or None
        The pointviz.PointCloud built from the same arrays, when pointviz is available.
    """

    name: str
    points: np.ndarray
    normals: np.ndarray
    radii: np.ndarray
    mesh_vertices: np.ndarray | None = None
    mesh_faces: np.ndarray | None = None
    notes: dict = field(default_factory=dict)
    cloud: object | None = None

    @property
    def n(self) -> int:
        """Number of surfels."""
        return int(self.points.shape[0])

    @property
    def diagonal(self) -> float:
        """Length of the bounding-box diagonal (the unit of the |Δt| agreement)."""
        return float(np.linalg.norm(self.points.max(axis=0) - self.points.min(axis=0)))


def load_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle mesh without any processing (no merging, no reordering).

    Parameters
    ----------
    path : Path
        A PLY/OBJ/... file trimesh can read.

    Returns
    -------
    vertices : ndarray, shape (nv, 3), float64
    faces : ndarray, shape (nf, 3), int64
    """
    import trimesh

    mesh = trimesh.load(str(path), process=False, force="mesh")
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def sample_mesh_surface(vertices: np.ndarray, faces: np.ndarray, n: int, seed: int
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Sample points uniformly by area on a triangle mesh; normals are the face normals.

    Parameters
    ----------
    vertices : ndarray, shape (nv, 3)
    faces : ndarray, shape (nf, 3)
    n : int
        Number of samples.
    seed : int
        Seed of the generator (the same seed gives the same samples).

    Returns
    -------
    points, normals : ndarray, shape (n, 3), float64
    """
    rng = np.random.default_rng(seed)
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    cross = np.cross(b - a, c - a)
    area2 = np.linalg.norm(cross, axis=1)
    keep = area2 > 0.0
    cross, area2, a, b, c = cross[keep], area2[keep], a[keep], b[keep], c[keep]
    face = rng.choice(len(area2), size=n, p=area2 / area2.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1.0  # fold the unit square onto the triangle: uniform barycentrics
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    points = a[face] + u[:, None] * (b[face] - a[face]) + v[:, None] * (c[face] - a[face])
    normals = cross[face] / area2[face, None]
    return points, normals


def knn_radii(points: np.ndarray, workers: int = -1) -> np.ndarray:
    """Radius rule of the fallback: RADIUS_SCALE times the distance to the RADIUS_NEIGHBOUR-th NN.

    Parameters
    ----------
    points : ndarray, shape (n, 3)
    workers : int
        Threads for the k-d tree query (-1 = all).

    Returns
    -------
    ndarray, shape (n,), float64
    """
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(points).query(points, k=RADIUS_NEIGHBOUR + 1, workers=workers)
    return RADIUS_SCALE * dist[:, RADIUS_NEIGHBOUR]


def pca_normals(points: np.ndarray, toward: np.ndarray, workers: int = -1) -> np.ndarray:
    """Unit normals by PCA of NORMAL_NEIGHBOURS neighbours, oriented toward viewpoints.

    Parameters
    ----------
    points : ndarray, shape (n, 3)
    toward : ndarray, shape (n, 3)
        Per point, a position the normal should face (the scanner that saw it).
    workers : int
        Threads for the k-d tree query.

    Returns
    -------
    ndarray, shape (n, 3), float64
    """
    from scipy.spatial import cKDTree

    _, idx = cKDTree(points).query(points, k=NORMAL_NEIGHBOURS, workers=workers)
    nbr = points[idx]
    centred = nbr - nbr.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", centred, centred)
    _, vecs = np.linalg.eigh(cov)
    normals = vecs[:, :, 0]  # eigenvector of the smallest eigenvalue
    flip = np.einsum("ij,ij->i", normals, toward - points) < 0.0
    normals[flip] *= -1.0
    return normals


def read_ascii_ply_vertices(path: Path) -> np.ndarray:
    """Read x, y, z of the vertex element of an ASCII PLY (the Stanford range scans).

    Parameters
    ----------
    path : Path

    Returns
    -------
    ndarray, shape (n, 3), float64
    """
    with open(path, "rb") as fh:
        count, columns = 0, []
        in_vertex = False
        for raw in fh:
            line = raw.decode("ascii", "replace").strip()
            if line.startswith("format") and "ascii" not in line:
                raise ValueError(f"{path}: only ASCII PLY range scans are supported")
            if line.startswith("element"):
                parts = line.split()
                in_vertex = parts[1] == "vertex"
                if in_vertex:
                    count = int(parts[2])
            elif line.startswith("property") and in_vertex:
                columns.append(line.split()[-1])
            elif line == "end_header":
                break
        cols = [columns.index(c) for c in ("x", "y", "z")]
        data = np.loadtxt(fh, max_rows=count, usecols=cols, dtype=np.float64, ndmin=2)
    if data.shape[0] != count:
        raise ValueError(f"{path}: expected {count} vertices, read {data.shape[0]}")
    return data


def quaternion_matrix(qx: float, qy: float, qz: float, qw: float) -> np.ndarray:
    """Rotation matrix of a unit quaternion given as (x, y, z, w)."""
    q = np.array([qw, qx, qy, qz], dtype=np.float64)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def load_conf_scans(conf: Path) -> tuple[np.ndarray, np.ndarray]:
    """Register the ``bmesh`` scans of a Stanford ``.conf`` file into one frame.

    Each line ``bmesh FILE tx ty tz qx qy qz qw`` maps scan points by p' = R(q)^T p + t: the
    transpose (conjugate quaternion) is the convention that registers the dragon scans (median
    distance between overlapping neighbouring scans 0.3-0.9 mm against 21-30 mm with R(q)).

    Parameters
    ----------
    conf : Path

    Returns
    -------
    points : ndarray, shape (n, 3), float64
        All scans, registered.
    scanners : ndarray, shape (n, 3), float64
        Per point, the scanner position in the common frame (the scan's translation), used to
        orient normals.
    """
    points, scanners = [], []
    for line in Path(conf).read_text().splitlines():
        parts = line.split()
        if not parts or parts[0] != "bmesh":
            continue
        t = np.array([float(v) for v in parts[2:5]])
        rot = quaternion_matrix(*(float(v) for v in parts[5:9]))
        local = read_ascii_ply_vertices(Path(conf).parent / parts[1])
        points.append(local @ rot + t)
        # Cyberware scans look at the object from +z in the scan's frame (about 1 m away).
        eye = rot.T @ np.array([0.0, 0.0, 1.0]) + t
        scanners.append(np.broadcast_to(eye, local.shape))
    if not points:
        raise ValueError(f"{conf}: no bmesh lines")
    return np.concatenate(points), np.concatenate(scanners)


def as_float32(a: np.ndarray) -> np.ndarray:
    """C-contiguous float32 copy (or view) of ``a``."""
    return np.ascontiguousarray(a, dtype=np.float32)


# ----------------------------------------------------------------------------------------------
# rays


@dataclass
class Camera:
    """A pinhole camera with pointviz's convention (vertical fov, rows from the top-left).

    Attributes
    ----------
    eye, target, up : ndarray, shape (3,)
    fov_degrees : float
        Vertical field of view.
    width, height : int
        Image size in pixels.
    """

    eye: np.ndarray
    target: np.ndarray
    up: np.ndarray
    fov_degrees: float
    width: int
    height: int

    def rays(self) -> np.ndarray:
        """Primary rays through pixel centres, row by row from the top-left.

        Returns
        -------
        ndarray, shape (height * width, 6), float32
            Origin and unit direction per ray.
        """
        forward = self.target - self.eye
        forward = forward / np.linalg.norm(forward)
        right = np.cross(forward, self.up)
        right /= np.linalg.norm(right)
        true_up = np.cross(right, forward)
        half_h = math.tan(math.radians(self.fov_degrees) / 2.0)
        half_w = half_h * self.width / self.height
        xs = ((np.arange(self.width) + 0.5) / self.width * 2.0 - 1.0) * half_w
        ys = (1.0 - (np.arange(self.height) + 0.5) / self.height * 2.0) * half_h
        gx, gy = np.meshgrid(xs, ys)  # (height, width): row 0 is the top
        dirs = forward + gx[..., None] * right + gy[..., None] * true_up
        dirs = dirs.reshape(-1, 3)
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        origins = np.broadcast_to(self.eye, dirs.shape)
        return as_float32(np.hstack([origins, dirs]))


def fit_camera(points: np.ndarray, width: int, height: int,
               fov_degrees: float = DEFAULT_FOV_DEGREES,
               view: tuple[float, float, float] = (0.0, 0.0, 1.0),
               up: tuple[float, float, float] = (0.0, 1.0, 0.0)) -> Camera:
    """A camera looking at the bounding-box centre from ``view`` that frames the bounding box.

    Parameters
    ----------
    points : ndarray, shape (n, 3)
    width, height : int
    fov_degrees : float
        Vertical field of view.
    view : tuple of float
        Direction from the centre to the eye.
    up : tuple of float

    Returns
    -------
    Camera
    """
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = (lo + hi) / 2.0
    direction = np.asarray(view, dtype=np.float64)
    direction /= np.linalg.norm(direction)
    up_axis = np.asarray(up, dtype=np.float64)
    right = np.cross(-direction, up_axis)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, -direction)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])]) - centre
    half_x = np.abs(corners @ right).max()
    half_y = np.abs(corners @ true_up).max()
    half_z = np.abs(corners @ direction).max()
    tan_v = math.tan(math.radians(fov_degrees) / 2.0)
    tan_h = tan_v * width / height
    # The box's projected extent fits the image at the centre's depth, with a margin (a model
    # rarely fills its box's corners, so this frames it like a user would); the eye stays outside
    # the box.
    distance = max(FRAME_MARGIN * max(half_y / tan_v, half_x / tan_h), EYE_OUTSIDE_BOX * half_z)
    return Camera(centre + distance * direction, centre, up_axis,
                  fov_degrees, width, height)


def random_rays(points: np.ndarray, n: int, seed: int) -> np.ndarray:
    """Incoherent rays: origins uniform on a sphere around the model, aimed at random surfels.

    Parameters
    ----------
    points : ndarray, shape (m, 3)
        Surfel centres (targets are drawn from them).
    n : int
        Number of rays.
    seed : int

    Returns
    -------
    ndarray, shape (n, 6), float32
        Origin and unit direction per ray.
    """
    rng = np.random.default_rng(seed)
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = (lo + hi) / 2.0
    radius = RANDOM_RAY_SPHERE * float(np.linalg.norm(hi - lo)) / 2.0
    on_sphere = rng.normal(size=(n, 3))
    on_sphere /= np.linalg.norm(on_sphere, axis=1, keepdims=True)
    origins = centre + radius * on_sphere
    targets = points[rng.integers(0, len(points), size=n)]
    dirs = targets - origins
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    return as_float32(np.hstack([origins, dirs]))


# ----------------------------------------------------------------------------------------------
# timing and memory


def time_best(fn, repeat: int) -> tuple[float, object]:
    """Run ``fn`` ``repeat`` times; return the fastest wall time and the last result.

    The minimum is the estimate least affected by other jobs on a shared machine.

    Parameters
    ----------
    fn : callable
        No arguments.
    repeat : int
        At least 1.

    Returns
    -------
    seconds : float
    result : object
    """
    best, result = math.inf, None
    for _ in range(max(1, repeat)):
        start = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - start)
    return best, result


def peak_rss_bytes() -> int:
    """Peak resident set size of this process so far (Linux reports KiB)."""
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024
