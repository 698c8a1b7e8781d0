"""Minimal reproduction of the viewer's GUI stall when live mode comes on (pure Open3D, no tracer).

A window with a SceneWidget showing an N-point cloud (defaultLit points, sun light, a ground quad,
like the viewer's splat preview) first orbits for PREVIEW seconds; then it makes the calls the
viewer's live mode makes (hide cloud and ground, scene caching off, force_redraw) and shows a
synthetic "live frame" as the scene's background image at ~10 Hz for LIVE seconds, each frame a
new size (the live view's adaptive resolution) unless ``--fixed-size``. The GUI thread's blocking
is measured as the gaps between consecutive tick events (each window draw happens between two).

Run under Xvfb::

    xvfb-run -a -s "-screen 0 1600x1000x24" python benchmarks/o3d_live_stall.py --points 1000000

Prints one JSON line: the longest gap before and after live mode came on, when the longest one
after it started (seconds after live on), and the variant's switches.
"""

from __future__ import annotations

import argparse
import json
import os
import threading
import time

import numpy as np


def parse():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--points", type=int, default=1_000_000)
    p.add_argument("--preview", type=float, default=3.0, help="seconds of splat preview")
    p.add_argument("--live", type=float, default=10.0, help="seconds of live frames")
    p.add_argument("--fps", type=float, default=10.0, help="live frames per second")
    p.add_argument("--size", default="1200x860", help="window size WxH")
    p.add_argument("--point-size", type=float, default=3.0)
    p.add_argument("--grow-ui", action="store_true",
                   help="at live on, add a long label (the ImGui vertex buffer grows)")
    p.add_argument("--unlit", action="store_true", help="the points' shader is defaultUnlit")
    p.add_argument("--fixed-size", action="store_true",
                   help="every live frame is pasted into one texture of the viewport's size")
    p.add_argument("--remove", action="store_true", help="remove cloud and ground, not hide")
    p.add_argument("--no-geometry", action="store_true", help="no cloud or ground at all")
    p.add_argument("--keep-cache", action="store_true", help="leave scene caching on")
    p.add_argument("--no-sun", action="store_true", help="enable_sun_light(False)")
    p.add_argument("--no-post", action="store_true", help="set_post_processing(False)")
    p.add_argument("--no-ao", action="store_true", help="set_ambient_occlusion(False)")
    p.add_argument("--no-aa", action="store_true", help="set_antialiasing(False)")
    p.add_argument("--no-shadow", action="store_true", help="view.set_shadowing(False)")
    p.add_argument("--no-background", action="store_true",
                   help="live frames are not shown (only the redraws)")
    p.add_argument("--warm-background", action="store_true",
                   help="show a background image once during the preview already")
    return p.parse_args()


def main():
    t_start = time.monotonic()
    a = parse()
    import open3d as o3d
    import open3d.visualization.gui as gui
    import open3d.visualization.rendering as rendering

    w, h = (int(v) for v in a.size.split("x"))
    app = gui.Application.instance
    app.initialize()
    win = app.create_window("stall", w, h)
    sw = gui.SceneWidget()
    sw.scene = rendering.Open3DScene(win.renderer)
    bg = [0.1, 0.1, 0.12, 1.0]
    sw.scene.set_background(bg)
    sw.enable_scene_caching(True)
    win.add_child(sw)
    panel = gui.Vert()
    label = gui.Label("preview")
    panel.add_child(label)
    big = gui.Label("")
    panel.add_child(big)
    win.add_child(panel)

    def layout(ctx):
        r = win.content_rect
        pw = 250
        sw.frame = gui.Rect(r.x, r.y, r.width - pw, r.height)
        panel.frame = gui.Rect(r.get_right() - pw, r.y, pw, r.height)
    win.set_on_layout(layout)

    rng = np.random.default_rng(1)
    sc = sw.scene
    if not a.no_geometry:
        n = a.points
        v = rng.normal(size=(n, 3))
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        pcd = o3d.geometry.PointCloud()
        pcd.points = o3d.utility.Vector3dVector(v)
        pcd.normals = o3d.utility.Vector3dVector(v)
        pcd.colors = o3d.utility.Vector3dVector(rng.random((n, 3)))
        mat = rendering.MaterialRecord()
        mat.shader = "defaultUnlit" if a.unlit else "defaultLit"
        mat.point_size = a.point_size
        sc.add_geometry("cloud", pcd, mat)
        verts = np.array([[-3, -3, -1.2], [3, -3, -1.2], [3, 3, -1.2], [-3, 3, -1.2]], float)
        mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(verts),
                                         o3d.utility.Vector3iVector([[0, 1, 2], [0, 2, 3]]))
        mesh.compute_vertex_normals()
        gm = rendering.MaterialRecord()
        gm.shader = "defaultLit"
        gm.base_color = [0.6, 0.6, 0.65, 1.0]
        gm.base_roughness = 0.9
        sc.add_geometry("ground", mesh, gm)
    d = np.array([0.3, -0.5, -0.8], np.float32)
    sc.set_lighting(sc.LightingProfile.NO_SHADOWS, d)
    sc.scene.set_sun_light(d, [1.0, 1.0, 1.0], 60000)
    sc.scene.enable_sun_light(not a.no_sun)
    sc.scene.set_indirect_light_intensity(20000)
    view = sc.view
    if a.no_post:
        view.set_post_processing(False)
    if a.no_ao:
        view.set_ambient_occlusion(False)
    if a.no_aa:
        view.set_antialiasing(False)
    if a.no_shadow:
        view.set_shadowing(False)
    center = np.zeros(3)
    sw.setup_camera(40.0, o3d.geometry.AxisAlignedBoundingBox(-np.ones(3), np.ones(3)), center)

    st = {"t0": None, "live_at": None, "last": None, "gaps": [], "frames": 0, "next": 0.0,
          "sizes": set(), "done": False}

    def frame_image(t):
        fw, fh = sw.frame.width, sw.frame.height
        frac = 0.1 + 0.25 * (0.5 + 0.5 * np.sin(3.1 * t))  # adaptive: the fraction changes
        s = np.sqrt(frac)
        iw, ih = max(8, int(fw * s)), max(8, int(fh * s))
        img = np.empty((ih, iw, 3), np.uint8)
        img[...] = (rng.random(3) * 255).astype(np.uint8)
        img[::7] = 255
        if a.fixed_size:
            full = np.zeros((fh, fw, 3), np.uint8)
            yi = (np.arange(fh) * ih // fh)
            xi = (np.arange(fw) * iw // fw)
            full[...] = img[yi][:, xi]
            img = full
        st["sizes"].add(img.shape[:2])
        return o3d.geometry.Image(np.ascontiguousarray(img))

    def go_live():
        st["live_at"] = time.monotonic()
        for name in ("cloud", "ground"):
            if sc.has_geometry(name):
                if a.remove:
                    sc.remove_geometry(name)
                else:
                    sc.show_geometry(name, False)
        if not a.keep_cache:
            sw.enable_scene_caching(False)
        label.text = "live: starting"
        if a.grow_ui:
            big.text = "\n".join("live text line %04d" % i for i in range(30))
        sw.force_redraw()

    def on_tick():
        now = time.monotonic()
        if st["t0"] is None:
            st["t0"] = now
        if a.warm_background and len(st["gaps"]) == 0:
            sc.set_background(bg, frame_image(0.0))
            sw.force_redraw()
        if st["last"] is not None:
            st["gaps"].append((st["last"] - st["t0"], now - st["last"]))
        st["last"] = now
        t = now - st["t0"]
        if st["live_at"] is None:
            st["preview_ticks"] = st.get("preview_ticks", 0) + 1
            ang = 2 * np.pi * t / 6.0
            eye = [4 * np.cos(ang), 4 * np.sin(ang), 1.5]
            sc.camera.look_at(center, eye, [0, 0, 1])
            if a.warm_background and t > 0.2 and not st.get("warm_off"):
                sc.set_background(bg, None)
                st["warm_off"] = True
            if t >= a.preview:
                go_live()
            return True
        tl = now - st["live_at"]
        if tl >= a.live:
            if not st["done"]:
                st["done"] = True
                app.post_to_main_thread(win, win.close)
            return False
        if tl >= st["next"] and not a.no_background:
            st["next"] = tl + 1.0 / a.fps
            sc.set_background(bg, frame_image(tl))
            sw.force_redraw()
            win.post_redraw()
            st["frames"] += 1
            label.text = f"live frame {st['frames']}"
        return False

    win.set_on_tick_event(on_tick)
    app.run()
    t_end = time.monotonic()
    live_t = st["live_at"] - st["t0"] if st["live_at"] else None
    # the tick that switched live mode on is the first of the live part
    before = [g for t, g in st["gaps"] if live_t is None or t < live_t - 0.05]
    after = [(t, g) for t, g in st["gaps"] if live_t is not None and t >= live_t - 0.05]
    worst = max(after, key=lambda x: x[1]) if after else (None, None)
    out = {k: v for k, v in vars(a).items()}
    out.update(max_gap_before_s=round(max(before), 3) if before else None,
               max_gap_after_s=round(worst[1], 3) if worst[1] else None,
               worst_starts_after_live_s=round(worst[0] - live_t, 3) if worst[0] else None,
               gaps_over_1s_after=[(round(t - live_t, 2), round(g, 2))
                                   for t, g in after if g > 1.0],
               first_tick_s=round(st["t0"] - t_start, 2),
               close_to_exit_s=round(t_end - st["last"], 2), run_s=round(t_end - t_start, 2),
               ticks=len(st["gaps"]) + 1,
               preview_ticks=st.get("preview_ticks", 0),
               live_frames=st["frames"], texture_sizes=len(st["sizes"]),
               loadavg=open("/proc/loadavg").read().split()[:3])
    print(json.dumps(out))


if __name__ == "__main__":
    main()
