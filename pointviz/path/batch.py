"""Rendering every frame of a camera path to PNG files (and a video), resumably: in this process
or on a Dask cluster (:mod:`pointviz.distributed`); the frames are byte-identical either way."""

from __future__ import annotations

import hashlib
import os
import time
from pathlib import Path
from typing import Any

from ..camera import Camera
from ..errors import CancelledError, FileFormatError, InputError
from ..files import atomic_write_text, json_text, read_json_file
from ..frames import frame_png, is_complete_png
from ..interrupt import stage
from ..progress import ProgressBar
from ..settings import RenderSettings
from ..values import check_image_size as _size
from .camera_path import CameraPath
from .keyframes import check_fps

#: ``scheduler`` value that renders in this process (as does None).
SERIAL = "serial"
#: Frame file names inside ``out_dir`` (``frame_00000.png`` ...).
FRAME_NAME = "frame_{:05d}.png"
FRAME_GLOB = "frame_*.png"
#: The manifest that ties ``out_dir`` to one scene, camera sequence and render settings.
MANIFEST_NAME = "pointviz_path.json"
MANIFEST_FORMAT = "pointviz.path_render"
MANIFEST_VERSION = 1


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


def _prepare_out_dir(out: Path, manifest: dict, resume: bool, overwrite: bool) -> None:
    """Create ``out`` or check that its frames belong to this render; write the manifest.

    A folder holding frames of another render (another scene, path or settings) is refused
    unless ``overwrite``, which deletes those frames (only ``frame_*.png`` and the manifest).
    """
    if out.exists() and not out.is_dir():
        raise InputError(f"out_dir: {out} is a file, not a folder")
    out.mkdir(parents=True, exist_ok=True)
    mpath = out / MANIFEST_NAME
    frames = sorted(out.glob(FRAME_GLOB))
    reason = None
    if mpath.exists():
        try:
            old = read_json_file(mpath)
        except (InputError, FileFormatError) as exc:
            old, reason = None, f"its manifest {mpath.name} is unreadable ({exc})"
        if old is not None and not isinstance(old, dict):
            old, reason = None, f"its manifest {mpath.name} is not a JSON object"
        if old is not None:
            changed = [k for k in ("scene", "cameras", "settings", "n_frames")
                       if old.get(k) != manifest[k]]
            if changed:
                what = {"scene": "the scene", "cameras": "the camera path or image size",
                        "settings": "the render settings", "n_frames": "the frame count"}
                reason = ("it holds frames of a different render (" +
                          ", ".join(what[k] for k in changed) + " changed)")
            elif not resume and frames:
                reason = "it holds frames of this render and resume=False"
    elif frames:
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


def render_path(scene_or_cloud: Any, path: Any, out_dir: str | os.PathLike, *,
                width: int | None = None, height: int | None = None,
                video: str | os.PathLike | None = None, fps: float | None = None,
                scheduler: Any = None, workers: int = 2, retries: int = 3,
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
    scheduler : None, "serial", "local", "tcp://HOST:PORT" or dask.distributed.Client
        None (or "serial") renders in this process. "local" starts a LocalCluster of ``workers`` processes
        (one thread each); an address or Client uses an existing cluster. See
        :mod:`pointviz.distributed`. Frames are byte-identical either way.
    workers : int
        Worker processes of the "local" cluster.
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
        threads, ground). The same seed is used for every frame: the sampling pattern is fixed
        on screen, which avoids frame-to-frame noise.

    Returns
    -------
    dict
        ``frames`` (total), ``rendered``, ``skipped``, ``seconds`` (rendering wall time),
        ``fps`` (rendered frames per second of it), ``video_seconds``, ``out_dir``, ``video``,
        ``scheduler`` ("serial" or the scheduler address), ``workers``, ``scene_builds``
        (scene builds per worker pid) and ``startup_seconds`` (cluster start or connection and
        scene scatter, included in ``seconds``).
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
    _prepare_out_dir(out, manifest, resume, overwrite)
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
    if scheduler == SERIAL:
        scheduler = None
    if todo and scheduler is None:
        for i in todo:
            if is_cancelled():
                raise CancelledError("path render cancelled")
            png = frame_png(scene, Camera.from_dict(cameras[i]), render_kwargs, cancel=cancel)
            atomic_write_bytes(files[i], png, overwrite=True)
            if not advance():
                raise CancelledError("path render cancelled")
            stage("first_frame")  # (pauses the first time only)
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
            "video": None if video is None else str(video), **info}
