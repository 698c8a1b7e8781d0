"""Core benchmark: pointviz's surfel tracer against Embree oriented discs on the same surfels.

For each model (analytic sphere and torus samplings of ``--analytic-size`` surfels; Armadillo
surface-sampled to ``--sizes`` surfels; the registered dragon raw scans) and each thread count,
measured in the same run on the same surfels, rays and threads:

* build time (s), by wall clock around the whole Python-visible call on both sides (the
  ``SurfelScene`` constructor; ``EmbreeScene.discs``), and memory bytes per surfel (pointviz
  ``scene.memory_bytes / n``; Embree: bytes its allocator holds after the build / n, plus the
  28 B/surfel of its input buffers, and the build peak);
* Mrays/s for closest hit and for occlusion (any hit in (0, tmax), tmax = U(0.5, 1.5) x the Embree
  disc hit distance, so about half the hit rays are occluded), on coherent primary rays and on
  incoherent random rays; for Embree both single rays and packets of 4/8/16, the fastest reported;
* hit agreement of pointviz with Embree discs (fraction of rays both hit or both miss; median
  |Δt| over rays both hit, relative to the model diagonal);
* ratios pointviz / Embree discs (throughput: >1 means pointviz is faster; build time: >1 means
  pointviz is slower). What is compared: pointviz's default ``full`` variant (boxes near the top,
  normal-cone culling, level of detail when a pixel angle is given: none here) *with* the
  interpolation of the disks around each hit, against Embree's two-sided oriented discs (nearest
  disc only). pointviz runs without statistics (``stats=False``), as Embree counts nothing. The
  one-sided Embree variant (back-facing discs filtered, the semantics of culling) is reported
  beside it, measured right after (not interleaved);
* Mrays/s per core (throughput / threads), the figure to hold against tinybvh-class CPU
  tracers;
* the same pointviz scene traversed by the binary tree (``traversal="binary"``), interleaved
  with the wide traversal (the default) and Embree: its throughput, wide/binary ratios and how
  often the two traversals give the same t, nearest surfel and any-hit answer;
* anchors on the source mesh with the same rays: Embree triangles (same harness) and Open3D's
  ``RaycastingScene``;
* peak RSS after each phase.

The machine is shared, so absolute numbers are noisy; each time is the minimum of ``--repeat``
runs, and the ratios compare runs made moments apart in the same process.

Examples
--------
python benchmarks/bench_core.py --quick
python benchmarks/bench_core.py --sizes 1e6,3.6e6 --threads 1,2 --repeat 3
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common
from _baselines import (
    QUERY_MODES,
    BaselineUnavailable,
    EmbreeScene,
    Open3DTriangles,
    embree_available,
)

# Seeds: one per random choice, so every model and ray set is reproducible on its own.
SAMPLE_SEED = 20240611
RANDOM_RAYS_SEED = 7
TMAX_SEED = 11
SUBSAMPLE_SEED = 3

# Occlusion tmax = U(OCCLUSION_TMAX_LOW, OCCLUSION_TMAX_HIGH) x (Embree disc hit t): straddling the
# first hit gives a mix of occluded (early exit) and unoccluded (full traversal) rays.
OCCLUSION_TMAX_LOW = 0.5
OCCLUSION_TMAX_HIGH = 1.5

# --quick: tiny sizes so the whole run (build, every engine, both ray sets) takes seconds.
QUICK_SIZE = 20_000
QUICK_WIDTH, QUICK_HEIGHT = 64, 48

DEFAULT_SIZES = "1e6,3.6e6"
DEFAULT_ANALYTIC_SIZE = 400_000
DEFAULT_MODELS = "sphere,torus,dragon"
DEFAULT_WIDTH, DEFAULT_HEIGHT = 640, 480
DEFAULT_REPEAT = 3
# Builds are long at 3.6M surfels; two alternating builds per engine tame the load of other jobs.
DEFAULT_BUILD_REPEAT = 2
DEFAULT_THREADS = "1,2"
RESULTS = Path(__file__).resolve().parent / "results" / "core.json"


# ----------------------------------------------------------------------------------------------
# models


def _cloud_arrays(cloud) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions, normals and radii of a pointviz.PointCloud as float32 arrays."""
    points = getattr(cloud, "points", None)
    if points is None:
        points = cloud.positions
    return (common.as_float32(points), common.as_float32(cloud.normals),
            common.as_float32(cloud.radii))


def armadillo_model(data: Path, n: int, probe: common.PointvizProbe, workers: int
                    ) -> common.SurfelModel:
    """Armadillo sampled uniformly by area to ``n`` surfels (face normals, estimated radii).

    Parameters
    ----------
    data : Path
        Shared data folder.
    n : int
        Number of surfels.
    probe : PointvizProbe
        When pointviz is usable, its PointCloud estimates the radii (and is kept for the scene).
    workers : int
        Threads for the fallback k-d tree.

    Returns
    -------
    SurfelModel
    """
    vertices, faces = common.load_mesh(common.require_data(data, common.ARMADILLO_MESH))
    points, normals = common.sample_mesh_surface(vertices, faces, n, SAMPLE_SEED)
    notes = {"source": str(common.ARMADILLO_MESH), "sampling": f"uniform by area, seed {SAMPLE_SEED}",
             "normals": "face normals"}
    cloud = None
    if probe.available:
        cloud = probe.module.PointCloud(points, normals=normals)
        points, normals, radii = _cloud_arrays(cloud)
        notes["radii"] = "pointviz.PointCloud(points, normals).radii"
    else:
        radii = common.knn_radii(points, workers)
        notes["radii"] = (f"{common.RADIUS_SCALE} x distance to neighbour "
                          f"{common.RADIUS_NEIGHBOUR} (pointviz unavailable)")
    label = f"armadillo-{n / 1e6:g}M" if n >= 100_000 else f"armadillo-{n // 1000}k"
    return common.SurfelModel(label, common.as_float32(points), common.as_float32(normals),
                              common.as_float32(radii), vertices, faces, notes, cloud)


def analytic_model(shape: str, n: int, probe: common.PointvizProbe) -> common.SurfelModel:
    """A sphere or torus sampled by pointviz.shapes (exact normals, lattice or Voronoi radii).

    Parameters
    ----------
    shape : {"sphere", "torus"}
    n : int
        Number of surfels.
    probe : PointvizProbe
        pointviz must be usable (the samplings are its own).

    Returns
    -------
    SurfelModel
    """
    if not probe.available:
        raise common.DataMissingError(f"{shape}: the analytic samplings need pointviz")
    import importlib

    cloud = getattr(importlib.import_module("pointviz.shapes"), shape)(n)
    points, normals, radii = _cloud_arrays(cloud)
    label = f"{shape}-{n / 1e6:g}M" if n >= 1_000_000 else f"{shape}-{n // 1000}k"
    notes = {"source": f"pointviz.shapes.{shape}({n})", "normals": "analytic"}
    return common.SurfelModel(label, points, normals, radii, None, None, notes, cloud)


def dragon_model(data: Path, probe: common.PointvizProbe, workers: int,
                 subsample: int | None = None) -> common.SurfelModel:
    """The registered dragon raw scans (no source mesh, so no triangle anchors).

    Parameters
    ----------
    data : Path
    probe : PointvizProbe
        When usable, ``pointviz.load(conf)`` reads, registers and estimates normals and radii.
    workers : int
    subsample : int or None
        Keep this many points (seeded), for ``--quick``.

    Returns
    -------
    SurfelModel
    """
    conf = common.require_data(data, common.DRAGON_CONF)
    notes = {"source": str(common.DRAGON_CONF)}
    cloud = None
    if probe.available and hasattr(probe.module, "load") and subsample is None:
        cloud = probe.module.load(str(conf))
        points, normals, radii = _cloud_arrays(cloud)
        notes["loader"] = "pointviz.load(conf): pointviz normals and radii"
    else:
        points, scanners = common.load_conf_scans(conf)
        if subsample is not None and subsample < len(points):
            keep = np.random.default_rng(SUBSAMPLE_SEED).choice(len(points), subsample, replace=False)
            points, scanners = points[keep], scanners[keep]
        normals = common.pca_normals(points, scanners, workers)
        notes["loader"] = "benchmarks.common.load_conf_scans (R(q)^T p + t)"
        notes["normals"] = f"PCA of {common.NORMAL_NEIGHBOURS} neighbours, toward the scanner"
        if probe.available:
            cloud = probe.module.PointCloud(points, normals=normals)
            points, normals, radii = _cloud_arrays(cloud)  # exactly what pointviz traces
            notes["radii"] = "pointviz.PointCloud(points, normals).radii"
        else:
            radii = common.knn_radii(points, workers)
            notes["radii"] = (f"{common.RADIUS_SCALE} x distance to neighbour "
                              f"{common.RADIUS_NEIGHBOUR} (pointviz unavailable)")
    name = "dragon-scans" if subsample is None else f"dragon-scans-{subsample // 1000}k"
    return common.SurfelModel(name, common.as_float32(points), common.as_float32(normals),
                              common.as_float32(radii), None, None, notes, cloud)


# ----------------------------------------------------------------------------------------------
# rays


def primary_rays(model: common.SurfelModel, probe: common.PointvizProbe, width: int, height: int
                 ) -> tuple[np.ndarray, str]:
    """Primary rays of a camera framing the model (pointviz.Camera.fit when available).

    Returns
    -------
    rays : ndarray, shape (width * height, 6), float32
    source : str
        Which camera produced them.
    """
    if probe.available and model.cloud is not None:
        try:
            camera = probe.module.Camera.fit(model.cloud, width=width, height=height)
            rays = np.asarray(camera.rays(), dtype=np.float32).reshape(-1, 6)
            if len(rays) == width * height:
                return np.ascontiguousarray(rays), "pointviz.Camera.fit(cloud).rays()"
        except Exception as exc:  # noqa: BLE001 - fall back to the local camera, but say so
            print(f"  note: pointviz.Camera.fit failed ({type(exc).__name__}: {exc}); "
                  "using the local pinhole camera")
    camera = common.fit_camera(model.points, width, height)
    return camera.rays(), f"local pinhole, vfov {common.DEFAULT_FOV_DEGREES} deg, view +z"


def occlusion_tmax(t_ref: np.ndarray, rays: np.ndarray, diagonal: float, seed: int) -> np.ndarray:
    """Per-ray tmax straddling the reference hit; misses get a tmax past the whole model.

    Parameters
    ----------
    t_ref : ndarray, shape (n,)
        Reference closest-hit distance (inf on miss).
    rays : ndarray, shape (n, 6)
    diagonal : float
        Model diagonal.
    seed : int

    Returns
    -------
    ndarray, shape (n,), float32
    """
    rng = np.random.default_rng(seed)
    scale = rng.uniform(OCCLUSION_TMAX_LOW, OCCLUSION_TMAX_HIGH, size=len(t_ref))
    far = float(np.linalg.norm(rays[:, :3], axis=1).max()) + 10.0 * diagonal
    return np.where(np.isfinite(t_ref), t_ref * scale, far).astype(np.float32)


# ----------------------------------------------------------------------------------------------
# measurements


def mrays(n: int, seconds: float) -> float:
    """Millions of rays per second."""
    return n / seconds / 1e6 if seconds > 0 else math.inf


def agreement(t_a: np.ndarray, t_b: np.ndarray, diagonal: float) -> dict:
    """Hit/miss agreement and median |Δt| / diagonal over rays both hit.

    Parameters
    ----------
    t_a, t_b : ndarray, shape (n,)
        Hit distances, inf on miss.
    diagonal : float

    Returns
    -------
    dict
        ``hit_miss_agreement``, ``both_hit``, ``only_a``, ``only_b`` (fractions) and
        ``median_abs_dt_rel`` (None when no ray is hit by both).
    """
    ha, hb = np.isfinite(t_a), np.isfinite(t_b)
    both = ha & hb
    dt = np.abs(t_a[both].astype(np.float64) - t_b[both]) / diagonal
    return {
        "hit_miss_agreement": float(np.mean(ha == hb)),
        "both_hit": float(np.mean(both)),
        "only_a": float(np.mean(ha & ~hb)),
        "only_b": float(np.mean(~ha & hb)),
        "median_abs_dt_rel": float(np.median(dt)) if dt.size else None,
    }


def measure_embree(scene: EmbreeScene, rays: np.ndarray, tmax: np.ndarray, repeat: int) -> dict:
    """Time closest hit and occlusion in every query mode; keep the fastest of each.

    Returns
    -------
    dict
        ``closest``/``occluded``: {mode: Mrays/s}, best mode and its Mrays/s, and the closest-hit
        result of the best mode (``t_hit``, not serialised).
    """
    n = len(rays)
    out = {"closest_mrays": {}, "occluded_mrays": {}}
    results = {}
    for mode in QUERY_MODES:
        sec, res = common.time_best(lambda m=mode: scene.intersect(rays, mode=m), repeat)
        out["closest_mrays"][str(mode)] = mrays(n, sec)
        results[mode] = res
        sec, _ = common.time_best(lambda m=mode: scene.occluded(rays, tmax, mode=m), repeat)
        out["occluded_mrays"][str(mode)] = mrays(n, sec)
    for kind in ("closest", "occluded"):
        table = out[f"{kind}_mrays"]
        best = max(table, key=table.get)
        out[f"{kind}_best_mode"] = "single" if best == "1" else f"packet{best}"
        out[f"{kind}_best"] = table[best]
    # All modes must agree bit for bit (same kernels, different packetisation).
    t_single = results[1]["t_hit"]
    out["modes_identical"] = bool(all(np.array_equal(t_single, r["t_hit"], equal_nan=True)
                                      for r in results.values()))
    out["t_hit"] = t_single
    return out


def embree_memory(scene: EmbreeScene, n: int) -> dict:
    """Embree memory per primitive: BVH after build, build peak, input buffers."""
    return {
        "scene_bytes": scene.scene_bytes,
        "build_peak_bytes": scene.build_peak_bytes,
        "input_bytes": scene.input_bytes,
        "bytes_per_surfel": (scene.scene_bytes + scene.input_bytes) / n,
        "bvh_bytes_per_surfel": scene.scene_bytes / n,
        "build_peak_bytes_per_surfel": scene.build_peak_bytes / n,
    }


def build_pair(model: common.SurfelModel, args, probe: common.PointvizProbe, threads: int):
    """Build the Embree disc scene and, right after it, the pointviz scene (``--build-repeat`` times,
    alternating, keeping the fastest build of each so both see the same machine load).

    Returns
    -------
    embree : EmbreeScene
        The last Embree scene (the caller closes it).
    pv : object or None
        The last pointviz.SurfelScene, or None without pointviz.
    builds : dict
        Fastest build seconds by wall clock around the Python call: ``embree``, ``pointviz``;
        and by the engines' own timers: ``embree_core``, ``pointviz_core``.
    """
    builds = {"embree": math.inf, "pointviz": math.inf, "embree_core": math.inf,
              "pointviz_core": math.inf}
    embree = pv = None
    for _ in range(max(1, args.build_repeat)):
        if embree is not None:
            embree.close()
        pv = None  # release the previous pointviz scene before building the next
        start = time.perf_counter()
        embree = EmbreeScene.discs(model.points, model.normals, model.radii, threads=threads,
                                   quality=args.quality)
        builds["embree"] = min(builds["embree"], time.perf_counter() - start)
        builds["embree_core"] = min(builds["embree_core"], embree.build_seconds)
        if probe.available and model.cloud is not None:
            start = time.perf_counter()
            pv = probe.module.SurfelScene(model.cloud, variant=args.variant, threads=threads)
            wall = time.perf_counter() - start
            builds["pointviz"] = min(builds["pointviz"], wall)
            builds["pointviz_core"] = min(builds["pointviz_core"],
                                          float(getattr(pv, "build_seconds", wall) or wall))
    return embree, pv, builds


def binary_twin(model: common.SurfelModel, args, probe: common.PointvizProbe, threads: int):
    """The same pointviz scene traversed by the binary tree (``traversal="binary"``), the
    baseline of the wide traversal; None when this pointviz has no such option."""
    if not (probe.available and model.cloud is not None):
        return None
    try:
        return probe.module.SurfelScene(model.cloud, variant=args.variant, threads=threads,
                                        traversal="binary")
    except TypeError:
        return None


def paired_throughput(embree: EmbreeScene, pv, rays: np.ndarray, tmax: np.ndarray,
                      modes: tuple[int, int], repeat: int, pv_binary=None) -> dict:
    """Interleave Embree (its best modes) and pointviz runs (wide traversal, and the binary one
    when ``pv_binary`` is given); fastest of each, in Mrays/s.

    Alternating the engines within each repeat exposes all to the same load on a shared
    machine, which is what makes the ratios meaningful.
    """
    n = len(rays)
    calls = {
        "embree_closest": lambda: embree.intersect(rays, mode=modes[0]),
        "pointviz_closest": lambda: pv.cast_rays(rays, stats=False),
        "embree_occluded": lambda: embree.occluded(rays, tmax, mode=modes[1]),
        "pointviz_occluded": lambda: pv.occluded(rays, tmax, stats=False),
    }
    if pv_binary is not None:
        calls["binary_closest"] = lambda: pv_binary.cast_rays(rays, stats=False)
        calls["binary_occluded"] = lambda: pv_binary.occluded(rays, tmax, stats=False)
    best = dict.fromkeys(calls, math.inf)
    for _ in range(max(1, repeat)):
        for key, fn in calls.items():
            best[key] = min(best[key], common.time_best(fn, 1)[0])
    return {key: mrays(n, sec) for key, sec in best.items()}


def _pointviz_isa() -> str:
    """The instruction set of pointviz's traversal kernels ("?" for builds before dispatch)."""
    import importlib

    return getattr(importlib.import_module("pointviz.surfels"), "best_isa", lambda: "?")()


def _mode_number(label: str) -> int:
    return 1 if label == "single" else int(label.removeprefix("packet"))


def run_model(model: common.SurfelModel, args, probe: common.PointvizProbe) -> dict:
    """All measurements of one model at every thread count (see the module docstring)."""
    print(f"\n== {model.name}: {model.n:,} surfels, diagonal {model.diagonal:.4g}")
    for key, value in model.notes.items():
        print(f"  {key}: {value}")
    rays_p, camera_source = primary_rays(model, probe, args.width, args.height)
    ray_sets = {"primary": rays_p,
                "random": common.random_rays(model.points, len(rays_p), RANDOM_RAYS_SEED)}
    print(f"  rays: {len(rays_p):,} primary ({camera_source}) + {len(rays_p):,} random")
    record = {"name": model.name, "surfels": model.n, "diagonal": model.diagonal,
              "notes": model.notes, "camera": camera_source, "rays": len(rays_p),
              "mesh_triangles": None if model.mesh_faces is None else len(model.mesh_faces),
              "threads": {}, "rss_after_models": common.peak_rss_bytes()}
    tmax_sets: dict[str, np.ndarray] = {}
    for threads in args.threads:
        rec = {"embree_discs": {}, "embree_triangles": {}, "open3d": {}, "pointviz": {},
               "pointviz_binary": {}, "ratios": {}, "agreement": {}}
        scene, pv, builds = build_pair(model, args, probe, threads)
        pv_binary = binary_twin(model, args, probe, threads)
        try:
            # Embree discs (the reference for tmax and agreement): every query mode.
            rec["embree_discs"] = {"build_s": builds["embree"],
                                   "build_core_s": builds["embree_core"], "quality": args.quality,
                                   **embree_memory(scene, model.n), "device": scene.device_info()}
            rec["rss_after_builds"] = common.peak_rss_bytes()
            for set_name, rays in ray_sets.items():
                if set_name not in tmax_sets:  # tmax from the first (single-ray) result, reused
                    t_ref = scene.intersect(rays)["t_hit"]
                    tmax_sets[set_name] = occlusion_tmax(t_ref, rays, model.diagonal,
                                                         TMAX_SEED)
                m = measure_embree(scene, rays, tmax_sets[set_name], args.repeat)
                m["hit_fraction"] = float(np.mean(np.isfinite(m["t_hit"])))
                m["occluded_answer"] = scene.occluded(rays, tmax_sets[set_name])
                m["occluded_fraction"] = float(np.mean(m["occluded_answer"]))
                rec["embree_discs"][set_name] = m
            # pointviz, interleaved with Embree discs at their best modes.
            if pv is not None:
                rec["pointviz"] = {"build_s": builds["pointviz"],
                                   "build_core_s": builds["pointviz_core"],
                                   "isa": _pointviz_isa(),
                                   "variant": args.variant, "memory_bytes": int(pv.memory_bytes),
                                   "bytes_per_surfel": pv.memory_bytes / model.n}
                for set_name, rays in ray_sets.items():
                    ed = rec["embree_discs"][set_name]
                    tmax = tmax_sets[set_name]
                    res = pv.cast_rays(rays)
                    stats = dict(getattr(pv, "last_stats", {}) or {})
                    occ = np.asarray(pv.occluded(rays, tmax), dtype=bool)
                    modes = (_mode_number(ed["closest_best_mode"]),
                             _mode_number(ed["occluded_best_mode"]))
                    paired = paired_throughput(scene, pv, rays, tmax, modes, args.repeat,
                                               pv_binary)
                    t_pv = np.asarray(res["t_hit"], dtype=np.float32)
                    if pv_binary is not None:
                        res_b = pv_binary.cast_rays(rays)
                        t_b = np.asarray(res_b["t_hit"], dtype=np.float32)
                        occ_b = np.asarray(pv_binary.occluded(rays, tmax), dtype=bool)
                        rec["pointviz_binary"]["bytes_per_surfel"] = (pv_binary.memory_bytes
                                                                      / model.n)
                        rec["pointviz_binary"][set_name] = {
                            "closest_best": paired["binary_closest"],
                            "occluded_best": paired["binary_occluded"],
                            "stats": {k: float(v) for k, v in pv_binary.last_stats.items()
                                      if np.isscalar(v)},
                            # the wide traversal against the binary one on the same rays
                            "same_t_fraction": float(np.mean(
                                (t_b == t_pv) | (np.isinf(t_b) & np.isinf(t_pv)))),
                            "same_nearest_fraction": float(np.mean(
                                np.asarray(res_b["index"]) == np.asarray(res["index"]))),
                            "same_occluded_fraction": float(np.mean(occ_b == occ)),
                        }
                    rec["pointviz"][set_name] = {
                        "closest_best": paired["pointviz_closest"],
                        "occluded_best": paired["pointviz_occluded"],
                        "hit_fraction": float(np.mean(np.isfinite(t_pv))),
                        "t_hit": t_pv,
                        "occluded_fraction": float(np.mean(occ)),
                        "stats": {k: float(v) for k, v in stats.items() if np.isscalar(v)},
                        "paired_embree": {"closest": paired["embree_closest"],
                                          "occluded": paired["embree_occluded"]},
                    }
                    rec["agreement"][set_name] = agreement(t_pv, ed["t_hit"], model.diagonal)
                    rec["agreement"][set_name]["occluded_agreement"] = float(
                        np.mean(occ == ed["occluded_answer"]))
                    rec["ratios"][set_name] = {
                        "closest_throughput": paired["pointviz_closest"] / paired["embree_closest"],
                        "occluded_throughput": (paired["pointviz_occluded"]
                                                / paired["embree_occluded"]),
                    }
                    if pv_binary is not None:
                        rec["ratios"][set_name].update({
                            "binary_closest_throughput": (paired["binary_closest"]
                                                          / paired["embree_closest"]),
                            "binary_occluded_throughput": (paired["binary_occluded"]
                                                           / paired["embree_occluded"]),
                            "wide_vs_binary_closest": (paired["pointviz_closest"]
                                                       / paired["binary_closest"]),
                            "wide_vs_binary_occluded": (paired["pointviz_occluded"]
                                                        / paired["binary_occluded"]),
                        })
                rec["ratios"]["build_time"] = builds["pointviz"] / builds["embree"]
                rec["ratios"]["build_time_core_timers"] = (builds["pointviz_core"]
                                                           / builds["embree_core"])
                rec["ratios"]["bytes_per_surfel"] = (rec["pointviz"]["bytes_per_surfel"]
                                                     / rec["embree_discs"]["bytes_per_surfel"])
        finally:
            scene.close()
            del pv, pv_binary
        rec["rss_after_pointviz"] = common.peak_rss_bytes()
        # Embree one-sided discs (back-facing hits filtered out): the semantics of a renderer that
        # culls back-facing surfels; agreement columns compare it with pointviz.
        if not args.no_one_sided:
            with EmbreeScene.discs(model.points, model.normals, model.radii, threads=threads,
                                   quality=args.quality, one_sided=True) as one:
                rec["embree_discs_one_sided"] = {"build_s": one.build_seconds,
                                                 **embree_memory(one, model.n)}
                for set_name, rays in ray_sets.items():
                    m = measure_embree(one, rays, tmax_sets[set_name], args.repeat)
                    m["hit_fraction"] = float(np.mean(np.isfinite(m["t_hit"])))
                    m["agreement_vs_discs"] = agreement(
                        m["t_hit"], rec["embree_discs"][set_name]["t_hit"], model.diagonal)
                    if rec["pointviz"]:
                        m["agreement_vs_pointviz"] = agreement(
                            rec["pointviz"][set_name]["t_hit"], m["t_hit"], model.diagonal)
                    rec["embree_discs_one_sided"][set_name] = m
                    if rec["pointviz"]:
                        pv_rec = rec["pointviz"][set_name]
                        rec["ratios"][set_name]["closest_vs_one_sided"] = (
                            pv_rec["closest_best"] / m["closest_best"])
                        rec["ratios"][set_name]["occluded_vs_one_sided"] = (
                            pv_rec["occluded_best"] / m["occluded_best"])
        # Embree triangles and Open3D on the source mesh.
        if model.mesh_faces is not None and not args.no_anchors:
            with EmbreeScene.triangles(model.mesh_vertices, model.mesh_faces, threads=threads,
                                       quality=args.quality) as tri:
                rec["embree_triangles"] = {"build_s": tri.build_seconds,
                                           **embree_memory(tri, len(model.mesh_faces))}
                for set_name, rays in ray_sets.items():
                    m = measure_embree(tri, rays, tmax_sets[set_name], args.repeat)
                    m["hit_fraction"] = float(np.mean(np.isfinite(m["t_hit"])))
                    m["agreement_vs_discs"] = agreement(
                        m["t_hit"], rec["embree_discs"][set_name]["t_hit"], model.diagonal)
                    rec["embree_triangles"][set_name] = m
            try:
                o3d_scene = Open3DTriangles(model.mesh_vertices, model.mesh_faces, threads)
                rec["open3d"] = {"build_s": o3d_scene.build_seconds}
                for set_name, rays in ray_sets.items():
                    sec_c, _ = common.time_best(
                        lambda r=rays, o=o3d_scene: o.intersect(r), args.repeat)
                    sec_o, _ = common.time_best(
                        lambda r=rays, t=tmax_sets[set_name], o=o3d_scene: o.occluded(r, t),
                        args.repeat)
                    rec["open3d"][set_name] = {"closest_best": mrays(len(rays), sec_c),
                                               "occluded_best": mrays(len(rays), sec_o)}
                del o3d_scene
            except BaselineUnavailable as exc:
                rec["open3d"] = {"skipped": str(exc)}
        record["threads"][str(threads)] = rec
        print_rows(model, threads, rec)
    return record



# ----------------------------------------------------------------------------------------------
# output


def _fmt(value, spec: str = ".3g") -> str:
    return "-" if value is None else format(value, spec)


def print_rows(model: common.SurfelModel, threads: int, rec: dict) -> None:
    """Print one block of the table: every engine on every ray set at this thread count."""
    head = (f"{'threads':>7} {'engine':<17} {'rays':<8} {'build s':>8} {'B/prim':>9} "
            f"{'closest Mr/s':>13} {'(mode)':<9} {'occl Mr/s':>10} {'(mode)':<9} {'hit%':>6} "
            f"{'agree':>6} {'med|dt|/d':>9}")
    print(head)
    print(f"{'':>7} (agree = hit/miss agreement, med|dt|/d = median |Δt| / diagonal: pointviz vs "
          "Embree discs; Embree 1-sided vs pointviz; triangles vs discs)")
    print("-" * len(head))
    engines = [("embree discs", rec["embree_discs"], model.n),
               ("embree 1-sided", rec.get("embree_discs_one_sided"), model.n),
               ("embree triangles", rec["embree_triangles"], model.n),
               ("open3d triangles", rec["open3d"], model.n),
               (f"pointviz {rec['pointviz'].get('variant', '')}", rec["pointviz"], model.n)]
    for label, data, n in engines:
        if not data or "skipped" in data:
            continue
        per = data.get("bytes_per_surfel")
        if label == "embree triangles":  # per triangle of the source mesh
            per = (data["scene_bytes"] + data["input_bytes"]) / len(model.mesh_faces)
        for set_name in ("primary", "random"):
            m = data.get(set_name)
            if m is None:
                continue
            if label.startswith("pointviz"):
                agree = rec["agreement"].get(set_name)
            elif label == "embree 1-sided":
                agree = m.get("agreement_vs_pointviz") or m.get("agreement_vs_discs")
            else:
                agree = m.get("agreement_vs_discs")
            print(f"{threads:>7} {label:<17} {set_name:<8} {_fmt(data.get('build_s')):>8} "
                  f"{_fmt(per, '.1f'):>9} {_fmt(m['closest_best']):>13} "
                  f"{m.get('closest_best_mode', ''):<9} {_fmt(m['occluded_best']):>10} "
                  f"{m.get('occluded_best_mode', ''):<9} "
                  f"{_fmt(100 * m['hit_fraction'] if 'hit_fraction' in m else None, '.1f'):>6} "
                  f"{_fmt(agree and agree['hit_miss_agreement'], '.4f'):>6} "
                  f"{_fmt(agree and agree['median_abs_dt_rel'], '.1e'):>9}")
    if rec["ratios"]:
        r = rec["ratios"]
        print(f"{'':>7} ratios pointviz/embree discs: build time {r['build_time']:.2f}x, "
              f"bytes/surfel {r['bytes_per_surfel']:.2f}x, throughput closest "
              f"{r['primary']['closest_throughput']:.2f}x (primary) "
              f"{r['random']['closest_throughput']:.2f}x (random), occlusion "
              f"{r['primary']['occluded_throughput']:.2f}x / {r['random']['occluded_throughput']:.2f}x"
              " (interleaved runs)")
        print(f"{'':>7}   build by the engines' own timers: "
              f"{r['build_time_core_timers']:.2f}x; pointviz kernels: {rec['pointviz']['isa']}")
        for set_name in ("primary", "random"):
            pe = rec["pointviz"][set_name]["paired_embree"]
            pvr = rec["pointviz"][set_name]
            print(f"{'':>7}   interleaved {set_name}: embree discs closest {pe['closest']:.3g} / "
                  f"occl {pe['occluded']:.3g} Mr/s; pointviz "
                  f"{pvr['closest_best']:.3g} / {pvr['occluded_best']:.3g} Mr/s "
                  f"({pvr['closest_best'] / threads:.3g} / {pvr['occluded_best'] / threads:.3g} "
                  "Mr/s per core)")
            if "wide_vs_binary_closest" in r[set_name]:
                b = rec["pointviz_binary"][set_name]
                print(f"{'':>7}   binary traversal {set_name}: {b['closest_best']:.3g} / "
                      f"{b['occluded_best']:.3g} Mr/s ({b['closest_best'] / threads:.3g} / "
                      f"{b['occluded_best'] / threads:.3g} per core) = "
                      f"{r[set_name]['binary_closest_throughput']:.2f}x / "
                      f"{r[set_name]['binary_occluded_throughput']:.2f}x embree discs; "
                      f"wide/binary {r[set_name]['wide_vs_binary_closest']:.2f}x / "
                      f"{r[set_name]['wide_vs_binary_occluded']:.2f}x; same t "
                      f"{b['same_t_fraction']:.5f}, nearest {b['same_nearest_fraction']:.5f}, "
                      f"any hit {b['same_occluded_fraction']:.5f}; binary "
                      f"{rec['pointviz_binary']['bytes_per_surfel']:.1f} B/surfel")
            if "closest_vs_one_sided" in r[set_name]:
                print(f"{'':>7}   vs one-sided embree discs ({set_name}, not interleaved): closest "
                      f"{r[set_name]['closest_vs_one_sided']:.2f}x, occlusion "
                      f"{r[set_name]['occluded_vs_one_sided']:.2f}x")
    ed = rec["embree_discs"]
    print(f"{'':>7} embree discs: BVH {ed['bvh_bytes_per_surfel']:.1f} B/surfel + input 28 B; "
          f"build peak {ed['build_peak_bytes_per_surfel']:.1f} B/surfel; "
          f"single vs packet (primary closest): "
          + ", ".join(f"{k}:{v:.2f}" for k, v in ed["primary"]["closest_mrays"].items()))


def _jsonable(obj):
    """Drop arrays (per-ray answers) and convert numpy scalars for json.dump."""
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items() if not isinstance(v, np.ndarray)}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


# ----------------------------------------------------------------------------------------------
# main


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """Command line of the benchmark."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", type=Path, default=common.default_data_dir(),
                   help="shared data folder (default: <repo>/../shared/data)")
    p.add_argument("--sizes", default=DEFAULT_SIZES,
                   help="Armadillo surfel counts, comma separated (default %(default)s)")
    p.add_argument("--models", default=DEFAULT_MODELS,
                   help="which models: sphere, torus, armadillo, dragon (default %(default)s)")
    p.add_argument("--analytic-size", type=lambda v: int(float(v)), default=DEFAULT_ANALYTIC_SIZE,
                   help="surfels of the sphere and torus samplings (default %(default)s)")
    p.add_argument("--threads", default=DEFAULT_THREADS,
                   help="thread counts, comma separated (default %(default)s)")
    p.add_argument("--width", type=int, default=DEFAULT_WIDTH)
    p.add_argument("--height", type=int, default=DEFAULT_HEIGHT)
    p.add_argument("--repeat", type=int, default=DEFAULT_REPEAT,
                   help="timed runs per measurement; the fastest is kept (default %(default)s)")
    p.add_argument("--build-repeat", type=int, default=DEFAULT_BUILD_REPEAT,
                   help="builds per engine, alternating; the fastest is kept (default %(default)s)")
    p.add_argument("--quality", choices=("low", "medium", "high"), default="medium",
                   help="Embree build quality (default %(default)s)")
    p.add_argument("--variant", default="full", help="pointviz SurfelScene variant")
    p.add_argument("--no-anchors", action="store_true",
                   help="skip Embree triangles and Open3D on the source mesh")
    p.add_argument("--no-one-sided", action="store_true",
                   help="skip the one-sided Embree disc variant (back-face filter)")
    p.add_argument("--quick", action="store_true",
                   help=f"smoke run: {QUICK_SIZE:,} surfels, {QUICK_WIDTH}x{QUICK_HEIGHT} rays, "
                        "repeat 1")
    p.add_argument("--output", type=Path, default=RESULTS,
                   help="JSON results (default benchmarks/results/core.json)")
    args = p.parse_args(argv)
    args.threads = [int(t) for t in str(args.threads).split(",") if t.strip()]
    args.sizes = [int(float(s)) for s in str(args.sizes).split(",") if s.strip()]
    args.models = [m.strip() for m in args.models.split(",") if m.strip()]
    if args.quick:
        args.sizes, args.width, args.height = [QUICK_SIZE], QUICK_WIDTH, QUICK_HEIGHT
        args.analytic_size = QUICK_SIZE
        args.repeat = args.build_repeat = 1
    return args


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; returns the process exit code."""
    args = parse_args(argv)
    ok, reason = embree_available()
    if not ok:
        print(f"Embree baseline unavailable: {reason}")
        return 2
    probe = common.probe_pointviz()
    if not probe.available:
        print(f"NOTE: {probe.reason}; the pointviz columns and ratios are skipped "
              "(Embree and Open3D baselines only).")
    workers = max(args.threads)
    builders = [lambda s=shape: analytic_model(s, args.analytic_size, probe)
                for shape in ("sphere", "torus") if shape in args.models]
    if "armadillo" in args.models:
        builders += [lambda n=n: armadillo_model(args.data, n, probe, workers) for n in args.sizes]
    if "dragon" in args.models:
        builders.append(lambda: dragon_model(args.data, probe, workers,
                                             QUICK_SIZE if args.quick else None))
    results = {"benchmark": "core", "date": time.strftime("%Y-%m-%dT%H:%M:%S"),
               "machine": {"platform": platform.platform(), "python": platform.python_version(),
                           "cpu_count": __import__("os").cpu_count()},
               "args": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
               "pointviz": probe.reason or "available",
               "memory_accounting": (
                   "pointviz: scene.memory_bytes / n. Embree: bytes held by Embree's allocator "
                   "after rtcCommitScene (rtcSetDeviceMemoryMonitorFunction) / n + 28 B/surfel of "
                   "shared input buffers (float4 centre+radius, float3 normal); build peak separate."),
               "occlusion_tmax": f"U({OCCLUSION_TMAX_LOW}, {OCCLUSION_TMAX_HIGH}) x Embree disc "
                                 f"hit t (seed {TMAX_SEED}); misses: beyond the model",
               "models": []}
    for build in builders:
        try:
            model = build()
        except common.DataMissingError as exc:
            print(f"SKIP model: {exc}")
            continue
        results["models"].append(run_model(model, args, probe))
        del model
    results["peak_rss_bytes"] = common.peak_rss_bytes()
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(_jsonable(results), indent=1))
    print(f"\nwrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
