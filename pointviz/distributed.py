"""Rendering camera-path frames on a Dask cluster (``dask.distributed``).

How the work is split
---------------------
* Every frame is one task, submitted with ``retries=`` so that a failed task is re-run, and a
  task on a worker that dies is rescheduled by the scheduler on another worker.
* The scene travels to each worker **once**: the client scatters the
  :class:`~pointviz.scene.Scene` itself with ``broadcast=True``; it pickles without its C++
  trees (the clouds' arrays with their normals and radii already estimated, the surfel
  options, materials, lights, ground, sky). Tasks receive the scattered object from the
  worker's own memory; the first task on a worker builds the trees *on that object*
  (:meth:`Scene.build`), so a tree is built once per worker process and reused by every later
  frame on it. A worker that joins later (e.g. restarted by its nanny) fetches the scene from
  a peer, once.
* Every task carries the client's pointviz version and a digest of its compiled core; a
  worker running another build refuses (its frames would not match).
* Workers return PNG bytes; the client writes the files, so workers need no shared file system
  and the resume logic of :func:`pointviz.render_path` stays on one machine.

Renders are deterministic per seed whatever the thread count, so the frames are byte-identical
to a serial render of the same scene and settings.

When to use it
--------------
For more machines (``tcp://HOST:PORT``), or for process isolation on one (``"local"``: a worker
that crashes is restarted and its frames re-run). It is not the default: on one machine
:func:`pointviz.render_path` renders in its own process (``scheduler="auto"``), which already
uses every core on each frame, holds one copy of the scene and builds one tree. What a
LocalCluster of 2 single-thread workers adds on 2 cores (benchmarks/README.md, "Camera paths on
one machine (2026-11-25)", the dragon's scans, 25 frames of 320x240): 0.5-1.4 s to start the
two worker processes (each imports numpy, Dask and pointviz: ~0.6 s of CPU), the scene's pickle
and scatter (10 MiB, 0.1 s), a tree and a denoiser per worker on its first frame (+0.1 s), 0.2 s
to close, the scheduler's and nannies' own CPU beside the frames; in all 1.1-1.5x the CPU time
and 1.5-2.6x the peak memory of the render in one process (682 MiB instead of 261 for a
1.2M-point sphere).
The client waits on the frames' futures (a finished frame is taken at once; the wait is cut
every POLL_INTERVAL_S only to check for a cancel), it does not sleep between checks.
"""

from __future__ import annotations

import functools
import hashlib
import os
import time
import warnings
from collections.abc import Callable

from .errors import CancelledError, InputError, PointvizError, require
from .interrupt import stage
from .settings import check_int

#: Worker processes of a "local" LocalCluster (the machine this was written on has 2 cores).
DEFAULT_WORKERS = 2
#: A frame task is re-run this many times after an error or the loss of its worker.
DEFAULT_RETRIES = 3
#: Seconds to wait for a remote scheduler, and for the local cluster's workers to start.
CONNECT_TIMEOUT_S = 60.0
#: Longest wait for a frame before the cancel flag is checked again (a finished frame ends the
#: wait at once: the client waits on the futures, it does not sleep between checks).
POLL_INTERVAL_S = 0.2


def core_identity() -> str:
    """pointviz version and a digest of the compiled core's file: workers must match the client.
    Read once per process (the core cannot change under a running process)."""
    return _core_identity()


@functools.cache
def _core_identity() -> str:
    from . import __version__, _core

    with open(_core.__file__, "rb") as f:
        digest = hashlib.sha256(f.read()).hexdigest()[:16]
    return f"{__version__}+{digest}"


def scene_spec(scene_or_cloud):
    """Deprecated: the :class:`~pointviz.scene.Scene` itself now pickles without its trees.

    Returns :func:`pointviz.rendering.as_scene` of the argument, with its content hash
    (``scene.key``) computed.
    """
    from .rendering import as_scene

    warnings.warn("pointviz.distributed.scene_spec() is deprecated: pass the Scene itself "
                  "(it pickles without its trees; its content hash is Scene.key)",
                  DeprecationWarning, stacklevel=2)
    scene = as_scene(scene_or_cloud)
    _ = scene.key
    return scene


def __getattr__(name: str):
    if name == "SceneSpec":  # the picklable scene description, now the Scene itself
        from .scene import Scene

        warnings.warn("pointviz.distributed.SceneSpec is deprecated: use pointviz.Scene "
                      "(it pickles without its trees)", DeprecationWarning, stacklevel=2)
        return Scene
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def render_frame_task(scene, camera_dict: dict, render_kwargs: dict,
                      core: str | None = None) -> tuple[bytes, dict]:
    """One frame on a worker: PNG bytes and where/how it was made.

    Parameters
    ----------
    scene : Scene
        The scattered scene (its C++ trees are built on this worker's first frame, then
        reused by every later frame in this process).
    camera_dict : dict
        :meth:`Camera.to_dict` of the frame's camera.
    render_kwargs : dict
        Keyword arguments of :func:`pointviz.render`.
    core : str, optional
        The client's :func:`core_identity`: a worker running another build refuses (its
        frames would not match a serial render).

    Returns
    -------
    (bytes, dict)
        The PNG file's bytes and ``{"pid", "built", "seconds"}``.
    """
    from .camera import Camera
    from .frames import frame_png

    if core is not None and core != core_identity():
        raise PointvizError(
            f"worker pid {os.getpid()}: its pointviz core ({core_identity()}) differs from the "
            f"client's ({core}); frames would not match a serial render: install the same "
            f"pointviz build on every worker")
    start = time.perf_counter()
    built = scene.build() > 0  # so the first frame's time is the build's, then the render's
    png = frame_png(scene, Camera.from_dict(camera_dict), render_kwargs)
    return png, {"pid": os.getpid(), "built": built, "seconds": time.perf_counter() - start}


def _connect(scheduler, workers: int):
    """A Client (and the cluster to close, if we started one) for ``scheduler``."""
    distributed = require("distributed", "paths")
    if scheduler is None:
        raise InputError("scheduler: None renders in this process (render_path); a Dask render "
                         "needs 'local', a tcp://HOST:PORT address or a dask.distributed.Client")
    if isinstance(scheduler, str) and scheduler == "local":
        check_int(workers, "workers")
        cluster = distributed.LocalCluster(
            n_workers=int(workers), threads_per_worker=1, processes=True,
            dashboard_address=":0", silence_logs=40)  # logging.ERROR
        try:
            client = distributed.Client(cluster, timeout=CONNECT_TIMEOUT_S)
        except BaseException:
            cluster.close()
            raise
        return client, cluster, True
    if isinstance(scheduler, str):
        if not scheduler.startswith(("tcp://", "tls://", "ucx://", "inproc://", "ws://", "wss://")):
            raise InputError(f"scheduler: expected 'local', a Dask Client or an address like "
                             f"tcp://HOST:PORT, got {scheduler!r}")
        try:
            client = distributed.Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        except OSError as exc:
            raise PointvizError(f"scheduler: cannot connect to {scheduler}: {exc}") from None
        return client, None, True
    if isinstance(scheduler, distributed.Client):
        return scheduler, None, False
    raise InputError(f"scheduler: expected 'local', a tcp://HOST:PORT address or a "
                     f"dask.distributed.Client, got {type(scheduler).__name__}")


def render_frames(scene, jobs: list[tuple[int, dict]], render_kwargs: dict,
                  on_frame: Callable[[int, bytes, dict], object], *, scheduler,
                  workers: int = DEFAULT_WORKERS, retries: int = DEFAULT_RETRIES,
                  cancel: Callable[[], bool] | None = None) -> dict:
    """Render frames on a Dask cluster, calling ``on_frame`` on this thread as each arrives.

    Parameters
    ----------
    scene : Scene
        Sent to every worker once (see the module's notes).
    jobs : list of (int, dict)
        Frame index and camera dict of each frame to render.
    render_kwargs : dict
        For :func:`pointviz.render` (``threads`` defaults to the cores per local worker).
    on_frame : callable(index, png_bytes, info)
        Returning False cancels the remaining frames.
    scheduler : "local", "tcp://HOST:PORT" or dask.distributed.Client
        "local": a LocalCluster of ``workers`` processes, closed afterwards. (There is no
        default: ``scheduler=None`` means "in this process" wherever it is accepted, see
        :func:`pointviz.render_path`.)
    retries : int
        Re-runs of a frame after an error (lost workers are rescheduled by Dask as well).
    cancel : callable() -> bool, optional
        Checked whenever a frame arrives and at least every POLL_INTERVAL_S while none does;
        True cancels (CancelledError).

    Returns
    -------
    dict
        ``workers`` (count at start), ``scene_builds`` (per worker pid), ``address`` and
        ``startup_seconds`` (connecting or starting the cluster, and scattering the scene).
    """
    distributed = require("distributed", "paths")
    render_kwargs = dict(render_kwargs)
    if render_kwargs.get("threads") is None and scheduler == "local":
        render_kwargs["threads"] = max(1, (os.cpu_count() or 1) // max(1, int(workers)))
    start = time.perf_counter()
    client, cluster, close_client = _connect(scheduler, workers)
    builds: dict[int, int] = {}
    futures = []
    try:
        if cluster is not None:
            client.wait_for_workers(int(workers), timeout=CONNECT_TIMEOUT_S)
        n_workers = len(client.scheduler_info(n_workers=-1)["workers"])
        if n_workers == 0:
            raise PointvizError(f"scheduler: {client.scheduler.address} has no workers")
        stage("cluster")
        remote = client.scatter(scene, broadcast=True, hash=False)
        stage("scattered")
        startup = time.perf_counter() - start
        core = core_identity()
        futures = [client.submit(render_frame_task, remote, cam, render_kwargs, core,
                                 key=f"pointviz-frame-{scene.key[:12]}-{index:05d}-{os.getpid()}",
                                 retries=int(retries), pure=False)
                   for index, cam in jobs]
        index_of = {f.key: index for f, (index, _) in zip(futures, jobs)}
        pending = set(futures)
        while pending:
            if cancel is not None and cancel():
                raise CancelledError("path render cancelled")
            try:  # returns as soon as a frame is done; the timeout only bounds a cancel's wait
                finished, _ = distributed.wait(list(pending), timeout=POLL_INTERVAL_S,
                                               return_when="FIRST_COMPLETED")
            except TimeoutError:
                continue
            for fut in sorted(finished, key=lambda f: index_of[f.key]):
                pending.discard(fut)
                png, info = fut.result()
                builds[info["pid"]] = builds.get(info["pid"], 0) + int(info["built"])
                if on_frame(index_of[fut.key], png, info) is False:
                    raise CancelledError("path render cancelled")
                stage("first_frame")  # (pauses the first time only)
                fut.release()
        return {"workers": n_workers, "scene_builds": builds,
                "address": client.scheduler.address, "startup_seconds": startup}
    finally:
        for f in futures:
            if not f.done():
                f.cancel()
        if close_client:
            client.close()
        if cluster is not None:
            cluster.close()
