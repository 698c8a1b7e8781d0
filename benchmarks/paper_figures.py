"""Reproduce Figures 5, 6 and 7 of Zakaria et al. (GRAPP 2006) on pointviz, with Embree alongside.

* **Figure 5** — traversal time of the full-view 400x400 primary rays per traversal variant
  (``kdtree``, ``lod``, ``lod+cull``, ``full``), with Embree oriented discs on the same surfels and
  Embree triangles on the source mesh (Armadillo only) timed in the same process.
* **Figure 6** — average nodes visited, disk tests and maximum depth per ray (``scene.last_stats``),
  over all rays and over the rays that hit.
* **Figure 7** — a camera-distance sweep (multiples of ``Camera.fit``'s distance) with LoD on and
  off, plus the image error LoD costs at each distance: PSNR and FLIP of the LoD normal image
  against the no-LoD one.

Models: Armadillo surface-sampled to ``--size`` surfels (default 3.6M, the paper's dragon) and the
registered dragon raw scans (``pointviz.load(dragonStandRight.conf)``, ~470k points) upsampled to
the same size by jittering samples inside each scan disk (see :func:`upsample_in_disks`).

Times are the core traversal call (``scene.tree.cast`` on float64 rays, no statistics; Python-side
validation excluded, as the paper reports traversal alone) and Embree's ``rtcIntersect1`` per ray,
one thread each by default. The machine is shared: every measurement is repeated ``--repeat``
times with all engines interleaved within a repeat, and the median is kept, so ratios compare
runs made moments apart.

This module also holds the helpers the other ``paper_*``/``bench_*`` scripts of issue 7 share.

Examples
--------
python benchmarks/paper_figures.py --quick
python benchmarks/paper_figures.py            # 3.6M surfels, both models (minutes, ~3 GB)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common

# Seeds: one per random choice.
SAMPLE_SEED = 20240611      # same as bench_core, so the Armadillo surfels are the same
UPSAMPLE_SEED = 17
SUBSAMPLE_SEED = 3

#: The paper's image size (section 3) and its dragon's point count.
PAPER_WIDTH = PAPER_HEIGHT = 400
PAPER_SIZE = 3_609_600

#: The paper's variants in the order of its Figure 5 (plus ``bvh``: the hierarchy with boxes at
#: every level and neither LoD nor culling, which an earlier version of this script called
#: "kdtree"), and its numbers (seconds of traversal).
VARIANTS = ("kdtree", "bvh", "lod", "lod+cull", "full")
#: The baselines the other variants are compared with.
BASELINES = ("kdtree", "bvh")
PAPER_FIG5 = {"dragon": {"kdtree": 110.0, "lod": 60.0, "lod+cull": 50.0, "full": 32.0},
              "statue": {"kdtree": 420.0, "lod": 220.0, "lod+cull": 200.0, "full": 160.0}}
#: Paper's Figure 7 (distance in its units; seconds without / with LoD).
PAPER_FIG7 = {"distance": [350, 550, 750, 1500], "no_lod": [158.1, 146.0, 103.2, 80.1],
              "lod": [126.0, 69.4, 45.1, 20.1]}

#: Camera-distance multiples of the fitted distance for Figure 7 (the paper went 350 -> 1500).
DISTANCES = (1.0, 1.5, 2.0, 4.0, 8.0)

#: --quick: tiny sizes so a whole run takes seconds.
QUICK_SIZE = 20_000
QUICK_PIXELS = 64

#: FLIP's default viewing condition (67 pixels per degree: a 0.7 m distance to a 4K 32" screen).
FLIP_RANGE = "LDR"

#: Colour of background pixels in the error images (black: a miss and a hit differ strongly).
BACKGROUND = 0.0


# ----------------------------------------------------------------------------------------------
# command line shared by the issue-7 scripts


def base_parser(description: str, name: str) -> argparse.ArgumentParser:
    """Argument parser with the options every issue-7 script has.

    Parameters
    ----------
    description : str
    name : str
        Results subfolder (``benchmarks/results/<name>/``).

    Returns
    -------
    argparse.ArgumentParser
    """
    p = argparse.ArgumentParser(description=description,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", type=Path, default=common.default_data_dir(),
                   help="shared data folder (default: <repo>/../shared/data)")
    p.add_argument("--out", type=Path, default=common.REPO_ROOT / "benchmarks" / "results" / name,
                   help=f"results folder for JSON and PNG (default benchmarks/results/{name}/)")
    p.add_argument("--quick", action="store_true",
                   help=f"smoke run: {QUICK_SIZE:,} surfels, {QUICK_PIXELS}x{QUICK_PIXELS}, repeat 1")
    p.add_argument("--repeat", type=int, default=3,
                   help="interleaved repeats per measurement; the median is kept (default 3)")
    p.add_argument("--threads", type=int, default=1,
                   help="threads of every engine (default 1: the steadiest on a shared machine)")
    p.add_argument("--clock", choices=("cpu", "wall"), default="cpu",
                   help="clock of the reported medians: process CPU time (default; excludes time "
                        "other users take on a shared machine; use with 1 thread) or wall time")
    return p


def machine_info() -> dict:
    """Platform, Python, CPU count, load average, and which code was measured.

    The code is the git commit of the repository (with ``dirty`` when tracked files differ from
    it) and the modification time of the compiled core that was imported: the core is rebuilt
    in place while people work, so a result says which build produced it.
    """
    import subprocess

    def git(*cmd):
        try:
            return subprocess.run(["git", *cmd], cwd=common.REPO_ROOT, capture_output=True,
                                  text=True, check=False, timeout=10).stdout.strip()
        except (OSError, subprocess.SubprocessError):
            return ""

    core = None
    try:
        from pointviz import _core

        core = time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(os.path.getmtime(_core.__file__)))
    except (ImportError, OSError):
        pass
    return {"platform": platform.platform(), "python": platform.python_version(),
            "cpu_count": os.cpu_count(), "loadavg": list(os.getloadavg()),
            "git_commit": git("rev-parse", "--short", "HEAD"),
            "git_dirty": bool(git("status", "--porcelain", "--untracked-files=no")),
            "core_built": core}


def write_json(out_dir: Path, name: str, data: dict) -> Path:
    """Write ``data`` as ``out_dir/name`` (atomic replace; results are regenerated, not user files)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / name
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(jsonable(data), indent=1))
    tmp.replace(path)
    return path


def jsonable(obj):
    """Convert numpy scalars/arrays and non-finite floats for json.dump."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return jsonable(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def save_figure(fig, out_dir: Path, name: str) -> Path:
    """Save a matplotlib figure as a small PNG (dpi chosen to stay well under 200 KB)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / name
    fig.tight_layout()
    fig.savefig(path, dpi=80, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path


def pyplot():
    """matplotlib.pyplot on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


# ----------------------------------------------------------------------------------------------
# models


class Model:
    """A surfel cloud for the figures, with its source mesh when there is one.

    Attributes
    ----------
    name : str
    cloud : pointviz.PointCloud
    mesh : tuple of ndarray or None
        (vertices (nv, 3) float64, faces (nf, 3) int64) of the source mesh.
    notes : dict
        How the surfels were made.
    """

    def __init__(self, name, cloud, mesh, notes):
        self.name, self.cloud, self.mesh, self.notes = name, cloud, mesh, notes

    @property
    def n(self) -> int:
        """Number of surfels."""
        return len(self.cloud.points)


def armadillo(data: Path, n: int) -> Model:
    """Armadillo.ply sampled uniformly by area to ``n`` surfels (face normals, pointviz radii).

    Parameters
    ----------
    data : Path
        Shared data folder.
    n : int

    Returns
    -------
    Model
    """
    import pointviz

    vertices, faces = common.load_mesh(common.require_data(data, common.ARMADILLO_MESH))
    points, normals = common.sample_mesh_surface(vertices, faces, n, SAMPLE_SEED)
    cloud = pointviz.PointCloud(points, normals=normals, name="armadillo")
    _ = cloud.radii  # estimate now, outside any timing
    return Model("armadillo", cloud, (vertices, faces),
                 {"source": str(common.ARMADILLO_MESH),
                  "sampling": f"uniform by area, seed {SAMPLE_SEED}, face normals",
                  "radii": "pointviz.PointCloud estimator"})


def upsample_in_disks(points, normals, radii, factor: int, seed: int):
    """``factor`` samples per surfel, uniform inside its disk (same normal), replacing it.

    A registered scan is a set of overlapping disks; drawing new samples inside each disk keeps
    the surface (and its noise) while multiplying the density, which is how we reach the paper's
    millions of points from the ~470k of the dragon scans.

    Parameters
    ----------
    points : (n, 3) float64
    normals : (n, 3) float32, unit
    radii : (n,) float32
    factor : int
        Samples per input surfel (>= 1).
    seed : int

    Returns
    -------
    points : (n * factor, 3) float64
    normals : (n * factor, 3) float32
    """
    rng = np.random.default_rng(seed)
    nrm = np.asarray(normals, dtype=np.float64)
    # Orthonormal frame per disk: e1 = normalize(n x a), a the axis least aligned with n.
    a = np.zeros_like(nrm)
    a[np.arange(len(nrm)), np.argmin(np.abs(nrm), axis=1)] = 1.0
    e1 = np.cross(nrm, a)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(nrm, e1)
    m = len(points) * factor
    rep = np.repeat(np.arange(len(points)), factor)
    rho = np.asarray(radii, dtype=np.float64)[rep] * np.sqrt(rng.random(m))  # uniform by area
    phi = rng.random(m) * 2.0 * np.pi
    out = (np.asarray(points, dtype=np.float64)[rep] + (rho * np.cos(phi))[:, None] * e1[rep]
           + (rho * np.sin(phi))[:, None] * e2[rep])
    return out, np.asarray(normals, dtype=np.float32)[rep]


def dragon(data: Path, n: int | None, quick: bool = False) -> Model:
    """The registered dragon raw scans; upsampled inside the disks to about ``n`` surfels.

    Parameters
    ----------
    data : Path
    n : int or None
        Target size; None or <= the scan size keeps the scans as they are (in ``quick`` mode a
        seeded subset of ``QUICK_SIZE`` points is kept instead).
    quick : bool

    Returns
    -------
    Model
    """
    import pointviz

    conf = common.require_data(data, common.DRAGON_CONF)
    scans = pointviz.load(str(conf))
    notes = {"source": str(common.DRAGON_CONF), "scan_points": len(scans.points),
             "loader": "pointviz.load(conf): pointviz normals and radii"}
    if quick:
        keep = np.random.default_rng(SUBSAMPLE_SEED).choice(len(scans.points), QUICK_SIZE,
                                                            replace=False)
        cloud = scans.subset(np.sort(keep))
        notes["subset"] = f"{QUICK_SIZE} points, seed {SUBSAMPLE_SEED}"
        return Model("dragon", cloud, None, notes)
    if n is None or n <= len(scans.points):
        return Model("dragon", scans, None, notes)
    factor = math.ceil(n / len(scans.points))
    points, normals = upsample_in_disks(scans.points, scans.normals, scans.radii, factor,
                                        UPSAMPLE_SEED)
    cloud = pointviz.PointCloud(points, normals=normals, name="dragon")
    _ = cloud.radii  # estimate now, outside any timing
    notes["upsampling"] = (f"{factor} samples per scan point, uniform inside its disk (same "
                           f"normal), seed {UPSAMPLE_SEED}; radii re-estimated by pointviz")
    return Model("dragon", cloud, None, notes)


def load_models(args, names, size: int) -> list[Model]:
    """Build the requested models (``armadillo``, ``dragon`` upsampled to ``size``, ``dragon-raw``
    the scans as they are), skipping missing data loudly."""
    models = []
    for name in names:
        try:
            if name == "armadillo":
                models.append(armadillo(args.data, QUICK_SIZE if args.quick else size))
            elif name == "dragon":
                models.append(dragon(args.data, size, quick=args.quick))
            elif name == "dragon-raw":
                m = dragon(args.data, None, quick=args.quick)
                m.name = "dragon-raw"
                models.append(m)
            else:
                raise SystemExit(f"--models: unknown model {name!r} "
                                 "(armadillo, dragon, dragon-raw)")
        except common.DataMissingError as exc:
            print(f"SKIP {name}: {exc}")
    return models


# ----------------------------------------------------------------------------------------------
# cameras, rays, images


def fit_camera(cloud, pixels: int):
    """The full view of the paper: ``Camera.fit`` at ``pixels`` x ``pixels``."""
    import pointviz

    return pointviz.Camera.fit(cloud, width=pixels, height=pixels)


def camera_at(camera, factor: float):
    """The same view from ``factor`` times farther away (same target, field of view and size)."""
    import pointviz

    eye = np.asarray(camera.target) - np.asarray(camera.forward) * camera.distance * factor
    return pointviz.Camera.look_at(eye, camera.target, up=camera.true_up, fov_deg=camera.fov_deg,
                                   width=camera.width, height=camera.height)


def rays64(camera) -> np.ndarray:
    """The camera's primary rays as C-contiguous float64 (what the core reads without a copy)."""
    return np.ascontiguousarray(camera.rays(), dtype=np.float64)


def core_cast(scene, rays: np.ndarray, pixel_angle: float, threads: int, stats=False, **opts):
    """One traversal of ``rays`` by the core; ``opts`` override TraceOptions fields.

    Parameters
    ----------
    scene : pointviz.SurfelScene
    rays : (n, 6) float64
    pixel_angle : float
        0 disables LoD (no footprint).
    threads : int
    stats : bool
    **opts
        e.g. ``box_depth=5``, ``lod=False``, ``lod_pixels=2.0``.

    Returns
    -------
    out : dict
        The core's arrays (``t_hit``, ``normals``, ...).
    stats : dict
    """
    o = scene.trace_options()
    for k, v in opts.items():
        if k == "lod_criterion":
            from pointviz import _core

            v = getattr(_core.LodCriterion, v)
        setattr(o, k, v)
    return scene.tree.cast(rays, o, pixel_angle=float(pixel_angle), threads=threads, stats=stats)


def normal_image(out: dict, camera) -> np.ndarray:
    """(h, w, 3) float32 image in [0, 1]: the hit normal mapped by 0.5 + 0.5 n; misses black."""
    n = np.asarray(out["normals"], dtype=np.float32)
    img = np.where(np.isfinite(out["t_hit"])[:, None], 0.5 + 0.5 * n, BACKGROUND)
    return np.clip(img, 0.0, 1.0).reshape(camera.height, camera.width, 3).astype(np.float32)


def psnr(ref: np.ndarray, test: np.ndarray) -> float:
    """PSNR in dB of two images in [0, 1] (inf when identical)."""
    mse = float(np.mean((ref.astype(np.float64) - test) ** 2))
    return math.inf if mse == 0 else 10.0 * math.log10(1.0 / mse)


def flip(ref: np.ndarray, test: np.ndarray) -> float:
    """Mean LDR-FLIP error of ``test`` against ``ref`` (both (h, w, 3) in [0, 1], sRGB)."""
    import flip_evaluator

    _, mean, _ = flip_evaluator.evaluate(ref, test, FLIP_RANGE, applyMagma=False)
    return float(mean)


# ----------------------------------------------------------------------------------------------
# timing


def interleaved(calls: dict, repeat: int, clock: str = "cpu") -> dict:
    """Run every callable once per repeat, in turn; return each one's median seconds and all runs.

    Alternating engines within a repeat exposes all of them to the same load on a shared machine,
    which is what makes their ratios meaningful; the median resists one disturbed run.

    Parameters
    ----------
    calls : dict of str -> callable
    repeat : int
    clock : {"cpu", "wall"}
        Which clock ``median`` reports. "cpu" is this process's CPU time (all its threads): for
        one-thread runs it excludes the time the scheduler gives to other users of a shared
        machine (load averages of 4-6 on 2 cores were seen), so it measures the work itself.
        "wall" is elapsed time: the right clock for multi-threaded runs. Both are recorded.

    Returns
    -------
    dict of str -> {"median": float, "runs": list, "wall_median": float, "cpu_median": float}
    """
    wall = {k: [] for k in calls}
    cpu = {k: [] for k in calls}
    for _ in range(max(1, repeat)):
        for key, fn in calls.items():
            c0, w0 = time.process_time(), time.perf_counter()
            fn()
            wall[key].append(time.perf_counter() - w0)
            cpu[key].append(time.process_time() - c0)
    out = {}
    for k in calls:
        runs = cpu[k] if clock == "cpu" else wall[k]
        out[k] = {"median": statistics.median(runs), "runs": runs,
                  "wall_median": statistics.median(wall[k]), "cpu_median": statistics.median(cpu[k])}
    return out


def embree_discs(cloud, threads: int):
    """Embree oriented discs on exactly the surfels pointviz traces, or (None, reason)."""
    from _baselines import BaselineUnavailable, EmbreeScene

    try:
        return EmbreeScene.discs(common.as_float32(cloud.points), common.as_float32(cloud.normals),
                                 common.as_float32(cloud.radii), threads=threads), ""
    except (BaselineUnavailable, OSError, RuntimeError) as exc:
        return None, str(exc)


def embree_triangles(mesh, threads: int):
    """Embree triangles on the source mesh, or (None, reason)."""
    from _baselines import BaselineUnavailable, EmbreeScene

    if mesh is None:
        return None, "no source mesh (raw scans)"
    try:
        return EmbreeScene.triangles(mesh[0], mesh[1], threads=threads), ""
    except (BaselineUnavailable, OSError, RuntimeError) as exc:
        return None, str(exc)


def embree_calls(discs, tris, rays32: np.ndarray) -> dict:
    """Timing callables of the Embree baselines that exist (single rays: like pointviz)."""
    calls = {}
    if discs is not None:
        calls["embree discs"] = lambda: discs.intersect(rays32, mode=1)
    if tris is not None:
        calls["embree triangles"] = lambda: tris.intersect(rays32, mode=1)
    return calls


# ----------------------------------------------------------------------------------------------
# Figures 5 and 6


def figures_5_6(model: Model, args) -> dict:
    """Traversal time and per-ray statistics of each variant at the fitted full view."""
    import pointviz

    px = QUICK_PIXELS if args.quick else PAPER_WIDTH
    cam = fit_camera(model.cloud, px)
    rays = rays64(cam)
    rays32 = common.as_float32(rays)
    scenes = {v: pointviz.SurfelScene(model.cloud, variant=v, threads=args.threads) for v in VARIANTS}
    discs, why_d = embree_discs(model.cloud, args.threads)
    tris, why_t = embree_triangles(model.mesh, args.threads)
    calls = {v: (lambda s=s: core_cast(s, rays, cam.pixel_angle, args.threads))
             for v, s in scenes.items()}
    calls.update(embree_calls(discs, tris, rays32))
    times = interleaved(calls, args.repeat, args.clock)
    rec = {"model": model.name, "n": model.n, "notes": model.notes, "pixels": px,
           "camera": cam.to_dict(), "pixel_angle": cam.pixel_angle,
           "embree_skipped": {k: v for k, v in (("discs", why_d), ("triangles", why_t)) if v},
           "variants": {}, "embree": {}}
    hit_rows = None
    for v, s in scenes.items():
        out = s.cast_rays(rays, camera=cam)
        st_all = dict(s.last_stats)
        hit = np.isfinite(out["t_hit"])
        if hit_rows is None:
            hit_rows = np.flatnonzero(hit)
        s.cast_rays(rays[hit_rows], camera=cam)
        rec["variants"][v] = {
            "seconds": times[v]["median"], "runs": times[v]["runs"],
            "box_depth": s.box_depth, "depth": s.depth, "bytes_per_surfel": s.memory_bytes / s.n_surfels,
            "references_per_surfel": getattr(s.tree, "n_references", s.n_surfels) / s.n_surfels,
            "build_seconds": s.build_seconds, "hit_fraction": float(hit.mean()),
            "all_rays": {k: st_all[k] for k in ("nodes_visited", "disk_tests", "max_depth")},
            "hit_rays": {k: s.last_stats[k] for k in ("nodes_visited", "disk_tests", "max_depth")},
        }
    for k in ("embree discs", "embree triangles"):
        if k in times:
            rec["embree"][k] = {"seconds": times[k]["median"], "runs": times[k]["runs"]}
    for name in BASELINES:
        base = rec["variants"][name]
        for v, r in rec["variants"].items():
            r[f"drop_vs_{name}"] = 1.0 - r["seconds"] / base["seconds"]
            for which in ("all_rays", "hit_rays"):
                r[f"{which}_drop_vs_{name}"] = {
                    k: 1.0 - r[which][k] / base[which][k] if base[which][k] else None
                    for k in r[which]}
    if discs is not None:
        rec["full_over_embree_discs"] = rec["variants"]["full"]["seconds"] / rec["embree"]["embree discs"]["seconds"]
        discs.close()
    if tris is not None:
        tris.close()
    return rec


def print_fig56(rec: dict) -> None:
    """Figure 5/6 table of one model."""
    print(f"\n== Figures 5/6: {rec['model']} ({rec['n']:,} surfels, {rec['pixels']}^2 rays)")
    head = (f"{'variant':<17}{'time ms':>9}{'vs kd':>7}{'vs bvh':>7}{'nodes/ray':>10}"
            f"{'disks/ray':>10}"
            f"{'maxdepth':>9}{'| hit rays: nodes':>18}{'disks':>7}{'depth':>7}{'boxdepth':>9}")
    print(head)
    print("-" * len(head))
    for v, r in rec["variants"].items():
        a, h = r["all_rays"], r["hit_rays"]
        print(f"{v:<17}{1e3 * r['seconds']:>9.1f}{-100 * r['drop_vs_kdtree']:>+6.0f}%"
              f"{-100 * r['drop_vs_bvh']:>+6.0f}%"
              f"{a['nodes_visited']:>10.1f}{a['disk_tests']:>10.1f}{a['max_depth']:>9.2f}"
              f"{h['nodes_visited']:>18.1f}{h['disk_tests']:>7.1f}{h['max_depth']:>7.2f}"
              f"{r['box_depth']:>6}/{r['depth']}")
    for k, e in rec["embree"].items():
        print(f"{k:<17}{1e3 * e['seconds']:>9.1f}")
    if "full_over_embree_discs" in rec:
        print(f"full / embree discs time ratio: {rec['full_over_embree_discs']:.2f}x")


def chart_fig56(records: list, out_dir: Path) -> list[Path]:
    """Figure 5 (time bars per variant, Embree as lines) and Figure 6 (three stat panels)."""
    plt = pyplot()
    paths = []
    fig, axes = plt.subplots(1, len(records), figsize=(5 * len(records), 3.6), squeeze=False)
    for ax, rec in zip(axes[0], records):
        ms = [1e3 * rec["variants"][v]["seconds"] for v in VARIANTS]
        ax.bar(VARIANTS, ms, color="#4878a8")
        for v, m in zip(VARIANTS, ms):
            d = rec["variants"][v]["drop_vs_kdtree"]
            ax.annotate(f"{m:.0f} ms\n{-100 * d:+.0f}%", (v, m), ha="center", va="bottom", fontsize=8)
        styles = {"embree discs": ("#c44e52", "--"), "embree triangles": ("#55a868", ":")}
        for k, e in rec["embree"].items():
            ax.axhline(1e3 * e["seconds"], color=styles[k][0], ls=styles[k][1], label=k)
        ax.set_title(f"{rec['model']} {rec['n'] / 1e6:.2g}M surfels, {rec['pixels']}$^2$ rays")
        ax.set_ylabel("traversal time (ms, 1 thread)")
        ax.set_ylim(0, 1.3 * max(ms))
        if rec["embree"]:
            ax.legend(fontsize=8, loc="upper right")
    fig.suptitle("Figure 5: traversal time per variant (paper: -60..-70% kdtree -> full)", y=1.03)
    paths.append(save_figure(fig, out_dir, "fig5_traversal_time.png"))

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.4))
    width = 0.8 / max(1, len(records))
    x = np.arange(len(VARIANTS))
    for j, rec in enumerate(records):
        for ax, key, title in zip(axes, ("nodes_visited", "disk_tests", "max_depth"),
                                  ("nodes visited / ray", "disk tests / ray", "max depth / ray")):
            ax.bar(x + j * width, [rec["variants"][v]["all_rays"][key] for v in VARIANTS], width,
                   label=f"{rec['model']} (all rays)")
            ax.plot(x + j * width, [rec["variants"][v]["hit_rays"][key] for v in VARIANTS], "k_",
                    ms=14, label=f"{rec['model']} (hit rays)" if key == "nodes_visited" else None)
            ax.set_xticks(x + width * (len(records) - 1) / 2, VARIANTS)
            ax.set_title(title)
    axes[0].legend(fontsize=7)
    fig.suptitle("Figure 6: per-ray statistics (bars: all rays; marks: rays that hit)", y=1.03)
    paths.append(save_figure(fig, out_dir, "fig6_stats.png"))
    return paths


# ----------------------------------------------------------------------------------------------
# Figure 7


def figure_7(model: Model, args) -> dict:
    """Distance sweep: LoD on/off (same tree), kdtree, Embree; and the image error of LoD."""
    import pointviz

    px = QUICK_PIXELS if args.quick else PAPER_WIDTH
    base = fit_camera(model.cloud, px)
    full = pointviz.SurfelScene(model.cloud, variant="full", threads=args.threads)
    base_scenes = {v: pointviz.SurfelScene(model.cloud, variant=v, threads=args.threads)
                   for v in BASELINES}
    discs, _ = embree_discs(model.cloud, args.threads)
    tris, _ = embree_triangles(model.mesh, args.threads)
    rows = []
    for factor in DISTANCES:
        cam = camera_at(base, factor)
        rays = rays64(cam)
        calls = {
            "lod": lambda r=rays, c=cam: core_cast(full, r, c.pixel_angle, args.threads),
            "no lod": lambda r=rays: core_cast(full, r, 0.0, args.threads),
        }
        calls.update({v: (lambda r=rays, b=b: core_cast(b, r, 0.0, args.threads))
                      for v, b in base_scenes.items()})
        calls.update(embree_calls(discs, tris, common.as_float32(rays)))
        times = interleaved(calls, args.repeat, args.clock)
        out_lod, st_lod = core_cast(full, rays, cam.pixel_angle, args.threads, stats=True)
        out_ref, st_ref = core_cast(full, rays, 0.0, args.threads, stats=True)
        hit_rows = np.flatnonzero(np.isfinite(out_ref["t_hit"]))
        hit_rays = np.ascontiguousarray(rays[hit_rows])
        # The rays that hit, alone: far away they are a few percent of the frame, and the misses
        # (one root test each, the same for every structure) dominate the frame's time.
        structures = {"lod": (full, cam.pixel_angle), "no lod": (full, 0.0),
                      **{b: (sc_b, 0.0) for b, sc_b in base_scenes.items()}}
        hit_times = interleaved({v: (lambda sc=sc, pa=pa: core_cast(sc, hit_rays, pa, args.threads))
                                 for v, (sc, pa) in structures.items()}, args.repeat, args.clock)
        per_hit_ray = {}  # the paper's per-ray statistics over the rays that hit, per structure
        for v, (sc, pa) in structures.items():
            _, st = core_cast(sc, hit_rays, pa, args.threads, stats=True)
            per_hit_ray[v] = {k: st[k] for k in ("nodes_visited", "disk_tests", "max_depth")}
            per_hit_ray[v]["seconds"] = hit_times[v]["median"]
        img_lod, img_ref = normal_image(out_lod, cam), normal_image(out_ref, cam)
        hit = np.isfinite(out_ref["t_hit"])
        row = {"factor": factor, "distance": cam.distance,
               "seconds": {k: t["median"] for k, t in times.items()},
               "runs": {k: t["runs"] for k, t in times.items()},
               "nodes_per_ray": {"lod": st_lod["nodes_visited"], "no lod": st_ref["nodes_visited"]},
               "hit_rays": per_hit_ray,
               "hit_fraction": float(hit.mean()),
               "lod_node_hits": float(np.mean(out_lod["index"] == -2)),
               "psnr_db": psnr(img_ref, img_lod), "flip": flip(img_ref, img_lod),
               "hit_mismatch": float(np.mean(hit != np.isfinite(out_lod["t_hit"])))}
        row["lod_speedup"] = row["seconds"]["no lod"] / row["seconds"]["lod"]
        # the paper's claim: full (with LoD) against the KD-tree, as a drop in time
        row["full_drop_vs"] = {b: 1.0 - row["seconds"]["lod"] / row["seconds"][b]
                               for b in BASELINES}
        row["full_drop_vs_hit_rays"] = {
            b: 1.0 - per_hit_ray["lod"]["seconds"] / per_hit_ray[b]["seconds"] for b in BASELINES}
        rows.append(row)
    for e in (discs, tris):
        if e is not None:
            e.close()
    return {"model": model.name, "n": model.n, "pixels": px, "fit_distance": base.distance,
            "rows": rows, "paper": PAPER_FIG7}


def print_fig7(rec: dict) -> None:
    """Figure 7 table of one model."""
    print(f"\n== Figure 7: {rec['model']} ({rec['n']:,} surfels), distance sweep")
    keys = [k for k in ("lod", "no lod", "kdtree", "bvh", "embree discs", "embree triangles")
            if k in rec["rows"][0]["seconds"]]
    head = (f"{'x fit':>6}{'hit%':>6}" + "".join(f"{k + ' ms':>18}" for k in keys)
            + f"{'speedup':>8}{'full/kd':>8}{'full/bvh':>9}{'hits: /kd':>10}{'/bvh':>6}"
            + f"{'nodes lod/no':>14}{'PSNR dB':>8}"
            + f"{'FLIP':>7}{'lodhit%':>8}")
    print(head)
    print("-" * len(head))
    for r in rec["rows"]:
        print(f"{r['factor']:>6g}{100 * r['hit_fraction']:>6.1f}"
              + "".join(f"{1e3 * r['seconds'][k]:>18.1f}" for k in keys)
              + f"{r['lod_speedup']:>7.2f}x{-100 * r['full_drop_vs']['kdtree']:>+7.0f}%"
              f"{-100 * r['full_drop_vs']['bvh']:>+8.0f}%"
              f"{-100 * r['full_drop_vs_hit_rays']['kdtree']:>+9.0f}%"
              f"{-100 * r['full_drop_vs_hit_rays']['bvh']:>+5.0f}%"
              f"{r['nodes_per_ray']['lod']:>7.1f}/"
              f"{r['nodes_per_ray']['no lod']:<6.1f}{r['psnr_db']:>8.1f}{r['flip']:>7.3f}"
              f"{100 * r['lod_node_hits']:>8.1f}")
    p = rec["paper"]
    print("paper (dragon, s):  distance " + " ".join(f"{d:>6}" for d in p["distance"])
          + " | no LoD " + " ".join(f"{t:g}" for t in p["no_lod"])
          + " | LoD " + " ".join(f"{t:g}" for t in p["lod"])
          + " | speedup " + " ".join(f"{a / b:.2f}" for a, b in zip(p["no_lod"], p["lod"])))


def chart_fig7(records: list, out_dir: Path) -> Path:
    """Time against distance (log-log) and, on a second axis, LoD's FLIP error."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(records), figsize=(6.5 * len(records), 4.0), squeeze=False)
    styles = {"lod": ("#4878a8", "-o"), "no lod": ("#dd8452", "-s"), "kdtree": ("#8172b3", "-^"),
              "bvh": ("#937860", "-v"),
              "embree discs": ("#c44e52", "--"), "embree triangles": ("#55a868", ":")}
    for ax, rec in zip(axes[0], records):
        f = [r["factor"] for r in rec["rows"]]
        for k, (c, st) in styles.items():
            if k in rec["rows"][0]["seconds"]:
                ax.plot(f, [1e3 * r["seconds"][k] for r in rec["rows"]], st, color=c, label=k)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xticks(f, [f"{v:g}x" for v in f])
        ax.xaxis.set_minor_formatter(plt.NullFormatter())
        ax.set_xlabel("camera distance (x fitted distance)")
        ax.set_ylabel("traversal time (ms, 1 thread)")
        ax.set_title(f"{rec['model']} {rec['n'] / 1e6:.2g}M surfels")
        ax2 = ax.twinx()
        ax2.plot(f, [r["flip"] for r in rec["rows"]], "k:", marker="x", label="FLIP LoD vs no LoD")
        ax2.set_ylabel("FLIP (LoD vs no LoD, normal image)")
        lines = ax.get_legend_handles_labels()
        lines2 = ax2.get_legend_handles_labels()
        ax.legend(lines[0] + lines2[0], lines[1] + lines2[1], fontsize=7, loc="lower left")
    fig.suptitle("Figure 7: traversal time vs distance, LoD on/off, and LoD's image error", y=1.03)
    return save_figure(fig, out_dir, "fig7_distance.png")


# ----------------------------------------------------------------------------------------------
# the KD-tree baseline's own settings

#: SAH intersection costs (relative to one node step) and leaf sizes tried for the KD-tree.
KD_INTERSECT_COSTS = (1.0, 2.0, 4.0)
KD_LEAF_SIZES = (4, 8, 16)
#: Distances (x fit) of the tuning sweep: the framing view and a far one.
KD_TUNING_DISTANCES = (1.0, 4.0)


def kdtree_tuning(model: Model, args) -> dict:
    """The KD-tree's SAH settings swept against the default, bvh and full (fairness check).

    A baseline tuned worse than it could be would flatter the paper's claim: every setting is
    timed interleaved with ``bvh`` and ``full`` at the framing and a far view.
    """
    import pointviz
    from pointviz import _core

    px = QUICK_PIXELS if args.quick else PAPER_WIDTH
    base = fit_camera(model.cloud, px)
    full = pointviz.SurfelScene(model.cloud, variant="full", threads=args.threads)
    bvh = pointviz.SurfelScene(model.cloud, variant="bvh", threads=args.threads)
    opts = bvh.trace_options()  # no LoD, no culling: what the KD-tree does
    pts = np.ascontiguousarray(model.cloud.points, dtype=np.float64)
    arrays = (pts, common.as_float32(model.cloud.normals), common.as_float32(model.cloud.radii),
              None, tuple(bvh.origin))
    trees, settings = {}, []
    for ic in KD_INTERSECT_COSTS:
        for leaf in KD_LEAF_SIZES:
            key = f"kd ic={ic:g} leaf={leaf}"
            trees[key] = _core.KdTree(*arrays, intersect_cost=ic, max_leaf=leaf)
            t = trees[key]
            settings.append({"key": key, "intersect_cost": ic, "max_leaf": leaf,
                             "build_seconds": t.build_seconds, "depth": t.depth,
                             "references_per_surfel": t.n_references / model.n,
                             "bytes_per_surfel": t.memory_bytes / model.n})
    rows = []
    for factor in KD_TUNING_DISTANCES:
        cam = camera_at(base, factor)
        rays = rays64(cam)
        calls = {k: (lambda t=t, r=rays: t.cast(r, opts, 0.0, args.threads, False))
                 for k, t in trees.items()}
        calls["bvh"] = lambda r=rays: core_cast(bvh, r, 0.0, args.threads)
        calls["full"] = lambda r=rays, c=cam: core_cast(full, r, c.pixel_angle, args.threads)
        times = interleaved(calls, args.repeat, args.clock)
        rows.append({"factor": factor, "seconds": {k: v["median"] for k, v in times.items()}})
    return {"model": model.name, "n": model.n, "pixels": px, "settings": settings, "rows": rows}


def print_kdtree_tuning(rec: dict) -> None:
    """Tuning table: one row per setting, time at each distance and its ratio to full."""
    print(f"\n== KD-tree settings: {rec['model']} ({rec['n']:,} surfels)")
    cols = "".join(f"{str(r['factor']) + 'x ms':>10}{'/full':>7}" for r in rec["rows"])
    print(f"{'setting':<20}{'refs/surfel':>12}{'B/surfel':>9}{'build s':>8}" + cols)
    for st in rec["settings"]:
        print(f"{st['key']:<20}{st['references_per_surfel']:>12.2f}{st['bytes_per_surfel']:>9.0f}"
              f"{st['build_seconds']:>8.1f}"
              + "".join(f"{1e3 * r['seconds'][st['key']]:>10.1f}"
                        f"{r['seconds'][st['key']] / r['seconds']['full']:>7.2f}"
                        for r in rec["rows"]))
    for k in ("bvh", "full"):
        print(f"{k:<20}{'':>29}"
              + "".join(f"{1e3 * r['seconds'][k]:>10.1f}{'':>7}" for r in rec["rows"]))


# ----------------------------------------------------------------------------------------------
# main


def main(argv: list[str] | None = None) -> int:
    """Run Figures 5, 6 and 7; print the tables, write JSON and PNGs; return the exit code."""
    p = base_parser(__doc__.split("\n\n")[0], "paper_figures")
    p.add_argument("--size", type=float, default=PAPER_SIZE,
                   help="surfels per model (default the paper's dragon, %(default)g)")
    p.add_argument("--models", default="armadillo,dragon,dragon-raw",
                   help="armadillo, dragon (upsampled to --size), "
                        "dragon-raw (the scans as they are)")
    p.add_argument("--figures", default="5,7",
                   help="which figures: 5 (with 6), 7, kd (the KD-tree's SAH settings swept)")
    p.add_argument("--replot", action="store_true",
                   help="redraw the charts from the JSON already in --out (no measurement)")
    args = p.parse_args(argv)
    if args.replot:
        result = json.loads((args.out / "paper_figures.json").read_text())
        if result["fig5"]:
            chart_fig56(result["fig5"], args.out)
        if result["fig7"]:
            chart_fig7(result["fig7"], args.out)
        return 0
    if args.quick:
        args.repeat = 1
    probe = common.probe_pointviz()
    if not probe.available:
        print(probe.reason)
        return 2
    figures = {f.strip() for f in args.figures.split(",")}
    result = {"benchmark": "paper_figures", "date": time.strftime("%Y-%m-%dT%H:%M:%S"),
              "machine": machine_info(), "args": {k: str(v) for k, v in vars(args).items()},
              "timing": ("median of --repeat interleaved runs, clock --clock (cpu: process CPU "
                         "time); pointviz = core traversal (scene.tree.cast, float64 rays, no "
                         "stats); Embree = rtcIntersect1 per ray"),
              "paper": {"fig5": PAPER_FIG5, "fig7": PAPER_FIG7},
              "fig5": [], "fig7": [], "kd_tuning": []}
    models = load_models(args, [m.strip() for m in args.models.split(",") if m.strip()],
                         int(args.size))
    for model in models:
        print(f"\n# {model.name}: {model.n:,} surfels ({model.notes})")
        if "5" in figures:
            rec = figures_5_6(model, args)
            print_fig56(rec)
            result["fig5"].append(rec)
        if "7" in figures:
            rec = figure_7(model, args)
            print_fig7(rec)
            result["fig7"].append(rec)
        if "kd" in figures:
            rec = kdtree_tuning(model, args)
            print_kdtree_tuning(rec)
            result["kd_tuning"].append(rec)
    result["peak_rss_bytes"] = common.peak_rss_bytes()
    charts = []
    if result["fig5"]:
        charts += chart_fig56(result["fig5"], args.out)
    if result["fig7"]:
        charts.append(chart_fig7(result["fig7"], args.out))
    result["charts"] = [c.name for c in charts]
    path = write_json(args.out, "paper_figures.json", result)
    print(f"\nwrote {path} and {', '.join(c.name for c in charts)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
