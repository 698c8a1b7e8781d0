"""The live viewport (issue 17): frame rate while the camera orbits, samples after it stops.

Opens ``pointviz.view(live=True, orbit=SECONDS)`` in a subprocess on 1M surfels sampled from
Armadillo.ply over a mirror ground (the scene of benchmarks/bench_frame.py) with a 640x480
viewport, and reads the report: ``live_fps`` (ray-traced frames shown per second while the camera
moves), ``live_resolution`` (mean fraction of the viewport's pixels traced per moving frame),
``still_spp`` (samples per pixel 3 s after the camera stopped) and ``preview_fps`` (the splat
preview's own rate). A driver thread meanwhile times GUI-thread round trips from before the GUI
loop starts until the window closes (``viewer.call(..., redraw=False)``: a call that does not
itself redraw the window, as tests/test_viewer.py and bench_viewer.py time them; with
``redraw=True`` every probe redrew the window, which took 1.5 of the 3 s hold's CPU-seconds from the tracer). Anchors, measured in the same run and interleaved with the
viewer runs: a bare loop of ``render()`` calls on the same built scene (1 spp, shadows, one
reflection, all cores) at 640x480 and at 320x240 (1/4 of the pixels), at normal priority and
niced as the live view traces. Targets: live_fps >= 8 at
live_resolution >= 1/4, still_spp >= 16, every GUI round trip within 100 ms from the window's
first tick to its close (also reported: over the whole run, and from the first live frame on);
each round trip carries the window's phase, and the slow ones what the GUI thread did meanwhile
(pointviz.viewer.gui_trace). Printed ratios (what predicts an idle machine's figures
from a loaded one): live fps / the bare loop's fps at the same resolution (measured right after
each viewer run at the size its mean resolution traces), and still_spp / (3 s x the bare 640x480
fps); each also against the niced loop.

Run under a display: ``xvfb-run -a -s "-screen 0 1800x1000x24" python
benchmarks/bench_viewer_live.py [--rounds 2] [--orbit 6]``. Writes
benchmarks/results/viewer/live.json.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import common  # noqa: E402

SIZE = 1_000_000
WIDTH, HEIGHT = 640, 480
#: The issue's targets.
TARGET_FPS = 8.0
TARGET_RESOLUTION = 0.25
TARGET_STILL_SPP = 16
#: Seconds of bare render() calls per anchor measurement.
ANCHOR_SECONDS = 4.0
#: Seconds the camera holds still before still_spp is read (pointviz.viewer.o3d_live.HOLD_S).
HOLD_S = 3.0
#: Spacing of the GUI round trips timed from the window's start to its close, seconds.
CALL_SPACING_S = 0.05
#: The issue's "the GUI answers within 100 ms throughout", ms; judged from the window's first
#: tick (before it, the window is being built and shows nothing) to its close.
TARGET_GUI_MS = 100.0
#: Round trips at least this long are explained from the window's trace (what the GUI thread
#: did meanwhile), seconds.
SLOW_S = 0.08

SCENE = """
import sys
sys.path.insert(0, {here!r})
import paper_figures as pf
import pointviz
from pathlib import Path
model = pf.armadillo(Path({data!r}), {n})
scene = pointviz.Scene(model.cloud, ground="mirror")
"""

VIEWER = SCENE + """
import json, threading, time, traceback
from pointviz.viewer import worker
{setup}
lat, res = [], {{}}

def drive(v):
    # one GUI round trip every {spacing} s from before the loop starts until the window closes
    try:
        v.time_round_trips({spacing}, lat)
    except BaseException:
        if not v.closed:
            res["error"] = traceback.format_exc()

v = pointviz.view(scene, live=True, orbit={orbit}, width={w}, height={h}, threads={threads},
                  report="report.json", overwrite=True,
                  on_ready=lambda v: threading.Thread(target=drive, args=(v,), daemon=True).start())
rep = json.load(open("report.json"))
res.update({{k: rep.get(k) for k in ("live_fps", "live_resolution", "still_spp", "preview_fps")}})
res["still_shown"] = rep["live"].get("still_shown")
res["live"] = rep["live"]
tr = v.gui_trace
res["gui_round_trips"] = [[round(t - tr.t0, 4), round(d, 4), tr.phase_at(t - tr.t0)]
                          for t, d in lat]
res["gui_slow_round_trips"] = [tr.explain(t, d) for t, d in lat if d >= {slow}]
res["gui_trace"] = tr.to_dict()
print("RESULT" + json.dumps(res))
sys.stdout.flush()
import os; os._exit(0)
"""

ANCHOR = SCENE + """
import json, time
res = {{}}
for nice in (False, True):
    for w, h in {sizes}:
        cam = pointviz.Camera.fit(model.cloud, width=w, height=h)
        pointviz.render(scene, cam, spp=1, shadows=True, reflections=1)   # trees built, warm
        n, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < {seconds}:
            pointviz.render(scene, cam, spp=1, shadows=True, reflections=1, background=nice)
            n += 1
        res[f"{{w}}x{{h}}" + (" nice" if nice else "")] = n / (time.perf_counter() - t0)
print("RESULT" + json.dumps(res))
"""

#: Viewer variants: (name, tracer threads: 0 = all cores, -1 = all but one; setup code).
VARIANTS = (("nice, all cores", 0, ""), ("nice, cores-1", -1, ""))


def num(x, digits: int = 2) -> str:
    """``x`` printed with ``digits`` decimals; "n/a" for None (a run that did not finish)."""
    return "n/a" if x is None else f"{x:.{digits}f}"


def live_size(fraction: float) -> tuple[int, int]:
    """The frame size the live view traces at ``fraction`` of the viewport's pixels."""
    from pointviz.viewer.live import scaled_camera
    from pointviz import Camera

    cam = scaled_camera(Camera((0, 0, 1), (0, 0, 0), width=WIDTH, height=HEIGHT), fraction)
    return cam.width, cam.height


def gui_latency(res: dict) -> dict:
    """Round-trip statistics (ms) over the spans the target is judged on: the whole run (from
    before the GUI loop starts), from the window's first tick (it is up and answering: the
    target's span), and from the first live frame on."""
    trips = res["gui_round_trips"]
    phases = dict((p, t) for t, p in res["gui_trace"]["phases"] + res["gui_trace"]["events"])
    out = {"gui_calls": len(trips)}
    for key, since in (("all", None), ("from_first_tick", phases.get("first tick")),
                       ("from_first_live_frame", phases.get("first live frame"))):
        ms = np.array([d for t, d, _ in trips if since is None or t >= since]) * 1e3
        out[f"gui_{key}"] = ({"calls": len(ms), "p95_ms": float(np.percentile(ms, 95)),
                              "p99_ms": float(np.percentile(ms, 99)), "max_ms": float(ms.max())}
                             if len(ms) else None)
    target = out["gui_from_first_tick"] or {}
    out["gui_p95_ms"], out["gui_max_ms"] = target.get("p95_ms"), target.get("max_ms")
    out["gui_meets_target"] = bool(target) and target["max_ms"] <= TARGET_GUI_MS
    return out


def anchor(fmt: dict, work: Path, sizes) -> dict:
    """The bare render() loop's fps at ``sizes``, normal priority and niced ("WxH nice")."""
    res = run_script(ANCHOR.format(**fmt, seconds=ANCHOR_SECONDS, sizes=tuple(sizes)), work)
    res["load_average"] = os.getloadavg()[0]
    print("anchor: bare render() loop", {k: round(v, 2) for k, v in res.items()}, "fps",
          flush=True)
    return res


def run_script(script: str, cwd: Path, env=None) -> dict:
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         timeout=1800, check=False, cwd=cwd, env={**os.environ, **(env or {})})
    lines = [x for x in out.stdout.splitlines() if x.startswith("RESULT")]
    if not lines:
        raise RuntimeError(f"run failed ({out.returncode}):\n{out.stderr[-3000:]}")
    res = json.loads(lines[-1][len("RESULT"):])
    if "error" in res:
        raise RuntimeError(res["error"])
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=1, help="interleaved rounds")
    ap.add_argument("--orbit", type=float, default=6.0, help="orbit seconds (default 6)")
    ap.add_argument("--all-cores-only", action="store_true",
                    help="only the all-cores viewer variant (half the run time)")
    ap.add_argument("--size", type=float, default=SIZE, help="surfels (default 1e6)")
    ap.add_argument("--data", type=Path, default=common.default_data_dir())
    ap.add_argument("--out", type=Path, default=HERE / "results" / "viewer" / "live.json")
    args = ap.parse_args(argv)
    if not os.environ.get("DISPLAY"):
        print("bench_viewer_live: no X display; run it under xvfb-run -a", file=sys.stderr)
        return 2
    if not (args.data / common.ARMADILLO_MESH).exists():
        print(f"SKIP: {args.data / common.ARMADILLO_MESH} not found")
        return 0
    n = int(args.size)
    work = Path(os.environ.get("TMPDIR", "/tmp")) / f"bench_viewer_live_{os.getpid()}"
    work.mkdir(parents=True, exist_ok=True)
    cores = os.cpu_count() or 1
    fmt = dict(here=str(HERE), data=str(args.data), n=n, w=WIDTH, h=HEIGHT)
    rows, anchors = [], []
    for _ in range(args.rounds):
        anchors.append(anchor(fmt, work, ((WIDTH, HEIGHT), (WIDTH // 2, HEIGHT // 2))))
        for name, threads, setup in VARIANTS[:1] if args.all_cores_only else VARIANTS:
            t = cores if threads == 0 else max(1, cores + threads)
            load0 = os.getloadavg()[0]
            res = run_script(VIEWER.format(**fmt, setup=setup, spacing=CALL_SPACING_S,
                                           orbit=args.orbit, threads=t, slow=SLOW_S), work)
            row = {"variant": name, "threads": t, **res, **gui_latency(res),
                   "load_average_before": load0, "load_average": os.getloadavg()[0]}
            if row["live_resolution"] is not None:  # the bare loop at the same resolution
                w, h = live_size(row["live_resolution"])
                same = anchor(fmt, work, ((w, h),))
                row["bare_fps_at_live_resolution"] = same[f"{w}x{h}"]
                row["bare_nice_fps_at_live_resolution"] = same[f"{w}x{h} nice"]
            rows.append(row)
            print(f"{name:16s} live_fps {num(row['live_fps'])} at {num(row['live_resolution'])} "
                  f"of the pixels, still_spp {row['still_spp']}, preview_fps "
                  f"{num(row['preview_fps'], 1)}, GUI calls from the first tick p95 "
                  f"{num(row['gui_p95_ms'], 0)} ms max {num(row['gui_max_ms'], 0)} ms (whole "
                  f"run max {num((row['gui_all'] or {}).get('max_ms'), 0)}, from the first live "
                  f"frame {num((row['gui_from_first_live_frame'] or {}).get('max_ms'), 0)}), "
                  f"load {row['load_average']:.1f}", flush=True)
            for e in row["gui_slow_round_trips"]:
                print(f"{'':16s} slow round trip at {e['t']:.2f} s ({e['phase']}): "
                      f"{e['seconds'] * 1e3:.0f} ms, untraced {e['untraced_s'] * 1e3:.0f} ms, "
                      f"spans {e['spans'][:3]}", flush=True)
    full = float(np.median([a[f"{WIDTH}x{HEIGHT}"] for a in anchors]))
    quarter = float(np.median([a[f"{WIDTH // 2}x{HEIGHT // 2}"] for a in anchors]))
    # the same loop at the live view's priority (nice, as the viewer traces): on a loaded
    # machine the priority, not the viewer, decides most of the difference
    full_nice = float(np.median([a[f"{WIDTH}x{HEIGHT} nice"] for a in anchors]))
    quarter_nice = float(np.median([a[f"{WIDTH // 2}x{HEIGHT // 2} nice"] for a in anchors]))
    for r in rows:
        if r["live_fps"] is None or r["live_resolution"] is None:  # the orbit did not finish
            r["meets_targets"] = False
            continue
        r["fps_ratio_to_bare_quarter"] = r["live_fps"] / quarter
        r["fps_ratio_to_bare_same_resolution"] = r["live_fps"] / r["bare_fps_at_live_resolution"]
        r["still_spp_ratio_to_bare"] = r["still_spp"] / (HOLD_S * full)
        r["fps_ratio_to_bare_nice_same_resolution"] = (r["live_fps"]
                                                       / r["bare_nice_fps_at_live_resolution"])
        r["still_spp_ratio_to_bare_nice"] = r["still_spp"] / (HOLD_S * full_nice)
        r["meets_targets"] = bool(r["live_fps"] >= TARGET_FPS
                                  and r["live_resolution"] >= TARGET_RESOLUTION
                                  and r["still_spp"] >= TARGET_STILL_SPP)
    doc = {"benchmark": "viewer_live", "date": time.strftime("%Y-%m-%dT%H:%M:%S"),
           "surfels": n, "viewport": [WIDTH, HEIGHT], "orbit_s": args.orbit, "cpu_count": cores,
           "anchor_fps": {"full": full, "quarter": quarter, "full_nice": full_nice,
                          "quarter_nice": quarter_nice, "runs": anchors},
           "targets": {"live_fps": TARGET_FPS, "live_resolution": TARGET_RESOLUTION,
                       "still_spp": TARGET_STILL_SPP, "gui_max_ms_from_first_tick": TARGET_GUI_MS},
           "rows": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".tmp")
    tmp.write_text(json.dumps(doc, indent=1))
    tmp.replace(args.out)
    print(f"\nanchor (bare render loop): {full:.2f} fps at {WIDTH}x{HEIGHT}, {quarter:.2f} fps "
          f"at {WIDTH // 2}x{HEIGHT // 2}; nice: {full_nice:.2f} and {quarter_nice:.2f}")
    for r in rows:
        if "fps_ratio_to_bare_quarter" not in r:
            print(f"{r['variant']:16s} no live frame rate: the scripted orbit did not finish "
                  f"(report: {r['live']})")
            continue
        print(f"{r['variant']:16s} live_fps {r['live_fps']:.2f} ({r['fps_ratio_to_bare_quarter']:.2f}x "
              f"the bare 1/4-pixel loop; {r['fps_ratio_to_bare_same_resolution']:.2f}x the bare "
              f"loop's {r['bare_fps_at_live_resolution']:.2f} fps at the same resolution) at "
              f"{r['live_resolution']:.2f}, still_spp {r['still_spp']} "
              f"({r['still_spp_ratio_to_bare']:.2f}x the {HOLD_S:.0f} s x bare {WIDTH}x{HEIGHT} fps "
              f"= {HOLD_S * full:.1f} samples), load {r['load_average']:.1f}, targets "
              f"{'met' if r['meets_targets'] else 'NOT met'}")
        print(f"{'':16s} against the nice bare loop: fps ratio "
              f"{r['fps_ratio_to_bare_nice_same_resolution']:.2f}, still_spp ratio "
              f"{r['still_spp_ratio_to_bare_nice']:.2f}")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
