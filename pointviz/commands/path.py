"""``pointviz path INPUT PATH.json -o FRAMES_DIR``: render a camera path to frames (and a video).

PATH.json is a camera path file (``CameraPath.save``, the viewer's keyframes) or the word
``orbit`` for one revolution around the input lasting ``--orbit`` seconds. Frames go to
FRAMES_DIR/frame_00000.png ...; an interrupted run resumes when run again with the same
arguments.

Frames render in this process by default (``--scheduler auto``): every core renders each frame
(the core's threads, two frames in flight), the scene is loaded and its tree built once: on one
machine the fastest way, with the least memory (README.md, "Camera paths").
``--scheduler local`` renders on a local Dask cluster of ``--workers`` processes instead (process
isolation: a crashed worker is restarted and its frame re-run), ``--scheduler tcp://HOST:PORT``
on an existing Dask cluster (more machines). The frames are byte-identical whichever renders them.
"""

from __future__ import annotations

from ..path import AUTO, DEFAULT_ORBIT_SECONDS, LOCAL, SERIAL
from ..progress import ProgressBar
from .common import (
    add_input_options,
    add_render_options,
    make_scene_and_camera,
    render_kwargs,
)

#: PATH.json value that asks for an orbit instead of a file.
ORBIT = "orbit"


def add_parser(sub) -> None:
    p = sub.add_parser("path", help="render a camera path to frames and video", description=__doc__)
    add_input_options(p)
    p.add_argument("path", metavar="PATH.json", help=f"camera path file, or '{ORBIT}'")
    p.add_argument("-o", "--output", required=True, metavar="FRAMES_DIR",
                   help="folder for frame_00000.png ... (created if missing)")
    add_render_options(p)
    p.add_argument("--video", metavar="OUT.mp4|OUT.gif", help="also encode the frames as a video")
    p.add_argument("--fps", type=float, default=None,
                   help="frames per second of an orbit and of the video (default: the path's, 30)")
    p.add_argument("--orbit", type=float, default=DEFAULT_ORBIT_SECONDS, metavar="SECONDS",
                   help=f"duration of the orbit when PATH.json is '{ORBIT}'")
    p.add_argument("--scheduler", default=AUTO, metavar="ADDRESS",
                   help=f"'{AUTO}' (the default: this process, every core on each frame, the "
                        f"fastest on one machine), '{SERIAL}' (this process), '{LOCAL}' (a Dask "
                        "LocalCluster of --workers processes on this machine) or tcp://HOST:PORT "
                        "of an existing Dask scheduler")
    p.add_argument("--workers", type=int, default=2,
                   help=f"processes of the local cluster (--scheduler {LOCAL})")
    p.add_argument("--retries", type=int, default=3, help="re-runs of a failed frame task")
    p.add_argument("--no-resume", action="store_true",
                   help="re-render frames already in FRAMES_DIR (needs --overwrite)")
    p.add_argument("--overwrite", action="store_true",
                   help="delete frames of a different render in FRAMES_DIR; replace the video")
    p.add_argument("--progress", action="store_true", help="show progress even when not a terminal")
    # Once it returns, its frames (and video) are complete and any cluster it started is closed.
    p.set_defaults(run=run, exit_fast=True)


def _camera_path(args, scene):
    from ..errors import InputError
    from ..path import DEFAULT_FPS, CameraPath

    if args.path == ORBIT:
        if not args.orbit > 0:
            raise InputError(f"--orbit: expected seconds > 0, got {args.orbit}")
        return CameraPath.orbit(scene, seconds=args.orbit, fps=args.fps or DEFAULT_FPS,
                                width=args.width or 640, height=args.height or 480,
                                fov_deg=40.0 if args.fov is None else args.fov)
    return CameraPath.load(args.path)


def run(args) -> int:
    from ..errors import InputError
    from ..path import render_path

    if args.workers < 1:
        raise InputError(f"--workers: expected at least 1, got {args.workers}")
    if args.camera:
        raise InputError("--camera: a path command takes its cameras from PATH.json")
    scene, _ = make_scene_and_camera(args)
    path = _camera_path(args, scene)
    summary = render_path(
        scene, path, args.output, width=args.width, height=args.height, video=args.video,
        fps=args.fps, scheduler=args.scheduler, workers=args.workers, retries=args.retries,
        resume=not args.no_resume, overwrite=args.overwrite,
        progress=ProgressBar("path", enabled=True if args.progress else None),
        **render_kwargs(args))
    where = "this process" if summary["scheduler"] == "serial" else (
        f"{summary['workers']} workers at {summary['scheduler']}")
    print(f"{args.output}: {summary['frames']} frames ({summary['rendered']} rendered, "
          f"{summary['skipped']} already there) in {summary['seconds']:.1f} s on {where}"
          + (f", {summary['fps']:.2f} frames/s" if summary["rendered"] else "")
          + f", exposure {summary['exposure']:.3g}")
    if summary["video"]:
        print(f"{summary['video']}: {summary['frames']} frames at "
              f"{args.fps or path.fps:g} fps")
    return 0
