"""Which interpolation is most accurate? Surfel hits against the true surface.

For each model, surfels are sampled from a known surface; primary rays of a camera framing it
are cast through the surfel tree with each interpolation ("none": the first disk, "paper": the
weights printed in the paper, "smooth": this project's falloff) and the hit position and normal
are compared with the true surface hit of the same ray (analytic, or Open3D's RaycastingScene on
the source mesh). Prints a table and writes benchmarks/results/interp.json.

    python benchmarks/bench_interp.py [--data DIR] [--quick]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ARMADILLO_MESH, default_data_dir, load_mesh, sample_mesh_surface  # noqa: E402

import pointviz  # noqa: E402
from pointviz import shapes  # noqa: E402

INTERPOLATIONS = ("none", "paper", "smooth")
#: Depth windows tried for the blending interpolations (in radii of the nearest disk).
WINDOWS = (0.5, 1.0, 2.0)


def truth_sphere(rays, center, radius):
    o = rays[:, :3] - center
    d = rays[:, 3:]
    b = np.einsum("ij,ij->i", o, d)
    c = np.einsum("ij,ij->i", o, o) - radius**2
    disc = b * b - c
    t = np.where(disc > 0, -b - np.sqrt(np.maximum(disc, 0)), np.inf)
    n = (o + d * np.where(np.isfinite(t), t, 0)[:, None]) / radius
    return t, n


def truth_mesh(rays, vertices, faces):
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)),
                        o3d.core.Tensor(faces.astype(np.uint32)))
    ans = scene.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))
    t = ans["t_hit"].numpy().astype(np.float64)
    n = ans["primitive_normals"].numpy().astype(np.float64)
    return t, n


def evaluate(cloud, rays, t_true, n_true, scale):
    rows = []
    hit_true = np.isfinite(t_true)
    d = rays[:, 3:]
    facing = np.abs(np.einsum("ij,ij->i", n_true, d)) > 0.2  # off-silhouette rays
    for interp in INTERPOLATIONS:
        for window in (WINDOWS if interp != "none" else (1.0,)):
            scene = pointviz.SurfelScene(cloud, interpolation=interp, window=window)
            out = scene.cast_rays(rays)
            hit = np.isfinite(out["t_hit"])
            both = hit & hit_true & facing
            n = out["normals"][both].astype(np.float64)
            nt = n_true[both] / np.linalg.norm(n_true[both], axis=1, keepdims=True)
            # the true normal's orientation may differ (mesh winding): compare as lines
            ang = np.degrees(np.arccos(np.clip(np.abs(np.einsum("ij,ij->i", n, nt)), 0, 1)))
            rows.append({
                "interpolation": interp, "window": window,
                "normal_error_mean_deg": float(ang.mean()),
                "normal_error_p95_deg": float(np.quantile(ang, 0.95)),
                "depth_error_mean_rel": float(np.abs(out["t_hit"][both] - t_true[both]).mean() / scale),
                "hit_agreement": float(np.mean(hit == hit_true)),
                "disks_blended_mean": float(out["count"][both].mean()),
            })
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=default_data_dir())
    ap.add_argument("--quick", action="store_true", help="tiny sizes (smoke run)")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results" / "interp.json")
    args = ap.parse_args(argv)
    n_surfels = 20_000 if args.quick else 400_000
    size = (64, 48) if args.quick else (400, 300)
    results = {}

    sphere = shapes.sphere(n_surfels)
    cam = pointviz.Camera.fit(sphere, width=size[0], height=size[1])
    rays = cam.rays(dtype=np.float64)
    t, n = truth_sphere(rays, np.zeros(3), 1.0)
    results["sphere"] = evaluate(sphere, rays, t, n, 2.0)

    mesh_path = args.data / ARMADILLO_MESH
    if mesh_path.exists():
        v, f = load_mesh(mesh_path)
        pts, normals = sample_mesh_surface(v, f, n_surfels, seed=5)
        arm = pointviz.PointCloud(pts, normals=normals)
        cam = pointviz.Camera.fit(arm, width=size[0], height=size[1])
        rays = cam.rays(dtype=np.float64)
        t, n = truth_mesh(rays, v, f)
        results["armadillo"] = evaluate(arm, rays, t, n, float(np.linalg.norm(v.max(0) - v.min(0))))
    else:
        print(f"note: {mesh_path} absent: Armadillo skipped")

    print(f"{'model':10s} {'interp':7s} {'window':>6s} {'normal err':>10s} {'p95':>6s} {'depth err':>10s} {'agree':>6s} {'disks':>5s}")
    for model, rows in results.items():
        for r in rows:
            print(f"{model:10s} {r['interpolation']:7s} {r['window']:6.1f} {r['normal_error_mean_deg']:9.3f}° "
                  f"{r['normal_error_p95_deg']:5.2f}° {r['depth_error_mean_rel']:10.2e} {r['hit_agreement']:6.4f} "
                  f"{r['disks_blended_mean']:5.2f}")
    for model, rows in results.items():
        base = next(r for r in rows if r["interpolation"] == "none")["normal_error_mean_deg"]
        best = min(rows, key=lambda r: r["normal_error_mean_deg"])
        default = next(r for r in rows if r["interpolation"] == "smooth" and r["window"] == 1.0)
        print(f"{model}: best {best['interpolation']} (window {best['window']}); default smooth/1.0 "
              f"normal error = {default['normal_error_mean_deg'] / base:.2f} x first-disk")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"surfels": n_surfels, "image": size, "results": results}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
