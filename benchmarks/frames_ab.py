"""Every buffer of a set of frames, saved from one build and compared with another's.

Issue 18's renderer changes that should keep the frames to the bit are checked against main's
build with this: ``save`` renders the frames with the running build (run it once with each venv),
``compare`` prints, per frame and buffer, whether the bits are equal, and where they are not the
mean and largest |difference| of the colour and the mean FLIP of the tone-mapped frames.

The frames: a 200k-surfel striped torus (``lod_budget.striped_torus``) at 1x, 2.5x and 7.5x the
framing distance, 480x360 and 173x97 (a width off the vector steps), full detail, 1 px and
E = 0.005, at 1 and 3 samples, the studio, outdoor and flat looks; and a Scene with a matte, a
glossy and a mirror ground, a soft point light, an area light, a soft directional light and a
hard one, from a low view over the horizon, at 1 and 2 samples.

Examples
--------
/work/venvs/main/bin/python benchmarks/frames_ab.py save /tmp/main.npz
python benchmarks/frames_ab.py save /tmp/this.npz
python benchmarks/frames_ab.py compare /tmp/main.npz /tmp/this.npz
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

BUFFERS = ("color", "depth", "normal", "alpha", "albedo", "object_alpha")


def frames():
    import lod_budget
    import paper_figures as pf

    import pointviz
    from pointviz import AreaLight, DirectionalLight, PointLight, Scene, shapes

    model = lod_budget.striped_torus(200_000)
    scene = pointviz.SurfelScene(model.cloud, variant="full", threads=1)
    for w, h in ((480, 360), (173, 97)):
        base = pointviz.Camera.fit(model.cloud, width=w, height=h)
        for factor in (1.0, 2.5, 7.5):
            cam = pf.camera_at(base, factor)
            for look in ("studio", "outdoor", "flat"):
                for spp in (1, 3):
                    for name, v in (("full", {"lod_pixels": 0.0}), ("1px", {"lod_pixels": 1.0}),
                                    ("auto", {"lod_pixels": "auto", "max_error": 0.005})):
                        if look != "studio" and (name != "auto" or w != 480):
                            continue
                        key = f"torus_{w}x{h}_{factor}x_{look}_{name}_spp{spp}"
                        yield key, pointviz.render(scene, cam, spp=spp, shadows=True, reflections=1,
                                                   threads=1, look=look, **v)
    cloud = shapes.torus(30_000)
    lights = [DirectionalLight(direction=(0.3, 1.0, 0.2), intensity=1.2, angle_deg=4.0),
              DirectionalLight(direction=(-1.0, 0.4, 0.5), intensity=0.3, angle_deg=0.0, shadows=False),
              PointLight(position=(0.0, 2.5, 2.0), intensity=4.0, radius=0.2),
              AreaLight(corner=(-1.0, 2.0, 0.0), edge_u=(1.0, 0.0, 0.0), edge_v=(0.0, 0.0, 1.0),
                        intensity=3.0)]
    base = pointviz.Camera.fit(cloud, width=160, height=120)
    for ground in ("matte", "glossy", "mirror"):
        sc = Scene([cloud], lights=lights, ground=ground)
        for factor, lift in ((1.0, 0.0), (4.0, -0.15)):
            cam = pf.camera_at(base, factor)
            if lift:
                eye = np.asarray(cam.eye) + np.asarray(cam.true_up) * lift * cam.distance
                cam = pointviz.Camera.look_at(eye, cam.target, up=cam.true_up, fov_deg=cam.fov_deg,
                                              width=cam.width, height=cam.height)
            for spp in (1, 2):
                yield (f"scene_{ground}_{factor}x_spp{spp}",
                       pointviz.render(sc, cam, spp=spp, shadows=True, reflections=1, threads=1))


def save(path: str) -> int:
    out = {}
    for key, fr in frames():
        for b in BUFFERS:
            out[f"{key}:{b}"] = np.asarray(getattr(fr, b))
        out[f"{key}:exposure"] = np.asarray(getattr(fr, "exposure", 1.0), dtype=np.float64)
    np.savez_compressed(path, **out)
    print(f"{len(out)} arrays saved to {path}")
    return 0


def compare(a_path: str, b_path: str) -> int:
    from pointviz import images
    from pointviz.comparison.metrics import flip as mean_flip

    a, b = np.load(a_path), np.load(b_path)
    keys = sorted({k.split(":")[0] for k in a.files})
    worst_flip = worst_mean = worst_max = 0.0
    differ = 0
    for key in keys:
        bad = [buf for buf in BUFFERS
               if not np.array_equal(a[f"{key}:{buf}"].view(np.uint32), b[f"{key}:{buf}"].view(np.uint32))]
        if not bad:
            continue
        differ += 1
        ca, cb = a[f"{key}:color"], b[f"{key}:color"]
        d = np.abs(ca.astype(np.float64) - cb.astype(np.float64))
        exp = float(a[f"{key}:exposure"])
        # both tone mapped at a's exposure, as bench_lod.py does
        flip = mean_flip(images.to_srgb8(ca, exp).astype(np.float32) / 255.0,
                         images.to_srgb8(cb, exp).astype(np.float32) / 255.0)[0]
        worst_flip, worst_mean, worst_max = max(worst_flip, flip), max(worst_mean, d.mean()), max(worst_max, d.max())
        print(f"{key}: {', '.join(bad)} differ; colour mean |d| {d.mean():.3g}, max {d.max():.3g}, FLIP {flip:.3g}")
    print(f"{len(keys)} frames, {differ} differ; worst mean |d| {worst_mean:.3g}, max {worst_max:.3g}, "
          f"FLIP {worst_flip:.3g}")
    return 0


if __name__ == "__main__":
    if sys.argv[1] == "save":
        sys.exit(save(sys.argv[2]))
    sys.exit(compare(sys.argv[2], sys.argv[3]))
