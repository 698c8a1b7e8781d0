"""Scripting the Open3D viewer: what ``pointviz view --render/--live --screenshot`` asks the window
to do (a state machine stepped by the GUI thread's tick event), screenshots of the X display,
the JSON report, and :meth:`AutomationMixin.call` for drivers on other threads."""

from __future__ import annotations

import json
import os
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from . import model

#: Automation: seconds to wait after the preview's first frame before rendering (the software
#: rasteriser presents the first frames late), and after showing the frame before the grab.
AUTOMATION_WARMUP_S = 0.6
AUTOMATION_SETTLE_S = 0.5
#: Automation: attempts to grab a non-blank screenshot (AUTOMATION_SETTLE_S apart): 30 s, so
#: that only a window that never presents its frame gives up (a loaded machine takes seconds).
SCREENSHOT_ATTEMPTS = 60
#: A grab whose pixel standard deviation is at most this is blank (nothing presented yet).
BLANK_STD = 1.0
#: Live view: a grab whose viewport differs from the live frame last handed to the window by more
#: than this mean absolute difference (8-bit levels, see live_view_difference) still shows an
#: older picture: under load the X server presents a redraw seconds late. The frame shown is
#: within half a level of its image (o3d_display; ~10 levels with Open3D's post-processing on);
#: a picture from the orbit, another camera, is ~40 off.
LIVE_SHOWN_TOLERANCE = 20.0


@dataclass
class Automation:
    """What ``pointviz view --render --screenshot`` (and the tests) ask the window to do.

    Attributes
    ----------
    render : bool
        Press Render once the preview is up (after the live script, with ``live``).
    live : bool
        Turn the live ray-traced viewport on, hold still HOLD_S seconds (after the orbit).
    orbit : float or None
        With ``live``: first circle the data for this many seconds (see
        :class:`~pointviz.viewer.o3d_live.LiveScript`).
    screenshot : str or None
        Save a screenshot of the whole window there (PNG), then close.
    frame : str or None
        Save the ray-traced frame (``.npz`` with color/depth/normal/alpha and the camera JSON).
    report : str or None
        Write a JSON report: timings, widget rectangles in the screenshot, camera, settings.
    overwrite : bool
    close : bool
        Close the window when done.
    gui_trace : bool
        Add what the GUI thread did when (:class:`~pointviz.viewer.gui_trace.GuiTrace`) to the
        report.
    """

    render: bool = False
    live: bool = False
    orbit: float | None = None
    screenshot: str | None = None
    frame: str | None = None
    report: str | None = None
    overwrite: bool = False
    close: bool = True
    gui_trace: bool = False
    state: str = "wait"
    t_state: float = 0.0
    info: dict = field(default_factory=dict)


def grab_window(window_rect) -> np.ndarray:
    """Pixels of a screen rectangle of the X display, (h, w, 3) uint8.

    Uses Pillow's XCB grab (``ImageGrab.grab(xdisplay=...)``): it reads what the X server shows,
    i.e. the whole window as presented, panel and all.
    """
    from PIL import ImageGrab

    x, y, w, h = window_rect
    img = ImageGrab.grab(bbox=(x, y, x + w, y + h), xdisplay=os.environ.get("DISPLAY"))
    return np.asarray(img.convert("RGB"))


class AutomationMixin:
    """Automation and scripting of :class:`.o3d_app.O3DViewer` (GUI thread unless stated)."""

    def _set_auto_state(self, state) -> None:
        self.automation.state = state
        self.automation.t_state = time.monotonic()

    def _automate(self, now) -> None:
        """One step of the automation state machine (GUI thread, from the tick event)."""
        a = self.automation
        if a.state == "wait":
            self._set_auto_state("warmup")
        elif a.state == "warmup" and now - a.t_state >= AUTOMATION_WARMUP_S:
            if a.live:
                from .o3d_live import LiveScript

                self.live_script = LiveScript(float(a.orbit or 0.0))
                self._set_auto_state("live")
            elif a.render:
                self._set_auto_state("rendering")
                self._on_render()
            else:
                self._set_auto_state("settle")
        elif a.state == "live" and self._step_live_script(now):
            if a.render:
                self._set_auto_state("rendering")
                self._on_render()
            else:
                self._set_auto_state("settle")
        elif a.state == "settle" and now - a.t_state >= AUTOMATION_SETTLE_S:
            self.gui_trace.mark("screenshot")
            a.info["attempts"] = a.info.get("attempts", 0) + 1
            with self.gui_trace.span("screenshot grab"):
                shot = self.screenshot() if a.screenshot else None
            with self.gui_trace.span("screenshot check"):
                blank = shot is not None and self._shows_blank(shot)
            if (blank
                    and a.info["attempts"] < SCREENSHOT_ATTEMPTS):
                self.window.post_redraw()
                self._set_auto_state("settle")  # not presented yet: grab again a bit later
                return
            self._set_auto_state("done")
            with self.gui_trace.span("finish automation"):
                self._finish_automation(shot)

    def _shows_blank(self, shot) -> bool:
        """True while the grab shows a blank window, a blank frame panel although a frame is
        shown there, or a live viewport still showing an older picture than the live frame the
        window was given (under load the redraw with the new image reaches the X server late)."""
        if shot.std() <= BLANK_STD:
            return True
        if self.live_frame is not None and self.live is not None:
            x, y, w, h = self.widget_rects()["preview"]
            diff = live_view_difference(shot[y:y + h, x:x + w], self.live_frame.image)
            if self.automation is not None:
                self.automation.info["live_view_difference"] = round(diff, 2)
            if diff > LIVE_SHOWN_TOLERANCE:
                return True
        if self.frame is None or not self.result.visible:
            return False
        x, y, w, h = self.widget_rects()["result"]
        return shot[y:y + h, x:x + w].std() <= BLANK_STD

    def widget_rects(self) -> dict:
        """Preview, frame and panel rectangles relative to the window's content (pixels)."""
        r = self.window.content_rect

        def rel(f):
            return [f.x - r.x, f.y - r.y, f.width, f.height]

        return {"preview": rel(self.preview.frame), "result": rel(self.result.frame),
                "panel": rel(self.panel.frame), "content": [0, 0, r.width, r.height]}

    def screenshot(self) -> np.ndarray:
        """The whole window's content as shown on screen, (h, w, 3) uint8 (any thread).

        The first frames of a software-rendered window can reach the X server late; callers
        retry while the grab is blank (see BLANK_STD).
        """
        os_frame = self.window.os_frame
        r = self.window.content_rect
        return grab_window((os_frame.x + r.x, os_frame.y + r.y, r.width, r.height))

    def _finish_automation(self, shot) -> None:
        from ..files import atomic_write_bytes
        from ..images import encode_png

        a = self.automation
        try:
            if shot is not None:
                atomic_write_bytes(a.screenshot, encode_png(shot), a.overwrite)
                a.info["screenshot"] = os.fspath(a.screenshot)
                a.info["screenshot_size"] = [int(shot.shape[1]), int(shot.shape[0])]
            if a.frame and self.frame is not None:
                save_frame_npz(a.frame, self.frame, self.frame_camera, a.overwrite)
            elif a.frame and self.live_frame is not None:  # live only: the live view's frame
                save_frame_npz(a.frame, self.live_frame.frame, self.live_frame.camera,
                               a.overwrite, spp=np.int64(self.live_frame.spp),
                               moving=np.bool_(self.live_frame.moving))
        except Exception as exc:  # noqa: BLE001 - reported, then the window closes
            a.info["error"] = f"{type(exc).__name__}: {exc}"
        if a.close:
            # not from inside this tick event: closing a window in its own callback crashes
            self.app.post_to_main_thread(self.window, self.window.close)

    @property
    def automation_error(self) -> str | None:
        """What went wrong in automation (render error, screenshot failure), else None."""
        return None if self.automation is None else self.automation.info.get("error")

    def report(self) -> dict:
        a = self.automation
        return {"timings": self.timings, "rects": self.widget_rects(),
                "settings": self.settings.to_dict(),
                "up": [float(v) for v in self.scene.up], "up_control": self.cmb_up.selected_text,
                "camera": None if self.frame_camera is None else self.frame_camera.to_dict(),
                "preview_points": len(self.preview_info.points),
                "total_points": int(self.preview_info.total),
                "status": self.status.text, "render_label": self.render_label.text,
                **self._live_summary(),
                **({} if a is None else {"automation": a.info}),
                **({"gui_trace": self.gui_trace.to_dict()} if a is not None and a.gui_trace
                   else {})}

    def _live_summary(self) -> dict:
        live = self.live_report()
        keys = ("live_fps", "live_resolution", "still_spp", "preview_fps")
        return {"live": live, **{k: live[k] for k in keys if k in live}}

    def _write_report(self) -> None:
        a = self.automation
        if a is None or not a.report:
            return
        from ..files import atomic_write_text

        atomic_write_text(a.report, json.dumps(self.report(), indent=2, default=str),
                          overwrite=a.overwrite)

    def call(self, fn, timeout: float = 30.0, redraw: bool = True):
        """Run ``fn()`` on the GUI thread and return its result (call from another thread).

        With ``redraw`` (the default) the window is redrawn after ``fn``, so that widget changes
        show at once; without, ``fn`` runs at the next tick event (every ~10 ms) and the window
        is not redrawn for it (queries of state, and what changes nothing on screen).
        """
        box: dict = {}
        done = threading.Event()

        def run():
            try:
                box["value"] = fn()
            except BaseException as exc:  # noqa: BLE001 - re-raised on the caller's thread
                box["error"] = exc
            done.set()

        if redraw:
            self.app.post_to_main_thread(self.window, run)
        else:
            self._tick_queue.append(run)
        if not done.wait(timeout):
            raise TimeoutError(f"GUI thread did not run the call within {timeout} s")
        if "error" in box:
            raise box["error"]
        return box.get("value")


    def time_round_trips(self, spacing: float, out: list, timeout: float = 60.0) -> None:
        """(driver thread) Time one GUI round trip (``call(lambda: None, redraw=False)``) every
        ``spacing`` seconds until the window closes, appending ``(start, seconds)`` (start in
        ``time.monotonic()`` seconds) to ``out``. A call that times out counts as ``timeout``,
        unless the window closed meanwhile (a call posted as it closed is never answered)."""
        while not self.closed:
            t = time.monotonic()
            try:
                self.call(lambda: None, timeout=timeout, redraw=False)
                out.append((t, time.monotonic() - t))
            except TimeoutError:
                if self.closed:
                    break
                out.append((t, timeout))
            time.sleep(spacing)


def live_view_difference(panel: np.ndarray, image: np.ndarray) -> float:
    """Mean absolute difference (8-bit levels) between a live frame's ``image`` (ih, iw, 3) and
    a grabbed viewport ``panel`` (h, w, 3) that shows it upscaled: the panel's pixels are averaged
    over each image pixel's cell first, so that how the window filters the upscale (nearest or
    linear) hardly counts and an older picture stands out. inf if either is empty."""
    h, w = panel.shape[:2]
    ih, iw = image.shape[:2]
    if min(h, w, ih, iw) == 0:
        return float("inf")
    rows = np.minimum((np.arange(h) * ih / h).astype(np.int64), ih - 1)
    cols = np.minimum((np.arange(w) * iw / w).astype(np.int64), iw - 1)
    cell = (rows[:, None] * iw + cols[None, :]).ravel()
    count = np.bincount(cell, minlength=ih * iw)
    seen = count > 0
    diff = 0.0
    for c in range(3):
        sums = np.bincount(cell, weights=panel[..., c].ravel().astype(np.float64),
                           minlength=ih * iw)
        mean = sums[seen] / count[seen]
        diff += np.abs(mean - image[..., c].ravel()[seen].astype(np.float64)).sum()
    return float(diff / (3 * seen.sum()))


def save_frame_npz(path, frame, camera, overwrite=False, **fields) -> None:
    """Frame buffers and camera JSON in one ``.npz`` (tests compare it with a direct render);
    ``fields`` are more arrays to store."""
    import io

    from ..files import atomic_write_bytes

    buf = io.BytesIO()
    extra = {k: getattr(frame, k) for k in ("albedo", "object_alpha", "noisy_color")
             if getattr(frame, k, None) is not None}
    np.savez(buf, color=frame.color, depth=frame.depth, normal=frame.normal, alpha=frame.alpha,
             camera=np.array(model.camera_json(camera)), exposure=np.float64(frame.exposure),
             **extra, **fields)
    atomic_write_bytes(path, buf.getvalue(), overwrite)



__all__ = ["Automation", "AutomationMixin", "grab_window", "live_view_difference", "save_frame_npz"]
