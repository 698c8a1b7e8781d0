"""Baselines the pointviz core is measured against: Embree discs and triangles, Open3D raycasting.

``EmbreeScene`` wraps ``benchmarks/embree_discs/embree_discs.cpp``, compiled on first use with
``g++ -O3 -march=native -shared -fPIC ... -lembree3`` into ``<repo>/build/benchmarks/`` (already
ignored by git) and loaded with ctypes. ``Open3DTriangles`` wraps ``o3d.t.geometry.RaycastingScene``
(Embree triangles behind Open3D's own API and threading) as the "what a user would reach for"
anchor.

Memory accounting of Embree (documented here because the benchmark divides it by the surfel count):
``scene_bytes`` is what Embree's allocator still holds after the build (BVH and its primitive
blocks, tracked with ``rtcSetDeviceMemoryMonitorFunction``); ``build_peak_bytes`` is the peak during
the build; ``input_bytes`` are the shared input buffers Embree reads at query time but does not
allocate itself: for discs 16 B (x, y, z, r as float4) + 12 B (normal float3) = 28 B per surfel.
"""

from __future__ import annotations

import ctypes
import hashlib
import math
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parent.parent
SOURCE = Path(__file__).resolve().parent / "embree_discs" / "embree_discs.cpp"
BUILD_DIR = REPO_ROOT / "build" / "benchmarks"
EMBREE_HEADER = "embree3/rtcore.h"
COMPILE_FLAGS = ("-O3", "-march=native", "-std=c++17", "-shared", "-fPIC", "-pthread")
LINK_FLAGS = ("-lembree3",)

# Query modes of the library: 1 = rtcIntersect1/rtcOccluded1 per ray, else packet width.
QUERY_MODES = (1, 4, 8, 16)
QUALITIES = {"low": 0, "medium": 1, "high": 2}

# Embree device properties (rtcore_device.h) reported next to the numbers.
DEVICE_PROPERTIES = {
    "version": 0,
    "native_ray4": 32,
    "native_ray8": 33,
    "native_ray16": 34,
    "point_geometry": 101,
    "tasking_system": 128,  # 0 internal, 1 TBB, 2 PPL
}

ERROR_BUFFER = 512


class BaselineUnavailable(RuntimeError):
    """A baseline cannot run here (no compiler, no Embree headers, no Open3D); says why."""


def _find_embree_header() -> Path | None:
    """Return the directory that holds ``embree3/rtcore.h`` in the usual places, or None."""
    for root in (Path("/usr/include"), Path("/usr/local/include"), Path("/opt/homebrew/include")):
        if (root / EMBREE_HEADER).is_file():
            return root
    return None


def library_path(build_dir: Path = BUILD_DIR) -> Path:
    """Path of the compiled library, keyed by a hash of the source and flags (no stale builds)."""
    digest = hashlib.sha256(SOURCE.read_bytes() + " ".join(COMPILE_FLAGS).encode()).hexdigest()[:12]
    return Path(build_dir) / f"embree_discs_{digest}.so"


def build_library(build_dir: Path = BUILD_DIR, force: bool = False) -> Path:
    """Compile ``embree_discs.cpp`` if needed and return the shared library's path.

    Parameters
    ----------
    build_dir : Path
        Output folder (created).
    force : bool
        Recompile even when an up-to-date library exists.

    Returns
    -------
    Path

    Raises
    ------
    BaselineUnavailable
        When g++ or the Embree 3 headers are missing, or compilation fails.
    """
    out = library_path(build_dir)
    if out.is_file() and not force:
        return out
    compiler = shutil.which("g++") or shutil.which("c++")
    if compiler is None:
        raise BaselineUnavailable("no C++ compiler (g++) on PATH")
    include = _find_embree_header()
    if include is None:
        raise BaselineUnavailable(f"{EMBREE_HEADER} not found: install libembree-dev (Embree 3)")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp.so")
    cmd = [compiler, *COMPILE_FLAGS, f"-I{include}", str(SOURCE), "-o", str(tmp), *LINK_FLAGS]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise BaselineUnavailable(f"compiling {SOURCE.name} failed:\n{proc.stderr.strip()}")
    tmp.replace(out)  # atomic: concurrent benchmark runs never load a half-written file
    return out


def _load(build_dir: Path = BUILD_DIR) -> ctypes.CDLL:
    """Build (if needed) and load the library, declaring the C signatures."""
    lib = ctypes.CDLL(str(build_library(build_dir)))
    vp, ll, i, f, d = ctypes.c_void_p, ctypes.c_longlong, ctypes.c_int, ctypes.c_float, ctypes.c_double
    cp = ctypes.c_char_p
    sig = {
        "ed_create": (vp, [i, cp, cp, i]),
        "ed_release": (None, [vp]),
        "ed_device_property": (ll, [vp, i]),
        "ed_build_discs": (i, [vp, vp, vp, ll, i, i, i, cp, i]),
        "ed_build_triangles": (i, [vp, vp, ll, vp, ll, i, i, cp, i]),
        "ed_build_seconds": (d, [vp]),
        "ed_build_peak_bytes": (ll, [vp]),
        "ed_scene_bytes": (ll, [vp]),
        "ed_input_bytes": (ll, [vp]),
        "ed_device_bytes": (ll, [vp]),
        "ed_intersect": (i, [vp, vp, ll, f, f, i, vp, vp, vp]),
        "ed_occluded": (i, [vp, vp, ll, f, vp, i, vp]),
    }
    for name, (restype, argtypes) in sig.items():
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = restype, argtypes
    return lib


def _ptr(a: np.ndarray | None) -> int | None:
    return None if a is None else a.ctypes.data


def _rays32(rays: np.ndarray) -> np.ndarray:
    rays = np.ascontiguousarray(rays, dtype=np.float32)
    if rays.ndim != 2 or rays.shape[1] != 6:
        raise ValueError(f"rays must have shape (n, 6), got {rays.shape}")
    return rays


class EmbreeScene:
    """An Embree 3 device and one scene (oriented discs or triangles), queried over N threads.

    Use :meth:`discs` or :meth:`triangles` to create one; call :meth:`close` (or use ``with``).

    Parameters
    ----------
    threads : int
        Embree build threads ("threads=N") and query threads (std::thread chunks).
    extra_config : str
        Appended to the device config string (e.g. ``"isa=avx2"``).
    build_dir : Path
        Where the library is compiled.
    """

    def __init__(self, threads: int = 1, extra_config: str = "", build_dir: Path = BUILD_DIR):
        self._lib = _load(build_dir)
        err = ctypes.create_string_buffer(ERROR_BUFFER)
        self._h = self._lib.ed_create(int(threads), extra_config.encode(), err, ERROR_BUFFER)
        if not self._h:
            raise BaselineUnavailable(err.value.decode() or "rtcNewDevice failed")
        self.threads = int(threads)
        self.kind = ""
        self.primitives = 0

    # construction -----------------------------------------------------------------------------

    @classmethod
    def discs(cls, points: np.ndarray, normals: np.ndarray, radii: np.ndarray, threads: int = 1,
              quality: str = "medium", one_sided: bool = False, **kwargs) -> EmbreeScene:
        """Build a scene of RTC_GEOMETRY_TYPE_ORIENTED_DISC_POINT.

        Parameters
        ----------
        points, normals : array_like, shape (n, 3)
            Centres and normals (converted to float32).
        radii : array_like, shape (n,)
        threads : int
        quality : {"low", "medium", "high"}
            RTC_BUILD_QUALITY_*.
        one_sided : bool
            Ignore hits from behind a disc (direction . normal > 0) with an Embree filter
            function; Embree's discs are two-sided otherwise. Costs a callback per candidate hit.
        **kwargs
            Passed to the constructor.

        Returns
        -------
        EmbreeScene
        """
        scene = cls(threads, **kwargs)
        try:
            scene.build_discs(points, normals, radii, quality, one_sided=one_sided)
        except Exception:
            scene.close()
            raise
        return scene

    @classmethod
    def triangles(cls, vertices: np.ndarray, faces: np.ndarray, threads: int = 1,
                  quality: str = "medium", **kwargs) -> EmbreeScene:
        """Build a scene of RTC_GEOMETRY_TYPE_TRIANGLE (see :meth:`discs`)."""
        scene = cls(threads, **kwargs)
        try:
            scene.build_triangles(vertices, faces, quality)
        except Exception:
            scene.close()
            raise
        return scene

    def build_discs(self, points, normals, radii, quality: str = "medium", scene_flags: int = 0,
                    one_sided: bool = False):
        """(Re)build the scene from discs; see :meth:`discs`."""
        points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
        n = len(points)
        xyzr = np.empty((n, 4), dtype=np.float32)
        xyzr[:, :3] = points
        xyzr[:, 3] = np.asarray(radii, dtype=np.float32).reshape(n)
        nrm = np.ascontiguousarray(np.asarray(normals, dtype=np.float32).reshape(n, 3))
        err = ctypes.create_string_buffer(ERROR_BUFFER)
        rc = self._lib.ed_build_discs(self._h, _ptr(xyzr), _ptr(nrm), n, QUALITIES[quality],
                                      scene_flags, int(one_sided), err, ERROR_BUFFER)
        if rc != 0:
            raise RuntimeError(f"Embree disc build failed: {err.value.decode()}")
        self.kind, self.primitives = ("discs-one-sided" if one_sided else "discs"), n

    def build_triangles(self, vertices, faces, quality: str = "medium", scene_flags: int = 0):
        """(Re)build the scene from a triangle mesh; see :meth:`triangles`."""
        v = np.ascontiguousarray(np.asarray(vertices, dtype=np.float32).reshape(-1, 3))
        f = np.ascontiguousarray(np.asarray(faces, dtype=np.uint32).reshape(-1, 3))
        err = ctypes.create_string_buffer(ERROR_BUFFER)
        rc = self._lib.ed_build_triangles(self._h, _ptr(v), len(v), _ptr(f), len(f),
                                          QUALITIES[quality], scene_flags, err, ERROR_BUFFER)
        if rc != 0:
            raise RuntimeError(f"Embree triangle build failed: {err.value.decode()}")
        self.kind, self.primitives = "triangles", len(f)

    # measurements -----------------------------------------------------------------------------

    @property
    def build_seconds(self) -> float:
        """Wall time from rtcNewGeometry to the end of rtcCommitScene."""
        return float(self._lib.ed_build_seconds(self._h))

    @property
    def scene_bytes(self) -> int:
        """Bytes Embree holds after the build (BVH), excluding the shared input buffers."""
        return int(self._lib.ed_scene_bytes(self._h))

    @property
    def build_peak_bytes(self) -> int:
        """Peak bytes Embree allocated during the build."""
        return int(self._lib.ed_build_peak_bytes(self._h))

    @property
    def input_bytes(self) -> int:
        """Bytes of the input buffers Embree reads (28 per disc; 12 per vertex + 12 per face)."""
        return int(self._lib.ed_input_bytes(self._h))

    def device_info(self) -> dict:
        """Embree version, native packet widths, tasking system of this device."""
        return {k: int(self._lib.ed_device_property(self._h, v)) for k, v in DEVICE_PROPERTIES.items()}

    # queries ----------------------------------------------------------------------------------

    def intersect(self, rays: np.ndarray, tfar: float = math.inf, tnear: float = 0.0,
                  mode: int = 1) -> dict:
        """Closest hit of each ray.

        Parameters
        ----------
        rays : array_like, shape (n, 6)
            Origin and direction (float32; t is in units of the direction's length).
        tfar, tnear : float
            Ray interval.
        mode : {1, 4, 8, 16}
            1 = rtcIntersect1 per ray; else packets of that many consecutive rays.

        Returns
        -------
        dict
            ``t_hit`` (n,) float32, inf on miss; ``primitive_ids`` (n,) int32, -1 on miss;
            ``normals`` (n, 3) float32 unit geometric normal, 0 on miss.
        """
        rays = _rays32(rays)
        n = len(rays)
        t = np.empty(n, dtype=np.float32)
        prim = np.empty(n, dtype=np.int32)
        ng = np.empty((n, 3), dtype=np.float32)
        rc = self._lib.ed_intersect(self._h, _ptr(rays), n, tnear, tfar, int(mode), _ptr(t),
                                    _ptr(prim), _ptr(ng))
        if rc != 0:
            raise ValueError(f"ed_intersect failed (mode {mode}, scene built: {bool(self.kind)})")
        return {"t_hit": t, "primitive_ids": prim, "normals": ng}

    def occluded(self, rays: np.ndarray, tmax, tnear: float = 0.0, mode: int = 1) -> np.ndarray:
        """Whether anything lies on each ray in (tnear, tmax).

        Parameters
        ----------
        rays : array_like, shape (n, 6)
        tmax : float or array_like, shape (n,)
        tnear : float
        mode : {1, 4, 8, 16}

        Returns
        -------
        ndarray, shape (n,), bool
        """
        rays = _rays32(rays)
        n = len(rays)
        tmax = np.ascontiguousarray(np.broadcast_to(np.asarray(tmax, dtype=np.float32), (n,)))
        out = np.empty(n, dtype=np.uint8)
        rc = self._lib.ed_occluded(self._h, _ptr(rays), n, tnear, _ptr(tmax), int(mode), _ptr(out))
        if rc != 0:
            raise ValueError(f"ed_occluded failed (mode {mode})")
        return out.view(np.bool_)

    # lifetime ---------------------------------------------------------------------------------

    def close(self) -> None:
        """Release the scene and the device (idempotent)."""
        if getattr(self, "_h", None):
            self._lib.ed_release(self._h)
            self._h = None

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        self.close()


def embree_available() -> tuple[bool, str]:
    """Whether the Embree baseline can be built and loaded here; never raises.

    Returns
    -------
    ok : bool
    reason : str
        Empty when ok.
    """
    try:
        with EmbreeScene(1) as scene:
            if not scene.device_info()["point_geometry"]:
                return False, "this Embree build has no point geometry (EMBREE_GEOMETRY_POINT=OFF)"
    except (BaselineUnavailable, OSError) as exc:
        return False, str(exc)
    return True, ""


class Open3DTriangles:
    """Open3D's ``RaycastingScene`` on a triangle mesh (Embree triangles behind Open3D's API).

    Parameters
    ----------
    vertices : array_like, shape (nv, 3)
    faces : array_like, shape (nf, 3)
    threads : int
        Build and query threads (Open3D's ``nthreads``).
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, threads: int = 1):
        try:
            import open3d as o3d
        except ImportError as exc:  # pragma: no cover - depends on the environment
            raise BaselineUnavailable(f"open3d not importable: {exc}") from exc
        self._o3d = o3d
        self.threads = int(threads)
        v = o3d.core.Tensor(np.asarray(vertices, dtype=np.float32))
        f = o3d.core.Tensor(np.asarray(faces, dtype=np.uint32))
        start = time.perf_counter()
        self._scene = o3d.t.geometry.RaycastingScene(nthreads=self.threads)
        self._scene.add_triangles(v, f)
        # Open3D commits lazily on the first query; force it so the build is timed here.
        probe = np.array([[0.0, 0.0, 0.0, 0.0, 0.0, 1.0]], dtype=np.float32)
        self._scene.cast_rays(o3d.core.Tensor(probe), nthreads=self.threads)
        self.build_seconds = time.perf_counter() - start

    def intersect(self, rays: np.ndarray) -> dict:
        """Closest hit: ``t_hit`` (n,) float32, inf on miss; ``primitive_ids`` (n,) int64, -1."""
        out = self._scene.cast_rays(self._o3d.core.Tensor(_rays32(rays)), nthreads=self.threads)
        t = out["t_hit"].numpy()
        prim = out["primitive_ids"].numpy().astype(np.int64)
        prim[~np.isfinite(t)] = -1
        return {"t_hit": t, "primitive_ids": prim}

    def occluded(self, rays: np.ndarray, tmax) -> np.ndarray:
        """Any hit in (0, tmax): per-ray tmax by scaling each direction by tmax and using tfar=1.

        Open3D's ``test_occlusions`` takes one scalar tfar; since t is measured in units of the
        direction's length, scaling the directions gives the same per-ray test.
        """
        rays = _rays32(rays).copy()
        tmax = np.broadcast_to(np.asarray(tmax, dtype=np.float32), (len(rays),))
        finite = np.isfinite(tmax)
        rays[finite, 3:] *= tmax[finite, None]
        far = np.float32(1.0) if finite.all() else math.inf
        if not finite.all() and finite.any():
            raise ValueError("mix finite and infinite tmax in separate calls")
        out = self._scene.test_occlusions(self._o3d.core.Tensor(rays), tnear=0.0, tfar=far,
                                          nthreads=self.threads)
        return out.numpy().astype(bool)
