"""Options shared by the subcommands that render (render, path, view, compare)."""

from __future__ import annotations

import argparse
import sys
import threading
from dataclasses import MISSING, fields
from types import SimpleNamespace

import numpy as np

from ..errors import InputError
from ..interrupt import stage
from ..settings import INTERPOLATIONS, RenderSettings
from ..values import axis


def add_input_options(p) -> None:
    p.add_argument("input", help="point cloud, mesh, registered scans (.conf), or 'demo'")
    p.add_argument("--sample", type=sample_count, default="auto", metavar="N",
                   help="for meshes: sample N surface points instead of using the vertices; "
                        "'vertices': the vertices as they are; default 'auto': the vertices, "
                        "or a dense sampling where they lie too far apart for the picture")
    p.add_argument("--no-fit", dest="fit", action="store_false", default=None,
                   help="raw scans: keep the points as scanned (no surface fit, no thinning)")
    p.add_argument("--up", default=None, metavar="AXIS",
                   help="the data's up direction: x, y, z, -x, -y, -z or X,Y,Z, a leading minus "
                        "after '=' (--up=-z; default: the file's convention: +z for LAS/LAZ, -y "
                        "for depth-camera frames, else +y)")


def sample_count(text: str):
    """``--sample``: a positive count, ``auto`` or ``vertices`` (None: no sampling)."""
    if text in ("auto", "vertices"):
        return None if text == "vertices" else text
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(
            f"expected a positive number of points, 'auto' or 'vertices', got {text!r}")
    return value


def parse_up(text: str | None):
    """``--up``: an axis name with an optional sign, or three numbers; None if not given."""
    if text is None:
        return None
    named = axis(text)
    if named is not None:
        return named
    try:
        values = [float(v) for v in text.strip().split(",")]
    except ValueError:
        values = []
    if len(values) != 3 or not np.all(np.isfinite(values)) or not np.linalg.norm(values) > 0:
        raise InputError(f"--up: expected x, y, z, -x, -y, -z or three numbers X,Y,Z (not all "
                         f"zero), got {text!r}")
    return tuple(values)


def add_render_options(p) -> None:
    g = p.add_argument_group("rendering")
    g.add_argument("--camera", metavar="CAM.json", help="camera file (from the viewer's Copy camera)")
    g.add_argument("--width", type=int, default=None, help="image width (default 640)")
    g.add_argument("--height", type=int, default=None, help="image height (default 480)")
    g.add_argument("--fov", type=float, default=None,
                   help="vertical field of view in degrees (default 40, or the camera file's)")
    g.add_argument("--light", action="append", default=None, metavar="X,Y,Z[,INTENSITY]",
                   help="directional light toward X,Y,Z (repeatable)")
    g.add_argument("--interpolation", choices=INTERPOLATIONS, default=None,
                   help="how disks around a hit are blended")
    for f in fields(RenderSettings):
        add_setting_option(g, f)


def add_setting_option(g, f) -> None:
    """The command-line option of one :class:`~pointviz.settings.RenderSettings` field: its
    flag, default, choices and help all come from the field."""
    m = f.metadata
    if not m["cli"]:
        return
    default = f.default if m["cli_default"] is MISSING else m["cli_default"]
    flag = m["flag"] or "--" + f.name.replace("_", "-")
    if m["kind"] is bool:  # on by default: a --no-... switch
        g.add_argument(flag, dest=f.name, action="store_false", default=default,
                       help=f"turn off (on by default): {m['help']}")
        return
    kind, kw = m["kind"], {}
    if m["choices"]:
        names = tuple(c for c in m["choices"] if isinstance(c, str))
        if kind in (int, float):  # a number or a name ("--lod auto")
            kind = _number_or(names, kind)
        else:
            kw["choices"] = list(names)
    shown = "" if default is None else f" (default {default})"
    g.add_argument(flag, dest=f.name, type=kind, default=default, metavar=m["metavar"],
                   help=m["help"] + shown, **kw)


def _number_or(names: tuple, kind: type):
    """An argparse type taking one of ``names`` or a number of ``kind``."""
    def parse(text: str):
        word = text.strip().lower()
        return word if word in names else kind(text)

    parse.__name__ = f"{kind.__name__} or {'/'.join(names)}"
    return parse


def load_input(args, radii: bool = True):
    """The cloud (or built-in demo scene) named on the command line; without ``radii`` the
    radii it needs are left to the caller (:func:`pointviz.io.estimate_radii_of`)."""
    up = parse_up(getattr(args, "up", None))
    if args.input == "demo":
        if up is not None:
            raise InputError("--up: the built-in demo scene has its own up; it is for files")
        from ..shapes import demo_scene

        return demo_scene()
    from ..io import load

    kw = {} if up is None else {"up": up}
    cloud = load(args.input, sample=args.sample, fit=getattr(args, "fit", None),
                 estimate=True if radii else "normals", **kw)
    report_fit(cloud)
    return cloud, None


def report_fit(cloud) -> None:
    """One line on stderr saying what the surface fit of raw scans changed, if it ran."""
    if getattr(cloud, "fit_report", None) is not None:
        print(f"pointviz: {cloud.fit_report['summary']}", file=sys.stderr)


def parse_lights(specs):
    from ..scene import DirectionalLight

    if not specs:
        return None
    lights = []
    for spec in specs:
        try:
            vals = [float(v) for v in spec.split(",")]
        except ValueError:
            raise InputError(f"--light: expected X,Y,Z[,INTENSITY], got {spec!r}") from None
        if len(vals) not in (3, 4) or not np.all(np.isfinite(vals)):
            raise InputError(f"--light: expected X,Y,Z[,INTENSITY], got {spec!r}")
        if not np.linalg.norm(vals[:3]) > 0:
            raise InputError(f"--light: direction must not be zero, got {spec!r}")
        lights.append(DirectionalLight(direction=tuple(vals[:3]),
                                       intensity=vals[3] if len(vals) == 4 else 1.0))
    return lights


def make_scene_and_camera(args, prepare: bool = True, hand_over: bool = False):
    """Scene and camera from the common options; with ``prepare``, normals, radii and trees are
    made now (:func:`prepare_scene`), else on first use (the viewer: on its worker thread, after
    the window is up). With ``hand_over`` (and ``prepare``) a loaded cloud is handed over to its
    tree's build (:func:`handed_over_scene`), for a caller that needs nothing but the scene."""
    from .. import rendering  # noqa: F401 - the core and numpy, before the first stage
    from ..camera import Camera
    from ..cloud import PointCloud
    from ..scene import Scene

    stage("imported")
    # a cloud handed over whose camera is fitted has its radii estimated beside the camera fit
    defer_radii = hand_over and prepare and not args.camera
    loaded, demo_camera = load_input(args, radii=not defer_radii)
    stage("loaded")
    lights = parse_lights(args.light)
    kw = {}
    if args.interpolation:
        kw["interpolation"] = args.interpolation
    consume = hand_over and prepare and isinstance(loaded, PointCloud)
    if isinstance(loaded, Scene):
        scene = loaded
        if lights is not None:
            scene = scene.replace(lights=lights)
        if args.ground not in (None, "auto"):  # a scene keeps its own unless told
            scene = scene.with_ground(args.ground)
        if args.look not in (None, "auto"):
            scene = scene.with_look(args.look)
    elif not consume:  # (else the scene is made from the tree, once the camera is fitted)
        scene = Scene([loaded], lights=lights, ground=args.ground or "auto",
                      look=args.look or "auto", **kw)
    radii_done = _radii_in_background(loaded, args.input) if defer_radii and consume else None
    fov = 40.0 if args.fov is None else args.fov
    fitting = None  # a handed-over cloud's camera is fitted beside its tree's build
    if args.camera:
        camera = Camera.from_json(args.camera)
    elif demo_camera is not None:
        camera = demo_camera
    elif consume:
        fitting = _camera_in_background(loaded, fov)
    else:
        try:
            camera = Camera.fit(scene if not hasattr(loaded, "points") else loaded, fov_deg=fov)
        finally:
            if radii_done is not None:
                radii_done()
    if fitting is not None:
        try:
            if radii_done is not None:
                radii_done()  # the build needs them
            RenderSettings(**render_kwargs(args))  # bad options fail before the tree
            scene = handed_over_scene(loaded, lights, args.ground or "auto", args.look or "auto",
                                      kw)
            scene.bounds()  # the frame's bounds and ground level, computed once, now
        except BaseException:
            # Ctrl-C (at the "normals" or "built" stage) or an error: the background threads end
            # before the exception leaves. A daemon thread still in native code when the
            # interpreter finalises is ended by pthread_exit, whose unwinding through C++ frames
            # aborts the process ("terminate called without an active exception", exit -6
            # instead of 130, seen under load).
            _settle(fitting, radii_done)
            raise
        camera = fitting()
    camera = _sized(camera, args)
    if prepare and fitting is None:
        RenderSettings(**render_kwargs(args))  # bad options fail before the trees
        if consume:
            scene = handed_over_scene(loaded, lights, args.ground or "auto", args.look or "auto",
                                      kw)
        else:
            prepare_scene(scene)
    return scene, camera


def _sized(camera, args):
    """The camera with the field of view and image size the options give."""
    if args.fov is not None and args.fov != camera.fov_deg:
        camera = camera.replace(fov_deg=args.fov)  # validates: names fov_deg when out of range
    if args.width or args.height:
        w = args.width or int(round(camera.width * (args.height / camera.height)))
        h = args.height or int(round(camera.height * (args.width / camera.width)))
        camera = camera.with_size(w, h)
    return camera


def _camera_in_background(cloud, fov: float):
    """Fit the camera of a cloud about to be handed over to its tree's build on a worker thread,
    so that the fit (numpy on one core) runs beside the build (the core, without Python's
    lock). The fit gets a copy of its sample of the points (:func:`pointviz.framing.fit_sample`:
    the rows :meth:`Camera.fit` looks at, all of them below FIT_SAMPLE points), which gives the
    camera of the whole cloud, bit for bit, since the build frees the cloud's own arrays.
    Returns the function that waits for the camera and raises what the fit raised."""
    from ..camera import Camera
    from ..framing import fit_sample

    # what Camera.fit reads of a cloud: its points' sample, up and a single viewpoint (per-point
    # viewpoints are not kept alive beside the build that frees the cloud's arrays)
    vp = cloud.viewpoints
    view = SimpleNamespace(points=np.array(fit_sample(cloud.points)), up=cloud.up,
                           viewpoints=vp if vp is not None and np.shape(vp) == (3,) else None)
    return _in_background("pointviz-camera", lambda: Camera.fit(view, fov_deg=fov))


def _radii_in_background(loaded, path):
    """Estimate the radii of a loaded cloud that has none on a worker thread (the core's
    estimation runs without Python's lock), while the caller fits the camera, which needs only
    the points. Returns the function that waits for them and raises what the estimation
    raised; None when there is nothing to estimate."""
    if not hasattr(loaded, "points") or loaded.has_radii:
        return None
    from ..io import estimate_radii_of

    return _in_background("pointviz-radii", lambda: estimate_radii_of(loaded, path))


def _in_background(name: str, work):
    """Run ``work()`` on a daemon thread named ``name``; returns the function that waits for it
    and returns its result or raises what it raised."""
    out = []

    def run():
        try:
            out.append((True, work()))
        except BaseException as exc:  # noqa: BLE001 - raised again by the caller's wait
            out.append((False, exc))

    thread = threading.Thread(target=run, name=name, daemon=True)
    thread.start()

    def wait():
        thread.join()
        ok, value = out[0]
        if not ok:
            raise value
        return value

    wait.thread = thread
    return wait


def _settle(*waits) -> None:
    """Wait for the threads behind :func:`_in_background`'s wait functions (None: skipped)
    without taking their results: on the way out of an error, so that none outlives it."""
    for wait in waits:
        if wait is not None:
            wait.thread.join()


def handed_over_scene(cloud, lights, ground, look, options: dict):
    """The scene of one cloud whose arrays go to its tree's build
    (``SurfelScene(consume_cloud=True)``: each is freed once copied), so that a large file
    costs the tree and not the cloud beside it at the peak. The cloud cannot be used
    afterwards. The tree has the options :class:`~pointviz.scene.Scene` gives its own (culling
    when its surfels close a surface: ``cull="auto"``); bounds, ground and the "auto" look come
    from its float32 surfels.
    Ends at the stages of :func:`prepare_scene`."""
    from ..scene import Scene
    from ..surfels import SurfelScene

    _ = cloud.normals, cloud.radii
    stage("normals")
    up = getattr(cloud, "up", None)  # read before the hand-over
    tree = SurfelScene(cloud, consume_cloud=True, **{"cull": "auto", **options})
    stage("built")
    return Scene([tree], lights=lights, ground=ground, look=look, up=up)


def prepare_scene(scene) -> None:
    """Estimate missing normals and radii, then build every surfel tree, now: each step ends at
    a named stage (:func:`pointviz.interrupt.stage`), where Ctrl-C takes effect."""
    for obj in scene.objects:
        cloud = getattr(obj.geometry, "cloud", obj.geometry)
        if hasattr(cloud, "points"):
            _ = cloud.normals, cloud.radii
    stage("normals")
    scene.build()
    stage("built")


def render_kwargs(args) -> dict:
    """Keyword arguments of :func:`pointviz.render` from the options. Ground and look are the
    scene's (:func:`make_scene_and_camera` applied them), so they are not passed again."""
    kw = {name: getattr(args, name) for name in RenderSettings.names()}
    kw.pop("ground")
    kw.pop("look")
    kw["denoise"] = denoise_default(args)
    return kw


def denoise_default(args) -> bool:
    """Final frames are denoised unless --no-denoise; without the denoiser installed, a one-line
    note says how to get it and the frame stays as traced."""
    from ..denoise import check_available
    from ..errors import MissingDependencyError

    if not getattr(args, "denoise", True):
        return False
    try:
        check_available()
    except MissingDependencyError as exc:
        sys.stderr.write(f"note: frames are not denoised: {exc}\n")
        return False
    return True
