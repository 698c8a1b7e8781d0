"""Render an orbit of the registered Stanford dragon scans to MP4.

The 15 raw range scans of ``stanford_dragon/dragon_stand`` are placed by their ``.conf``
registration and rendered as surfels (normals and radii estimated from the points), one
revolution, in this process by default (every core on each frame: the fastest on one machine;
``--scheduler local`` for a 2-process Dask cluster). Interrupt it and run it again: it resumes.

    python examples/orbit_dragon.py                          # 240 frames, 640x480
    python examples/orbit_dragon.py --frames 24 --size 160x120   # quick look
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

#: Where the shared data lives relative to this file (the repository's sibling ``shared/data``).
DATA_DIR = Path(__file__).resolve().parents[2] / "shared" / "data"
DRAGON_CONF = Path("stanford_dragon/dragon_stand/dragonStandRight.conf")


def parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WxH, got {text!r}") from None
    return w, h


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", type=Path, default=DATA_DIR, help="the shared data folder")
    p.add_argument("--frames", type=int, default=240, help="frames in the revolution")
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--size", type=parse_size, default=(640, 480), metavar="WxH")
    p.add_argument("--spp", type=int, default=4)
    p.add_argument("--scheduler", default="auto",
                   help="'auto' (this process, the default), 'local' (2-process Dask cluster) "
                        "or tcp://HOST:PORT")
    p.add_argument("--out", type=Path, default=Path("dragon_orbit"), help="frames folder")
    p.add_argument("--video", type=Path, default=Path("dragon_orbit.mp4"))
    p.add_argument("--overwrite", action="store_true")
    args = p.parse_args(argv)

    import pointviz
    from pointviz.path import CameraPath

    conf = args.data / DRAGON_CONF
    if not conf.is_file():
        print(f"{conf}: not found (pass --data to the shared data folder)", file=sys.stderr)
        return 2
    cloud = pointviz.load(conf)
    print(f"{conf.name}: {len(cloud.points):,} points")
    w, h = args.size
    # seconds = frames / fps puts a keyframe on every frame; the path is closed, so it has
    # frames + 1 frames, the last repeating the first
    path = CameraPath.orbit(cloud, seconds=args.frames / args.fps, fps=args.fps, width=w,
                            height=h, easing="linear")
    scene = pointviz.Scene([cloud], ground="matte")
    summary = pointviz.render_path(
        scene, path, args.out, video=args.video, overwrite=args.overwrite, spp=args.spp,
        scheduler=args.scheduler)
    print(f"{args.out}: {summary['rendered']} frames rendered, {summary['skipped']} resumed, "
          f"{summary['fps']:.2f} frames/s; {args.video}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
