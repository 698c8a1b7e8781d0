"""The render worker: ray traces one frame at a time on its own thread.

The worker owns no widgets and knows no GUI toolkit. It reports through three callbacks that it
calls **on the worker thread**; each backend wraps them so that only one call crosses threads
(Open3D: ``gui.Application.instance.post_to_main_thread``; pyvista: a queue drained by a timer
on the GUI thread). Cancellation is a :class:`threading.Event` handed to
:func:`pointviz.render` as ``cancel=``: the core checks it between tiles.
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass, field

from ..errors import CancelledError

#: Least time between two progress reports, seconds: each report redraws the window, which a
#: software-rendered GUI pays for with CPU the tracer needs; 5 updates a second look smooth.
PROGRESS_INTERVAL_S = 0.2
#: How long :meth:`RenderWorker.shutdown` waits for the thread by default, seconds.
SHUTDOWN_TIMEOUT_S = 10.0
#: Trace at a lower CPU priority (``render(background=True)``) and, unless the settings name a
#: thread count, on all cores but CORES_LEFT_TO_THE_GUI: the GUI thread then gets a core as soon
#: as it has work. Of the four combinations, this one kept GUI calls fastest both idle and with
#: every core busy (benchmarks/bench_viewer.py; README there).
RENDER_IN_BACKGROUND = True
CORES_LEFT_TO_THE_GUI = 1


@dataclass
class RenderJob:
    """One frame to trace.

    Attributes
    ----------
    scene : Scene
        The input scene (its trees are built on first use, on the worker thread).
    settings : ViewerSettings
    camera : Camera
    job_id : int
        Increases with every job; reports of an older job are ignored by the GUI.
    compare : bool
        Also reconstruct a mesh from the same points (screened Poisson, pointviz.compare) and
        render it with the same camera, lights and ground.
    """

    scene: object
    settings: object
    camera: object
    job_id: int = 0
    compare: bool = False
    submitted: float = field(default_factory=time.monotonic)


@dataclass
class RenderResult:
    """What a finished job hands to the GUI.

    Attributes
    ----------
    frame : Frame
        The ray-traced surfels.
    seconds : float
        Wall time of the whole job (tree build on first use included).
    mesh_frame : Frame or None
        With ``compare``: the reconstructed mesh, same camera and shading.
    mesh_note : str
        With ``compare``: faces and reconstruction time.
    image : (h, w, 3) uint8 or None
        What the GUI shows: the frame in sRGB (with ``compare``, the mesh's beside it), made on
        the worker thread so that the GUI thread only uploads it.
    """

    frame: object
    seconds: float
    mesh_frame: object = None
    mesh_note: str = ""
    image: object = None


class RenderWorker:
    """Runs :func:`pointviz.render` for one :class:`RenderJob` at a time on a daemon thread.

    Parameters
    ----------
    on_progress : callable(job_id, done, total)
    on_done : callable(job_id, RenderResult)
    on_error : callable(job_id, exception)
        ``CancelledError`` is reported here too, so the GUI can reset its buttons.

    All three run on the worker thread and must only hand their arguments over to the GUI
    thread. Methods of this class are called from the GUI thread.
    """

    def __init__(self, on_progress, on_done, on_error, render_fn=None):
        self._on_progress = on_progress
        self._on_done = on_done
        self._on_error = on_error
        self._render_fn = render_fn
        self._thread: threading.Thread | None = None
        self._cancel = threading.Event()
        self._next_id = 0

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def thread(self) -> threading.Thread | None:
        return self._thread

    def submit(self, scene, settings, camera, compare: bool = False) -> RenderJob:
        """Cancel any running job (without waiting) and start a new one."""
        self.cancel()
        self._next_id += 1
        job = RenderJob(scene, settings, camera, self._next_id, compare)
        self._cancel = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(job, self._cancel),
                                        name=f"pointviz-render-{job.job_id}", daemon=True)
        self._thread.start()
        return job

    def cancel(self) -> None:
        """Ask the running job to stop (returns at once; the worker reports CancelledError)."""
        self._cancel.set()

    def shutdown(self, timeout: float = SHUTDOWN_TIMEOUT_S) -> bool:
        """Cancel and wait for the thread; True if it has ended."""
        self.cancel()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout)
        return t is None or not t.is_alive()

    # -------------------------------------------------------------------- worker thread
    def _run(self, job: RenderJob, cancel: threading.Event) -> None:
        from ..rendering import render
        from .model import render_scene

        render_fn = self._render_fn or render
        last = [0.0]

        def progress(done, total):
            now = time.monotonic()
            if done >= total or now - last[0] >= PROGRESS_INTERVAL_S:
                last[0] = now
                self._on_progress(job.job_id, done, total)
            return not cancel.is_set()

        start = time.monotonic()
        try:
            scene = render_scene(job.scene, job.settings)
            if cancel.is_set():
                raise CancelledError("render cancelled")
            kwargs = dict(job.settings.render_kwargs(), background=RENDER_IN_BACKGROUND)
            if kwargs.get("threads") is None:
                kwargs["threads"] = max(1, (os.cpu_count() or 1) - CORES_LEFT_TO_THE_GUI)
            frame = render_fn(scene, job.camera, progress=progress, cancel=cancel, **kwargs)
            result = RenderResult(frame, 0.0)
            if job.compare:
                mesh_scene, result.mesh_note = mesh_scene_of(scene)
                if cancel.is_set():
                    raise CancelledError("render cancelled")
                result.mesh_frame = render_fn(mesh_scene, job.camera, progress=progress,
                                              cancel=cancel, **kwargs)
            result.image = display_image(result)
        except BaseException as exc:  # noqa: BLE001 - every failure goes back to the GUI
            self._on_error(job.job_id, exc)
            return
        result.seconds = time.monotonic() - start
        self._on_done(job.job_id, result)


#: White gap between the point and mesh pictures of a comparison, pixels.
COMPARE_GAP_PX = 4


def display_image(result: RenderResult):
    """The sRGB picture of a result, (h, w, 3) uint8: the frame, and the mesh's to its right."""
    import numpy as np

    img = result.frame.to_srgb8()
    if result.mesh_frame is not None:
        gap = np.full((img.shape[0], COMPARE_GAP_PX, 3), 255, np.uint8)
        img = np.concatenate([img, gap, result.mesh_frame.to_srgb8()], axis=1)
    return np.ascontiguousarray(img)


#: Octree depth of the viewer's screened Poisson reconstruction (2**8 cells across the object:
#: a few seconds on a million points, enough to see where meshing loses detail).
COMPARE_POISSON_DEPTH = 8


def mesh_scene_of(scene):
    """The same scene with every point cloud replaced by a screened-Poisson mesh of it.

    Returns
    -------
    (Scene, str)
        The mesh scene (same materials, lights, ground, sky) and a note for the status bar.
    """
    from ..meshes import MeshGeometry
    from ..reconstruct import poisson

    geoms, faces, secs = [], 0, 0.0
    for obj in scene.objects:
        cloud = getattr(obj.geometry, "cloud", obj.geometry)
        if not hasattr(cloud, "points"):
            geoms.append(obj.geometry)
            continue
        rec = poisson(cloud, depth=COMPARE_POISSON_DEPTH)
        geoms.append(MeshGeometry(rec.vertices, rec.faces, rec.colors, name="poisson"))
        faces += len(rec.faces)
        secs += rec.seconds
    return scene.replace(clouds=geoms), f"mesh: Poisson depth {COMPARE_POISSON_DEPTH}, {faces:,} faces, {secs:.1f} s"
