"""What one redraw of the viewer's splat preview costs on the software rasteriser, by point count,
shader, point size and window size (pure Open3D, no tracer).

Each configuration runs in its own process (Open3D's application initialises once per process): a
window whose SceneWidget shows N points on a sphere (the viewer's preview view: no antialiasing,
ambient occlusion or shadow maps; sun light, a ground quad) while the camera circles it, one new
camera per tick, for SECONDS. Measured: the gaps between tick events (the GUI thread draws the
window between two, so a gap is one redraw's wait), GUI round trips (a function queued for the
next tick every 20 ms from another thread, as the viewer's ``call(..., redraw=False)``), and the
process's CPU seconds per redraw (the GUI thread's and the rasteriser's threads' work together).

Run under Xvfb::

    xvfb-run -a -s "-screen 0 1600x1000x24" python benchmarks/o3d_preview_cost.py \
        --points 1000000 250000 100000 --shaders defaultLit defaultUnlit --point-sizes 3 6

Prints one JSON line per configuration: median / p95 / max tick gap and the gaps over 80 ms (with
their times), the longest round trip (also leaving out the first WARM_S), CPU per redraw in ms,
redraws per second, and the load average. Results: benchmarks/README.md, issue 17.
"""

from __future__ import annotations

import argparse
import collections
import itertools
import json
import os
import subprocess
import sys
import threading
import time

import numpy as np

#: Seconds after the first tick that the "after warm" figures leave out (the first draws compile
#: the shaders).
WARM_S = 1.0


def parse(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--points", type=int, nargs="+", default=[1_000_000, 250_000])
    p.add_argument("--shaders", nargs="+", default=["defaultLit", "defaultUnlit"])
    p.add_argument("--point-sizes", type=float, nargs="+", default=[3.0])
    p.add_argument("--sizes", nargs="+", default=["640x480"],
                   help="scene widget sizes WxH (the window adds nothing around it)")
    p.add_argument("--max-fps", type=float, nargs="+", default=[0.0],
                   help="redraws asked for per second at most (0: one per tick)")
    p.add_argument("--post", type=int, nargs="+", default=[1],
                   help="1: Open3D's post-processing on (the viewer's), 0: off")
    p.add_argument("--ground", type=int, nargs="+", default=[1], help="1: a ground quad, 0: none")
    p.add_argument("--seconds", type=float, default=3.0, help="orbit seconds per configuration")
    p.add_argument("--one", help=argparse.SUPPRESS)  # internal: run one configuration (JSON)
    return p.parse_args(argv)


def run_one(cfg: dict) -> dict:
    import open3d as o3d
    import open3d.visualization.gui as gui
    import open3d.visualization.rendering as rendering

    w, h = (int(v) for v in cfg["size"].split("x"))
    app = gui.Application.instance
    app.initialize()
    win = app.create_window("preview cost", w, h)
    sw = gui.SceneWidget()
    sw.scene = rendering.Open3DScene(win.renderer)
    sw.scene.set_background([0.82, 0.86, 0.92, 1.0])
    win.add_child(sw)
    win.set_on_layout(lambda ctx: setattr(sw, "frame", win.content_rect))
    view = sw.scene.view
    view.set_antialiasing(False)
    view.set_ambient_occlusion(False)
    view.set_shadowing(False)
    if not cfg["post"]:
        view.set_post_processing(False)
    rng = np.random.default_rng(1)
    n = cfg["points"]
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    pcd = o3d.geometry.PointCloud()
    pcd.points = o3d.utility.Vector3dVector(v)
    pcd.normals = o3d.utility.Vector3dVector(v)
    pcd.colors = o3d.utility.Vector3dVector(np.full((n, 3), 0.7))
    mat = rendering.MaterialRecord()
    mat.shader = cfg["shader"]
    mat.point_size = cfg["point_size"]
    sc = sw.scene
    sc.add_geometry("cloud", pcd, mat)
    verts = np.array([[-3, -3, -1.05], [3, -3, -1.05], [3, 3, -1.05], [-3, 3, -1.05]], float)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(verts),
                                     o3d.utility.Vector3iVector([[0, 1, 2], [0, 2, 3]]))
    mesh.compute_vertex_normals()
    mesh.triangle_uvs = o3d.utility.Vector2dVector(np.zeros((6, 2)))
    gm = rendering.MaterialRecord()
    gm.shader = "defaultLit"
    gm.base_color = [0.6, 0.6, 0.65, 1.0]
    gm.base_roughness = 0.9
    if cfg["ground"]:
        sc.add_geometry("ground", mesh, gm)
    d = np.array([0.3, -0.5, -0.8], np.float32)
    sc.set_lighting(sc.LightingProfile.NO_SHADOWS, d)
    sc.scene.set_sun_light(d, [1.0, 1.0, 1.0], 75000)
    sc.scene.enable_sun_light(True)
    sc.scene.set_indirect_light_intensity(15000)
    center = np.zeros(3)
    sw.setup_camera(40.0, o3d.geometry.AxisAlignedBoundingBox(-np.ones(3), np.ones(3)), center)

    queue: collections.deque = collections.deque()
    st = {"t0": None, "last": None, "gaps": [], "trips": [], "cpu0": None, "done": False}

    def probe():
        while not st["done"]:
            ev = threading.Event()
            t = time.monotonic()
            queue.append(ev.set)
            if not ev.wait(60):
                break
            if st["t0"] is not None and t >= st["t0"]:  # the window is up (not its startup)
                st["trips"].append((t - st["t0"], time.monotonic() - t))
            time.sleep(0.02)

    def on_tick():
        now = time.monotonic()
        while queue:
            queue.popleft()()
        if st["t0"] is None:
            st["t0"], st["cpu0"] = now, time.process_time()
            return True
        if st["last"] is not None:
            st["gaps"].append((st["last"] - st["t0"], now - st["last"]))
        st["last"] = now
        t = now - st["t0"]
        if cfg["max_fps"] and now - st.get("drawn", 0.0) < 1.0 / cfg["max_fps"]:
            return False
        st["drawn"] = now
        st["redraws"] = st.get("redraws", 0) + 1
        if t >= cfg["seconds"]:
            if not st["done"]:
                st["done"], st["cpu"] = True, time.process_time() - st["cpu0"]
                st["elapsed"] = t
                app.post_to_main_thread(win, win.close)
            return False
        ang = 2 * np.pi * t / 6.0
        sc.camera.look_at(center, [3.2 * np.cos(ang), 3.2 * np.sin(ang), 1.2], [0, 0, 1])
        return True

    win.set_on_tick_event(on_tick)
    threading.Thread(target=probe, daemon=True).start()
    app.run()
    at, g = (np.array(x) for x in zip(*st["gaps"]))
    g *= 1e3
    steady = g[at >= WARM_S]
    trip_at, trips = (np.array(x) for x in zip(*(st["trips"] or [(0.0, 0.0)])))
    trips *= 1e3
    return {**cfg, "ticks": len(g), "redraws": st["redraws"], "gap_median_ms": round(float(np.median(g)), 1),
            "gap_p95_ms": round(float(np.percentile(g, 95)), 1),
            "gap_max_ms": round(float(g.max()), 1),
            "gap_max_at_s": round(float(at[np.argmax(g)]), 2),
            "gap_max_after_warm_ms": round(float(steady.max()), 1) if len(steady) else None,
            "long_gaps": [[round(float(t), 2), round(float(x))] for t, x in zip(at, g) if x > 80],
            "round_trip_max_ms": round(float(trips.max()), 1),
            "round_trip_max_after_warm_ms": round(float(trips[trip_at >= WARM_S].max()), 1)
            if (trip_at >= WARM_S).any() else None,
            "cpu_per_redraw_ms": round(1e3 * st["cpu"] / max(st["redraws"], 1), 1),
            "redraws_per_s": round(st["redraws"] / st["elapsed"], 1),
            "loadavg": os.getloadavg()[0]}


def main(argv=None) -> int:
    a = parse(argv)
    if a.one:
        print("RESULT" + json.dumps(run_one(json.loads(a.one))), flush=True)
        os._exit(0)
    for n, shader, ps, size, fps, post, ground in itertools.product(
            a.points, a.shaders, a.point_sizes, a.sizes, a.max_fps, a.post, a.ground):
        cfg = {"points": n, "shader": shader, "point_size": ps, "size": size, "max_fps": fps,
               "post": post, "ground": ground, "seconds": a.seconds}
        out = subprocess.run([sys.executable, __file__, "--one", json.dumps(cfg)],
                             capture_output=True, text=True, timeout=600, check=False)
        lines = [x for x in out.stdout.splitlines() if x.startswith("RESULT")]
        print(lines[-1][len("RESULT"):] if lines else json.dumps({**cfg, "error":
                                                                 out.stderr[-500:]}),
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
