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

Part 3 (``--cli``, the command as users run it): ``pointviz path INPUT orbit -o DIR`` in a fresh
process per run, for each scheduler mode of ``--cli-modes`` (alternated: every mode once, then
again, ``--cli-reps`` times), frame count of ``--cli-frames``, size of ``--cli-sizes`` and input of
``--cli-data`` (``dragon``: the raw scans with the default fit; ``dragon-nofit``: the same scans
as scanned; ``sphere1m``: a generated 1.2M-point sphere PLY with normals, ``--no-fit``). Per run:

* ``wall``   : the command's wall time (start-up, loading, normals/radii, rendering, exit);
* ``steady`` : frames/s once frames flow: the frames after the first fifth, from their files'
  modification times (so the cluster's start-up and per-worker tree builds are not in it);
* ``CPU s``  : user + system CPU time of the whole process tree (the processes it waited for);
* ``rss``    : peak resident memory of the whole process tree (the command, a LocalCluster's
  nanny and worker processes), the sum of RSS sampled every 50 ms (pages shared between
  processes are counted in each, as ``ps`` does);
* the 1-minute load average at the run's start and end, printed beside every figure.

A mode is ``default`` (no ``--scheduler``), ``serial``, ``local``, ``auto``, or any of those
prefixed ``main:`` to run main's build (``--main-bin``, e.g. ``/work/venvs/main/bin``) instead of this
one's. The frames of every run of one cell are checked byte-identical to the first run's.

Usage::

    python benchmarks/bench_paths.py                      # dragon scans if present, else demo
    python benchmarks/bench_paths.py --data demo --frames 12 --size 160x120   # quick
    python benchmarks/bench_paths.py --cli --cli-modes main:default,default \
        --cli-frames 25,100 --cli-sizes 320x240,640x480 --cli-data dragon,sphere1m
"""

from __future__ import annotations

import argparse
import os
import subprocess
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


def make_sphere_ply(path: Path, n: int) -> Path:
    """A binary PLY of ``n`` points on a unit sphere (Fibonacci lattice, 0.2 % radial noise)
    with outward normals: a large input whose loading is cheap, to time rendering at scale."""
    if path.is_file():
        return path
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    u = np.stack([r * np.cos(phi), z, r * np.sin(phi)], axis=1)
    rng = np.random.default_rng(7)
    pts = u * (1.0 + 0.002 * rng.standard_normal((n, 1)))
    rows = np.hstack([pts, u]).astype("<f4")
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\n"
              + "".join(f"property float {c}\n" for c in ("x", "y", "z", "nx", "ny", "nz"))
              + "end_header\n").encode()
    tmp = path.with_suffix(".part")
    with open(tmp, "wb") as f:
        f.write(header)
        f.write(rows.tobytes())
    tmp.rename(path)
    return path


def cli_input(name: str, work: Path) -> list[str]:
    """The command's input arguments for a ``--cli-data`` name."""
    conf = default_data_dir() / DRAGON_CONF
    if name == "dragon":
        return [str(conf)]
    if name == "dragon-nofit":
        return [str(conf), "--no-fit"]
    if name.startswith("sphere"):
        n = {"sphere1m": 1_200_000}.get(name) or int(float(name[len("sphere"):]))
        return [str(make_sphere_ply(work / f"sphere_{n}.ply", n)), "--no-fit"]
    raise SystemExit(f"--cli-data: unknown input {name!r}")


def load1() -> float:
    return os.getloadavg()[0]


def run_cli(exe: str, inputs: list[str], out: Path, frames: int, size: tuple[int, int],
            scheduler: str | None) -> dict:
    """One ``pointviz path`` run: wall, steady frames/s, peak RSS of the process tree."""
    import psutil

    w, h = size
    cmd = [exe, "path", *inputs, "orbit", "-o", str(out), "--width", str(w), "--height", str(h),
           "--fps", "30", "--orbit", repr((frames - 1) / 30.0)]  # n frames: both ends
    if scheduler is not None:
        cmd += ["--scheduler", scheduler]
    import resource

    load0 = load1()
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    peak = 0
    root = psutil.Process(proc.pid)
    while proc.poll() is None:
        try:
            procs = [root, *root.children(recursive=True)]
        except psutil.Error:
            procs = []
        total = 0
        for q in procs:
            try:
                total += q.memory_info().rss
            except psutil.Error:
                pass
        peak = max(peak, total)
        time.sleep(0.05)
    stdout, stderr = proc.communicate()
    wall = time.perf_counter() - t0
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{stderr[-2000:]}")
    files = sorted(out.glob("frame_*.png"))
    if len(files) != frames:
        raise SystemExit(f"{' '.join(cmd)}: {len(files)} frames, expected {frames}")
    times = sorted(f.stat().st_mtime for f in files)
    k = len(times) // 5
    span = times[-1] - times[k]
    steady = (len(times) - 1 - k) / span if span > 0 else float("nan")
    return {"wall": wall, "steady": steady, "rss": peak / 2**20, "cpu": cpu, "load0": load0,
            "load1": load1(), "files": files, "summary": stdout.strip().splitlines()[0]}


def cli_modes(args, work: Path) -> None:
    """Part 3: the CLI per mode, alternated (see the module's notes)."""
    here = Path(sys.executable).parent / "pointviz"
    modes = args.cli_modes
    print(f"\n## CLI: pointviz path INPUT orbit -o DIR; modes {modes} alternated, "
          f"{args.cli_reps} rounds; CLI defaults otherwise (spp, shadows, reflections)")
    print(f"{'data':14s} {'frames':>6s} {'size':>8s} {'mode':>14s} {'wall s':>7s} "
          f"{'steady f/s':>10s} {'CPU s':>7s} {'peak RSS MiB':>12s} {'load':>9s}")
    for data in args.cli_data:
        inputs = cli_input(data, work)
        for size in args.cli_sizes:
            for frames in args.cli_frames:
                rows: dict[str, list[dict]] = {m: [] for m in modes}
                first = None
                for rep in range(args.cli_reps):
                    order = modes if rep % 2 == 0 else modes[::-1]
                    for mode in order:
                        build, _, sched = mode.rpartition(":")
                        exe = (str(Path(args.main_bin) / "pointviz") if build == "main"
                               else str(here))
                        out = work / f"frames_{len(rows[mode])}_{mode.replace(':', '_')}"
                        if out.exists():
                            for f in out.iterdir():
                                f.unlink()
                        r = run_cli(exe, inputs, out, frames, size,
                                    None if sched == "default" else sched)
                        if first is None:
                            first = [f.read_bytes() for f in r["files"]]
                        same = sum(a == f.read_bytes() for a, f in zip(first, r["files"]))
                        r["same"] = same
                        rows[mode].append(r)
                        print(f"{data:14s} {frames:6d} {size[0]:>4d}x{size[1]:<3d} {mode:>14s} "
                              f"{r['wall']:7.2f} {r['steady']:10.2f} {r['cpu']:7.1f} "
                              f"{r['rss']:12.0f} "
                              f"{r['load0']:4.1f}-{r['load1']:.1f}"
                              + ("" if same == frames else f"  FRAMES DIFFER ({same}/{frames})"),
                              flush=True)
                base = modes[0]
                for mode in modes[1:]:
                    ratio = [m["wall"] / b["wall"] for b, m in zip(rows[base], rows[mode])]
                    print(f"{'':14s} {'':6s} {'':8s} wall {mode} / {base}: "
                          + " ".join(f"{x:.2f}" for x in ratio), flush=True)


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
    p.add_argument("--cli", action="store_true", help="only part 3: the command per scheduler mode")
    p.add_argument("--cli-modes", type=lambda t: t.split(","), default=["serial", "local"])
    p.add_argument("--cli-frames", type=lambda t: [int(v) for v in t.split(",")],
                   default=[25, 100, 300])
    p.add_argument("--cli-sizes", type=lambda t: [parse_size(v) for v in t.split(",")],
                   default=[(320, 240), (640, 480)])
    p.add_argument("--cli-data", type=lambda t: t.split(","), default=["dragon", "sphere1m"])
    p.add_argument("--cli-reps", type=int, default=2)
    p.add_argument("--main-bin", default="/work/venvs/main/bin",
                   help="bin folder of main's build, for modes prefixed main:")
    p.add_argument("--work", type=Path, default=None,
                   help="folder for the generated sphere and the frames (default: a temporary one)")
    args = p.parse_args(argv)
    if args.cli:
        if args.work is not None:
            args.work.mkdir(parents=True, exist_ok=True)
            cli_modes(args, args.work)
        else:
            with tempfile.TemporaryDirectory() as tmp:
                cli_modes(args, Path(tmp))
        return 0
    scene, label = load_scene(args.data)
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
