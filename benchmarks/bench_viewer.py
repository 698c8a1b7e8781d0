"""GUI-call latency of the Open3D viewer while it ray traces, idle and with every core busy.

For each way of running the tracer next to the GUI (normal priority on all cores; lower
priority, ``render(background=True)``; all cores but one; both), the script opens the viewer in
a subprocess on the Dragon scans (or a generated sphere without the shared data), presses
Render, waits for the first progress report, then times CALLS round trips of ``viewer.call``
(a function run on the GUI thread, what every button and every progress report needs) while
the render runs. It does so on an idle machine and while LOAD_PROCESSES processes each keep a
core busy. All variants run in the same session, interleaved, so that their ratios hold
although wall times on a shared machine do not.

Run under a display: ``xvfb-run -a python benchmarks/bench_viewer.py [--rounds 2]``.
Writes benchmarks/results/viewer/viewer.json and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from common import DRAGON_CONF, default_data_dir  # noqa: E402

#: Round trips timed per run; one every CALL_SPACING_S, so that the run spans several seconds
#: of the render (tiles, progress reports and redraws all happen meanwhile).
CALLS = 60
CALL_SPACING_S = 0.05
#: Busy-loop processes of the "loaded" condition: one per core of the 2-core reference machine.
LOAD_PROCESSES = 2
#: The target: a GUI call answered within this many seconds during any render.
TARGET_S = 0.100
#: A call not answered within this many seconds is recorded as taking this long.
CALL_TIMEOUT_S = 30.0
#: Variants: (name, render at lower priority, tracer threads: 0 = all cores, -1 = all but one,
#: None = no render at all: the anchor, what the GUI costs by itself on this machine).
#: A variant's optional fourth entry is Python run in the viewer process before the window opens
#: (to switch one suspect off), the fifth extra environment variables.
VARIANTS = (("normal, all cores", False, 0), ("nice, all cores", True, 0),
            ("normal, cores-1", False, -1), ("nice, cores-1", True, -1),
            ("nice, cores-1, progress redraws 10x rarer", True, -1,
             "worker.PROGRESS_INTERVAL_S = 10 * worker.PROGRESS_INTERVAL_S"),
            ("nice, cores-1, LP_NUM_THREADS=1", True, -1, "", {"LP_NUM_THREADS": "1"}),
            ("nice, cores-1, switchinterval 1ms", True, -1, "sys.setswitchinterval(0.001)"),
            ("nice, cores-1, calls redraw the window", True, -1, "REDRAW = True"),
            ("no render (anchor)", True, None))

DRIVER = """
import json, sys, threading, time, traceback
import numpy as np
import pointviz
from pointviz.viewer import worker
worker.RENDER_IN_BACKGROUND = {background}
REDRAW = False  # the timed calls change nothing on screen: no redraw of the window for them
{setup}
{load_cloud}
res = {{}}

def drive(v):
    try:
        v.call(lambda: None, timeout=600)              # the loop runs (first draw done)
        if {render}:
            v.call(v._on_render, timeout=600)
            deadline = time.monotonic() + 600
            while v.call(lambda: v.progress.value, timeout=600, redraw=False) <= 0:  # first report
                assert time.monotonic() < deadline, "no progress report"
        lat, wait = [], []
        for _ in range({calls}):
            box = {{}}
            t = time.perf_counter()
            try:
                v.call(lambda: box.setdefault("ran", time.perf_counter()), timeout={timeout},
                       redraw=REDRAW)
            except TimeoutError:                       # counted as the timeout, not dropped
                pass
            lat.append(time.perf_counter() - t)
            wait.append(box.get("ran", t + {timeout}) - t)  # posted -> running on the GUI thread
            time.sleep({spacing})
        res["running"] = v.worker.running or not {render}
        res["latency_s"] = lat
        res["wait_s"] = wait
    except BaseException:
        res["error"] = traceback.format_exc()
    finally:
        v.app.post_to_main_thread(v.window, v.window.close)

pointviz.view(cloud, spp=4096, width=640, height=480, threads={threads},
              on_ready=lambda v: threading.Thread(target=drive, args=(v,), daemon=True).start())
print("RESULT" + json.dumps(res))
sys.stdout.flush()
import os; os._exit(0)
"""

DRAGON = """
from pointviz.io import load
cloud = load({path!r})
"""
SPHERE = """
from pointviz.shapes import sphere
cloud = sphere(200000, color=(0.8, 0.35, 0.2))
"""


def run_variant(background: bool, threads: int, load_cloud: str, setup: str = "",
                env: dict | None = None) -> dict:
    n = os.cpu_count() or 1
    t = n if threads == 0 else max(1, n - 1)  # explicit: the viewer's default is cores-1
    script = DRIVER.format(background=background, load_cloud=textwrap.dedent(load_cloud),
                           calls=CALLS, spacing=CALL_SPACING_S, threads=t, timeout=CALL_TIMEOUT_S,
                           render=threads is not None, setup=setup)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         timeout=900, check=False, env={**os.environ, **(env or {})})
    lines = [x for x in out.stdout.splitlines() if x.startswith("RESULT")]
    if not lines:
        raise RuntimeError(f"viewer run failed ({out.returncode}):\n{out.stderr[-3000:]}")
    res = json.loads(lines[-1][len("RESULT"):])
    if "error" in res:
        raise RuntimeError(res["error"])
    if not res["running"]:
        raise RuntimeError("the render ended before the measurement did")
    return res


def busy_processes(n: int):
    return [subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(n)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=1, help="interleaved rounds of every variant")
    ap.add_argument("--data", type=Path, default=default_data_dir())
    ap.add_argument("--out", type=Path, default=HERE / "results" / "viewer" / "viewer.json")
    ap.add_argument("--only", action="append", metavar="TEXT",
                    help="run only the variants whose name contains TEXT (repeatable; the "
                         "first variant, the ratios' base, always runs)")
    args = ap.parse_args(argv)
    if not os.environ.get("DISPLAY"):
        print("bench_viewer: no X display; run it under xvfb-run -a", file=sys.stderr)
        return 2
    dragon = args.data / DRAGON_CONF
    load_cloud = DRAGON.format(path=str(dragon)) if dragon.exists() else SPHERE
    data_name = "dragon scans (dragonStandRight.conf)" if dragon.exists() else "sphere(200000)"
    selected = [v for i, v in enumerate(VARIANTS)
                if i == 0 or not args.only or any(t in v[0] for t in args.only)]
    if args.only and any(t == v[0] for t in args.only for v in VARIANTS):  # exact names
        selected = [v for i, v in enumerate(VARIANTS) if i == 0 or v[0] in args.only]
    samples: dict = {}
    waits: dict = {}
    loads: dict = {}
    for _ in range(args.rounds):
        for condition in ("idle", "loaded"):
            load = busy_processes(LOAD_PROCESSES) if condition == "loaded" else []
            try:
                for name, background, threads, *extra in selected:
                    res = run_variant(background, threads, load_cloud, *extra)
                    samples.setdefault((condition, name), []).extend(res["latency_s"])
                    waits.setdefault((condition, name), []).extend(res["wait_s"])
                    loads.setdefault((condition, name), []).append(os.getloadavg()[0])
                    lat = np.array(res["latency_s"]) * 1e3
                    print(f"{condition:6s} {name:40s} median {np.median(lat):6.1f} ms  "
                          f"p95 {np.percentile(lat, 95):6.1f} ms  max {lat.max():6.1f} ms  "
                          f"(load {os.getloadavg()[0]:.1f})", flush=True)
            finally:
                for p in load:
                    p.kill()
                    p.wait()
    rows = []
    for (condition, name), lat in samples.items():
        a = np.array(lat)
        w = np.array(waits[condition, name])
        rows.append({"condition": condition, "variant": name, "calls": len(a),
                     "wait_p95_s": float(np.percentile(w, 95)), "wait_max_s": float(w.max()),
                     "load_average_1min": float(np.mean(loads[condition, name])),
                     "median_s": float(np.median(a)), "p95_s": float(np.percentile(a, 95)),
                     "max_s": float(a.max()), "within_target": float(np.mean(a <= TARGET_S))})
    base = {r["condition"]: r for r in rows if r["variant"] == VARIANTS[0][0]}
    for r in rows:
        r["p95_ratio_to_normal_all_cores"] = r["p95_s"] / base[r["condition"]]["p95_s"]
    doc = {"data": data_name, "cpu_count": os.cpu_count(), "calls_per_run": CALLS,
           "rounds": args.rounds, "load_processes": LOAD_PROCESSES, "target_s": TARGET_S,
           "rows": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1))
    print(f"\n{data_name}, {os.cpu_count()} cores, {CALLS * args.rounds} calls per cell")
    print("round trip (post, run on the GUI thread, caller woken); wait: post -> run")
    print(f"{'condition':9s} {'variant':40s} {'median':>8s} {'p95':>8s} {'max':>8s} "
          f"{'<=100ms':>8s} {'p95/normal':>10s} {'wait p95':>9s} {'wait max':>9s} {'load':>5s}")
    for r in rows:
        print(f"{r['condition']:9s} {r['variant']:40s} {r['median_s'] * 1e3:7.1f}m "
              f"{r['p95_s'] * 1e3:7.1f}m {r['max_s'] * 1e3:7.1f}m {r['within_target']:8.0%} "
              f"{r['p95_ratio_to_normal_all_cores']:10.2f} {r['wait_p95_s'] * 1e3:8.1f}m "
              f"{r['wait_max_s'] * 1e3:8.1f}m {r['load_average_1min']:5.1f}")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
