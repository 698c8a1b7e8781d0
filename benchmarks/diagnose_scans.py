"""Issue 14's diagnosis: which cause makes which artifact on registered raw scans.

The Stanford dragon's raw scans (``stanford_dragon/dragon_stand/dragonStandRight.conf``, 469k
points) are rendered with the default camera and compared pixel by pixel with the dragon's VRIP
reconstruction (``recon_derived``, same frame) rendered by embreex with the same camera and
shading: the mesh is the oracle of where the surface is and which way it faces.

Measured:

* normals (data side): per point, the angle between the estimated normal and the nearest mesh
  vertex's normal (unsigned: orientation is handled by the renderer's face-forwarding), and
  per pixel the shading normal's error with ``interpolation="none"`` (the nearest disk) and
  ``"smooth"`` (the blend): dark cracks where the normal points away from the light;
* stray points (data side): points farther than STRAY_MM from the mesh;
* self-shadowing (render side): under one hard key light with nothing else, pixels the mesh
  shows lit that the surfels show in shadow, for several shadow-ray offset policies
  (``normal_offset`` / ``tmin`` in local radii); pixels are compared only where both hit the
  same surface (depth within DEPTH_MM) and the mesh faces the light by more than 10 degrees;
* sky occlusion (render side): the same for the studio look's sky-visibility rays alone.

Writes ``docs/issue14/`` pictures and ``benchmarks/results/diagnose/diagnose.json``.

Examples
--------
python benchmarks/diagnose_scans.py
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common

STRAY_MM = 3.0
#: A false-shadow pixel with at most this many dark neighbours (of 8) is a speckle.
SPECKLE_NEIGHBOURS = 2
DEPTH_MM = 1.0
#: Offset policies tried (normal offset, tmin) in local radii; (1, 2) is the renderer's.
POLICIES = ((0.25, 0.5), (0.5, 1.0), (1.0, 2.0), (2.0, 4.0))
#: The key light's direction relative to the camera, as the studio look places it.
WIDTH, HEIGHT = 640, 480


def _render_core(scene, cam, spp, normal_offset, tmin, shadows=True):
    """pointviz.render with an explicit offset policy (the core's settings)."""
    from pointviz import _core
    from pointviz.rendering import camera_model

    rs, origin = scene.to_core(cam, 1.0)
    st = _core.RenderSettings()
    st.spp, st.reflections, st.shadows, st.lod_pixels = spp, 0, shadows, 1.0
    st.normal_offset, st.offset_tmin = normal_offset, tmin
    bufs, stats = _core.render(rs, camera_model(cam, origin), st, None)
    return bufs


def main(argv=None) -> int:
    import argparse

    import pointviz
    from pointviz.comparison import MeshGeometry
    from pointviz.scene import LOOKS, Scene
    from scipy.spatial import cKDTree

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, default=common.default_data_dir())
    p.add_argument("--docs", type=Path, default=common.REPO_ROOT / "docs" / "issue14")
    p.add_argument("--out", type=Path, default=common.REPO_ROOT / "benchmarks" / "results" / "diagnose")
    args = p.parse_args(argv)
    try:
        conf = common.require_data(args.data, Path("stanford_dragon/dragon_stand/dragonStandRight.conf"))
        mesh_path = common.require_data(args.data, Path("stanford_dragon/recon_derived/dragon_vrip_res3_meshlab.ply"))
    except common.DataMissingError as exc:
        print(f"SKIP: {exc}")
        return 0
    import trimesh
    from PIL import Image

    cloud = pointviz.load(conf)
    mesh = trimesh.load(mesh_path, process=False)
    verts, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    vnormals = np.asarray(mesh.vertex_normals)
    cam = pointviz.Camera.fit(cloud, width=WIDTH, height=HEIGHT)
    rec = {"points": len(cloud.points), "mesh_faces": len(faces), "camera": cam.to_dict()}

    # -- per point: normals and strays against the mesh ---------------------------------------
    dense, fidx = trimesh.sample.sample_surface_even(mesh, 400000, seed=0)
    tree = cKDTree(dense)
    dist, nearest = tree.query(cloud.points, workers=-1)
    stray = dist > STRAY_MM * 1e-3
    ref_n = np.asarray(mesh.face_normals)[fidx[nearest]]
    cosang = np.abs(np.einsum("ij,ij->i", cloud.normals, ref_n))
    on = ~stray
    rec["stray_points"] = int(stray.sum())
    rec["stray_fraction"] = float(stray.mean())
    rec["normal_error_deg_median"] = float(np.degrees(np.arccos(np.clip(np.median(cosang[on]), 0, 1))))
    for deg in (30, 60):
        rec[f"points_normal_error_over_{deg}"] = float((cosang[on] < np.cos(np.radians(deg))).mean())
    flipped = np.einsum("ij,ij->i", cloud.normals, ref_n) < 0
    rec["points_normal_flipped"] = float(flipped[on].mean())
    # how many scan layers overlap: surface points with a point of another scan within 1 radius
    print(f"{len(cloud.points):,} points, {rec['stray_points']} stray (> {STRAY_MM} mm from the "
          f"mesh); normal error median {rec['normal_error_deg_median']:.1f} deg, "
          f"> 30 deg: {100 * rec['points_normal_error_over_30']:.1f} %, > 60 deg: "
          f"{100 * rec['points_normal_error_over_60']:.1f} %, flipped (outward vs inward) "
          f"{100 * rec['points_normal_flipped']:.1f} %")

    # -- per pixel: shading normals, none vs smooth ---------------------------------------------
    rays = cam.rays()
    mg = MeshGeometry(verts, faces)
    m_hit = mg.cast_rays(rays.astype(np.float64))
    per = {}
    for interp in ("none", "smooth"):
        ss = pointviz.SurfelScene(cloud, interpolation=interp, cull=False)
        out = ss.cast_rays(rays, camera=cam, stats=False)
        both = np.isfinite(out["t_hit"]) & np.isfinite(m_hit["t_hit"])
        same = both & (np.abs(out["t_hit"] - m_hit["t_hit"]) < DEPTH_MM * 1e-3)
        c = np.abs(np.einsum("ij,ij->i", out["normals"][same], m_hit["normals"][same]))
        per[interp] = {"pixels": int(same.sum()),
                       "over_30": float((c < np.cos(np.radians(30))).mean()),
                       "over_60": float((c < np.cos(np.radians(60))).mean()),
                       "median_deg": float(np.degrees(np.arccos(np.clip(np.median(c), 0, 1))))}
        print(f"pixels ({interp:6s}): normal error median {per[interp]['median_deg']:.1f} deg, "
              f"> 30 deg {100 * per[interp]['over_30']:.1f} %, > 60 deg {100 * per[interp]['over_60']:.1f} %")
    rec["pixel_normals"] = per
    same_mask = same.reshape(HEIGHT, WIDTH)

    # -- self-shadowing under one hard key light, by offset policy ---------------------------
    key = replace(LOOKS["studio"], ambient=0.0, occlusion=0.0, fill=0.0, key_angle_deg=0.0,
                  backdrop=False, ground="none", auto_exposure=False)
    surf_scene = Scene([cloud], look=key, ground="none")
    mesh_scene = Scene([mg], look=key, ground="none", up=cloud.up)
    m_bufs = _render_core(mesh_scene, cam, 1, 1.0, 2.0)
    mesh_lit = m_bufs["color"][..., 1] > 1e-4
    light = key.lights(cam, surf_scene.up)[0]
    ldir = np.asarray(light.direction) / np.linalg.norm(light.direction)
    faces_light = (m_hit["normals"] @ ldir).reshape(HEIGHT, WIDTH)
    # the mesh's normal faces the camera in the render; faces_light uses its facing side
    view = rays[:, 3:].reshape(HEIGHT, WIDTH, 3)
    nm = m_hit["normals"].reshape(HEIGHT, WIDTH, 3)
    nm = np.where((np.einsum("hwk,hwk->hw", nm, view) > 0)[..., None], -nm, nm)
    faces_light = np.einsum("hwk,k->hw", nm, ldir) > np.sin(np.radians(10))
    judged = same_mask & faces_light & mesh_lit
    judged_dark = same_mask & faces_light & ~mesh_lit   # in the mesh's cast shadows
    # control: one clean layer of surfels on the mesh itself (its normals, the scans' count)
    pts_c, fid_c = trimesh.sample.sample_surface_even(mesh, len(cloud.points), seed=1)
    control = pointviz.PointCloud(pts_c, normals=np.asarray(mesh.face_normals)[fid_c], up=cloud.up)
    pictures = []
    for name, c in (("shadow", cloud), ("shadow_control", control)):
        rec[name] = {}
        sc = Scene([c], look=key, ground="none")
        for no, tm in POLICIES:
            b = _render_core(sc, cam, 1, no, tm)
            dark = b["color"][..., 1] <= 1e-4
            false_shadow = judged & dark
            frac = float(false_shadow.sum() / max(judged.sum(), 1))
            # speckles: false-shadow pixels with at most SPECKLE_NEIGHBOURS dark neighbours of
            # 8 (the rest are bands along terminators, where the coarse mesh and the scans differ)
            pad = np.pad(dark, 1)
            nb = sum(pad[1 + dy:HEIGHT + 1 + dy, 1 + dx:WIDTH + 1 + dx]
                     for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx)
            speckle = false_shadow & (nb <= SPECKLE_NEIGHBOURS)
            sfrac = float(speckle.sum() / max(judged.sum(), 1))
            missed = float((judged_dark & ~dark).sum() / max(judged_dark.sum(), 1))
            rec[name][f"{no:g}/{tm:g}"] = {"false_shadow": frac, "speckles": sfrac,
                                           "missed_shadow": missed}
            what = "scans" if c is cloud else "control: clean surfels on the mesh"
            print(f"{what}: shadow rays, offset {no:g} / tmin {tm:g} radii: {100 * frac:.2f} % of "
                  f"lit surface pixels in false shadow, {100 * sfrac:.2f} % isolated speckles; "
                  f"{100 * missed:.2f} % of the mesh's cast-shadow pixels lit")
            if c is cloud:
                img = np.clip(b["color"] / max(np.percentile(b["color"], 99), 1e-6), 0, 1)
                img[false_shadow] = (1.0, 0.0, 0.0)
                pictures.append((img * 255).astype(np.uint8))

    # -- sky occlusion alone ----------------------------------------------------------------
    sky = replace(LOOKS["studio"], key=0.0, fill=0.0, backdrop=False, ground="none",
                  auto_exposure=False)
    occ = Scene([cloud], look=sky, ground="none")
    free = Scene([cloud], look=replace(sky, occlusion=0.0), ground="none")
    rec["occlusion"] = {}
    for no, tm in POLICIES:
        a = _render_core(occ, cam, 8, no, tm)["color"][..., 1]
        f = _render_core(free, cam, 1, no, tm)["color"][..., 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            vis = np.where(same_mask, a / f, np.nan)
        rec["occlusion"][f"{no:g}/{tm:g}"] = float(np.nanmean(vis))
        print(f"sky visibility, offset {no:g} / tmin {tm:g}: mean {np.nanmean(vis):.3f} over the "
              f"surface pixels")

    args.docs.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate([np.concatenate(pictures[:2], 1), np.concatenate(pictures[2:], 1)], 0)).save(
        args.docs / "dragon_false_shadows_by_offset.png")
    # the normals that make the dark cracks: points whose normal is > 60 deg off, in red
    bad = on & (cosang < np.cos(np.radians(60)))
    colors = np.tile([0.85, 0.85, 0.85], (len(cloud.points), 1))
    colors[bad] = (1.0, 0.0, 0.0)
    colors[stray] = (0.0, 0.3, 1.0)
    marked = pointviz.PointCloud(cloud.points, normals=cloud.normals, radii=cloud.radii,
                                 colors=colors, up=cloud.up)
    fr = pointviz.render(Scene([marked], look="flat", ground="none"), cam, spp=2, shadows=False)
    fr.save(args.docs / "dragon_bad_normals_red_strays_blue.png", overwrite=True)
    args.out.mkdir(parents=True, exist_ok=True)
    rec["date"] = time.strftime("%Y-%m-%dT%H:%M:%S")
    (args.out / "diagnose.json").write_text(json.dumps(rec, indent=2, default=float))
    print(f"wrote {args.docs} and {args.out / 'diagnose.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
