"""``pointviz view INPUT``: the interactive viewer (splat preview, Render button, outputs).

With ``--render --screenshot OUT.png`` the window opens, renders the view once, saves a
screenshot of the whole window (preview and ray-traced frame) and exits with status 0: for
scripts, tests and docs (run it under ``xvfb-run`` on a machine without a display).
"""

from __future__ import annotations

import math
import os
import sys

from ..errors import InputError
from ..interrupt import cancelled, check
from .common import add_input_options, add_render_options, make_scene_and_camera, render_kwargs

#: Leave the process without Python's teardown once the Open3D window has closed and every
#: output is written: Open3D 0.20's GUI segfaults or hangs now and then while its static
#: renderer objects are destroyed at interpreter exit (about 1 run in 6 under Xvfb + lavapipe),
#: which would turn a successful run into exit status 139.
EXIT_WITHOUT_TEARDOWN = True


def add_parser(sub) -> None:
    p = sub.add_parser("view", help="open the interactive viewer", description=__doc__)
    add_input_options(p)
    p.add_argument("--backend", choices=["open3d", "pyvista"], default="open3d",
                   help="preview toolkit (default open3d)")
    p.add_argument("--render", action="store_true", help="press Render once the preview is up")
    p.add_argument("--live", action="store_true",
                   help="ray trace the viewport live (1 spp at an adaptive resolution while the "
                        "camera moves, accumulating and denoising while it holds still)")
    p.add_argument("--orbit", type=float, metavar="SECONDS",
                   help="with --live: circle the data for SECONDS, hold still 3 s, then save "
                        "the screenshot and report and close")
    p.add_argument("--screenshot", metavar="OUT.png",
                   help="save a screenshot of the whole window, then exit")
    p.add_argument("--frame", metavar="OUT.npz",
                   help="also save the ray-traced frame's buffers and camera (.npz)")
    p.add_argument("--report", metavar="OUT.json", help="write timings and layout (JSON) on exit")
    p.add_argument("--color-by", choices=["rgb", "normal", "height", "intensity"], default="rgb",
                   help="preview colouring")
    p.add_argument("--preview-points", type=int, default=None, metavar="N",
                   help="most points the preview draws (a subset above; the tracer uses all)")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    add_render_options(p)
    p.set_defaults(run=run)


def run(args) -> int:
    from ..viewer import view
    from ..viewer.model import DEFAULT_PREVIEW_MAX_POINTS

    if args.orbit is not None and not args.live:
        raise InputError("--orbit: needs --live")
    if args.orbit is not None and not (math.isfinite(args.orbit) and args.orbit >= 0):
        raise InputError(f"--orbit: expected seconds >= 0, got {args.orbit}")
    if args.live and args.backend != "open3d":
        raise InputError("--live: needs the open3d backend")
    scene, camera = make_scene_and_camera(args, prepare=False)
    overrides = {**render_kwargs(args),
                 "color_mode": args.color_by, "ground": None,  # the scene already has --ground
                 "width": args.width or 0, "height": args.height or 0,
                 "preview_max_points": args.preview_points or DEFAULT_PREVIEW_MAX_POINTS}
    given_camera = camera if (args.camera or args.input == "demo") else None
    view(scene, args.backend, camera=given_camera, render=args.render, live=args.live,
                  orbit=args.orbit,
                  screenshot=args.screenshot, frame=args.frame, report=args.report,
                  overwrite=args.overwrite, **overrides)
    interrupted = cancelled()  # Ctrl-C in the terminal closed the window
    if args.screenshot and not interrupted:
        print(f"{args.screenshot}: screenshot of the viewer")
    if args.backend == "open3d" and EXIT_WITHOUT_TEARDOWN:
        if interrupted:
            print("pointviz: interrupted", file=sys.stderr)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(130 if interrupted else 0)
    check()
    return 0
