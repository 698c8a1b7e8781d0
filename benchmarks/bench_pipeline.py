"""Issue 15's end-to-end figures: start to PNG, per-frame cost, loader throughput.

Three measurements, each against anchors taken in the same run (interleaved, medians of
``--repeat``):

1. ``pointviz render SCANS.conf -o x.png`` as a subprocess, wall time from start to exit, against
   the core's own tree build + frame time in that same process (target <= 4x, goal 2x). Inputs:
   the dragon's 15 registered raw scans (469k points), and generated noisy, misregistered range
   scans of a sphere (8 scans, ~1M points) written as a ``.conf`` of binary and of ASCII PLY
   files. The breakdown (start-up and imports, load, normals, radii, camera fit, build, frame,
   write) says where the rest goes.
2. A 64x64 ``render(surfel_scene, camera)`` of a 2M-surfel scene against the same frame of a
   20k-surfel scene (target within 2x: nothing per frame may grow with the cloud).
   The ``lidar`` part measures the same for real LiDAR tiles (``lidar/lone-star.laz``, 519k
   points; ``lidar/autzen_trim.laz``, 110k points, RGB): no fit, normals oriented from above.
3. Loader throughput (MB/s) per format: ``pointviz.load(estimate=False)`` against reading the
   same bytes (disk speed from the page cache) and against Open3D's reader (laspy without
   parallel decompression for LAZ).

Examples
--------
python benchmarks/bench_pipeline.py --quick
python benchmarks/bench_pipeline.py
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common

#: Issue 15's targets.
TARGET_START_TO_PNG = 4.0
GOAL_START_TO_PNG = 2.0
TARGET_FRAME_RATIO = 2.0
#: Virtual scans of a unit sphere: scanners this many radii from its centre, a grid of rays per
#: scan, depth noise (fraction of the diameter) and misregistration (translation, same unit).
SCANS = 8
SCAN_DISTANCE = 3.0
SCAN_GRID = 400  # 400^2 rays, ~78% hit: ~125k points per scan, ~1M in all
SCAN_NOISE = 0.001
SCAN_MISREGISTRATION = 0.0005
#: The ``lidar`` part's tiles (under the data folder), with their labels.
LIDAR_FILES = (("lidar/lone-star.laz", "LiDAR tile (lone-star.laz, 519k points, LAZ)"),
               ("lidar/autzen_trim.laz", "LiDAR tile (autzen_trim.laz, 110k points, LAZ, RGB)"))
#: Surfel counts of the per-frame comparison.
SMALL_SCENE, LARGE_SCENE = 20_000, 2_000_000
FRAME_PIXELS = 64
#: Points of the generated files of the loader comparison.
LOADER_POINTS = 1_000_000

# Runs the CLI in a fresh process with timers around each stage; writes them as JSON. Each timer
# keeps its stage's own time: time spent in a nested timed stage (radii inside the SurfelScene
# build, normals inside the fit) counts for the nested stage only, so the stages add up. A stage
# that runs on another thread, beside the main thread's work (the radii beside the camera fit),
# is kept as "<stage>_beside" and left out of the sum; the main thread's wait for it is a stage.
TIMED_CLI = r"""
import json, os, sys, threading, time
t_start = time.perf_counter()
import pointviz.cli
out = sys.argv.pop(1)  # the CLI sees its own arguments, as when run as a program
# what main() does first when run as a program, before numpy loads (one OpenBLAS thread for
# "render"); importing the stages to time below loads numpy before main() runs
blas = getattr(pointviz.cli, "SINGLE_THREADED_BLAS", ())
if getattr(pointviz.cli, "_named_command", lambda a: None)(sys.argv[1:]) in blas:
    pointviz.cli._single_threaded_blas()
if pointviz.cli._named_command(sys.argv[1:]) in getattr(pointviz.cli, "REUSE_FREED_MEMORY", ()):
    pointviz.cli._reuse_freed_memory()  # (main() does it again: the same settings)
import pointviz, pointviz.io, pointviz.rendering, pointviz.surfels, pointviz.camera
import pointviz.denoise, pointviz.commands.common
from pointviz.cloud import PointCloud
t = {"imports": time.perf_counter() - t_start,
     "openblas_threads": os.environ.get("OPENBLAS_NUM_THREADS")}
local = threading.local()  # per thread: time of the timed stages inside the running one

def timed(key, fn):
    def wrapper(*a, **kw):
        s = time.perf_counter()
        outer, local.nested = getattr(local, "nested", 0.0), 0.0
        try:
            return fn(*a, **kw)
        finally:
            spent = time.perf_counter() - s
            name = key if threading.current_thread() is threading.main_thread() else key + "_beside"
            t[name] = t.get(name, 0.0) + spent - local.nested
            local.nested = outer + spent
    return wrapper

in_background = getattr(pointviz.commands.common, "_radii_in_background", None)
def radii_in_background(*a, **kw):
    wait = in_background(*a, **kw)
    return None if wait is None else timed("radii_wait", wait)
if in_background is not None:  # (an older tree, for A/B runs, estimates them in load())
    pointviz.commands.common._radii_in_background = radii_in_background
camera_beside = getattr(pointviz.commands.common, "_camera_in_background", None)
def camera_in_background(*a, **kw):
    return timed("camera_wait", camera_beside(*a, **kw))
if camera_beside is not None:  # (older trees fit the camera on the main thread)
    pointviz.commands.common._camera_in_background = camera_in_background

for name in ("normals", "radii"):  # first access estimates them
    prop = getattr(PointCloud, name)
    setattr(PointCloud, name, property(timed(name, prop.fget)))
PointCloud.fitted = timed("fit", PointCloud.fitted)
pointviz.io.load = timed("load", pointviz.io.load)
pointviz.camera.Camera.fit = classmethod(timed("camera_fit", pointviz.camera.Camera.fit.__func__))
init = pointviz.surfels.SurfelScene.__init__
def scene_init(self, *a, **kw):
    init(self, *a, **kw)
    t["build"] = t.get("build", 0.0) + self.build_seconds
pointviz.surfels.SurfelScene.__init__ = timed("build_total", scene_init)
pointviz.denoise.denoise_frame = timed("denoise", pointviz.denoise.denoise_frame)
render = pointviz.rendering.render
def render_and_record(*a, **kw):
    frame = render(*a, **kw)
    t["frame"] = frame.stats["seconds"]
    return frame
pointviz.rendering.render = timed("render", render_and_record)
pointviz.rendering.Frame.save = timed("write", pointviz.rendering.Frame.save)
import pointviz.scene
pointviz.scene.Scene.bounds = timed("bounds", pointviz.scene.Scene.bounds)

def dump(code):
    t["exit_code"] = code
    with open(out, "w") as fh:
        json.dump(t, fh)

exit_now = getattr(pointviz.cli, "_exit_now", None)
def dump_and_exit(code):  # the CLI ends the process itself once its output is written
    dump(code)
    exit_now(code)
if exit_now is not None:
    pointviz.cli._exit_now = dump_and_exit
dump(pointviz.cli.main())
"""
#: The stages of TIMED_CLI, in pipeline order; together with "other" they make up the wall time.
STAGES = ("imports", "load", "fit", "normals", "radii", "camera_fit", "radii_wait", "build_total",
          "bounds", "camera_wait", "render", "denoise", "write")


def median(values):
    return float(statistics.median(values))


# ---------------------------------------------------------------------------------------------
# inputs


def sphere_scans(seed: int, grid: int = SCAN_GRID):
    """Virtual range scans of the unit sphere, each in its scanner's frame.

    Returns
    -------
    list of (local (m, 3) float32, R (3, 3), t (3,))
        ``local @ R + t`` places a scan (the ``.conf`` convention of pointviz.io); each scanner
        looks down the -z axis of its frame. Depth noise along the rays, and a small error in each
        scan's placement (the registration is not exact).
    """
    rng = np.random.default_rng(seed)
    scans = []
    half = np.tan(np.arcsin(1.0 / SCAN_DISTANCE))
    a, b = np.meshgrid(np.linspace(-half, half, grid), np.linspace(-half, half, grid))
    for k in range(SCANS):
        w = rng.normal(size=3)
        w /= np.linalg.norm(w)
        u = np.cross(w, [0.3, 0.5, 0.8])
        u /= np.linalg.norm(u)
        v = np.cross(w, u)
        rot = np.stack([u, v, w])  # rows: local x, y, z in world; det +1
        eye = SCAN_DISTANCE * w
        d = -w + a.reshape(-1, 1) * u + b.reshape(-1, 1) * v
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        # |eye + s d| = 1: s^2 + 2 s (eye.d) + |eye|^2 - 1 = 0, nearest root
        ed = d @ eye
        disc = ed**2 - (eye @ eye - 1.0)
        hit = disc > 0
        s = -ed[hit] - np.sqrt(disc[hit])
        s += rng.normal(scale=2.0 * SCAN_NOISE, size=s.shape)  # depth noise: 0.1% of the size
        world = eye + s[:, None] * d[hit]
        t = rng.normal(scale=SCAN_MISREGISTRATION, size=3)  # where the registration puts it
        local = (world - t) @ rot.T  # so that local @ rot + t + error = world
        scans.append((local.astype(np.float32), rot, t))
    return scans


def write_conf(folder: Path, scans, fmt: str) -> Path:
    """A ``.conf`` of PLY scans (``fmt`` "ascii" or "binary_little_endian")."""
    from scipy.spatial.transform import Rotation

    folder.mkdir(parents=True, exist_ok=True)
    lines = []
    for k, (local, rot, t) in enumerate(scans):
        name = f"scan{k}.ply"
        head = (f"ply\nformat {fmt} 1.0\nelement vertex {len(local)}\nproperty float x\n"
                "property float y\nproperty float z\nend_header\n").encode()
        with open(folder / name, "wb") as fh:
            fh.write(head)
            if fmt == "ascii":
                np.savetxt(fh, local, fmt="%.6f")
            else:
                fh.write(local.astype("<f4").tobytes())
        # the reader places rows as p @ quaternion_matrix(q) + t: that matrix is rot
        q = Rotation.from_matrix(rot).as_quat()  # (x, y, z, w)
        lines.append(f"bmesh {name} {' '.join(f'{x:.9g}' for x in t)} "
                     f"{' '.join(f'{x:.9g}' for x in q)}")
    conf = folder / "scans.conf"
    conf.write_text("\n".join(lines) + "\n")
    return conf


# ---------------------------------------------------------------------------------------------
# 1. start to PNG


def compile_bytecode() -> None:
    """Byte-compile the pointviz package (its ``__pycache__`` folders), as installing it does:
    start-up is then measured as a user's install has it. Without this, an environment with
    PYTHONDONTWRITEBYTECODE set compiles every module from source in every run (~0.05 s of CPU
    for the ~50 modules ``render`` imports)."""
    import compileall

    import pointviz

    compileall.compile_dir(Path(pointviz.__file__).parent, quiet=1)


def start_to_png(conf: Path, out_dir: Path, repeat: int, extra: list[str]) -> dict:
    """Median stage times of ``pointviz render`` over ``repeat`` fresh processes."""
    compile_bytecode()
    runs = []
    for r in range(repeat):
        png = out_dir / f"start_to_png_{conf.parent.name}_{r}.png"
        png.unlink(missing_ok=True)
        timings = out_dir / "timings.json"
        cmd = [sys.executable, "-c", TIMED_CLI, str(timings), "render", str(conf), "-o", str(png),
               *extra]
        start = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.perf_counter() - start
        if proc.returncode != 0:
            raise RuntimeError(f"pointviz render failed: {proc.stderr.strip()[-500:]}")
        t = json.loads(timings.read_text())
        t["wall"] = wall
        runs.append(t)
    keys = ["wall", *STAGES, "radii_beside", "camera_fit_beside", "build", "frame"]
    med = {k: median([r.get(k, 0.0) for r in runs]) for k in keys}
    med["openblas_threads"] = runs[0].get("openblas_threads")
    med["anchor"] = median([r.get("build", 0.0) + r.get("frame", 0.0) for r in runs])
    med["ratio"] = median([r["wall"] / (r.get("build", 0.0) + r.get("frame", 0.0)) for r in runs])
    return med


def print_start_to_png(label: str, med: dict) -> None:
    # the CLI builds the SurfelScene inside render() (Scene.to_core): render's own time is the
    # core's frame and the scene setup around it
    med = {k: med.get(k, 0.0)
           for k in ("wall", "anchor", "ratio", "build", "frame", "radii_beside",
                     "camera_fit_beside", *STAGES)}
    other = med["wall"] - sum(med[k] for k in STAGES)
    print(f"\n{label}: start to PNG {med['wall']:.2f} s = {med['ratio']:.1f}x the core's tree "
          f"build + frame ({med['anchor']:.2f} s; target <= {TARGET_START_TO_PNG:g}x, "
          f"goal {GOAL_START_TO_PNG:g}x)")
    rows = [("start-up + imports", med["imports"]), ("read + place", med["load"]),
            ("surface fit (+ its normals)", med["fit"]), ("normals", med["normals"]),
            ("radii", med["radii"]), ("camera fit", med["camera_fit"]),
            ("  radii beside it (not summed)", med["radii_beside"]),
            ("waiting for those radii", med["radii_wait"]),
            ("SurfelScene (tree build)", med["build_total"]),
            ("  of which the core's build", med["build"]),
            ("  camera fit beside it (not summed)", med["camera_fit_beside"]),
            ("scene bounds and ground level", med["bounds"]),
            ("waiting for that camera", med["camera_wait"]),
            ("frame (the core)", med["frame"]),
            ("render() setup around the frame", med["render"] - med["frame"]),
            ("denoise", med["denoise"]),
            ("write PNG", med["write"]), ("other (interpreter, CLI, exit)", other)]
    for name, secs in rows:
        print(f"  {name:36s} {secs:7.3f} s  {100 * secs / med['wall']:5.1f} %")
    rest = med["wall"] - med["normals"] - med["radii"] - med["radii_wait"] - med["fit"]
    budget = TARGET_START_TO_PNG * med["anchor"] - rest
    print(f"  everything but the fit, normals and radii: {rest:.2f} s = "
          f"{rest / med['anchor']:.2f}x the anchor; the {TARGET_START_TO_PNG:g}x target leaves "
          f"{budget:.2f} s for them")
    outside = med["wall"] - med["fit"] - med["normals"] - med["anchor"]
    print(f"  outside the fit (+ its normals) and the anchor: {outside:.2f} s")


# ---------------------------------------------------------------------------------------------
# 2. per-frame cost


def sphere_surfels(n: int, seed: int):
    import pointviz
    from pointviz.cloud import PointCloud

    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    radius = 2.0 * np.sqrt(4.0 / n)  # covers the sphere: ~pi r^2 n > 4 pi
    cloud = PointCloud(p, p.astype(np.float32), radii=np.full(n, radius, np.float32))
    return pointviz.SurfelScene(cloud)


def frame_cost(repeat: int, large: int) -> dict:
    import pointviz

    scenes = {"small": sphere_surfels(SMALL_SCENE, 1), "large": sphere_surfels(large, 2)}
    cams = {k: pointviz.Camera.fit(s.cloud, width=FRAME_PIXELS, height=FRAME_PIXELS)
            for k, s in scenes.items()}
    for k in scenes:  # first frame: per-scene caches (bounds, ground) are filled here
        pointviz.render(scenes[k], cams[k], spp=1)
    wall = {k: [] for k in scenes}
    core = {k: [] for k in scenes}
    for _ in range(repeat):
        for k in scenes:
            start = time.perf_counter()
            frame = pointviz.render(scenes[k], cams[k], spp=1)
            wall[k].append(time.perf_counter() - start)
            core[k].append(frame.stats["seconds"])
    out = {f"{k}_{m}": median(v) for m, d in (("wall", wall), ("core", core)) for k, v in d.items()}
    out["ratio"] = out["large_wall"] / out["small_wall"]
    out["large_surfels"] = large
    return out


def print_frame(fc: dict) -> None:
    print(f"\n{FRAME_PIXELS}x{FRAME_PIXELS} render(surfel_scene): {fc['large_surfels']:,} surfels "
          f"{1e3 * fc['large_wall']:.1f} ms (core {1e3 * fc['large_core']:.1f}) vs "
          f"{SMALL_SCENE:,} surfels {1e3 * fc['small_wall']:.1f} ms (core "
          f"{1e3 * fc['small_core']:.1f}): {fc['ratio']:.2f}x (target <= {TARGET_FRAME_RATIO:g}x)")


# ---------------------------------------------------------------------------------------------
# 3. loaders


def loader_files(folder: Path, n: int) -> dict:
    """The same random points in every format, written by Open3D and laspy."""
    import laspy
    import open3d as o3d

    rng = np.random.default_rng(3)
    pts = rng.normal(size=(n, 3)) * 10.0
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pcd.normals = o3d.utility.Vector3dVector(nrm)
    pcd.colors = o3d.utility.Vector3dVector(rng.random((n, 3)))
    files = {}
    for name, ascii_ in (("binary.ply", False), ("ascii.ply", True), ("binary.pcd", False),
                         ("ascii.pcd", True)):
        path = folder / name
        o3d.io.write_point_cloud(str(path), pcd, write_ascii=ascii_)
        files[name] = path
    files["points.xyz"] = folder / "points.xyz"
    o3d.io.write_point_cloud(str(files["points.xyz"]), o3d.geometry.PointCloud(pcd.points))
    for ext in ("las", "laz"):
        header = laspy.LasHeader(point_format=3, version="1.2")
        header.scales = [1e-4] * 3
        header.offsets = [0.0, 0.0, 0.0]
        las = laspy.LasData(header)
        las.x, las.y, las.z = pts.T
        path = folder / f"points.{ext}"
        las.write(str(path))
        files[f"points.{ext}"] = path
    return files


def loader_throughput(files: dict, repeat: int, conf: Path | None) -> list[dict]:
    import laspy
    import open3d as o3d

    from pointviz.io import load

    def read_bytes(paths):
        return sum(len(Path(p).read_bytes()) for p in paths)

    def other_reader(path):
        if path.suffix in (".las", ".laz"):
            return laspy.read(str(path), laz_backend=laspy.LazBackend.Lazrs)  # one thread
        return o3d.io.read_point_cloud(str(path))

    cases = [(name, [path], (lambda p=path: load(p, estimate=False)),
              (lambda p=path: other_reader(p))) for name, path in files.items()]
    if conf is not None:
        scans = [line.split()[1] for line in conf.read_text().splitlines()
                 if line.startswith("bmesh")]
        scan_paths = [conf.parent / s for s in scans]
        cases.append((f"{conf.name} ({len(scans)} ASCII PLY scans)", scan_paths,
                      lambda: load(conf, estimate=False),
                      lambda: [o3d.io.read_point_cloud(str(p)) for p in scan_paths]))
    rows = []
    for name, paths, ours, theirs in cases:
        size = sum(os.path.getsize(p) for p in paths)
        t = {"ours": [], "disk": [], "other": []}
        for _ in range(repeat):
            for key, fn in (("disk", lambda: read_bytes(paths)), ("ours", ours), ("other", theirs)):
                start = time.perf_counter()
                fn()
                t[key].append(time.perf_counter() - start)
        m = {k: median(v) for k, v in t.items()}
        rows.append({"file": name, "megabytes": size / 1e6, **{f"{k}_seconds": v for k, v in m.items()},
                     "ours_mb_s": size / 1e6 / m["ours"], "disk_mb_s": size / 1e6 / m["disk"],
                     "other_mb_s": size / 1e6 / m["other"]})
    return rows


def print_loaders(rows: list[dict]) -> None:
    print("\nLoaders: pointviz.load(estimate=False) against reading the same bytes and against "
          "Open3D (laspy single-threaded for LAS/LAZ)")
    print(f"  {'file':42s} {'MB':>7s} {'pointviz MB/s':>14s} {'bytes MB/s':>11s} "
          f"{'other MB/s':>11s} {'vs other':>9s}")
    for r in rows:
        print(f"  {r['file']:42s} {r['megabytes']:7.1f} {r['ours_mb_s']:14.0f} "
              f"{r['disk_mb_s']:11.0f} {r['other_mb_s']:11.0f} "
              f"{r['other_seconds'] / r['ours_seconds']:8.2f}x")


# ---------------------------------------------------------------------------------------------


def show(results: dict) -> None:
    """Print the tables of a results JSON."""
    for label, med in results.get("start_to_png", {}).items():
        print_start_to_png(label, med)
    if "frame" in results:
        print_frame(results["frame"])
    if "loaders" in results:
        print_loaders(results["loaders"])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", type=Path, default=common.default_data_dir(),
                   help="shared data folder (default: <repo>/../shared/data)")
    p.add_argument("--out", type=Path,
                   default=common.REPO_ROOT / "benchmarks" / "results" / "pipeline.json",
                   help="results JSON (default benchmarks/results/pipeline.json)")
    p.add_argument("--repeat", type=int, default=3, help="runs per measurement; medians kept")
    p.add_argument("--quick", action="store_true",
                   help="smoke run: small generated inputs, repeat 1, no dragon")
    p.add_argument("--only", choices=("start", "lidar", "frame", "loaders"), action="append",
                   help="run only these parts (repeatable)")
    p.add_argument("--show", type=Path, metavar="JSON",
                   help="print the tables of an earlier run's JSON instead of measuring")
    args = p.parse_args(argv)
    if args.show is not None:
        show(json.loads(args.show.read_text()))
        return 0
    parts = set(args.only or ("start", "lidar", "frame", "loaders"))
    repeat = 1 if args.quick else max(1, args.repeat)
    grid = 60 if args.quick else SCAN_GRID
    results: dict = {"quick": args.quick, "repeat": repeat}
    dragon = args.data / common.DRAGON_CONF
    dragon = dragon if dragon.is_file() and not args.quick else None
    with tempfile.TemporaryDirectory(prefix="pointviz_pipeline_") as tmp:
        tmp = Path(tmp)
        if "start" in parts:
            scans = sphere_scans(seed=15, grid=grid)
            npts = sum(len(s[0]) for s in scans)
            inputs = []
            if dragon is not None:
                inputs.append((f"dragon raw scans ({dragon.name}, 469k points, 15 ASCII PLY)",
                               dragon))
            for fmt in ("binary_little_endian", "ascii"):
                conf = write_conf(tmp / fmt, scans, fmt)
                inputs.append((f"noisy sphere scans ({SCANS} x {fmt} PLY, {npts:,} points)", conf))
            extra = ["--width", "64", "--height", "48"] if args.quick else []
            results["start_to_png"] = {}
            for label, conf in inputs:
                med = start_to_png(conf, tmp, repeat, extra)
                results["start_to_png"][label] = med
                print_start_to_png(label, med)
        if "lidar" in parts:
            extra = ["--width", "64", "--height", "48"] if args.quick else []
            results.setdefault("start_to_png", {})
            for rel, label in LIDAR_FILES:
                path = args.data / rel
                if not path.is_file():
                    print(f"\n{label}: {path} not found, skipped")
                    continue
                med = start_to_png(path, tmp, repeat, extra)
                results["start_to_png"][label] = med
                print_start_to_png(label, med)
        if "frame" in parts:
            large = 200_000 if args.quick else LARGE_SCENE
            results["frame"] = frame_cost(max(repeat, 5), large)
            print_frame(results["frame"])
        if "loaders" in parts:
            n = 20_000 if args.quick else LOADER_POINTS
            files = loader_files(tmp, n)
            rows = loader_throughput(files, repeat, dragon)
            results["loaders"] = rows
            print_loaders(rows)
    if not args.quick:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=1))
        print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
