"""Script a camera move by hand, save it, and render it to a GIF.

Keyframes are cameras at times (seconds); the path interpolates them smoothly (centripetal
Catmull-Rom positions, slerped orientation, eased timing). The saved JSON is what
``pointviz path demo PATH.json -o FRAMES --video out.mp4`` takes on the command line.

    python examples/script_path.py --out script_frames --video script_path.gif
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, default=Path("script_frames"))
    p.add_argument("--video", type=Path, default=Path("script_path.gif"))
    p.add_argument("--path-file", type=Path, default=Path("script_path.json"))
    p.add_argument("--size", default="320x200", metavar="WxH")
    p.add_argument("--fps", type=float, default=12.0)
    p.add_argument("--overwrite", action="store_true")
    args = p.parse_args(argv)

    from pointviz import Camera, CameraPath, render_path
    from pointviz.shapes import demo_scene

    w, h = (int(v) for v in args.size.lower().split("x"))
    scene, _ = demo_scene(detail=0.5)
    path = CameraPath(width=w, height=h, fps=args.fps)
    # a low pass in front of the objects, a rise over the torus, then a wide view from the side
    path.add(Camera.look_at((-3.0, 0.8, 4.0), (-1.2, 0.7, 0.0), fov_deg=45), time=0.0)
    path.add(Camera.look_at((0.5, 1.2, 3.0), (0.0, 0.5, 0.0), fov_deg=45), time=1.5)
    path.add(Camera.look_at((2.6, 2.6, 1.8), (1.1, 0.3, 0.3), fov_deg=40), time=3.0)
    path.add(Camera.look_at((4.5, 2.0, -3.5), (0.0, 0.4, -0.2), fov_deg=50), time=4.5)
    path.save(args.path_file, overwrite=args.overwrite)
    summary = render_path(scene, path, args.out, video=args.video, overwrite=args.overwrite,
                          spp=2)
    print(f"{args.path_file}: {len(path)} keyframes, {path.n_frames} frames; "
          f"{summary['rendered']} rendered in {summary['seconds']:.1f} s -> {args.video}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
