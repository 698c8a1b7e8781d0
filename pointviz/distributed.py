"""Rendering camera-path frames on a Dask cluster (``dask.distributed``).

How the work is split
---------------------
* Every frame is one task, submitted with ``retries=`` so that a failed task is re-run, and a
  task on a worker that dies is rescheduled by the scheduler on another worker.
* The scene travels to each worker **once**: the client reduces it to a :class:`SceneSpec`
  (the clouds' arrays with their normals and radii already estimated, the surfel options,
  materials, lights, ground, sky) and scatters it with ``broadcast=True``. Tasks receive the
  scattered object from the worker's own memory; the first task on a worker builds the C++
  trees from it and keeps them *on that object* (:meth:`SceneSpec.scene`), so the tree is built
  once per worker process and reused by every later frame on it. A worker that joins later
  (e.g. restarted by its nanny) fetches the spec from a peer, once.
* The spec records the client's pointviz version and a digest of its compiled core; a worker
  running another build refuses (its frames would not match).
* Workers return PNG bytes; the client writes the files, so workers need no shared file system
  and the resume logic of :func:`pointviz.render_path` stays on one machine.

Renders are deterministic per seed whatever the thread count, so the frames are byte-identical
to a serial render of the same scene and settings.
"""

from __future__ import annotations

import hashlib
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .errors import CancelledError, InputError, PointvizError, require
from .geometry import Geometry
from .interrupt import stage
from .settings import check_int

#: Worker processes of the default LocalCluster (the machine this was written on has 2 cores).
DEFAULT_WORKERS = 2
#: A frame task is re-run this many times after an error or the loss of its worker.
DEFAULT_RETRIES = 3
#: Seconds to wait for a remote scheduler, and for the local cluster's workers to start.
CONNECT_TIMEOUT_S = 60.0
#: Seconds between checks of the cancel flag while waiting for frames.
POLL_INTERVAL_S = 0.2


@dataclass
class _ObjectSpec:
    """One scene object: a cloud (normals and radii already estimated) or a callback geometry."""

    geometry: object
    material: object
    surfel_kwargs: dict | None  # None: callback geometry, sent as is


@dataclass
class SceneSpec:
    """A picklable description of a :class:`~pointviz.scene.Scene`, rebuilt where it is used.

    Attributes
    ----------
    key : str
        SHA-256 of everything that affects the image (arrays, options, materials, lights).
    """

    key: str
    core: str
    objects: list
    lights: list | None
    ground: object
    background: tuple | None
    up: tuple
    ambient: float
    sky: dict
    look: object = None
    _built: object = field(default=None, repr=False, compare=False)
    _lock: object = field(default=None, repr=False, compare=False)

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_built"] = None  # trees never travel: they are rebuilt on each worker
        state["_lock"] = None
        return state

    def scene(self):
        """The Scene, built (C++ trees included) on first call in this process, then reused.

        Returns
        -------
        (Scene, bool)
            The scene and whether this call built it.
        """
        if self._lock is None:
            self._lock = threading.Lock()
        with self._lock:
            if self._built is not None:
                return self._built, False
            self._built = self._build()
            return self._built, True

    def _build(self):
        from .scene import Scene
        from .surfels import SurfelScene

        here = core_identity()
        if here != self.core:
            raise PointvizError(
                f"worker pid {os.getpid()}: its pointviz core ({here}) differs from the client's "
                f"({self.core}); frames would not match a serial render: install the same "
                f"pointviz build on every worker")
        geoms = []
        for obj in self.objects:
            if obj.surfel_kwargs is None:
                geoms.append(obj.geometry)
                continue
            geoms.append(SurfelScene(obj.geometry, **obj.surfel_kwargs))
        scene = Scene(geoms, lights=self.lights,
                      ground="none" if self.ground is None else self.ground,
                      background="sky" if self.background is None else self.background,
                      materials=[o.material for o in self.objects], up=self.up,
                      ambient=self.ambient, sky=self.sky or None,
                      look="auto" if self.look is None else self.look)
        for i in range(len(geoms)):
            if self.objects[i].surfel_kwargs is not None:
                scene.surfel_scene(i)  # build now, so the first frame's time is the render's
        return scene


def core_identity() -> str:
    """pointviz version and a digest of the compiled core's file: workers must match the client."""
    from . import __version__, _core

    with open(_core.__file__, "rb") as f:
        digest = hashlib.sha256(f.read()).hexdigest()[:16]
    return f"{__version__}+{digest}"


def _hash_array(h, arr) -> None:
    if arr is None:
        h.update(b"none")
        return
    a = np.ascontiguousarray(arr)
    h.update(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.tobytes())


def _callback_digest(geometry) -> str:
    """A content digest of a callback geometry: its pickle when it has one (meshes do), else
    its identity (then a resumed path render cannot tell it is the same geometry)."""
    import pickle

    try:
        return "callback:" + hashlib.sha256(pickle.dumps(geometry)).hexdigest()
    except Exception:  # noqa: BLE001 - unpicklable objects fall back to identity
        return f"callback-id:{type(geometry).__qualname__}:{id(geometry)}"


def _surfel_settings(ss) -> dict:
    """Constructor kwargs that rebuild SurfelScene ``ss`` identically (its origin included)."""
    kwargs = ss.settings
    kwargs["origin"] = tuple(float(v) for v in kwargs["origin"])
    kwargs["threads"] = None  # each worker uses its own cores
    return kwargs


def scene_spec(scene_or_cloud) -> SceneSpec:
    """Reduce a scene (or cloud) to a picklable :class:`SceneSpec` with a content hash.

    Normals and radii are estimated here, once, so that every worker renders the same surfels.
    The SurfelScene trees are built here too when the scene had not built them yet (the serial
    render needs them anyway, and the origin of each tree is part of the spec).
    """
    from .rendering import as_scene
    from .surfels import SurfelScene

    scene = as_scene(scene_or_cloud)
    h = hashlib.sha256()
    objects = []
    for i, obj in enumerate(scene.objects):
        g = obj.geometry
        if isinstance(g, SurfelScene) or not isinstance(g, Geometry):  # surfels or a cloud
            ss = scene.surfel_scene(i)
            cloud = ss.cloud
            _ = cloud.normals, cloud.radii  # estimate once, on the client
            kwargs = _surfel_settings(ss)
            for name in ("points", "normals", "radii", "colors"):
                _hash_array(h, getattr(cloud, name, None))
            h.update(repr(sorted(kwargs.items())).encode())
            objects.append(_ObjectSpec(cloud, obj.material, kwargs))
        else:
            h.update(_callback_digest(g).encode())
            objects.append(_ObjectSpec(g, obj.material, None))
        h.update(repr(obj.material).encode())
    rest = (scene.lights, scene.ground, scene.background, tuple(float(v) for v in scene.up),
            scene.ambient, sorted(scene.sky.items()), scene.look)
    h.update(repr(rest).encode())
    return SceneSpec(h.hexdigest(), core_identity(), objects, scene.lights, scene.ground, scene.background,
                     tuple(float(v) for v in scene.up), float(scene.ambient), dict(scene.sky),
                     scene.look, _built=scene)


def render_frame_task(spec: SceneSpec, camera_dict: dict, render_kwargs: dict) -> tuple[bytes, dict]:
    """One frame on a worker: PNG bytes and where/how it was made.

    Parameters
    ----------
    spec : SceneSpec
        The scattered scene (built into C++ trees on this worker's first frame).
    camera_dict : dict
        :meth:`Camera.to_dict` of the frame's camera.
    render_kwargs : dict
        Keyword arguments of :func:`pointviz.render`.

    Returns
    -------
    (bytes, dict)
        The PNG file's bytes and ``{"pid", "built", "seconds"}``.
    """
    from .camera import Camera
    from .frames import frame_png

    start = time.perf_counter()
    scene, built = spec.scene()
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


def render_frames(spec: SceneSpec, jobs: list[tuple[int, dict]], render_kwargs: dict,
                  on_frame: Callable[[int, bytes, dict], object], *, scheduler,
                  workers: int = DEFAULT_WORKERS, retries: int = DEFAULT_RETRIES,
                  cancel: Callable[[], bool] | None = None) -> dict:
    """Render frames on a Dask cluster, calling ``on_frame`` on this thread as each arrives.

    Parameters
    ----------
    spec : SceneSpec
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
        Polled every POLL_INTERVAL_S; True cancels (CancelledError).

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
        remote = client.scatter(spec, broadcast=True, hash=False)
        stage("scattered")
        startup = time.perf_counter() - start
        futures = [client.submit(render_frame_task, remote, cam, render_kwargs,
                                 key=f"pointviz-frame-{spec.key[:12]}-{index:05d}-{os.getpid()}",
                                 retries=int(retries), pure=False)
                   for index, cam in jobs]
        index_of = {f.key: index for f, (index, _) in zip(futures, jobs)}
        done = distributed.as_completed(futures, with_results=False)
        remaining = len(futures)
        while remaining:
            if cancel is not None and cancel():
                raise CancelledError("path render cancelled")
            batch = done.next_batch(block=False)
            if not batch:
                time.sleep(POLL_INTERVAL_S)
                continue
            for fut in batch:
                remaining -= 1
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
