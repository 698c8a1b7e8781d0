"""The Open3D viewer's output actions: file dialogs, saving the frame and the camera, keyframes and
camera-path playback, message boxes (GUI thread; mixed into :class:`.o3d_app.O3DViewer`)."""

from __future__ import annotations

import time

from ..errors import InputError
from . import model


class ActionsMixin:
    """Handlers of the Output panel. Uses the viewer's ``window``, ``gui``, ``frame``,
    ``settings`` and ``automation`` attributes."""

    def _file_dialog(self, title, filters, on_done) -> None:
        gui = self.gui
        dlg = gui.FileDialog(gui.FileDialog.SAVE, title, self.window.theme)
        for ext, desc in filters:
            dlg.add_filter(ext, desc)

        def done(path):
            self.window.close_dialog()
            try:
                on_done(path)
            except (OSError, InputError) as exc:
                self._message(title, str(exc))

        dlg.set_on_cancel(self.window.close_dialog)
        dlg.set_on_done(done)
        self.window.show_dialog(dlg)

    def _on_save_image(self) -> None:
        if self.frame is None:
            self._message("Save image", "Render a frame first.")
            return
        frame = self.frame
        self._file_dialog("Save image", [(".png", "PNG"), (".exr", "OpenEXR (linear)")],
                          lambda p: self._status_note(f"saved {frame.save(p)}"))

    def _on_copy_camera(self) -> None:
        """Show the current camera as JSON for ``pointviz render --camera`` (select + copy, or
        save it)."""
        camera = self.frame_camera if self.frame is not None else self.current_camera()
        text = model.camera_json(camera)
        self.last_camera_json = text
        gui = self.gui
        dlg = gui.Dialog("Camera")
        em = self.em
        layout = gui.Vert(int(0.5 * em), gui.Margins(em, em, em, em))
        up = model.up_option(self.scene.up, self.source_scene.up)
        self.last_camera_command = f"pointviz render --camera CAM.json{' ' + up if up else ''}"
        layout.add_child(gui.Label(f"Camera for `{self.last_camera_command}`:"))
        edit = gui.TextEdit()
        edit.text_value = text.replace("\n", " ")
        layout.add_child(edit)
        row = gui.Horiz(int(0.5 * em))
        save = gui.Button("Save as...")

        def save_as():
            self.window.close_dialog()
            self._file_dialog("Save camera", [(".json", "camera JSON")],
                              lambda p: self._status_note(f"saved {camera.to_json(p)}"))

        save.set_on_clicked(save_as)
        close = gui.Button("Close")
        close.set_on_clicked(self.window.close_dialog)
        row.add_child(save)
        row.add_child(close)
        layout.add_child(row)
        dlg.add_child(layout)
        self.window.show_dialog(dlg)
        print(text, end="", flush=True)

    def _on_add_keyframe(self) -> None:
        from ..path import CameraPath

        camera = self.current_camera()
        if self.path is None:
            self.path = CameraPath(width=camera.width, height=camera.height)
        try:
            self.path.add(camera)
        except InputError as exc:
            self._message("Add keyframe", str(exc))
        self.path_label.text = f"path: {len(self.path)} keyframes, {self.path.duration:.1f} s"

    def _on_save_path(self) -> None:
        if self.path is None or len(self.path) < 2:
            self._message("Save path", "Add at least two keyframes first.")
            return
        path = self.path
        self._file_dialog("Save camera path", [(".json", "camera path JSON")],
                          lambda p: self._status_note(f"saved {path.save(p)}"))

    def _on_play_path(self) -> None:
        if self.playing is not None:
            self.playing = None
            self.btn_play.text = "Play path"
            return
        if self.path is None or len(self.path) < 2:
            self._message("Play path", "Add at least two keyframes first.")
            return
        self.playing = (time.monotonic(), self.path)
        self.btn_play.text = "Stop"

    def _advance_path(self, now) -> bool:
        t0, path = self.playing
        t = path.start + (now - t0)
        if t >= path.start + path.duration:
            t = path.start + path.duration
            self.playing = None
            self.btn_play.text = "Play path"
        self.apply_camera(path.camera_at(t))
        return True

    def _status_note(self, text) -> None:
        self.render_label.text = text

    def _message(self, title, text) -> None:
        if self.automation is not None:  # no modal dialogs in automation: record instead
            self.automation.info.setdefault("messages", []).append(f"{title}: {text}")
            return
        self.window.show_message_box(title, text)



__all__ = ["ActionsMixin"]
