"""What the Open3D viewer's Up control costs: the GUI thread's time for one up change (the scene
seen anew with its trees shared, the camera fitted, the preview's colours and ground redone), next
to what the alternative costs in the same run: loading the file again and opening a new window
(``pointviz view F --up z``) until its first preview.

For each input the script opens the viewer in a subprocess, waits for the first preview, then
picks each of the Up control's axes in turn (+Z, -X, +X, -Z, -Y, +Y, then +Z again: the ground
level along an up is computed once, so the second +Z is the repeat cost), timing each change on
the GUI thread (``viewer.timings["up_changes"]``), and once renders the view after it.

Inputs: Lucy and the Cyberware horse from the shared data (z-up files that open lying down), and
a generated z-up box of 1M surfels (no scan of the shared data has 1M points).

Run under a display: ``xvfb-run -a -s "-screen 0 1600x1000x24" python benchmarks/bench_viewer_up.py``
(``--docs docs/viewer_up.png`` also writes Lucy's before/after picture). Writes
benchmarks/results/viewer/up.json and prints a table with the load average.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from common import default_data_dir  # noqa: E402

#: The order the Up control is driven in (the last repeats the first: the cached cost).
SEQUENCE = ("+Z", "-X", "+X", "-Z", "-Y", "+Y", "+Z")
#: Points of the generated box.
BOX_POINTS = 1_000_000
INPUTS = (("Lucy", "stanford_lucy/lucy_vtk_decimated.ply"),
          ("horse", "misc_scans/horse_cyberware.ply"),
          ("box 1M (generated)", None))

DRIVER = r"""
import json, os, sys, threading, time, traceback
import numpy as np
t0 = time.monotonic()
import pointviz
path, docs = {path!r}, {docs!r}
if path is None:
    from pointviz.cloud import PointCloud
    from pointviz.shapes import box
    b = box({points}, size=(0.5, 0.5, 2.5))
    cloud = PointCloud(np.asarray(b.points), normals=b.normals, radii=b.radii)
else:
    cloud = pointviz.load(path)
    _ = cloud.normals, cloud.radii
load_s = time.monotonic() - t0
res = {{"load_s": load_s, "points": len(cloud.points)}}

def grab(v, panel):
    v.call(v.preview.force_redraw)
    time.sleep(1.0)
    x, y, w, h = v.call(v.widget_rects, redraw=False)[panel]
    return v.screenshot()[y:y + h, x:x + w]

def drive(v):
    try:
        while v.call(lambda: "first_preview_s" not in v.timings, redraw=False):
            time.sleep(0.05)
        shots = [grab(v, "preview")] if docs else []
        for label in {sequence!r}:
            def pick(label=label):
                v.cmb_up.selected_text = label
                v._on_up_selected(v.cmb_up.selected_text, v.cmb_up.selected_index)
            v.call(pick)
            if docs and label == "+Z" and len(shots) == 1:
                shots.append(grab(v, "preview"))
                v.call(v._on_render)
                while v.call(lambda: v.frame is None, redraw=False):
                    time.sleep(0.1)
                shots.append(grab(v, "result"))
        if docs:
            h = min(s.shape[0] for s in shots)
            gap = np.full((h, 6, 3), 255, np.uint8)
            row = [shots[0][:h], gap, shots[1][:h], gap, shots[2][:h]]
            from PIL import Image  # 720 px wide, 96 colours: a small picture for the README
            im = Image.fromarray(np.ascontiguousarray(np.concatenate(row, axis=1)))
            im = im.resize((720, round(im.height * 720 / im.width)), Image.LANCZOS)
            im.quantize(colors=96, method=Image.Quantize.MEDIANCUT,
                        dither=Image.Dither.NONE).save(docs, optimize=True)
        res["timings"] = v.call(lambda: dict(v.timings), redraw=False)
    except BaseException:
        res["error"] = traceback.format_exc()
    v.app.post_to_main_thread(v.window, v.window.close)

pointviz.view(cloud, spp=2, on_ready=lambda v: threading.Thread(target=drive, args=(v,), daemon=True).start(),
              window_size=(1100, 520) if docs else None)
print("RESULT" + json.dumps(res, default=float))
sys.stdout.flush(); os._exit(0)
"""


def run_one(path, docs):
    script = DRIVER.format(path=None if path is None else str(path), docs=docs,
                           points=BOX_POINTS, sequence=SEQUENCE)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         timeout=1800, check=False)
    lines = [x for x in out.stdout.splitlines() if x.startswith("RESULT")]
    if out.returncode != 0 or not lines:
        raise RuntimeError(f"viewer failed ({out.returncode}): {out.stderr[-2000:]}")
    res = json.loads(lines[-1][len("RESULT"):])
    if "error" in res:
        raise RuntimeError(res["error"])
    return res


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, default=default_data_dir())
    p.add_argument("--docs", help="write Lucy's before/after picture here (PNG)")
    p.add_argument("--out", type=Path, default=HERE / "results" / "viewer" / "up.json")
    args = p.parse_args()
    rows = []
    for name, rel in INPUTS:
        path = None if rel is None else args.data / rel
        if path is not None and not path.exists():
            print(f"{name}: {path} absent, skipped")
            continue
        load = os.getloadavg()
        res = run_one(path, args.docs if name == "Lucy" else None)
        t = res["timings"]
        changes = [c["seconds"] for c in t["up_changes"]]
        reopen = res["load_s"] + t["first_preview_s"]
        rows.append({"input": name, "points": res["points"], "load_avg": [round(x, 2) for x in load],
                     "up_change_s": changes, "load_s": res["load_s"],
                     "first_preview_s": t["first_preview_s"], "reopen_s": reopen})
        print(f"{name:20s} {res['points']:>9,} pts  up change: first {changes[0] * 1e3:6.0f} ms, "
              f"median {sorted(changes)[len(changes) // 2] * 1e3:6.0f} ms, repeat (+Z again) "
              f"{changes[-1] * 1e3:6.0f} ms | reopen (load + first preview) {reopen:5.2f} s "
              f"({reopen / max(changes):.0f}x the slowest change) | load avg "
              f"{load[0]:.2f} {load[1]:.2f}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(rows, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
