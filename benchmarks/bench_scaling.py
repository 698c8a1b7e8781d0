"""Scaling of pointviz with surfel count and threads, with Embree oriented discs alongside.

For each size (Armadillo surface-sampled, 0.1M .. 20M surfels; ``--max`` caps it) and each thread
count (1, 2): build time, memory (``scene.memory_bytes`` per surfel; the largest growth of this
process's resident set over a build, after returning freed heap to the OS; peak RSS) and the
throughput of the full-view 400x400 primary rays with the ``full`` variant (LoD from the camera),
next to Embree discs built and queried with the same threads (``rtcIntersect1`` per ray) on the
same surfels and rays. Builds and queries of the two engines are interleaved and repeated
``--repeat`` times (median), so the ratios compare runs made moments apart on this shared
machine. Times are wall clock (``--clock``); the process CPU time is recorded too.

``--whole-process`` measures what one machine holds instead: for each size a fresh process
samples a unit sphere (Fibonacci lattice, generated in chunks straight into the arrays a
``PointCloud`` keeps), frames it (``Camera.fit``), builds the ``full`` scene by wall clock from
the cloud handed over (``SurfelScene(consume_cloud=True)``: each array is freed once the build
has copied it), traces 400x400 primary rays, then renders a 640x480 frame of the scene with
``pointviz.render`` (the defaults: "auto" look, ground, shadows on; 1 spp); its peak resident set
(``VmHWM`` in /proc/self/status) over the surfel count is the whole process's bytes per surfel,
Python arrays, build temporaries and interpreter included. The render's own peak is read after
restarting VmHWM (``/proc/self/clear_refs``) just before it.

Examples
--------
python benchmarks/bench_scaling.py --quick
python benchmarks/bench_scaling.py --max 3e6
python benchmarks/bench_scaling.py            # up to 20M surfels (~15 min, ~8 GB)
python benchmarks/bench_scaling.py --whole-process --sizes 1e6,1e7,1e8 --threads-list 2
"""

from __future__ import annotations

import gc
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common
import paper_figures as pf

SIZES = (100_000, 300_000, 1_000_000, 3_000_000, 10_000_000, 20_000_000)
QUICK_SIZES = (5_000, 20_000)
THREADS = (1, 2)


def rss_bytes() -> int:
    """Current resident set size of this process (Linux /proc)."""
    import os

    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def trim_heap() -> None:
    """Return freed heap pages to the OS (glibc ``malloc_trim``), so RSS growth means new memory.

    Without it, a build reuses pages freed by the previous one and its RSS growth reads as zero.
    """
    import ctypes

    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc: RSS growth is then only an upper bound
        pass


def measure_size(model: pf.Model, args) -> dict:
    """Build and cast at every thread count, pointviz and Embree interleaved."""
    import pointviz

    px = pf.QUICK_PIXELS if args.quick else pf.PAPER_WIDTH
    cam = pf.fit_camera(model.cloud, px)
    rays = pf.rays64(cam)
    rays32 = common.as_float32(rays)
    rec = {"n": model.n, "threads": {}}
    for threads in args.threads_list:
        builds = {"pointviz": [], "embree discs": []}
        rss_growth, scene, discs = [], None, None
        for _ in range(args.build_repeat):
            scene = discs = None
            gc.collect()
            trim_heap()
            before = rss_bytes()
            start = time.perf_counter()
            scene = pointviz.SurfelScene(model.cloud, variant="full", threads=threads)
            builds["pointviz"].append(time.perf_counter() - start)
            rss_growth.append(rss_bytes() - before)
            discs, why = pf.embree_discs(model.cloud, threads)
            if discs is not None:
                builds["embree discs"].append(discs.build_seconds)
        calls = {"pointviz": lambda s=scene, t=threads: pf.core_cast(s, rays, cam.pixel_angle, t)}
        if discs is not None:
            calls["embree discs"] = lambda d=discs: d.intersect(rays32, mode=1)
        times = pf.interleaved(calls, args.repeat, args.clock)
        row = {"build_seconds": {k: float(np.median(v)) for k, v in builds.items() if v},
               "cast_seconds": {k: t["median"] for k, t in times.items()},
               "mrays": {k: len(rays) / t["median"] / 1e6 for k, t in times.items()},
               "cpu_seconds": {k: t["cpu_median"] for k, t in times.items()},
               "bytes_per_surfel": scene.memory_bytes / model.n,
               "rss_growth_per_surfel": float(np.max(rss_growth)) / model.n,
               "depth": scene.depth, "box_depth": scene.box_depth}
        if discs is not None:
            row["embree_bytes_per_surfel"] = (discs.scene_bytes + discs.input_bytes) / model.n
            row["cast_ratio"] = times["pointviz"]["median"] / times["embree discs"]["median"]
            row["build_ratio"] = row["build_seconds"]["pointviz"] / row["build_seconds"]["embree discs"]
            discs.close()
        else:
            row["embree_skipped"] = why
        rec["threads"][str(threads)] = row
        del scene, discs
    rec["peak_rss_bytes"] = common.peak_rss_bytes()
    return rec


#: Lattice points generated per chunk: bounds the float64 temporaries of the sampling.
SAMPLE_CHUNK = 1 << 22
#: Image of the whole-process runs (the paper's 400 x 400 primary rays).
WHOLE_PROCESS_PIXELS = 400
#: Frame of the whole-process runs' ``pointviz.render`` step (defaults, shadows on, 1 spp).
RENDER_SIZE = (640, 480)


def peak_rss_whole_process() -> int:
    """Peak resident set of this process so far (VmHWM), in bytes."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError("/proc/self/status has no VmHWM")


def reset_peak_rss() -> bool:
    """Restart VmHWM at the current resident set (Linux >= 4.0: ``clear_refs`` value 5), so the
    peak read next is that of the steps run since; False where the kernel refuses."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def sphere_cloud_chunked(n: int):
    """A unit sphere of ``n`` surfels (Fibonacci lattice), built chunk by chunk.

    Positions go straight into the float64 array the PointCloud keeps, normals (equal to the
    positions on a unit sphere) into its float32 array; radii are one constant.

    Returns
    -------
    PointCloud
    """
    import pointviz
    from pointviz.shapes import LATTICE_RADIUS_FACTOR

    points = np.empty((n, 3), np.float64)
    normals = np.empty((n, 3), np.float32)
    golden = np.pi * (1.0 + 5.0**0.5)
    for b in range(0, n, SAMPLE_CHUNK):
        i = np.arange(b, min(n, b + SAMPLE_CHUNK), dtype=np.float64) + 0.5
        z = 1.0 - 2.0 * i / n
        r = np.sqrt(1.0 - z * z)
        phi = golden * i
        points[b:b + len(i), 0] = r * np.cos(phi)
        points[b:b + len(i), 1] = r * np.sin(phi)
        points[b:b + len(i), 2] = z
        normals[b:b + len(i)] = points[b:b + len(i)]
    radii = np.full(n, LATTICE_RADIUS_FACTOR * np.sqrt(4 * np.pi / n), np.float32)
    return pointviz.PointCloud(points, normals=normals, radii=radii)


def one_process(n: int, threads: int) -> dict:
    """The measurement of one ``--whole-process`` size, in this (fresh) process."""
    import pointviz

    base = peak_rss_whole_process()
    start = time.perf_counter()
    cloud = sphere_cloud_chunked(n)
    sample_s = time.perf_counter() - start
    cam = pointviz.Camera.fit(cloud, width=WHOLE_PROCESS_PIXELS, height=WHOLE_PROCESS_PIXELS)
    render_cam = pointviz.Camera.fit(cloud, width=RENDER_SIZE[0], height=RENDER_SIZE[1])
    rays = np.asarray(cam.rays(), dtype=np.float32)
    start = time.perf_counter()
    scene = pointviz.SurfelScene(cloud, variant="full", threads=threads, consume_cloud=True)
    build_s = time.perf_counter() - start
    del cloud
    gc.collect()
    after_build = peak_rss_whole_process()
    best = float("inf")
    for _ in range(3):
        start = time.perf_counter()
        out = scene.cast_rays(rays, camera=cam, stats=False)
        best = min(best, time.perf_counter() - start)
    hit_fraction = float(np.isfinite(out["t_hit"]).mean())
    after_cast = peak_rss_whole_process()
    n_rays = len(rays)
    del out, rays
    gc.collect()
    reset = reset_peak_rss()
    start = time.perf_counter()
    frame = pointviz.render(scene, render_cam, shadows=True, spp=1, threads=threads)
    render_s = time.perf_counter() - start
    render_peak = peak_rss_whole_process()
    peak = max(render_peak, after_cast)
    return {"n": n, "threads": threads, "sample_s": sample_s, "build_s": build_s,
            "mrays": n_rays / best / 1e6,
            "hit_fraction": hit_fraction,
            "render_s": render_s, "render_object_fraction": float(frame.object_alpha.mean()),
            "peak_rss_cast_per_surfel": after_cast / n,
            "peak_rss_render_per_surfel": render_peak / n if reset else None,
            "memory_bytes_per_surfel": scene.memory_bytes / n,
            "peak_rss_bytes": peak, "peak_rss_per_surfel": peak / n,
            "peak_rss_build_per_surfel": after_build / n, "interpreter_rss_bytes": base}


def whole_process(sizes: list[int], threads_list: list[int], out: Path) -> int:
    """Run ``one_process`` in a fresh interpreter per size and thread count; print and save."""
    print(f"{'surfels':>13}{'thr':>4}{'sample s':>9}{'build s':>9}{'Mr/s':>8}{'render s':>9}"
          f"{'core B/s':>9}{'rndr B/s':>9}{'peak B/s':>9}{'peak GB':>8}")
    rows = []
    for n in sizes:
        for threads in threads_list:
            cmd = [sys.executable, __file__, "--one", str(n), "--threads-list", str(threads)]
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode != 0:
                print(f"{n:>13,}{threads:>4}  failed: {proc.stderr.strip().splitlines()[-1:]}")
                continue
            r = json.loads(proc.stdout.strip().splitlines()[-1])
            rows.append(r)
            render_peak = r["peak_rss_render_per_surfel"] or float("nan")
            print(f"{n:>13,}{threads:>4}{r['sample_s']:>9.1f}{r['build_s']:>9.1f}{r['mrays']:>8.2f}"
                  f"{r['render_s']:>9.1f}{r['memory_bytes_per_surfel']:>9.1f}{render_peak:>9.1f}"
                  f"{r['peak_rss_per_surfel']:>9.1f}"
                  f"{r['peak_rss_bytes'] / 2**30:>8.2f}", flush=True)
            pf.write_json(out, "scaling_whole_process.json",
                          {"benchmark": "scaling (whole process)", "machine": pf.machine_info(),
                           "date": time.strftime("%Y-%m-%dT%H:%M:%S"), "rows": rows})
    if rows:
        print(f"wrote {chart_whole_process(rows, out)}")
    return 0


def chart_whole_process(rows: list, out_dir: Path) -> Path:
    """Build time, bytes per surfel (core and whole-process peak) and Mrays/s against size."""
    plt = pf.pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(14, 3.6))
    for t in sorted({r["threads"] for r in rows}):
        sel = [r for r in rows if r["threads"] == t]
        n = [r["n"] for r in sel]
        axes[0].plot(n, [r["build_s"] for r in sel], "-o", ms=3, label=f"build, {t} thr")
        axes[1].plot(n, [r["peak_rss_per_surfel"] for r in sel], "-o", ms=3,
                     label=f"whole process peak (VmHWM), {t} thr")
        if all(r.get("peak_rss_render_per_surfel") for r in sel):
            axes[1].plot(n, [r["peak_rss_render_per_surfel"] for r in sel], ":^", ms=3,
                         label=f"peak during render(), {t} thr")
        axes[1].plot(n, [r["memory_bytes_per_surfel"] for r in sel], "--s", ms=3,
                     label="core (memory_bytes)")
        axes[2].plot(n, [r["mrays"] for r in sel], "-o", ms=3, label=f"{t} thr")
    px = WHOLE_PROCESS_PIXELS
    for ax, title in zip(axes, ("build time (s, wall)", "bytes / surfel",
                                f"primary Mrays/s ({px}x{px})")):
        ax.set_xscale("log")
        ax.set_xlabel("surfels")
        ax.set_title(title)
        ax.legend(fontsize=7)
    axes[0].set_yscale("log")
    fig.suptitle("One process per size: unit sphere sampled in chunks, full variant")
    return pf.save_figure(fig, out_dir, "scaling_whole_process.png")


def print_row(rec: dict) -> None:
    """One line per (size, threads)."""
    for t, r in rec["threads"].items():
        b, m = r["build_seconds"], r["mrays"]
        print(f"{rec['n']:>11,}{t:>4}{b['pointviz']:>9.2f}{b.get('embree discs', float('nan')):>9.2f}"
              f"{r['bytes_per_surfel']:>8.1f}{r.get('embree_bytes_per_surfel', float('nan')):>8.1f}"
              f"{r['rss_growth_per_surfel']:>9.1f}{m['pointviz']:>9.2f}"
              f"{m.get('embree discs', float('nan')):>9.2f}{r.get('cast_ratio', float('nan')):>8.2f}"
              f"{rec['peak_rss_bytes'] / 2**30:>8.2f}", flush=True)


def chart(rows: list, out_dir: Path) -> Path:
    """Build time, bytes/surfel and Mrays/s against size, one line per engine and thread count."""
    plt = pf.pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(14, 3.6))
    n = [r["n"] for r in rows]
    for t in rows[0]["threads"]:
        for eng, ls in (("pointviz", "-o"), ("embree discs", "--s")):
            if eng not in rows[0]["threads"][t]["mrays"]:
                continue
            lab = f"{eng}, {t} thr"
            axes[0].plot(n, [r["threads"][t]["build_seconds"][eng] for r in rows], ls, ms=3, label=lab)
            axes[2].plot(n, [r["threads"][t]["mrays"][eng] for r in rows], ls, ms=3, label=lab)
    t0 = next(iter(rows[0]["threads"]))
    axes[1].plot(n, [r["threads"][t0]["bytes_per_surfel"] for r in rows], "-o", ms=3,
                 label="pointviz (memory_bytes)")
    axes[1].plot(n, [r["threads"][t0]["rss_growth_per_surfel"] for r in rows], ":o", ms=3,
                 label="pointviz (RSS growth in build)")
    if "embree_bytes_per_surfel" in rows[0]["threads"][t0]:
        axes[1].plot(n, [r["threads"][t0]["embree_bytes_per_surfel"] for r in rows], "--s", ms=3,
                     label="embree discs (BVH + 28 B input)")
    for ax, title in zip(axes, ("build time (s)", "bytes / surfel", "primary Mrays/s (400x400)")):
        ax.set_xscale("log")
        ax.set_xlabel("surfels")
        ax.set_title(title)
        ax.legend(fontsize=7)
    axes[0].set_yscale("log")
    fig.suptitle("Scaling with surfel count and threads (Armadillo, full variant)")
    return pf.save_figure(fig, out_dir, "scaling.png")


def argparse_hidden() -> str:
    """Help text of the internal --one option (one size, in the child process)."""
    import argparse

    return argparse.SUPPRESS


def main(argv: list[str] | None = None) -> int:
    """Run the scaling sweep; print the table, write JSON and a PNG; return the exit code."""
    p = pf.base_parser(__doc__.split("\n\n")[0], "scaling")
    p.set_defaults(clock="wall")  # throughput with 2 threads is a wall-time figure
    p.add_argument("--max", type=float, default=max(SIZES), help="largest size (default 20M)")
    p.add_argument("--threads-list", default="1,2", help="thread counts (default 1,2)")
    p.add_argument("--build-repeat", type=int, default=2,
                   help="builds per engine and thread count, alternating (median)")
    p.add_argument("--whole-process", action="store_true",
                   help="peak RSS of a fresh process per size (sphere sampled in chunks)")
    p.add_argument("--sizes", default="1e6,1e7",
                   help="--whole-process sizes, comma separated (default %(default)s)")
    p.add_argument("--one", type=float, default=None, help=argparse_hidden())
    args = p.parse_args(argv)
    args.threads_list = [int(t) for t in args.threads_list.split(",") if t.strip()]
    if args.one is not None:
        print(json.dumps(one_process(int(args.one), args.threads_list[0])))
        return 0
    if args.whole_process:
        sizes = [int(float(v)) for v in args.sizes.split(",") if v.strip()]
        return whole_process(sizes, args.threads_list, args.out)
    sizes = QUICK_SIZES if args.quick else tuple(s for s in SIZES if s <= args.max)
    if args.quick:
        args.repeat = args.build_repeat = 1
    probe = common.probe_pointviz()
    if not probe.available:
        print(probe.reason)
        return 2
    result = {"benchmark": "scaling", "date": time.strftime("%Y-%m-%dT%H:%M:%S"),
              "machine": pf.machine_info(), "args": {k: str(v) for k, v in vars(args).items()},
              "notes": ("pointviz full variant, core cast of float64 rays; Embree discs "
                        "rtcIntersect1; medians of interleaved repeats; RSS growth = resident "
                        "set after minus before the pointviz build"),
              "sizes": []}
    print(f"{'surfels':>11}{'thr':>4}{'pv bld s':>9}{'em bld s':>9}{'pv B/s':>8}{'em B/s':>8}"
          f"{'RSS B/s':>9}{'pv Mr/s':>9}{'em Mr/s':>9}{'pv/em t':>8}{'peak GB':>8}")
    for n in sizes:
        try:
            model = pf.armadillo(args.data, n)
        except common.DataMissingError as exc:
            print(f"SKIP: {exc}")
            return 0
        rec = measure_size(model, args)
        print_row(rec)
        result["sizes"].append(rec)
        del model
        gc.collect()
        # Partial results survive a run stopped halfway through the big sizes.
        pf.write_json(args.out, "scaling.json", result)
    result["charts"] = [chart(result["sizes"], args.out).name] if result["sizes"] else []
    path = pf.write_json(args.out, "scaling.json", result)
    print(f"\nwrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
