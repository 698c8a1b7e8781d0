"""Render a real scan with shadows and a mirror floor.

    python examples/render_scan.py [SCAN] [-o out/scan.png] [--width 800]

SCAN defaults to the registered Stanford dragon scans in ../shared/data (any file pointviz.load
reads works: .conf, .ply, .pcd, .las/.laz, .vtp, meshes).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pointviz

DEFAULT = (Path(__file__).resolve().parents[1].parent / "shared" / "data" / "stanford_dragon"
           / "dragon_stand" / "dragonStandRight.conf")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scan", nargs="?", default=str(DEFAULT))
    ap.add_argument("-o", "--output", default="out/scan.png")
    ap.add_argument("--width", type=int, default=800)
    ap.add_argument("--height", type=int, default=600)
    ap.add_argument("--spp", type=int, default=4)
    args = ap.parse_args()
    if not Path(args.scan).exists():
        raise SystemExit(f"{args.scan}: not found (pass a scan file; ../shared/data is absent)")

    cloud = pointviz.load(args.scan)
    print(f"{cloud}: normals and radii estimated per point")
    scene = pointviz.Scene(cloud, ground="mirror")
    camera = pointviz.Camera.fit(cloud, width=args.width, height=args.height)
    frame = pointviz.render(scene, camera, spp=args.spp)
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    frame.save(args.output, overwrite=True)
    print(f"wrote {args.output} in {frame.stats['seconds']:.2f} s "
          f"({frame.stats['rays_per_second'] / 1e6:.1f} Mrays/s)")


if __name__ == "__main__":
    main()
