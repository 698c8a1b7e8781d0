"""The Open3D viewer's live viewport (GUI thread side; mixed into :class:`.o3d_app.O3DViewer`).

With live mode on, the preview's SceneWidget hides the splats and shows the latest ray-traced
picture as its background image, which the widget stretches to the viewport (the upscaling of the
reduced frames while moving). The mouse still drives the widget's camera; every tick hands the
current camera to the :class:`~pointviz.viewer.live.LiveRenderer`, which never blocks: the GUI
thread takes a lock for a few assignments and never waits for the tracer.

Frames come back through ``post_to_main_thread`` coalesced (:meth:`LiveMixin._post_live_frame`):
the worker thread converts the picture into an Open3D image (the only O(pixels) step) and posts
at most one handler at a time; a frame that arrives while one waits replaces it, so the window
never redraws twice for frames it could not show.

``pointviz view --live --orbit SECONDS`` scripts it (:class:`LiveScript`): the splat preview
circles the data for a while (its own frame rate), then the live view does for SECONDS, holds
still for HOLD_S, and the window saves a screenshot and closes.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from . import model, o3d_display
from .live import LiveRenderer, orbit_camera
from . import worker

#: Seconds the camera holds still at the end of a scripted orbit before ``still_spp`` is read
#: (the issue's 3 s).
HOLD_S = 3.0
#: Seconds the scripted orbit spends on the splat preview alone (its frame rate), at most.
PREVIEW_ORBIT_S = 2.0
#: One scripted orbit: a full turn around the scene's up axis over the orbit's duration.
ORBIT_TURNS = 1.0
#: Least time between two live frames shown, seconds (at most 25 redraws a second). Each shown
#: frame redraws the window; a small scene's still passes come back far faster than that, and
#: redraws queued faster than the software rasteriser finishes them make the GUI thread wait
#: for it (Filament's frame pacing). A frame that arrives sooner waits for the tick.
LIVE_MIN_FRAME_INTERVAL_S = 0.04


@dataclass
class LiveScript:
    """The scripted orbit's progress and measurements (GUI thread).

    ``state`` goes preview → warmup (live on, until its first frame) → orbit → hold → done.
    """

    seconds: float
    state: str = "preview"
    t_state: float = 0.0
    start_camera: object = None
    preview_ticks: int = 0
    moving_shown: list = field(default_factory=list)   # (time, fraction) of moving frames shown
    still_spp: int = 0
    still_generation: int = -1
    still_shown: list = field(default_factory=list)    # (seconds into the hold, spp) shown


class LiveMixin:
    """Live mode of :class:`.o3d_app.O3DViewer`."""

    def _init_live(self) -> None:
        self.live = None          # the LiveRenderer while live mode is on
        self.live_frame = None    # the LiveFrame shown
        self.live_generation = 0  # the request the GUI last made
        self._live_floor = 0      # frames of older requests are not shown (an up change)
        self.live_stats = {"frames_shown": 0, "moving_frames_shown": 0, "frames_coalesced": 0,
                           "errors": []}
        self.live_script = None
        self._live_key = None     # what the last camera handed to the live renderer came from
        self._live_pending = None  # (LiveFrame, o3d Image) not shown yet
        self._live_pending_posted = False  # a handler that shows it is posted (else: the tick)
        self._live_shown_at = 0.0  # when the last live frame was shown (monotonic)
        self._live_pending_lock = threading.Lock()

    def _build_live_widgets(self, parent) -> None:
        cb = self.gui.Checkbox("Live ray tracing (L)")
        cb.set_on_checked(lambda v: self.set_live(bool(v)))
        parent.add_child(cb)
        self.chk_live = cb
        self.live_label = self.gui.Label("live: off (splat preview)")
        parent.add_child(self.live_label)

    def set_live(self, on: bool) -> None:
        """Switch between the live ray-traced viewport and the splat preview."""
        if on == (self.live is not None):
            return
        self._live_key = None  # a new renderer gets the camera at the next tick
        sc = self.preview.scene
        self.gui_trace.mark("live on" if on else "live off")
        if on:
            self.live = LiveRenderer(self._post_live_frame, self._live_prepare,
                                     self._post_live_error, threads=self.settings.threads,
                                     background=worker.RENDER_IN_BACKGROUND)
            self.live_frame = None
            self.preview.enable_scene_caching(False)  # the background changes every frame
            self.live_label.text = "live: starting..."
        else:
            self.live.shutdown()
            self._record_live_counts()
            self.live = None
            sc.set_background(self._background_color(), None)
            self.preview.enable_scene_caching(True)
            self.live_label.text = "live: off (splat preview)"
            self._update_point_size(force=True)  # not kept up while the splats were hidden
        self._show_splats(not on)
        self.preview.force_redraw()
        self.chk_live.checked = on  # last: a callback it may fire finds the state already set

    def _background_color(self):
        """The background colour parameter (encoded for the preview's view, o3d_display)."""
        return o3d_display.background_color(model.PREVIEW_BACKGROUND)

    def _show_splats(self, show: bool) -> None:
        sc = self.preview.scene
        for name in ("cloud", "ground"):
            if sc.has_geometry(name):
                sc.show_geometry(name, show)

    def _live_prepare(self, settings):
        """(worker thread) The scene and render() options of these settings."""
        return model.render_scene(self.scene, settings), settings.render_kwargs()

    def _live_tick(self) -> None:
        """Hand the current camera to the live renderer (every tick; the camera is only rebuilt
        when the preview's view, its size or the settings have changed since the last one)."""
        if self.live is None:
            return
        self._show_due_live(time.monotonic())
        cam, frame = self.preview.scene.camera, self.preview.frame
        key = (np.asarray(cam.get_view_matrix()).tobytes(),
               np.asarray(cam.get_projection_matrix()).tobytes(), frame.width, frame.height,
               id(self.settings))
        if key != self._live_key:
            self._live_key = key
            self.live_generation = self.live.update(self.current_camera(), self.settings)

    # -- worker thread -> GUI thread
    def _post_live_frame(self, lf) -> None:
        """(worker thread) Hand a frame to the GUI thread: its picture is converted here, and a
        handler is posted only if none is waiting (a waiting one shows this frame instead) and
        the last frame was shown LIVE_MIN_FRAME_INTERVAL_S ago or more (else the tick shows it
        when that time has passed, :meth:`_show_due_live`)."""
        image = self.o3d.geometry.Image(o3d_display.background_image(lf.image))
        with self._live_pending_lock:
            waiting = self._live_pending is not None
            self._live_pending = (lf, image)
            if waiting:
                self.live_stats["frames_coalesced"] += 1
            post = (not waiting and time.monotonic() - self._live_shown_at
                    >= LIVE_MIN_FRAME_INTERVAL_S)
            self._live_pending_posted |= post
        if post:
            self._post(self._show_pending_live, "show live frame")

    def _show_due_live(self, now) -> None:
        """(tick) Show a frame that came too soon after the last one, once its time has come."""
        if (self._live_pending is not None and not self._live_pending_posted
                and now - self._live_shown_at >= LIVE_MIN_FRAME_INTERVAL_S):
            with self.gui_trace.span("show live frame (tick)"):
                self._show_pending_live()

    def _show_pending_live(self) -> None:
        with self._live_pending_lock:
            pending, self._live_pending = self._live_pending, None
            self._live_pending_posted = False
        if pending is not None:
            self._show_live(*pending)

    def _post_live_error(self, exc) -> None:
        self._post(lambda: self._show_live_error(exc), "show live error")

    # -- GUI thread
    def _show_live(self, lf, image) -> None:
        if self.live is None or self.closed or lf.generation < self._live_floor:
            return
        tr = self.gui_trace
        if self.live_frame is None:
            tr.event("first live frame")
        if not lf.moving and lf.denoised:
            tr.event("first denoised frame")
        elif not lf.moving:
            tr.event("first still pass")
        self.live_frame = lf
        self._live_shown_at = time.monotonic()
        with tr.span("live set_background"):
            self.preview.scene.set_background(self._background_color(), image)
        with tr.span("live force_redraw"):
            self.preview.force_redraw()
            self.window.post_redraw()  # the panel's live label too
        st = self.live_stats
        st["frames_shown"] += 1
        if lf.moving:
            st["moving_frames_shown"] += 1
            self.live_label.text = (f"live: moving, {lf.camera.width}x{lf.camera.height} "
                                    f"({lf.fraction:.0%} of the pixels), {lf.seconds * 1e3:.0f} ms")
        else:
            self.live_label.text = (f"live: still, {lf.spp} spp"
                                    + (", denoised" if lf.denoised else ""))
        s = self.live_script
        if s is not None and s.state == "orbit" and lf.moving:
            s.moving_shown.append((time.monotonic(), lf.fraction))
        if s is not None and s.state == "hold" and lf.generation == s.still_generation:
            s.still_spp = 0 if lf.moving else lf.spp
            s.still_shown.append((round(time.monotonic() - s.t_state, 3), s.still_spp))

    def _show_live_error(self, exc) -> None:
        self.live_stats["errors"].append(f"{type(exc).__name__}: {exc}")
        self.live_label.text = "live: frame failed"
        if self.automation is not None:
            self.automation.info["error"] = f"live view: {type(exc).__name__}: {exc}"

    def _close_live(self) -> bool:
        """(on close) End the live worker; True if it ended."""
        if self.live is None:
            return True
        t = self.live.thread
        ended = self.live.shutdown()
        self._record_live_counts()
        self.live = None
        self.timings["live_worker_ended_on_close"] = ended and not t.is_alive()
        return ended

    # -- scripted orbit (automation; GUI thread, from the tick event)
    def _orbit_at(self, t: float):
        s = self.live_script
        angle = 2.0 * math.pi * ORBIT_TURNS * t / max(s.seconds, 1e-9)
        return orbit_camera(s.start_camera, self.center, self.scene.up, angle)

    def _step_live_script(self, now) -> bool:
        """One step of the scripted orbit; True when it has finished."""
        s = self.live_script
        dt = now - s.t_state
        if s.state == "preview":
            if s.start_camera is None:
                self.gui_trace.mark("preview orbit")
                s.start_camera, s.t_state = self.current_camera(), now
                return False
            span = min(PREVIEW_ORBIT_S, s.seconds)
            if dt < span:
                self.apply_camera(self._orbit_at(dt * s.seconds / span))
                s.preview_ticks += 1
                return False
            s.preview_seconds = dt
            self.apply_camera(s.start_camera)
            self.set_live(True)
            s.state, s.t_state = "warmup", now
        elif s.state == "warmup":
            if self.live_frame is not None:  # trees built, first frame shown
                self.gui_trace.mark("orbit")
                s.state, s.t_state = "orbit", now
        elif s.state == "orbit":
            if dt < s.seconds:
                self.apply_camera(self._orbit_at(dt))
                return False
            s.orbit_seconds = dt
            self.apply_camera(self._orbit_at(s.seconds))
            self._live_tick()
            s.still_generation = self.live_generation
            self.gui_trace.mark("hold")
            s.state, s.t_state = "hold", now
        elif s.state == "hold" and dt >= HOLD_S:
            self.gui_trace.mark("hold done")
            s.state = "done"
            return True
        return s.state == "done"

    def live_report(self) -> dict:
        """The live view's measurements (see ``pointviz view --live --report``)."""
        out = dict(self.live_stats, label=self.live_label.text, on=self.live is not None)
        s = self.live_script
        if s is None:
            return out
        shown = s.moving_shown
        orbit_s = getattr(s, "orbit_seconds", None)
        out.update({
            "orbit_seconds": s.seconds,
            "live_fps": len(shown) / orbit_s if orbit_s else None,
            "live_resolution": float(np.mean([f for _, f in shown])) if shown else None,
            "still_spp": s.still_spp,
            "still_shown": s.still_shown,
            "hold_seconds": HOLD_S,
            "preview_fps": (s.preview_ticks / s.preview_seconds
                            if getattr(s, "preview_seconds", 0) else None),
            "viewport": list(self._live_viewport()),
        })
        return out

    def _record_live_counts(self) -> None:
        lr = self.live
        self.live_stats.update(cancelled_frames=lr.cancelled_frames,
                               moving_frames_traced=lr.moving_frames,
                               still_passes_traced=lr.still_passes)

    def _live_viewport(self):
        cam = self.current_camera()
        return cam.width, cam.height


__all__ = ["HOLD_S", "LiveMixin", "LiveScript"]
