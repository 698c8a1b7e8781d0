"""The interactive viewer: ``pointviz.view(cloud_or_scene)`` and ``pointviz view INPUT``.

Two backends show a splat preview next to the ray-traced frame, with a Render action that traces
the preview's current view on a worker thread:

* ``"open3d"`` (default): an Open3D ``gui.Application`` window (:mod:`.o3d_app`);
* ``"pyvista"``: a VTK window with Gaussian point splats (:mod:`.pv_app`).

Submodules are imported on use; :mod:`.model` and :mod:`.worker` need no GUI toolkit.
"""

from __future__ import annotations

import math
import time

from ..errors import InputError

#: Backends accepted by :func:`view`.
BACKENDS = ("open3d", "pyvista")


def view(cloud_or_scene, backend: str = "open3d", *, camera=None, settings=None,
         render: bool = False, live: bool = False, orbit=None, screenshot=None, frame=None, report=None, overwrite=False,
         title: str | None = None, window_size=None, on_ready=None, gui_trace: bool = False,
         **setting_overrides):
    """Open the viewer on a cloud or scene and block until its window closes.

    Parameters
    ----------
    cloud_or_scene : PointCloud, SurfelScene or Scene
    backend : {"open3d", "pyvista"}
    camera : Camera, optional
        Initial view (default: the whole scene).
    settings : ViewerSettings, optional
        Default: from the scene (its light and ground), updated by ``setting_overrides``
        (any :class:`~pointviz.viewer.model.ViewerSettings` field, e.g. ``spp=16``, or
        ``up="+Z"``: the Up control's start value, the scene seen with that up).
    render : bool
        Press Render once the preview is up.
    live : bool
        Start with the live ray-traced viewport (Open3D backend), hold still 3 s, then go on
        (render, screenshot...).
    orbit : float, optional
        With ``live``: first circle the data for this many seconds (the report's ``live_fps``,
        ``live_resolution``, ``still_spp``, ``preview_fps``), then close the window.
    screenshot : path, optional
        Save a PNG of the whole window (preview and ray-traced frame), then close it.
    frame : path, optional
        Also save the ray-traced frame's buffers and camera as ``.npz``.
    report : path, optional
        Write a JSON report (timings, widget rectangles, camera, settings) when the window closes.
    overwrite : bool
        Replace existing screenshot/frame/report files.
    on_ready : callable(viewer), optional
        Called with the viewer object before the GUI loop starts (for scripts).
    gui_trace : bool
        Open3D backend: add to the report what the GUI thread did when (its timed callbacks
        and the window's phases; ``viewer.gui_trace`` holds it in any case).

    Returns
    -------
    viewer
        The backend's viewer object after its window closed (``.frame``, ``.timings``...).
    """
    t_start = time.monotonic()
    from . import model

    if backend not in BACKENDS:
        raise InputError(f"backend: expected one of {BACKENDS}, got {backend!r}")
    scene = model.as_scene(cloud_or_scene)
    if settings is None:
        settings = model.initial_settings(scene, **setting_overrides)
    elif setting_overrides:
        settings = settings.updated(**setting_overrides)
    if title is None:
        first = scene.objects[0].geometry
        name = getattr(getattr(first, "cloud", first), "name", None)
        title = f"pointviz — {name}" if name else "pointviz"
    for path in (screenshot, frame, report):
        if path is not None:
            from ..files import check_output_path

            check_output_path(path, overwrite)
    if orbit is not None and not (live and float(orbit) >= 0 and math.isfinite(float(orbit))):
        raise InputError(f"orbit: expected seconds >= 0 with live=True, got {orbit!r}"
                         + ("" if live else " without live"))
    if live and backend != "open3d":
        raise InputError("live: the live viewport needs the open3d backend")
    automated = render or live or screenshot is not None or frame is not None
    if backend == "open3d":
        from . import o3d_app

        auto = None
        if automated or report is not None:
            auto = o3d_app.Automation(render=render, live=live, orbit=orbit,
                                      screenshot=screenshot, frame=frame,
                                      report=report, overwrite=overwrite,
                                      close=screenshot is not None or frame is not None
                                      or orbit is not None, gui_trace=gui_trace)
        viewer = o3d_app.run(scene, settings, camera, title, auto, t_start,
                             window_size or o3d_app.DEFAULT_WINDOW_SIZE, on_ready)
        error = viewer.automation_error
        if error:
            from ..errors import PointvizError

            raise PointvizError(f"viewer: {error}")
        return viewer
    from . import pv_app

    return pv_app.run(scene, settings, camera, title, render=render, screenshot=screenshot,
                      frame=frame, report=report, overwrite=overwrite, t_start=t_start,
                      window_size=window_size or pv_app.DEFAULT_WINDOW_SIZE, on_ready=on_ready)


__all__ = ["BACKENDS", "view"]
