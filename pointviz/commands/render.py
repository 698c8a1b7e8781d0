"""``pointviz render INPUT -o out.png``: one final frame."""

from __future__ import annotations

from ..progress import ProgressBar
from .common import add_input_options, add_render_options, make_scene_and_camera, render_kwargs


def add_parser(sub) -> None:
    p = sub.add_parser("render", help="ray trace one frame", description=__doc__)
    add_input_options(p)
    p.add_argument("-o", "--output", required=True, help="output image (.png or .exr)")
    add_render_options(p)
    p.add_argument("--bits", type=int, choices=[8, 16], default=8, help="PNG bit depth")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    p.add_argument("--progress", action="store_true", help="show progress even when not a terminal")
    # nothing is left to clean up once run() returns: the PNG is written and renamed into place
    p.set_defaults(run=run, exit_fast=True)


def run(args) -> int:
    from ..images import check_image_path
    from ..rendering import render

    check_image_path(args.output, args.overwrite)  # fail before the expensive part
    setup = None
    if getattr(args, "denoise", True):  # the denoiser's setup overlaps the reading and the fit
        # this thread's imports first: the setup's own Python holds Python's lock, which the
        # reading and the fit, in the core, do not need
        from .. import camera as _camera, io as _io, scene as _scene  # noqa: F401
        from ..denoise import DENOISE_QUALITY, prepare_in_background

        setup = prepare_in_background(DENOISE_QUALITY, args.threads)
    try:
        # nothing needs the cloud once its tree is built: the build frees it as it copies it
        scene, camera = make_scene_and_camera(args, hand_over=True)
        bar = ProgressBar("render", enabled=True if args.progress else None)
        frame = render(scene, camera, progress=bar, **render_kwargs(args))
    finally:
        if setup is not None:  # (done long before, unless the run failed early)
            setup.join()
    frame.save(args.output, bits=args.bits, overwrite=args.overwrite)  # at frame.exposure
    s = frame.stats
    print(f"{args.output}: {camera.width}x{camera.height}, {s['seconds']:.2f} s, "
          f"{s['rays_per_second'] / 1e6:.2f} Mrays/s")
    return 0
