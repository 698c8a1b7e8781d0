"""Options shared by the subcommands that render (render, path, view, compare)."""

from __future__ import annotations

import sys

import numpy as np

from ..errors import InputError
from ..interrupt import stage


def add_input_options(p) -> None:
    p.add_argument("input", help="point cloud, mesh, registered scans (.conf), or 'demo'")
    p.add_argument("--sample", type=int, default=None, metavar="N",
                   help="for meshes: sample N surface points instead of using the vertices")
    p.add_argument("--no-fit", dest="fit", action="store_false", default=None,
                   help="raw scans: keep the points as scanned (no surface fit, no thinning)")


def add_render_options(p) -> None:
    g = p.add_argument_group("rendering")
    g.add_argument("--camera", metavar="CAM.json", help="camera file (from the viewer's Copy camera)")
    g.add_argument("--width", type=int, default=None, help="image width (default 640)")
    g.add_argument("--height", type=int, default=None, help="image height (default 480)")
    g.add_argument("--fov", type=float, default=None,
                   help="vertical field of view in degrees (default 40, or the camera file's)")
    g.add_argument("--spp", type=int, default=4, help="samples per pixel")
    g.add_argument("--no-shadows", action="store_true", help="skip shadow rays")
    g.add_argument("--reflections", type=int, default=1, help="reflection bounces")
    g.add_argument("--lod", type=float, default=1.0, metavar="PIXELS",
                   help="level-of-detail threshold in pixels (0: full detail)")
    g.add_argument("--light", action="append", default=None, metavar="X,Y,Z[,INTENSITY]",
                   help="directional light toward X,Y,Z (repeatable)")
    g.add_argument("--ground", choices=["auto", "matte", "mirror", "glossy", "none"],
                   default="auto", help="ground plane under the cloud")
    g.add_argument("--interpolation", choices=["smooth", "paper", "none"], default=None,
                   help="how disks around a hit are blended")
    g.add_argument("--look", choices=["auto", "studio", "outdoor", "flat"], default="auto",
                   help="lighting: studio (key, fill, sky occlusion, backdrop), outdoor (sun and "
                        "sky), flat (colours as scanned); auto: outdoor for terrain tiles, "
                        "studio for objects")
    g.add_argument("--no-denoise", action="store_true",
                   help="keep the tracer's noisy frame (default: denoised with Open Image Denoise "
                        "when the 'denoise' extra is installed)")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--threads", type=int, default=None)


def load_input(args):
    """The cloud (or built-in demo scene) named on the command line."""
    if args.input == "demo":
        from ..shapes import demo_scene

        return demo_scene()
    from ..io import load

    cloud = load(args.input, sample=args.sample, fit=getattr(args, "fit", None))
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


def make_scene_and_camera(args, prepare: bool = True):
    """Scene and camera from the common options; with ``prepare``, normals, radii and trees are
    made now (:func:`prepare_scene`), else on first use (the viewer: on its worker thread, after
    the window is up)."""
    from .. import rendering  # noqa: F401 - the core and numpy, before the first stage
    from ..camera import Camera
    from ..scene import Scene

    stage("imported")
    loaded, demo_camera = load_input(args)
    stage("loaded")
    lights = parse_lights(args.light)
    kw = {}
    if args.interpolation:
        kw["interpolation"] = args.interpolation
    if isinstance(loaded, Scene):
        scene = loaded
        if lights is not None:
            scene.lights = lights
        if args.ground != "auto":
            scene = scene.with_ground(args.ground)
        if args.look != "auto":
            scene = scene.with_look(args.look)
    else:
        scene = Scene([loaded], lights=lights, ground=args.ground, look=args.look, **kw)
    if args.camera:
        camera = Camera.from_json(args.camera)
    elif demo_camera is not None:
        camera = demo_camera
    else:
        camera = Camera.fit(scene if not hasattr(loaded, "points") else loaded,
                            fov_deg=40.0 if args.fov is None else args.fov)
    if args.fov is not None and args.fov != camera.fov_deg:
        camera = camera.replace(fov_deg=args.fov)  # validates: names fov_deg when out of range
    if args.width or args.height:
        w = args.width or int(round(camera.width * (args.height / camera.height)))
        h = args.height or int(round(camera.height * (args.width / camera.width)))
        camera = camera.with_size(w, h)
    if prepare:
        from ..rendering import check_render_options

        check_render_options(**render_kwargs(args))  # bad options fail before the trees
        prepare_scene(scene)
    return scene, camera


def prepare_scene(scene) -> None:
    """Estimate missing normals and radii, then build every surfel tree, now: each step ends at
    a named stage (:func:`pointviz.interrupt.stage`), where Ctrl-C takes effect."""
    for obj in scene.objects:
        cloud = getattr(obj.geometry, "cloud", obj.geometry)
        if hasattr(cloud, "points"):
            _ = cloud.normals, cloud.radii
    stage("normals")
    for i in range(len(scene.objects)):
        scene.surfel_scene(i)
    stage("built")


def render_kwargs(args) -> dict:
    return {"shadows": not args.no_shadows, "reflections": args.reflections, "spp": args.spp,
            "lod_pixels": args.lod, "seed": args.seed, "threads": args.threads,
            "denoise": denoise_default(args)}


def denoise_default(args) -> bool:
    """Final frames are denoised unless --no-denoise; without the denoiser installed, a one-line
    note says how to get it and the frame stays as traced."""
    from ..denoise import check_available
    from ..errors import MissingDependencyError

    if getattr(args, "no_denoise", False):
        return False
    try:
        check_available()
    except MissingDependencyError as exc:
        sys.stderr.write(f"note: frames are not denoised: {exc}\n")
        return False
    return True
