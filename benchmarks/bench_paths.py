"""Camera-path rendering: serial vs a 2-worker Dask LocalCluster, and LoD temporal flicker.

Part 1 (throughput): a ``--frames``-frame orbit rendered serially (one process, all cores as
threads) and on a LocalCluster of ``--workers`` processes (one thread each), same frames, same
settings, measured in the same run. Prints frames per second of both, their ratio, the cluster's
start-up share, and checks that the frames are byte-identical.

Part 2 (temporal stability): a slow orbit (``--step-deg`` degrees per frame, linear speed) rendered
with LoD on (``lod_pixels`` = 1) and off (0), same seed every frame. Measures, on the 8-bit sRGB
frames (units: 8-bit levels, mean over pixels and frames):

* ``d1``   = mean |I_t - I_{t-1}|: all temporal change (motion + flicker);
* ``hf``   = mean |I_t - (I_{t-1} + I_{t+1}) / 2|: the part that is not linear in time; smooth
  motion at constant speed nearly cancels, popping and flicker do not;
* ``pop``  = fraction of pixels with ``hf`` >= POP_LEVELS (a visible single-frame change);
* for the LoD error image E_t = I_on - I_off: mean |E_t| and its ``hf``.

LoD flicker is the LoD-on minus LoD-off difference of ``d1``/``hf``/``pop``, for each threshold of
``--lod-levels`` (1 px is the default threshold; 4 px exaggerates LoD to expose popping).

Usage::

    python benchmarks/bench_paths.py                      # dragon scans if present, else demo
    python benchmarks/bench_paths.py --data demo --frames 12 --size 160x120   # quick
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import DRAGON_CONF, default_data_dir

#: An hf of this many 8-bit levels in one frame is a visible pop (about 3 % of full scale).
POP_LEVELS = 8.0


def load_scene(name: str):
    """(scene, label): the registered dragon scans when available, else the built-in demo."""
    from pointviz.scene import Scene
    from pointviz.shapes import demo_scene

    conf = default_data_dir() / DRAGON_CONF
    if name == "dragon" and conf.is_file():
        import pointviz

        t0 = time.perf_counter()
        cloud = pointviz.load(conf)
        _ = cloud.normals, cloud.radii
        print(f"# dragon: {len(cloud.points):,} points from {conf.name} "
              f"({time.perf_counter() - t0:.1f} s to load, normals, radii)")
        return Scene([cloud]), f"dragon scans ({len(cloud.points):,} points)"
    if name == "dragon":
        print(f"# {conf} not found: using the demo scene")
    scene, _ = demo_scene()
    return scene, "demo scene (190k surfels)"


def parse_size(text: str) -> tuple[int, int]:
    w, h = text.lower().split("x")
    return int(w), int(h)


def throughput(scene, args, settings) -> None:
    from pointviz.path import CameraPath, render_path

    w, h = args.size
    path = CameraPath.orbit(scene, seconds=args.frames / 30.0, fps=30.0, width=w, height=h)
    cameras = path.cameras()[: args.frames]
    path = CameraPath(width=w, height=h, fps=30.0, easing="linear")
    for i, cam in enumerate(cameras):
        path.add(cam, time=i / 30.0)
    print(f"\n## throughput: {path.n_frames}-frame orbit, {w}x{h}, spp={settings['spp']}, "
          f"reflections={settings['reflections']}")
    with tempfile.TemporaryDirectory() as tmp:
        # warm-up: build the trees in this process so the serial time is rendering only
        t0 = time.perf_counter()
        scene.build()
        print(f"tree build (serial process): {time.perf_counter() - t0:.2f} s")
        serial = render_path(scene, path, Path(tmp) / "serial", progress=False, **settings)
        cluster = render_path(scene, path, Path(tmp) / "cluster", scheduler="local",
                              workers=args.workers, progress=False,
                              **{**settings, "threads": None})
        same = sum((Path(tmp) / "serial" / f.name).read_bytes() == f.read_bytes()
                   for f in (Path(tmp) / "cluster").glob("frame_*.png"))
    work = cluster["seconds"] - cluster["startup_seconds"]
    fps_serial = serial["fps"]
    fps_cluster = cluster["fps"]
    fps_cluster_warm = cluster["rendered"] / work
    print(f"serial ({settings['threads'] or 'all'} threads, 1 process): "
          f"{serial['seconds']:.2f} s, {fps_serial:.2f} frames/s")
    print(f"cluster ({cluster['workers']} processes x 1 thread): {cluster['seconds']:.2f} s "
          f"({cluster['startup_seconds']:.2f} s start-up + scatter; scene builds per worker "
          f"{sorted(cluster['scene_builds'].values())}), {fps_cluster:.2f} frames/s with start-up, "
          f"{fps_cluster_warm:.2f} frames/s without")
    print(f"ratio cluster/serial: {fps_cluster / fps_serial:.2f} with start-up, "
          f"{fps_cluster_warm / fps_serial:.2f} without")
    print(f"byte-identical frames: {same}/{path.n_frames}")


def temporal_metrics(frames: np.ndarray) -> dict:
    """d1, hf and pop of (n, h, w, 3) float frames (n >= 3)."""
    d1 = np.abs(np.diff(frames, axis=0)).mean()
    hf_px = np.abs(frames[1:-1] - 0.5 * (frames[:-2] + frames[2:])).mean(axis=3)
    return {"d1": float(d1), "hf": float(hf_px.mean()), "pop": float((hf_px >= POP_LEVELS).mean())}


def flicker(scene, args, settings) -> None:
    from pointviz.path import CameraPath
    from pointviz.rendering import render

    w, h = args.flicker_size
    n = args.flicker_frames
    per_rev = round(360.0 / args.step_deg)
    orbit = CameraPath.orbit(scene, seconds=float(per_rev), fps=1.0, width=w, height=h,
                             easing="linear")  # a keyframe on every frame: exactly step_deg apart
    cameras = orbit.cameras()[:n]
    print(f"\n## flicker: slow orbit {args.step_deg:g} deg/frame, {n} frames, {w}x{h}, "
          f"spp={settings['spp']}, same seed every frame (8-bit sRGB levels)")
    seqs = {}
    levels = sorted(set(args.lod_levels) | {0.0}, reverse=True)
    for lod in levels:
        name = "LoD off" if lod == 0 else f"LoD {lod:g} px"
        t0 = time.perf_counter()
        seqs[name] = np.stack([render(scene, c, **{**settings, "lod_pixels": lod}).to_srgb8()
                               for c in cameras]).astype(np.float64)
        print(f"{name}: rendered in {time.perf_counter() - t0:.1f} s")
    rows = {name: temporal_metrics(f) for name, f in seqs.items()}
    off = rows["LoD off"]
    print(f"{'':14s} {'d1':>7s} {'hf':>7s} {'pop>=8':>8s}   {'d1-off':>7s} {'hf-off':>7s} "
          f"{'pop-off':>8s}   {'mean|E|':>7s} {'hf(E)':>7s}")
    for name, m in rows.items():
        err = seqs[name] - seqs["LoD off"]
        err_hf = np.abs(err[1:-1] - 0.5 * (err[:-2] + err[2:])).mean()
        print(f"{name:14s} {m['d1']:7.3f} {m['hf']:7.3f} {100 * m['pop']:7.3f}%   "
              f"{m['d1'] - off['d1']:7.3f} {m['hf'] - off['hf']:7.3f} "
              f"{100 * (m['pop'] - off['pop']):7.3f}%   {np.abs(err).mean():7.3f} {err_hf:7.3f}")
    print("E = frame with LoD - frame without: mean|E| is the LoD error, hf(E) how much of it "
          "changes non-linearly from frame to frame (it also contains LoD-off's own shimmer).")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", choices=["dragon", "demo"], default="dragon")
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--size", type=parse_size, default=(320, 240), help="WxH of the throughput run")
    p.add_argument("--spp", type=int, default=2)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--threads", type=int, default=None, help="serial render threads (all cores)")
    p.add_argument("--step-deg", type=float, default=1.0)
    p.add_argument("--flicker-frames", type=int, default=24)
    p.add_argument("--flicker-size", type=parse_size, default=(320, 240))
    p.add_argument("--lod-levels", type=lambda t: [float(v) for v in t.split(",")],
                   default=[1.0, 4.0], help="LoD thresholds (pixels) compared with LoD off")
    p.add_argument("--skip-throughput", action="store_true")
    p.add_argument("--skip-flicker", action="store_true")
    args = p.parse_args(argv)
    scene, label = load_scene(args.data)
    import os

    print(f"# {label}; {os.cpu_count()} cores (shared machine: compare ratios, not absolutes)")
    settings = {"spp": args.spp, "reflections": 1, "shadows": True, "seed": 0,
                "threads": args.threads}
    if not args.skip_throughput:
        throughput(scene, args, settings)
    if not args.skip_flicker:
        flicker(scene, args, settings)
    return 0


if __name__ == "__main__":
    sys.exit(main())
