"""The Open3D viewer: a ``gui.Application`` window with a splat preview, the ray-traced frame and
a side panel.

Threads
-------
* :class:`O3DViewer` and every widget live on the **GUI thread** (the thread that calls
  ``gui.Application.instance.run()``); all its methods run there unless stated.
* The :class:`~pointviz.viewer.worker.RenderWorker` thread traces frames and owns no widget.
  Its reports cross to the GUI thread through ``post_to_main_thread`` only (``_post``).
* :meth:`O3DViewer.call` lets another thread (a script, a test) run a function on the GUI thread
  and wait for its result.

Model / view / controller: :class:`~pointviz.viewer.model.ViewerSettings` is the single source of
truth; each handler replaces fields of it and calls :meth:`O3DViewer._apply_settings`, which
pushes it into the widgets and the preview scene.
"""

from __future__ import annotations

import collections
import math
import threading
import time

import numpy as np

from .. import interrupt
from ..errors import InputError, require
from ..images import srgb_to_linear
from ..settings import SIDES
from . import model, o3d_display
from .model import PREVIEW_BACKGROUND
from .o3d_actions import ActionsMixin
from .o3d_automation import Automation, AutomationMixin, grab_window, save_frame_npz
from .gui_trace import GuiTrace
from .o3d_live import LiveMixin
from .worker import RenderWorker, display_image

#: Side panel width, in em (font heights).
PANEL_WIDTH_EM = 19
#: Status bar height, in em.
STATUS_HEIGHT_EM = 1.8
#: Default window size, pixels (fits a 1600 x 1000 Xvfb screen with room to spare).
DEFAULT_WINDOW_SIZE = (1580, 680)
#: Relative change of the preview point size that triggers a material update (avoids a
#: re-upload on every tick of a tiny zoom).
POINT_SIZE_TOLERANCE = 0.05
#: Open3D sun intensity (lux-like units of Filament) for a light of intensity 1.
SUN_INTENSITY_PER_UNIT = 75000.0
#: Open3D image-based (ambient) light intensity of the preview: dimmer than Open3D's default so
#: that the sun's direction reads on the splats, like the ray tracer's sky ambient.
PREVIEW_AMBIENT = 15000.0
#: Least time between two redraws of the window for the progress bar, seconds. Each redraw of
#: the whole window keeps the GUI thread (and the software rasteriser's threads) busy for
#: 20-40 ms idle and 100-250 ms with every core busy: a GUI call arriving meanwhile waits for it.
PROGRESS_REDRAW_INTERVAL_S = 1.0
#: Ground quad half size, in scene diagonals.
GROUND_HALF_SIZE = 2.0
#: The preview ground's base colour (sRGB) by ground kind, before the preview's shading.
PREVIEW_GROUND_COLORS = {"matte": (0.62, 0.64, 0.68), "mirror": (0.5, 0.54, 0.62)}
#: The ground quad's texture coordinates are all GROUND_UV (the quad has no texture). They must
#: be set: Open3D uploads a mesh without texture coordinates with its per-vertex UVs unwritten
#: (whatever the heap held), and its material samples its blank texture with anisotropic
#: filtering, which Mesa's software rasteriser (llvmpipe) does by looping over every texel of
#: the pixel's footprint: large garbage UVs made that millions of texels per ground pixel, and
#: the window hung in its first draw (seen under load, where the heap's contents vary).
#: Constant UVs have no footprint at all.
GROUND_UV = 0.0


class O3DViewer(LiveMixin, ActionsMixin, AutomationMixin):
    """The viewer window (GUI thread).

    Parameters
    ----------
    scene : Scene
        What to show and trace.
    settings : ViewerSettings
    camera : Camera, optional
        Initial view; default frames the scene.
    title : str
    automation : Automation, optional
    t_start : float, optional
        ``time.monotonic()`` when :func:`pointviz.view` was called (time-to-first-preview).
    window_size : (int, int)
    """

    def __init__(self, scene, settings, camera=None, title="pointviz", automation=None,
                 t_start=None, window_size=DEFAULT_WINDOW_SIZE):
        o3d = require("open3d", "viewer")
        self.o3d = o3d
        self.gui = o3d.visualization.gui
        self.rendering = o3d.visualization.rendering
        self.app = self.gui.Application.instance
        self.settings = settings.validate()
        self.source_scene = scene  # as given; ``scene`` is it seen with the settings' up
        self.scene = model.scene_with_up(scene, self.settings.up)
        self.automation = automation
        self.t_start = time.monotonic() if t_start is None else t_start
        self.timings: dict = {}
        # what the GUI thread did when (cheap; read by drivers that time GUI round trips)
        self.gui_trace = GuiTrace(self.t_start)
        self.gui_trace.hook_gc()
        self.frame = None  # last finished Frame
        self.mesh_frame = None
        self.frame_camera = None
        self.show_frame = True
        self.job = None  # the RenderJob being traced (None when idle)
        self.render_started = 0.0
        self.tick_times: list[float] = []  # ticks seen while a render runs (responsiveness)
        self.closed = False
        self.closed_at = None                   # when the close handler finished (monotonic)
        self.loop_ended = threading.Event()     # set once the GUI loop has returned
        self.path = None
        self.playing = None  # (t0 wall clock, path) while a path plays
        self._point_size = None
        self._shaded_for = None  # the light (azimuth, elevation) the preview's colours are shaded for
        self._last_view = None
        self._first_tick = None
        self._warming = False  # the first frame's background image (_warm_background) is up
        self._closing = False
        # work for the GUI thread that must not force a redraw of the window (progress reports,
        # ``call(..., redraw=False)``): drained by the tick event. Open3D redraws the whole
        # window after every ``post_to_main_thread`` function, which under a software
        # rasteriser costs 20-40 ms of CPU idle and several times that with every core busy
        self._tick_queue: collections.deque = collections.deque()
        self._progress_dirty = False
        self._progress_drawn = 0.0
        self.worker = RenderWorker(self._post_progress, self._post_done, self._post_error)
        self._init_live()

        self._measure_scene()

        w, h = window_size
        self.window = self.app.create_window(title, w, h)
        self._build_widgets()
        self._fit_viewport()
        self._load_preview()
        self._setup_camera(camera)
        self._apply_settings()
        self.timings["window_built_s"] = time.monotonic() - self.t_start

    def _measure_scene(self) -> None:
        lo, hi = (np.asarray(b, dtype=np.float64) for b in self.scene.bounds())
        self.center = 0.5 * (lo + hi)
        self.diagonal = float(np.linalg.norm(hi - lo))

    # ================================================================== construction
    def _build_widgets(self) -> None:
        gui = self.gui
        win = self.window
        em = win.theme.font_size
        self.em = em
        self.preview = gui.SceneWidget()
        self.preview.scene = self.rendering.Open3DScene(win.renderer)
        self.preview.scene.set_background(o3d_display.background_color(PREVIEW_BACKGROUND))
        self.preview.set_on_mouse(self._on_mouse)
        # redraw the 3D scene only when it changes, not for every progress-bar update: with a
        # software rasteriser a scene redraw costs tens of ms and competes with the tracer
        self.preview.enable_scene_caching(True)
        # the preview is a proxy (shadows and reflections come from the ray tracer): no
        # antialiasing, screen-space occlusion or shadow maps. With a software rasteriser
        # (llvmpipe) they cost seconds per frame on a 1M-point cloud, and Open3D's GUI thread
        # waits for every queued frame whenever its UI buffers grow (a panel text longer than
        # any before): 6-8 s of frozen window with them, 0.14-0.23 s without
        # (benchmarks/o3d_live_stall.py).
        view = self.preview.scene.view
        view.set_antialiasing(False)
        view.set_ambient_occlusion(False)
        view.set_shadowing(False)
        # nor post-processing: a full-screen pass per redraw that also re-maps the colours
        # (the live frames came out ~10 levels off); the colours are encoded instead (o3d_display)
        view.set_post_processing(o3d_display.POST_PROCESSING)
        self.result = gui.ImageWidget(self.o3d.geometry.Image(np.full((8, 8, 3), 40, np.uint8)))
        self.status = gui.Label("loading...")

        sep = round(0.4 * em)
        panel = gui.ScrollableVert(sep, gui.Margins(sep, sep, sep, sep))
        self.panel = panel

        # -- render controls
        box = gui.CollapsableVert("Ray tracing", sep, gui.Margins(0, 0, 0, 0))
        row = gui.Horiz(sep)
        self.btn_render = self._button(row, "Render", self._on_render)
        self.btn_cancel = self._button(row, "Cancel", self._on_cancel)
        self.btn_cancel.enabled = False
        box.add_child(row)
        self._build_live_widgets(box)
        self.progress = gui.ProgressBar()
        box.add_child(self.progress)
        self.render_label = gui.Label("press Render (R)")
        box.add_child(self.render_label)
        self.chk_shadows = self._checkbox(box, "Shadows", "shadows")
        self.num_reflections = self._number(box, "Reflections", "reflections", True, 0, 16)
        self.num_spp = self._number(box, "Samples / pixel", "spp", True, 1, 4096)
        self.num_lod = self._number(box, "LoD threshold (px)", "lod_pixels", False, 0, 64)
        self.sl_az = self._slider(box, "Light azimuth", "light_azimuth_deg", -180, 180)
        self.sl_el = self._slider(box, "Light elevation", "light_elevation_deg", -10, 90)
        self.cmb_ground = self._combo(box, "Ground", "ground", ["scene", *model.GROUNDS])
        self.cmb_sides = self._combo(box, "Sides", "sides", ["scene", *SIDES])
        self.num_width = self._number(box, "Width (0: view)", "width", True, 0, 8192)
        self.num_height = self._number(box, "Height (0: view)", "height", True, 0, 8192)
        self.cmb_display = self._combo(box, "Show frame", "display", list(model.DISPLAYS))
        self.chk_show = gui.Checkbox("Frame visible (overlay)")
        self.chk_show.checked = True
        self.chk_show.set_on_checked(self._on_show_frame)
        box.add_child(self.chk_show)
        panel.add_child(box)

        # -- preview controls
        box = gui.CollapsableVert("Preview", sep, gui.Margins(0, 0, 0, 0))
        self.cmb_up = gui.Combobox()
        for item in model.up_choices(self.source_scene.up):
            self.cmb_up.add_item(item)
        self.cmb_up.set_on_selection_changed(self._on_up_selected)
        self._labelled(box, "Up", self.cmb_up)
        self.cmb_color = self._combo(box, "Colour by", "color_mode", list(model.COLOR_MODES))
        self.sl_scale = self._slider(box, "Point scale", "point_scale", 0.25, 4.0, integer=False)
        self.num_maxpts = self._number(box, "LoD max points", "preview_max_points", True, 1000, 10**9)
        panel.add_child(box)

        # -- actions
        box = gui.CollapsableVert("Output", sep, gui.Margins(0, 0, 0, 0))
        self.btn_save = self._button(box, "Save image...", self._on_save_image)
        self._button(box, "Copy camera", self._on_copy_camera)
        row = gui.Horiz(sep)
        self._button(row, "Add keyframe", self._on_add_keyframe)
        self._button(row, "Save path...", self._on_save_path)
        box.add_child(row)
        self.btn_play = self._button(box, "Play path", self._on_play_path)
        self.path_label = gui.Label("path: 0 keyframes")
        box.add_child(self.path_label)
        self.btn_compare = self._button(box, "Compare with mesh", self._on_compare)
        if not _compare_available():
            self.btn_compare.enabled = False
            self.btn_compare.tooltip = "needs pointviz.compare (not installed)"
        panel.add_child(box)

        win.add_child(self.preview)
        win.add_child(self.result)
        win.add_child(panel)
        win.add_child(self.status)
        win.set_on_layout(self._on_layout)
        win.set_on_tick_event(self._on_tick)
        win.set_on_close(self._on_close)
        win.set_on_key(self._on_key)

    def _button(self, parent, text, handler):
        b = self.gui.Button(text)
        b.horizontal_padding_em = 0.5
        b.vertical_padding_em = 0.1
        b.set_on_clicked(handler)
        parent.add_child(b)
        return b

    def _labelled(self, parent, text, widget):
        grid = self.gui.VGrid(2, int(0.25 * self.em))
        grid.add_child(self.gui.Label(text))
        grid.add_child(widget)
        parent.add_child(grid)
        return widget

    def _checkbox(self, parent, text, key):
        cb = self.gui.Checkbox(text)
        cb.set_on_checked(lambda v: self._set(**{key: bool(v)}))
        parent.add_child(cb)
        return cb

    def _number(self, parent, text, key, integer, lo, hi):
        ne = self.gui.NumberEdit(self.gui.NumberEdit.INT if integer else self.gui.NumberEdit.DOUBLE)
        ne.set_limits(lo, hi)
        if integer:
            ne.set_on_value_changed(lambda v: self._set(**{key: int(v)}))
        else:
            ne.set_on_value_changed(lambda v: self._set(**{key: float(v)}))
        return self._labelled(parent, text, ne)

    def _slider(self, parent, text, key, lo, hi, integer=True):
        sl = self.gui.Slider(self.gui.Slider.INT if integer else self.gui.Slider.DOUBLE)
        sl.set_limits(lo, hi)
        sl.set_on_value_changed(lambda v: self._set(**{key: float(v)}))
        return self._labelled(parent, text, sl)

    def _combo(self, parent, text, key, items):
        cb = self.gui.Combobox()
        for item in items:
            cb.add_item(item)
        cb.set_on_selection_changed(
            lambda value, index: self._set(**{key: None if value == "scene" else value}))
        return self._labelled(parent, text, cb)

    # ================================================================== model -> view
    def _set(self, **changes) -> None:
        """Every handler ends here: replace settings fields, then push them everywhere."""
        try:
            self.settings = self.settings.updated(**changes)
        except InputError as exc:
            self._message("Invalid setting", str(exc))
        self._apply_settings(preview_changed=bool(
            {"color_mode", "preview_max_points"} & set(changes)))

    def _apply_settings(self, preview_changed=False) -> None:
        s = self.settings
        self.chk_shadows.checked = s.shadows
        self.num_reflections.int_value = s.reflections
        self.num_spp.int_value = s.spp
        if s.lod_pixels != "auto":  # the automatic level of detail has no threshold to show
            self.num_lod.double_value = s.lod_pixels
        self.sl_az.int_value = round(s.light_azimuth_deg)
        self.sl_el.int_value = round(s.light_elevation_deg)
        self.cmb_ground.selected_text = "scene" if s.ground is None else s.ground
        self.cmb_sides.selected_text = "scene" if s.sides is None else s.sides
        self.num_width.int_value = s.width
        self.num_height.int_value = s.height
        self.cmb_display.selected_text = s.display
        self.cmb_color.selected_text = s.color_mode
        self.cmb_up.selected_text = model.up_label(self.scene.up)
        self.sl_scale.double_value = s.point_scale
        self.num_maxpts.int_value = s.preview_max_points
        if preview_changed:
            self._load_preview()
        self._apply_lighting()
        self._apply_ground()
        self._update_point_size(force=True)
        if self.live is not None:  # a reloaded cloud or ground stays hidden in live mode
            self._show_splats(False)
        self.window.set_needs_layout()

    def _on_up_selected(self, text, index) -> None:
        """The Up control's handler (what the combobox calls with the item picked)."""
        self.set_up(text)

    def set_up(self, up) -> None:
        """Show the scene with another up (a label of :data:`model.UP_AXES` or a vector): the
        scene is seen anew (trees shared, nothing re-read), the camera frames it for that up,
        and the ground, light and preview shading turn with it. A render under way is
        cancelled and its frame never shown; the last frame (of the old up) is cleared."""
        if isinstance(up, str) and up not in model.UP_AXES and up.startswith("("):
            up = self.source_scene.up  # the scene's own up (the item made for it: no axis)
        t0 = time.monotonic()
        w, h = self._preview_size()
        try:
            change = model.change_up(self.source_scene, self.settings, up, w, h)
        except InputError as exc:
            self._message("Invalid setting", str(exc))
            self._apply_settings()
            return
        if np.array_equal(change.scene.up, self.scene.up):
            return
        self.gui_trace.mark("up change")
        if self.job is not None:  # a frame of the old up: cancelled, and ignored if it comes
            self.worker.cancel()
            self._end_job()
            self.progress.value = 0.0
        self.frame = self.mesh_frame = self.frame_camera = None
        self.result.update_image(self.o3d.geometry.Image(np.full((8, 8, 3), 40, np.uint8)))
        self.render_label.text = f"up {model.up_label(change.scene.up)}: press Render (R)"
        self.settings, self.scene = change.settings, change.scene
        self._measure_scene()
        self._shaded_for = None  # the shading depends on the up
        self._apply_settings(preview_changed=self.settings.color_mode == "height")
        self.apply_camera(change.camera)
        if self.live is not None:  # the live view's frames of the old up are never shown
            self._live_tick()
            self._live_floor = self.live_generation
        if self.automation is not None and self.automation.state == "rendering":
            self._on_render()  # the scripted render it cancelled, of the new scene
        self.timings.setdefault("up_changes", []).append(
            {"up": list(change.scene.up), "seconds": time.monotonic() - t0})

    def _apply_lighting(self) -> None:
        s = self.settings
        d = model.light_direction(s.light_azimuth_deg, s.light_elevation_deg, self.scene.up)
        if self._shaded_for != (s.light_azimuth_deg, s.light_elevation_deg):
            self._upload_cloud()  # the points' colours are shaded by the light
        sc = self.preview.scene
        sc.set_lighting(sc.LightingProfile.NO_SHADOWS, (-d).astype(np.float32))
        sc.scene.set_sun_light((-d).astype(np.float32), [1.0, 1.0, 1.0],
                               SUN_INTENSITY_PER_UNIT * s.light_intensity)
        sc.scene.enable_sun_light(True)
        sc.scene.set_indirect_light_intensity(PREVIEW_AMBIENT)

    def _apply_ground(self) -> None:
        sc = self.preview.scene
        if sc.has_geometry("ground"):
            sc.remove_geometry("ground")
        ground = self.settings.ground
        if ground is None:
            ground = "none" if self.scene.ground is None else (
                "mirror" if self.scene.ground.mirror > 0.3 else "matte")
        if ground == "none":
            return
        e1, e2, _ = model.horizontal_basis(self.scene.up)
        p = np.asarray(self.scene.ground_point(), dtype=np.float64)
        r = GROUND_HALF_SIZE * self.diagonal
        verts = np.array([p - r * e1 - r * e2, p + r * e1 - r * e2, p + r * e1 + r * e2,
                          p - r * e1 + r * e2])
        mesh = self.o3d.geometry.TriangleMesh(self.o3d.utility.Vector3dVector(verts),
                                              self.o3d.utility.Vector3iVector([[0, 1, 2], [0, 2, 3]]))  # facing up
        mesh.compute_vertex_normals()
        mesh.triangle_uvs = self.o3d.utility.Vector2dVector(np.full((6, 2), GROUND_UV))
        mat = self.rendering.MaterialRecord()
        # unlit, its colour shaded beforehand like the points' (a lit material's output would
        # reach the window unencoded with post-processing off, o3d_display)
        shaded = model.shade_colors(srgb_to_linear(np.array([PREVIEW_GROUND_COLORS[ground]])),
                                    np.array([self.scene.up], dtype=np.float64), self.settings,
                                    self.scene.up)
        mesh.vertex_colors = self.o3d.utility.Vector3dVector(
            np.repeat(o3d_display.point_colors(shaded), 4, axis=0))
        mat.shader = "defaultUnlit"
        sc.add_geometry("ground", mesh, mat)

    def _load_preview(self) -> None:
        t0 = time.monotonic()
        data = model.preview_data(self.scene, self.settings)
        self.preview_info = data
        self.median_radius = float(np.median(data.radii))
        self._upload_cloud()
        self.timings["preview_upload_s"] = time.monotonic() - t0
        self._update_status()

    def _upload_cloud(self) -> None:
        """(Re)place the preview's points, their colours shaded by the settings' lights."""
        data, s = self.preview_info, self.settings
        pcd = self.o3d.geometry.PointCloud()
        pcd.points = self.o3d.utility.Vector3dVector(data.points)
        colors = model.shade_colors(data.colors, data.normals, s, self.scene.up)
        pcd.colors = self.o3d.utility.Vector3dVector(o3d_display.point_colors(colors))
        sc = self.preview.scene
        if sc.has_geometry("cloud"):
            sc.remove_geometry("cloud")
        sc.add_geometry("cloud", pcd, self._point_material(self._point_size or 3.0))
        self._shaded_for = (s.light_azimuth_deg, s.light_elevation_deg)
        if self.live is not None:  # live mode: the splats stay hidden
            sc.show_geometry("cloud", False)

    def _point_material(self, size):
        mat = self.rendering.MaterialRecord()
        mat.shader = "defaultUnlit"  # colours shaded beforehand (model.shade_colors)
        mat.point_size = float(size)
        return mat

    def _setup_camera(self, camera) -> None:
        from ..camera import Camera

        w, h = self._preview_size()
        if camera is None:
            camera = Camera.fit(self.scene, fov_deg=40.0, width=w, height=h)
        self.apply_camera(camera)

    def _preview_size(self) -> tuple[int, int]:
        """The preview's size in pixels, from the layout rule (valid before the first layout)."""
        r = self.window.content_rect
        area_w = r.width - int(PANEL_WIDTH_EM * self.em)
        area_h = r.height - int(STATUS_HEIGHT_EM * self.em)
        if self.settings.display == "side":
            area_w //= 2
        return max(area_w, 1), max(area_h, 1)

    def _fit_viewport(self) -> None:
        """Live automation with a set width and height: size the window so that the preview (the
        live viewport) has exactly that many pixels (the size applies after the next event)."""
        a, s = self.automation, self.settings
        if a is None or not a.live or not (s.width and s.height):
            return
        n = 2 if s.display == "side" else 1
        size = self.gui.Size(n * s.width + int(PANEL_WIDTH_EM * self.em),
                             s.height + int(STATUS_HEIGHT_EM * self.em))
        self.window.size = size

    def apply_camera(self, camera) -> None:
        """Point the preview's camera like ``camera`` (eye, target, up), with a vertical field
        of view wide enough to show the camera's whole image in the preview's aspect."""
        w, h = self._preview_size()
        tan_h = camera.tan_half * max(1.0, camera.aspect * h / w)
        fov = math.degrees(2.0 * math.atan(tan_h))
        bbox = self.o3d.geometry.AxisAlignedBoundingBox(self.center - self.diagonal,
                                                        self.center + self.diagonal)
        self.preview.setup_camera(float(fov), bbox, camera.target.astype(np.float32))
        self.preview.look_at(camera.target.astype(np.float32), camera.eye.astype(np.float32),
                             camera.true_up.astype(np.float32))
        if self.live is None:  # live: the splats are hidden (set_live(False) sizes them)
            self._update_point_size(force=True)

    def _update_point_size(self, force=False) -> None:
        cam = self.preview.scene.camera
        view = np.asarray(cam.get_view_matrix())
        eye = np.linalg.inv(view)[:3, 3]
        frame = self.preview.frame
        size = model.point_size_px(self.median_radius, float(np.linalg.norm(eye - self.center)),
                                   max(frame.height, 1), cam.get_field_of_view(),
                                   self.settings.point_scale)
        old = self._point_size
        if force or old is None or abs(size - old) > POINT_SIZE_TOLERANCE * old:
            self._point_size = size
            if self.preview.scene.has_geometry("cloud"):
                self.preview.scene.modify_geometry_material("cloud", self._point_material(size))
            self._update_status()

    def _update_status(self) -> None:
        info = getattr(self, "preview_info", None)
        parts = [info.note if info else ""]
        if self._point_size:
            parts.append(f"point size {self._point_size:.1f} px")
        if "first_preview_s" in self.timings:
            parts.append(f"first preview {self.timings['first_preview_s']:.2f} s")
        if self.frame is not None:
            st = self.frame.stats
            parts.append(f"frame {self.frame.width}x{self.frame.height} in "
                         f"{self.timings.get('last_render_s', st['seconds']):.2f} s "
                         f"({st['rays_per_second'] / 1e6:.2f} Mrays/s)")
        self.status.text = "  |  ".join(p for p in parts if p)

    # ================================================================== layout and events
    def _on_layout(self, ctx) -> None:
        gui = self.gui
        r = self.window.content_rect
        em = self.em
        panel_w = int(PANEL_WIDTH_EM * em)
        status_h = int(STATUS_HEIGHT_EM * em)
        area_w = r.width - panel_w
        area_h = r.height - status_h
        self.panel.frame = gui.Rect(r.x + area_w, r.y, panel_w, area_h)
        self.status.frame = gui.Rect(r.x + int(0.5 * em), r.y + area_h, r.width - em, status_h)
        if self.settings.display == "side":
            half = area_w // 2
            self.preview.frame = gui.Rect(r.x, r.y, half, area_h)
            self.result.frame = gui.Rect(r.x + half, r.y, area_w - half, area_h)
            self.preview.visible = True
            self.result.visible = True
        else:
            self.preview.frame = gui.Rect(r.x, r.y, area_w, area_h)
            self.result.frame = gui.Rect(r.x, r.y, area_w, area_h)
            show = self.show_frame and self.frame is not None
            self.result.visible = show
            self.preview.visible = not show
        if self.live is None:  # the preview's height decides the point size
            self._update_point_size()

    def _on_tick(self) -> bool:
        with self.gui_trace.span("tick"):
            return self._tick()

    def _tick(self) -> bool:
        now = time.monotonic()
        if interrupt.cancelled() and not self._closing:  # Ctrl-C in the CLI's terminal
            self._closing = True
            self.app.post_to_main_thread(self.window, self.window.close)
            return False
        if self._first_tick is None:
            self._first_tick = now
            self.gui_trace.mark("first tick")
            self.timings["first_preview_s"] = now - self.t_start
            self._update_status()
            self._warm_background(True)
            return True
        if self._warming:
            self._warm_background(False)
        if self.job is not None:
            self.tick_times.append(now)
        redraw = self._drain_tick_queue(now)
        view = np.asarray(self.preview.scene.camera.get_view_matrix())
        if self._last_view is None or not np.allclose(view, self._last_view):
            self._last_view = view
            # live: the splats are hidden and the viewport shows the traced picture, which only
            # changes when a frame arrives (that redraws); a redraw per camera tick would cost
            # the software rasteriser's CPU for an unchanged picture
            if self.live is None:
                self._update_point_size()
                redraw = True
        if self.playing is not None:
            redraw |= self._advance_path(now)
        if self.automation is not None:
            with self.gui_trace.span("automation"):
                self._automate(now)
        with self.gui_trace.span("live tick"):
            self._live_tick()
        return redraw

    def _warm_background(self, on: bool) -> None:
        """Show a background image of the background's own colour for the first frame: the
        software rasteriser compiles the image's shaders then, not when the first live frame
        comes (a first live redraw of 0.3-1 s otherwise)."""
        self._warming = on
        if self.live is not None:
            return
        sc = self.preview.scene
        color = o3d_display.background_color(PREVIEW_BACKGROUND)
        if on:
            rgb = np.round(np.asarray(PREVIEW_BACKGROUND[:3]) * 255).astype(np.uint8)
            sc.set_background(color, self.o3d.geometry.Image(
                o3d_display.background_image(np.broadcast_to(rgb, (8, 8, 3)))))
        else:
            sc.set_background(color, None)
        self.preview.force_redraw()

    def _drain_tick_queue(self, now) -> bool:
        """Run the queued GUI-thread work; True when the progress bar is due for a redraw (at
        most once per PROGRESS_REDRAW_INTERVAL_S)."""
        while self._tick_queue:
            with self.gui_trace.span("tick queue"):
                self._tick_queue.popleft()()
        if self._progress_dirty and now - self._progress_drawn >= PROGRESS_REDRAW_INTERVAL_S:
            self._progress_dirty = False
            self._progress_drawn = now
            return True
        return False

    def _on_mouse(self, event):
        return self.gui.Widget.EventCallbackResult.IGNORED

    def _on_key(self, event):
        if event.type == self.gui.KeyEvent.Type.DOWN and event.key == self.gui.KeyName.R:
            self._on_render()
            return True
        if event.type == self.gui.KeyEvent.Type.DOWN and event.key == self.gui.KeyName.L:
            self.set_live(self.live is None)
            return True
        return False

    def _on_close(self) -> bool:
        """Window closing (GUI thread): cancel the render and wait for the worker to end."""
        t0 = time.monotonic()
        self.gui_trace.mark("close")
        self.closed = True
        ended = self.worker.shutdown()
        ended = self._close_live() and ended
        self.timings["close_join_s"] = time.monotonic() - t0
        self.timings["worker_ended_on_close"] = ended
        self._write_report()
        self.closed_at = time.monotonic()
        return True

    def _on_show_frame(self, checked) -> None:
        self.show_frame = bool(checked)
        self.window.set_needs_layout()

    # ================================================================== rendering
    def current_camera(self):
        """The pointviz Camera of the preview's current view, at the output size."""
        cam = self.preview.scene.camera
        frame = self.preview.frame
        w, h = model.output_size(self.settings, max(frame.width, 1), max(frame.height, 1))
        view = np.asarray(cam.get_view_matrix())
        eye = np.linalg.inv(view)[:3, 3]
        forward = -np.linalg.inv(view)[:3, 2]
        dist = max(float((self.center - eye) @ forward), 1e-3 * self.diagonal)
        return model.camera_from_gl(view, np.asarray(cam.get_projection_matrix()), w, h, dist)

    def _on_render(self, compare=False) -> None:
        """The Render button (and the R key, and automation): trace the current view."""
        camera = self.current_camera()
        self.job = self.worker.submit(self.scene, self.settings, camera, compare=compare)
        self.frame_camera = camera
        self.render_started = time.monotonic()
        self.tick_times = []
        self.progress.value = 0.0
        self.btn_cancel.enabled = True
        self.render_label.text = ("reconstructing + rendering..." if compare else
                                  f"rendering {camera.width}x{camera.height}...")

    def _on_compare(self) -> None:
        self._on_render(compare=True)

    def _on_cancel(self) -> None:
        self.worker.cancel()
        self.render_label.text = "cancelling..."

    # -- worker thread -> GUI thread (the only crossing)
    def _post(self, fn, what: str = "posted") -> None:
        if not self.closed:
            def run():
                with self.gui_trace.span(what):
                    fn()

            self.app.post_to_main_thread(self.window, run)

    def _post_progress(self, job_id, done, total):
        if not self.closed:  # no redraw of its own: the tick redraws the bar when it is due
            self._tick_queue.append(lambda: self._show_progress(job_id, done, total))

    def _post_done(self, job_id, result):
        self._post(lambda: self._show_result(job_id, result), "show render result")

    def _post_error(self, job_id, exc):
        self._post(lambda: self._show_error(job_id, exc), "show render error")

    # -- GUI thread
    def _current(self, job_id) -> bool:
        return self.job is not None and self.job.job_id == job_id and not self.closed

    def _show_progress(self, job_id, done, total) -> None:
        if self._current(job_id):
            self.progress.value = done / max(total, 1)
            self._progress_dirty = True

    def _end_job(self) -> None:
        if self.tick_times:
            gaps = np.diff([self.render_started, *self.tick_times])
            self.timings["ticks_during_render"] = len(self.tick_times)
            self.timings["max_tick_gap_during_render_s"] = float(gaps.max())
        self.job = None
        self.btn_cancel.enabled = False

    def _show_result(self, job_id, result) -> None:
        if not self._current(job_id):
            return
        self._end_job()
        self.frame = result.frame
        self.mesh_frame = result.mesh_frame
        self.timings["last_render_s"] = result.seconds
        self.timings.setdefault("renders", []).append(
            {"seconds": result.seconds, "core_seconds": result.frame.stats["seconds"],
             "size": [result.frame.width, result.frame.height],
             "spp": self.settings.spp})
        self.progress.value = 1.0
        if result.mesh_frame is not None:
            self.render_label.text = f"points | {result.mesh_note}"
        else:
            self.render_label.text = f"done in {result.seconds:.2f} s"
        img = result.image if result.image is not None else display_image(result)
        self.result.update_image(self.o3d.geometry.Image(img))
        self._update_status()
        self.window.set_needs_layout()
        self.window.post_redraw()
        if self.automation is not None and self.automation.state == "rendering":
            self._set_auto_state("settle")

    def _show_error(self, job_id, exc) -> None:
        from ..errors import CancelledError

        if not self._current(job_id):
            return
        self._end_job()
        self.progress.value = 0.0
        if isinstance(exc, CancelledError):
            self.render_label.text = "cancelled"
        else:
            self.render_label.text = "render failed"
            self._message("Render failed", f"{type(exc).__name__}: {exc}")
        if self.automation is not None and self.automation.state == "rendering":
            self.automation.info["error"] = f"{type(exc).__name__}: {exc}"
            self._set_auto_state("settle")

def _compare_available() -> bool:
    import importlib.util

    try:
        return importlib.util.find_spec("pointviz.comparison") is not None
    except (ImportError, ValueError):
        return False


def run(scene, settings, camera=None, title="pointviz", automation=None, t_start=None,
        window_size=DEFAULT_WINDOW_SIZE, on_ready=None) -> O3DViewer:
    """Open the window and run the GUI loop on this thread until it closes.

    ``on_ready(viewer)`` is called once the window exists, before the loop starts (scripts and
    tests start their driver thread there).
    """
    o3d = require("open3d", "viewer")
    app = o3d.visualization.gui.Application.instance
    app.initialize()
    viewer = O3DViewer(scene, settings, camera, title, automation, t_start, window_size)
    if on_ready is not None:
        on_ready(viewer)
    watchdog = threading.Thread(target=_quit_if_loop_outlives_window, args=(app, viewer),
                                name="pointviz-close-watchdog", daemon=True)
    watchdog.start()
    app.run()
    viewer.gui_trace.unhook_gc()
    viewer.loop_ended.set()
    viewer.worker.shutdown()
    return viewer


#: How long Open3D's loop may keep running after the window has closed (its close handler has
#: ended the workers and written every output), seconds, before it is asked to quit.
CLOSE_GRACE_S = 10.0


def _quit_if_loop_outlives_window(app, viewer) -> None:
    """(watchdog thread) Once the window has closed, give Open3D's loop CLOSE_GRACE_S to return,
    then ask it to quit. Under heavy load its loop was seen spinning on after its only window
    had closed, so ``app.run()`` never returned."""
    while not viewer.loop_ended.wait(0.5):
        if viewer.closed_at is not None and time.monotonic() - viewer.closed_at > CLOSE_GRACE_S:
            app.quit()
            return


__all__ = ["Automation", "O3DViewer", "grab_window", "run", "save_frame_npz"]
