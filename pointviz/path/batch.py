"""Rendering every frame of a camera path to PNG files (and a video), resumably: in this process
or on a Dask cluster (:mod:`pointviz.distributed`); the frames are byte-identical either way.

Where frames render by default (``scheduler="auto"``, also the command line's): in this process,
unless a cluster is named (``"local"``, an address or a Client). This process renders each frame
with every core (the core's threads), two frames in flight, and holds the scene and its trees
once; a LocalCluster of 2 single-thread workers on the same cores starts and imports 2 more
processes, sends each the scene and builds its trees, denoiser included, in each, for no more
cores. Measured on 2 cores (benchmarks/README.md, "Camera paths on one machine (2026-11-25)",
``pointviz path`` at the CLI's settings, alternated with the LocalCluster default it replaced,
load 0.9-6.0): on the dragon's scans and a 1.2M-point sphere, 25 and 100 frames at 320x240
and 640x480, 300 at 320x240, the wall time is 0.51-0.94x the cluster's in every run, the CPU
time 0.65-0.90x, and the peak memory of the process tree 0.38-0.66x (dragon, 320x240: 228 MiB
instead of 428).
"""

from __future__ import annotations

import hashlib
import os
import threading
import time
from pathlib import Path
from typing import Any

from ..camera import Camera
from ..errors import CancelledError, FileFormatError, InputError
from ..files import atomic_write_text, json_text, read_json_file
from ..frames import frame_png, is_complete_png
from ..interrupt import stage
from ..progress import ProgressBar
from ..settings import MAX_EXPOSURE, MIN_EXPOSURE, RenderSettings
from ..values import check_image_size as _size
from .camera_path import CameraPath
from .exposure import path_exposure
from .keyframes import check_fps

#: ``scheduler`` value that renders in this process (as does None).
SERIAL = "serial"
#: The default ``scheduler``: this process when no cluster is named (see the module's notes).
AUTO = "auto"
#: ``scheduler`` value that starts a LocalCluster of ``workers`` processes on this machine.
LOCAL = "local"
#: Frames rendered at once in this process (each with every core; see :func:`_render_here`).
FRAMES_IN_FLIGHT = 2
#: Frame file names inside ``out_dir`` (``frame_00000.png`` ...).
FRAME_NAME = "frame_{:05d}.png"
FRAME_GLOB = "frame_*.png"
#: The manifest that ties ``out_dir`` to one scene, camera sequence and render settings.
MANIFEST_NAME = "pointviz_path.json"
MANIFEST_FORMAT = "pointviz.path_render"
#: 2: frames share one exposure (``exposure``: metered, or the settings'); 1 exposed each frame
#: on its own, and its frames are not mixed with a newer render's.
MANIFEST_VERSION = 2
#: What must match for a folder's frames to be this render's (what each key means, in words).
MANIFEST_KEYS = {"version": "the manifest's version", "scene": "the scene",
                 "cameras": "the camera path or image size", "settings": "the render settings",
                 "n_frames": "the frame count", "exposure": "the exposure"}


def _settings_of(render_kwargs: dict) -> dict:
    """Every image-affecting render setting, defaults filled in (so explicit defaults match)."""
    if "progress" in render_kwargs or "cancel" in render_kwargs:
        raise InputError("render_path: progress and cancel apply to the whole path; pass them "
                         "as render_path(progress=..., cancel=...)")
    return RenderSettings.from_kwargs(render_kwargs, "render_path").manifest()


def _path_cameras(path: Any, width: int | None, height: int | None) -> tuple[list[dict], float]:
    """Camera dicts of every frame (at the requested size) and the path's fps."""
    if isinstance(path, (str, os.PathLike)):
        path = CameraPath.load(path)
    if not isinstance(path, CameraPath):
        raise InputError(f"path: expected a CameraPath or a path JSON file, got {type(path).__name__}")
    if path.n_frames == 0:
        raise InputError("path: the camera path has no keyframes")
    w = path.width if width is None else _size(width, "width")
    h = path.height if height is None else _size(height, "height")
    if width is not None and height is None:
        h = max(1, round(w * path.height / path.width))
    elif height is not None and width is None:
        w = max(1, round(h * path.width / path.height))
    return [cam.with_size(w, h).to_dict() for cam in path.cameras()], path.fps


def _digest(obj: Any) -> str:
    return hashlib.sha256(json_text(obj).encode()).hexdigest()


def _read_manifest(out: Path) -> tuple[dict | None, str | None]:
    """The manifest in ``out``, or None, with why it is unusable when it is there but unusable
    (unreadable, not a JSON object)."""
    mpath = out / MANIFEST_NAME
    if not mpath.exists():
        return None, None
    try:
        old = read_json_file(mpath)
    except (InputError, FileFormatError) as exc:
        return None, f"its manifest {mpath.name} is unreadable ({exc})"
    if not isinstance(old, dict):
        return None, f"its manifest {mpath.name} is not a JSON object"
    return old, None


def _prepare_out_dir(out: Path, manifest: dict, old: dict | None, unusable: str | None,
                     resume: bool, overwrite: bool) -> None:
    """Create ``out`` or check that its frames belong to this render; write the manifest.

    ``old``, ``unusable``: what :func:`_read_manifest` found in ``out``. A folder holding frames
    of another render (another scene, path or settings) is refused unless ``overwrite``, which
    deletes those frames (only ``frame_*.png`` and the manifest).
    """
    if out.exists() and not out.is_dir():
        raise InputError(f"out_dir: {out} is a file, not a folder")
    out.mkdir(parents=True, exist_ok=True)
    mpath = out / MANIFEST_NAME
    frames = sorted(out.glob(FRAME_GLOB))
    reason = unusable
    if old is not None:
        # the exposure last: a metered one follows from the rest
        changed = [k for k in MANIFEST_KEYS if old.get(k) != manifest[k]]
        if len(changed) > 1 and "exposure" in changed:
            changed.remove("exposure")
        if changed:
            reason = ("it holds frames of a different render (" +
                      ", ".join(MANIFEST_KEYS[k] for k in changed) + " changed)")
        elif not resume and frames:
            reason = "it holds frames of this render and resume=False"
    elif unusable is None and frames:
        reason = f"it holds {len(frames)} frame files but no {MANIFEST_NAME}"
    if reason is not None:
        if not overwrite:
            raise InputError(f"out_dir: {out}: {reason}; pass overwrite=True (CLI: --overwrite) "
                             f"to delete its frames, or choose another folder")
        for f in frames:
            f.unlink()
    for stale in out.glob(".frame_*.part"):  # left by a process killed mid-write
        stale.unlink()
    atomic_write_text(mpath, json_text(manifest), overwrite=True)


def _recorded_exposure(old: dict | None, manifest: dict) -> float | None:
    """The exposure an earlier manifest ``old`` records for the render ``manifest`` describes
    (all but its exposure), or None: no manifest, or one of another render."""
    if old is None or any(old.get(k) != v for k, v in manifest.items()):
        return None
    value = old.get("exposure")
    ok = isinstance(value, float) and MIN_EXPOSURE <= value <= MAX_EXPOSURE
    return value if ok else None


def _render_here(scene: Any, jobs: list[tuple[int, dict]], render_kwargs: dict, write: Any,
                 is_cancelled: Any) -> None:
    """Render ``jobs`` (index, camera dict) in this process, FRAMES_IN_FLIGHT at a time, and
    ``write(index, png)`` each on this thread in path order (False from it cancels).

    Each frame renders with the core's threads (every core by default) on a thread of a small
    pool; a second frame in flight fills the cores while the first one's tiles run out, its
    denoiser runs or its PNG is encoded. A cancel (``is_cancelled()``: render_path's
    ``cancel`` or the interrupt token; ``write``'s False; KeyboardInterrupt) stops the frames
    in flight at their next check and waits for them: nothing is written after this returns or
    raises.
    """
    import contextvars
    from collections import deque
    from concurrent.futures import ThreadPoolExecutor

    scene.build()  # once, here: the frames in flight share the trees
    stop = threading.Event()

    def stopped() -> bool:
        return stop.is_set() or is_cancelled()

    def one(camera: dict) -> bytes:
        return frame_png(scene, Camera.from_dict(camera), render_kwargs, cancel=stopped)

    in_flight: deque = deque()
    pending = iter(jobs)
    with ThreadPoolExecutor(FRAMES_IN_FLIGHT, thread_name_prefix="pointviz-frame") as pool:
        try:
            def submit() -> None:
                job = next(pending, None)
                if job is not None:  # each task in a copy of this context: the cancel token
                    ctx = contextvars.copy_context()
                    in_flight.append((job[0], pool.submit(ctx.run, one, job[1])))

            for _ in range(FRAMES_IN_FLIGHT):
                submit()
            while in_flight:
                if is_cancelled():
                    raise CancelledError("path render cancelled")
                i, fut = in_flight.popleft()
                png = fut.result()
                submit()
                if not write(i, png):
                    raise CancelledError("path render cancelled")
                stage("first_frame")  # (pauses the first time only)
        finally:
            stop.set()  # the frames still in flight stop at their next check; the pool waits
            for _, fut in in_flight:
                fut.cancel()


def render_path(scene_or_cloud: Any, path: Any, out_dir: str | os.PathLike, *,
                width: int | None = None, height: int | None = None,
                video: str | os.PathLike | None = None, fps: float | None = None,
                scheduler: Any = AUTO, workers: int = 2, retries: int = 3,
                resume: bool = True, overwrite: bool = False, progress: Any = True,
                cancel: Any = None, **render_kwargs: Any) -> dict:
    """Render every frame of a camera path to ``out_dir/frame_00000.png`` ..., optionally a video.

    Frames are written atomically (a temporary ``.frame_*.part`` file renamed into place), so
    a frame file either is complete or does not exist. ``out_dir`` also gets a manifest
    (MANIFEST_NAME) with digests of the scene, the cameras and the image settings: a rerun
    with the same inputs **resumes**, skipping frames whose file is a complete PNG; a rerun
    with different inputs is refused unless ``overwrite``.

    Parameters
    ----------
    scene_or_cloud : Scene, SurfelScene or PointCloud
    path : CameraPath or str
        A path object or its JSON file.
    out_dir : str or PathLike
        Created if missing (with its parents).
    width, height : int, optional
        Override the path's image size (one alone keeps the aspect ratio).
    video : str or PathLike, optional
        ``.mp4`` (H.264, yuv420p; odd sizes padded by one pixel) or ``.gif``, encoded from all
        the frames after rendering. An existing file is kept unless ``overwrite``.
    fps : float, optional
        Video frame rate; default the path's.
    scheduler : "auto", None, "serial", "local", "tcp://HOST:PORT" or dask.distributed.Client
        Where frames render; byte-identical frames whichever. "auto" (the default), None and
        "serial" render in this process, with every core as the core's threads, the scene
        once in memory: on one machine the fastest way (see the module's notes for the
        measurements). "local" starts a LocalCluster of ``workers`` processes (one thread
        each) on this machine, for process isolation (a worker that crashes is restarted and
        its frame re-run); an address or a Client uses an existing cluster, for more machines.
        See :mod:`pointviz.distributed`.
    workers : int
        Worker processes of the "local" cluster (not used by the other schedulers).
    retries : int
        Dask re-runs of a failed frame.
    resume : bool
        Skip frames already rendered by a run with the same inputs. False re-renders them
        (which needs ``overwrite``).
    overwrite : bool
        Allow deleting frames of another render in ``out_dir`` and replacing ``video``.
    progress : bool or callable(done, total)
        True: a progress bar over frames on stderr (when it is a terminal). A callable gets
        the frames done (skipped ones included) and the total; returning False cancels.
    cancel : threading.Event or callable, optional
        Set (or returning True) to stop; :class:`CancelledError` is raised, finished frames
        are kept and a rerun resumes after them.
    **render_kwargs
        Options of :func:`pointviz.render` (spp, shadows, reflections, lod_pixels, seed,
        threads, ground, exposure). The same seed is used for every frame: the sampling
        pattern is fixed on screen, which avoids frame-to-frame noise. Every frame is shown at
        one **exposure**: ``exposure`` if given, else the look's automatic exposure metered
        once over the path (:func:`pointviz.path.exposure.path_exposure`, in this process, before
        the frames; recorded in the manifest and reused when the render resumes), so that the
        backdrop does not brighten and darken with what each view shows.

    Returns
    -------
    dict
        ``frames`` (total), ``rendered``, ``skipped``, ``seconds`` (rendering wall time),
        ``fps`` (rendered frames per second of it), ``video_seconds``, ``out_dir``, ``video``,
        ``scheduler`` ("serial" or the scheduler address), ``workers``, ``scene_builds``
        (scene builds per worker pid) and ``startup_seconds`` (cluster start or connection and
        scene scatter, included in ``seconds``), ``exposure`` (the frames').
    """
    from ..distributed import render_frames
    from ..images import atomic_write_bytes
    from ..rendering import _cancel_check, as_scene

    cameras, path_fps = _path_cameras(path, width, height)
    fps = path_fps if fps is None else check_fps(fps)
    if video is not None:
        from ..video import check_video_path

        check_video_path(video, overwrite)
    settings = _settings_of(render_kwargs)
    is_cancelled = _cancel_check(cancel)
    if progress is True:
        report = ProgressBar("path")
    elif progress is False or progress is None:
        report = None
    elif callable(progress):
        report = progress
    else:
        raise InputError("progress: expected True, False or a callable(done, total)")

    scene = as_scene(scene_or_cloud)
    w, h = cameras[0]["width"], cameras[0]["height"]
    manifest = {"format": MANIFEST_FORMAT, "version": MANIFEST_VERSION, "scene": scene.key,
                "cameras": _digest(cameras), "settings": settings, "n_frames": len(cameras),
                "width": w, "height": h}
    out = Path(out_dir)
    old, unusable = _read_manifest(out)
    exposure = settings["exposure"]
    if exposure is None:  # one for every frame: the one recorded by an earlier run, or metered
        exposure = _recorded_exposure(old, manifest) if resume else None
        if exposure is None:
            exposure = path_exposure(scene, cameras, render_kwargs, cancel=is_cancelled)
    manifest["exposure"] = exposure
    render_kwargs = {**render_kwargs, "exposure": exposure}
    _prepare_out_dir(out, manifest, old, unusable, resume, overwrite)
    files = [out / FRAME_NAME.format(i) for i in range(len(cameras))]
    todo = [i for i, f in enumerate(files) if not is_complete_png(f, w, h)]
    skipped = len(cameras) - len(todo)
    done = skipped

    def advance() -> bool:
        nonlocal done
        done += 1
        return report is None or report(done, len(cameras)) is not False

    if report is not None and report(done, len(cameras)) is False:
        raise CancelledError("path render cancelled")
    start = time.perf_counter()
    info: dict = {"scheduler": "serial", "workers": 0, "scene_builds": {}, "startup_seconds": 0.0}
    if isinstance(scheduler, str) and scheduler in (SERIAL, AUTO):
        scheduler = None
    if todo and scheduler is None:
        def write(i: int, png: bytes) -> bool:
            atomic_write_bytes(files[i], png, overwrite=True)
            return advance()

        _render_here(scene, [(i, cameras[i]) for i in todo], render_kwargs, write, is_cancelled)
    elif todo:
        def on_frame(i: int, png: bytes, _info: dict) -> bool:
            atomic_write_bytes(files[i], png, overwrite=True)
            return advance()

        res = render_frames(scene, [(i, cameras[i]) for i in todo], render_kwargs, on_frame,
                            scheduler=scheduler, workers=workers, retries=retries,
                            cancel=is_cancelled)
        info = {"scheduler": res["address"], "workers": res["workers"],
                "scene_builds": res["scene_builds"], "startup_seconds": res["startup_seconds"]}
    seconds = time.perf_counter() - start
    video_seconds = 0.0
    if video is not None:
        from ..video import write_video

        t0 = time.perf_counter()
        write_video(video, files, fps, overwrite=overwrite)
        video_seconds = time.perf_counter() - t0
    rendered = len(todo)
    return {"frames": len(cameras), "rendered": rendered, "skipped": skipped,
            "seconds": seconds, "fps": rendered / seconds if rendered and seconds > 0 else 0.0,
            "video_seconds": video_seconds, "out_dir": str(out),
            "video": None if video is None else str(video), "exposure": exposure, **info}
