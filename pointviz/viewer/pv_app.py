"""The pyvista/VTK viewer: Gaussian point splats scaled by the surfel radii on the left, the
ray-traced frame on the right, Render on a key (``r``) and a button, Cancel on ``k``, the next
up direction on ``u`` (+X, +Y, +Z, -X, -Y, -Z in turn: this window has no settings panel to hold
the Open3D viewer's Up control; :meth:`PVViewer.set_up` does the same work).

Threads
-------
* :class:`PVViewer` and the VTK objects live on the **GUI thread** (the one that made the
  Plotter); VTK is not thread safe.
* The :class:`~pointviz.viewer.worker.RenderWorker` thread posts its reports into a
  :class:`queue.Queue`; a repeating VTK timer (or the automation loop) drains it on the GUI
  thread. That queue is the only crossing.
"""

from __future__ import annotations

import json
import queue
import time

import numpy as np

from ..errors import PointvizError, require
from . import model
from .worker import RenderWorker

#: Default window size (two 640 x 560 viewports).
DEFAULT_WINDOW_SIZE = (1280, 560)
#: How often the GUI thread drains the worker's queue, milliseconds.
DRAIN_INTERVAL_MS = 50
#: Splat size factor: VTK draws a splat of ``scale * radius`` whose shaded sphere covers only its
#: inner part; 2 closes the surface of a regularly sampled cloud (checked on the demo scene).
SPLAT_SCALE = 2.0
#: Ambient term of the splats: VTK shades each splat as a small sphere whose rim is dark, so a
#: strong ambient keeps a dense cloud from looking black.
SPLAT_AMBIENT = 0.6
#: Automation: seconds between two drains while waiting for the worker.
AUTOMATION_POLL_S = 0.02


class PVViewer:
    """The pyvista window (GUI thread). Parameters as for :class:`.o3d_app.O3DViewer`."""

    def __init__(self, scene, settings, camera=None, title="pointviz", off_screen=False,
                 window_size=DEFAULT_WINDOW_SIZE, t_start=None):
        self.pv = require("pyvista", "viewer")
        self.settings = settings.validate()
        self.source_scene = scene  # as given; ``scene`` is it seen with the settings' up
        self.scene = model.scene_with_up(scene, self.settings.up)
        self._light = None
        self.t_start = time.monotonic() if t_start is None else t_start
        self.timings: dict = {}
        self.frame = None
        self.frame_camera = None
        self.job = None
        self.closed = False
        self.queue: queue.Queue = queue.Queue()
        self.worker = RenderWorker(lambda *a: self.queue.put(("progress", a)),
                                   lambda *a: self.queue.put(("done", a)),
                                   lambda *a: self.queue.put(("error", a)))
        lo, hi = (np.asarray(b, dtype=np.float64) for b in scene.bounds())
        self.center, self.diagonal = 0.5 * (lo + hi), float(np.linalg.norm(hi - lo))
        self.window_size = tuple(int(v) for v in window_size)
        pl = self.pv.Plotter(shape=(1, 2), off_screen=off_screen, window_size=self.window_size,
                             title=title, lighting="light kit", border=False)
        self.plotter = pl
        pl.subplot(0, 0)
        pl.set_background((0.82, 0.86, 0.92), all_renderers=False)
        self._add_splats()
        self._add_light()
        self._set_camera(camera)
        self.status = pl.add_text("", position="lower_left", font_size=8, color="black",
                                  name="status")
        pl.subplot(0, 1)
        pl.set_background((0.16, 0.16, 0.16), all_renderers=False)
        self.progress_text = pl.add_text("press r (or the button) to render", position="upper_left",
                                         font_size=9, color="white", name="progress")
        pl.subplot(0, 0)
        pl.add_key_event("r", self.on_render)
        pl.add_key_event("k", self.on_cancel)
        pl.add_key_event("u", self.on_next_up)
        pl.add_checkbox_button_widget(lambda state: self.on_render(), value=False,
                                      position=(10, self.window_size[1] - 50), size=36,
                                      color_on="orange", color_off="orange")
        pl.add_text("Render", position=(52, self.window_size[1] - 42), font_size=9,
                    color="black", name="render_label")
        self._update_status()
        self.timings["window_built_s"] = time.monotonic() - self.t_start

    # ------------------------------------------------------------------ preview
    def _add_splats(self) -> None:
        t0 = time.monotonic()
        data = model.preview_data(self.scene, self.settings)
        self.preview_info = data
        cloud = self.pv.PolyData(np.asarray(data.points, dtype=np.float64))
        cloud["rgb"] = (np.clip(data.colors, 0, 1) * 255).astype(np.uint8)
        cloud["radius"] = (data.radii * SPLAT_SCALE * self.settings.point_scale).astype(np.float32)
        cloud["Normals"] = data.normals
        actor = self.plotter.add_mesh(cloud, style="points_gaussian", scalars="rgb", rgb=True,
                                      emissive=False, render_points_as_spheres=True,
                                      show_scalar_bar=False, ambient=SPLAT_AMBIENT,
                                      name="splats")
        actor.mapper.scale_array = "radius"
        self.timings["preview_upload_s"] = time.monotonic() - t0

    def _add_light(self) -> None:
        if self._light is not None:
            self.plotter.renderers[0].RemoveLight(self._light)
        s = self.settings
        d = model.light_direction(s.light_azimuth_deg, s.light_elevation_deg, self.scene.up)
        light = self.pv.Light(position=tuple(self.center + d * self.diagonal),
                              focal_point=tuple(self.center), light_type="scene light",
                              intensity=min(1.0, s.light_intensity))
        light.positional = False
        self.plotter.add_light(light)
        self._light = light

    def on_next_up(self) -> None:
        """The ``u`` key: the next of :data:`model.UP_AXES` after the current up."""
        labels = list(model.UP_AXES)
        label = model.up_label(self.scene.up)
        self.set_up(labels[(labels.index(label) + 1) % len(labels)] if label in labels
                    else labels[0])

    def set_up(self, up) -> None:
        """Show the scene with another up (a label of :data:`model.UP_AXES` or a vector), as
        the Open3D viewer's Up control does (:func:`model.change_up`): trees shared, camera
        re-framed, light and splats (height colours) anew; a render under way is cancelled and
        its frame never shown, and the frame of the old up is taken away."""
        w, h = self.viewport_size()
        change = model.change_up(self.source_scene, self.settings, up, w, h)
        if np.array_equal(change.scene.up, self.scene.up):
            return
        if self.job is not None:
            self.worker.cancel()
            self.job = None  # drain() drops the reports of a job that is no longer current
        self.settings, self.scene = change.settings, change.scene
        self.frame = self.frame_camera = None
        pl = self.plotter
        pl.subplot(0, 1)
        pl.remove_actor("frame")
        self._set_progress(f"up {model.up_label(self.scene.up)}: press r to render")
        pl.subplot(0, 0)
        self._add_splats()
        self._add_light()
        self._set_camera(change.camera)
        self._update_status()
        if not self.closed:
            pl.render()

    def _set_camera(self, camera) -> None:
        from ..camera import Camera

        w, h = self.viewport_size()
        if camera is None:
            camera = Camera.fit(self.scene, fov_deg=40.0, width=w, height=h)
        tan_h = camera.tan_half * max(1.0, camera.aspect * h / w)
        cam = self.plotter.renderers[0].camera
        cam.position = tuple(camera.eye)
        cam.focal_point = tuple(camera.target)
        cam.up = tuple(camera.true_up)
        cam.view_angle = float(np.degrees(2 * np.arctan(tan_h)))
        self.plotter.renderers[0].reset_camera_clipping_range()

    def viewport_size(self) -> tuple[int, int]:
        """Pixels of one of the two viewports."""
        if not self.closed:
            self._size = tuple(self.plotter.window_size)
        w, h = self._size
        return max(1, w // 2), max(1, h)

    def current_camera(self):
        """The pointviz Camera of the preview's current view, at the output size."""
        from ..camera import Camera

        cam = self.plotter.renderers[0].camera
        w, h = model.output_size(self.settings, *self.viewport_size())
        return Camera(cam.position, cam.focal_point, cam.up, cam.view_angle, w, h)

    def _update_status(self) -> None:
        parts = [self.preview_info.note]
        if self.frame is not None:
            st = self.frame.stats
            parts.append(f"frame {self.frame.width}x{self.frame.height} in "
                         f"{self.timings.get('last_render_s', st['seconds']):.2f} s")
        self.status.set_text("lower_left", "  |  ".join(parts))

    # ------------------------------------------------------------------ rendering
    def on_render(self) -> None:
        """The Render key/button: trace the current view on the worker thread."""
        camera = self.current_camera()
        self.frame_camera = camera
        self.job = self.worker.submit(self.scene, self.settings, camera)
        self.render_started = time.monotonic()
        self._set_progress(f"rendering {camera.width}x{camera.height}... (k: cancel)")

    def on_cancel(self) -> None:
        self.worker.cancel()

    def _set_progress(self, text) -> None:
        self.progress_text.set_text("upper_left", text)

    def drain(self) -> None:
        """Apply the worker's reports (GUI thread)."""
        from ..errors import CancelledError

        while True:
            try:
                kind, args = self.queue.get_nowait()
            except queue.Empty:
                return
            job_id = args[0]
            if self.job is None or job_id != self.job.job_id:
                continue
            if kind == "progress":
                done, total = args[1], args[2]
                self._set_progress(f"rendering... {100 * done / max(total, 1):.0f}% (k: cancel)")
            elif kind == "done":
                self.job = None
                self._show_frame(args[1])
            else:
                self.job = None
                exc = args[1]
                self.error = None if isinstance(exc, CancelledError) else f"{type(exc).__name__}: {exc}"
                self._set_progress("cancelled" if self.error is None else f"failed: {self.error}")
            if not self.closed:
                self.plotter.render()

    def _show_frame(self, result) -> None:
        pl = self.plotter
        self.frame = result.frame
        self.timings["last_render_s"] = result.seconds
        self.timings.setdefault("renders", []).append(
            {"seconds": result.seconds, "core_seconds": result.frame.stats["seconds"],
             "size": [result.frame.width, result.frame.height]})
        img = result.image if result.image is not None else result.frame.to_srgb8()
        h, w = img.shape[:2]
        pl.subplot(0, 1)
        plane = self.pv.Plane(center=(w / 2, h / 2, 0), direction=(0, 0, 1), i_size=w, j_size=h)
        tex = self.pv.Texture(np.ascontiguousarray(img))
        pl.add_mesh(plane, texture=tex, lighting=False, name="frame", show_scalar_bar=False)
        vw, vh = self.viewport_size()
        cam = pl.renderers[1].camera
        cam.parallel_projection = True
        cam.focal_point = (w / 2, h / 2, 0)
        cam.position = (w / 2, h / 2, max(w, h))
        cam.up = (0, 1, 0)
        cam.parallel_scale = 0.5 * max(h, w * vh / vw)
        pl.renderers[1].reset_camera_clipping_range()
        self._set_progress(f"done in {result.seconds:.2f} s")
        pl.subplot(0, 0)
        self._update_status()

    # ------------------------------------------------------------------ automation
    def wait_for_render(self, timeout: float = 600.0) -> None:
        """Drain reports until the current job ends (GUI thread; used without an event loop)."""
        end = time.monotonic() + timeout
        while self.job is not None and time.monotonic() < end:
            time.sleep(AUTOMATION_POLL_S)
            self.drain()

    def screenshot(self) -> np.ndarray:
        """The whole render window (both viewports and widgets), (h, w, 3) uint8."""
        return np.asarray(self.plotter.screenshot(return_img=True))[..., :3]

    def widget_rects(self) -> dict:
        """Preview and frame viewports in the screenshot, [x, y, w, h] pixels from the top-left."""
        self.viewport_size()
        w, h = self._size
        return {"preview": [0, 0, w // 2, h], "result": [w // 2, 0, w - w // 2, h],
                "content": [0, 0, w, h]}

    def report(self) -> dict:
        return {"timings": self.timings, "rects": self.widget_rects(),
                "settings": self.settings.to_dict(),
                "up": [float(v) for v in self.scene.up],
                "camera": None if self.frame_camera is None else self.frame_camera.to_dict(),
                "preview_points": len(self.preview_info.points),
                "total_points": int(self.preview_info.total)}

    def close(self) -> None:
        self.viewport_size()
        self.closed = True
        self.timings["worker_ended_on_close"] = self.worker.shutdown()
        self.plotter.close()


def run(scene, settings, camera=None, title="pointviz", *, render=False, screenshot=None,
        frame=None, report=None, overwrite=False, t_start=None,
        window_size=DEFAULT_WINDOW_SIZE, on_ready=None) -> PVViewer:
    """Open the pyvista viewer. With ``screenshot`` or ``frame`` it runs off screen: render
    once, save, close. Otherwise the window is interactive until closed."""
    from ..files import atomic_write_bytes, atomic_write_text
    from ..images import encode_png
    from .o3d_app import save_frame_npz

    automated = screenshot is not None or frame is not None
    viewer = PVViewer(scene, settings, camera, title, off_screen=automated,
                      window_size=window_size, t_start=t_start)
    if on_ready is not None:
        on_ready(viewer)
    viewer.error = None
    if automated:
        viewer.plotter.render()
        viewer.timings["first_preview_s"] = time.monotonic() - viewer.t_start
        if render:
            viewer.on_render()
            viewer.wait_for_render()
            viewer.plotter.render()
        if viewer.error:
            viewer.close()
            raise PointvizError(f"render failed: {viewer.error}")
        if screenshot is not None:
            atomic_write_bytes(screenshot, encode_png(viewer.screenshot()), overwrite)
        if frame is not None and viewer.frame is not None:
            save_frame_npz(frame, viewer.frame, viewer.frame_camera, overwrite)
        viewer.close()
    else:
        pl = viewer.plotter
        pl.add_timer_event(max_steps=2**31 - 1, duration=DRAIN_INTERVAL_MS, callback=lambda step: viewer.drain())
        if render:
            viewer.on_render()
        viewer.timings["first_preview_s"] = time.monotonic() - viewer.t_start
        pl.show(auto_close=False)
        viewer.close()
    if report is not None:
        atomic_write_text(report, json.dumps(viewer.report(), indent=2, default=str),
                          overwrite=overwrite)
    return viewer


__all__ = ["PVViewer", "run"]
