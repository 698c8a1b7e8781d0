"""Open the viewer on a scan (or the built-in demo) and, with --screenshot, render once and save a
screenshot of the whole window.

    python examples/view_scan.py                      # the demo scene, interactive
    python examples/view_scan.py scan.ply --backend pyvista
    xvfb-run -a python examples/view_scan.py --screenshot viewer.png   # headless, exits

The same as ``pointviz view INPUT [--render --screenshot OUT.png]``.
"""

from __future__ import annotations

import argparse
import json

import pointviz


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("input", nargs="?", default="demo", help="a point cloud file, or 'demo'")
    ap.add_argument("--backend", choices=["open3d", "pyvista"], default="open3d")
    ap.add_argument("--screenshot", help="render once, save a screenshot of the window, exit")
    ap.add_argument("--spp", type=int, default=4)
    args = ap.parse_args()
    camera = None
    if args.input == "demo":
        from pointviz.shapes import demo_scene

        source, camera = demo_scene()
    else:
        source = pointviz.load(args.input)
    report = None
    if args.screenshot:
        report = args.screenshot.rsplit(".", 1)[0] + ".json"
    viewer = pointviz.view(source, args.backend, camera=camera, spp=args.spp,
                           render=bool(args.screenshot), screenshot=args.screenshot,
                           report=report, overwrite=True)
    print(json.dumps(viewer.timings, indent=2, default=str))


if __name__ == "__main__":
    main()
