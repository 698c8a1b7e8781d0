"""Triangle meshes as a render backend: embreex closest-hit and occlusion queries behind the
callback-geometry interface, so a mesh renders with exactly the camera, lights, materials and
shading of the surfel renderer (``pointviz.render(Scene([MeshGeometry(...)]), camera)``).

The renderer calls :meth:`MeshGeometry.intersect` and :meth:`MeshGeometry.occluded` with rays in
the scene's local frame (world minus the origin given to :meth:`MeshGeometry.set_origin`); the
Embree scene is built there, in float32, once per origin.
"""

from __future__ import annotations

import time

import numpy as np

from .cloud import vertex_normals
from .errors import InputError, require

#: Embree (through embreex) takes a finite ``tfar``; rays with ``tmax = inf`` get this instead.
#: It is embreex's own default and far beyond any scene (pointviz re-centres scenes on the origin).
EMBREE_FAR = 1e37

#: Colour of a mesh without vertex colours: white, so the material's base colour shows, exactly
#: as for a cloud without colours.
DEFAULT_COLOR = (1.0, 1.0, 1.0)


class MeshGeometry:
    """A triangle mesh rendered through embreex (Embree 4).

    Parameters
    ----------
    vertices : (v, 3) array_like of float
        Positions (world coordinates, float64 kept until :meth:`set_origin`).
    faces : (f, 3) array_like of int
        Vertex indices, counter-clockwise seen from outside (the winding does not matter for
        shading: the renderer turns normals toward the ray).
    vertex_colors : (v, 3) array_like, optional
        sRGB colours in [0, 1] (or 0..255 integers), interpolated across each triangle.
    smooth : bool
        Interpolate area-weighted vertex normals (True, default) or use the face normals.
    name : str, optional
        A label for reports.

    Notes
    -----
    ``radii`` returned by :meth:`intersect` is the mean edge length of the hit triangle: the
    local size scale the renderer uses to offset secondary rays off the surface (the role a
    disk's radius plays for surfels).
    """

    def __init__(self, vertices, faces, vertex_colors=None, *, smooth: bool = True,
                 name: str | None = None):
        v = np.asarray(vertices)
        f = np.asarray(faces)
        if v.ndim != 2 or v.shape[1] != 3 or v.dtype.kind not in "fiu":
            raise InputError(f"vertices: expected an (v, 3) float array, got shape {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or f.dtype.kind not in "iu":
            raise InputError(f"faces: expected an (f, 3) integer array, got shape {f.shape}")
        if len(v) == 0 or len(f) == 0:
            raise InputError("vertices, faces: the mesh is empty")
        v = np.ascontiguousarray(v, dtype=np.float64)
        if not np.isfinite(v).all():
            raise InputError("vertices: contain NaN or inf")
        f = np.ascontiguousarray(f, dtype=np.int32)
        if f.min() < 0 or f.max() >= len(v):
            raise InputError(f"faces: indices must lie in [0, {len(v)}), got [{f.min()}, {f.max()}]")
        self.vertices = v
        self.faces = f
        if vertex_colors is not None:
            c = np.asarray(vertex_colors)
            if c.shape[0] != len(v) or c.ndim != 2 or c.shape[1] < 3:
                raise InputError(f"vertex_colors: expected ({len(v)}, 3), got {c.shape}")
            c = c[:, :3]
            c = c / 255.0 if c.dtype.kind in "iu" else c
            vertex_colors = np.ascontiguousarray(np.clip(c, 0.0, 1.0), dtype=np.float32)
        self.vertex_colors = vertex_colors
        self.smooth = bool(smooth)
        self.name = name
        a, b, c3 = (v[f[:, k]] for k in range(3))
        fn = np.cross(b - a, c3 - a)
        ln = np.linalg.norm(fn, axis=1, keepdims=True)
        self.face_normals = np.divide(fn, ln, out=np.zeros_like(fn), where=ln > 0).astype(np.float32)
        self.vertex_normals = vertex_normals(v, f).astype(np.float32)
        edges = (np.linalg.norm(b - a, axis=1) + np.linalg.norm(c3 - b, axis=1)
                 + np.linalg.norm(a - c3, axis=1)) / 3.0
        self.face_scale = edges.astype(np.float32)
        self._origin = None
        self._scene = None
        self._mesh = None
        self.build_seconds = 0.0

    # -- the callback-geometry protocol ------------------------------------------------------
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) float64 (3,) axis-aligned bounds of the vertices faces use."""
        used = self.vertices[np.unique(self.faces)]
        return used.min(axis=0), used.max(axis=0)

    def set_origin(self, origin) -> None:
        """Build the Embree scene in the frame centred on ``origin`` (float64 (3,)); a no-op when
        the origin has not changed. ``build_seconds`` records the BVH build."""
        origin = np.asarray(origin, dtype=np.float64).reshape(3)
        if self._scene is not None and np.array_equal(origin, self._origin):
            return
        rtcore_scene = require("embreex.rtcore_scene", "compare")
        mesh_construction = require("embreex.mesh_construction", "compare")
        t0 = time.perf_counter()
        scene = rtcore_scene.EmbreeScene()
        local = np.ascontiguousarray(self.vertices - origin, dtype=np.float32)
        self._mesh = mesh_construction.TriangleMesh(scene, local, self.faces)
        # embreex commits (builds the BVH) on the first query: make that happen here
        scene.run(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32))
        self.build_seconds = time.perf_counter() - t0
        self._scene = scene
        self._origin = origin

    def _ready(self):
        if self._scene is None:
            lo, hi = self.bounds()
            self.set_origin(0.5 * (lo + hi))
        return self._scene

    @staticmethod
    def _split(rays):
        r = np.asarray(rays, dtype=np.float32)
        if r.ndim != 2 or r.shape[1] != 8:
            raise InputError(f"rays: expected (n, 8) float32 (origin, dir, tmin, tmax), got {r.shape}")
        tmin = np.maximum(r[:, 6], 0.0)
        # Embree's rays start at t = 0: move the origin to tmin and shorten the ray instead
        o = np.ascontiguousarray(r[:, :3] + r[:, 3:6] * tmin[:, None])
        d = np.ascontiguousarray(r[:, 3:6])
        far = np.minimum(r[:, 7] - tmin, EMBREE_FAR).astype(np.float32)
        return o, d, tmin, far

    def intersect(self, rays):
        """Closest hits.

        Parameters
        ----------
        rays : (n, 8) float32
            Origin xyz, unit direction xyz, tmin, tmax, in the local frame.

        Returns
        -------
        tuple of C-contiguous float32 arrays
            ``t`` (n,) (inf on a miss), ``normals`` (n, 3) unit, ``colors`` (n, 3) sRGB,
            ``radii`` (n,) local size scale.
        """
        scene = self._ready()
        o, d, tmin, far = self._split(rays)
        n = len(o)
        t = np.full(n, np.inf, np.float32)
        normals = np.zeros((n, 3), np.float32)
        colors = np.empty((n, 3), np.float32)
        colors[:] = DEFAULT_COLOR
        radii = np.zeros(n, np.float32)
        live = far > 0
        if live.any():
            res = scene.run(o[live], d[live], dists=np.ascontiguousarray(far[live]), output=1)
            prim = res["primID"]
            hit = prim >= 0
            idx = np.flatnonzero(live)[hit]
            prim = prim[hit]
            t[idx] = res["tfar"][hit] + tmin[idx]
            u = res["u"][hit][:, None]
            v = res["v"][hit][:, None]
            w = 1.0 - u - v
            tri = self.faces[prim]
            if self.smooth:
                vn = self.vertex_normals
                nn = w * vn[tri[:, 0]] + u * vn[tri[:, 1]] + v * vn[tri[:, 2]]
                ln = np.linalg.norm(nn, axis=1, keepdims=True)
                bad = ~(ln[:, 0] > 1e-12)
                nn = np.where(bad[:, None], self.face_normals[prim], nn / np.maximum(ln, 1e-30))
            else:
                nn = self.face_normals[prim]
            normals[idx] = nn
            if self.vertex_colors is not None:
                vc = self.vertex_colors
                colors[idx] = w * vc[tri[:, 0]] + u * vc[tri[:, 1]] + v * vc[tri[:, 2]]
            radii[idx] = self.face_scale[prim]
        return t, normals, colors, radii

    def occluded(self, rays) -> np.ndarray:
        """Any hit in each ray's [tmin, tmax]: (n,) bool, C-contiguous."""
        scene = self._ready()
        o, d, _, far = self._split(rays)
        out = np.zeros(len(o), dtype=bool)
        live = far > 0
        if live.any():
            res = scene.run(o[live], d[live], dists=np.ascontiguousarray(far[live]),
                            query="OCCLUDED")
            out[live] = np.asarray(res) >= 0
        return out

    # -- convenience -------------------------------------------------------------------------
    def cast_rays(self, rays) -> dict:
        """World-space closest hits for (n, 6) rays (origin, direction): ``t_hit``, ``normals``,
        ``positions`` (float64), like :meth:`pointviz.SurfelScene.cast_rays`."""
        r = np.asarray(rays, dtype=np.float64)
        if r.ndim != 2 or r.shape[1] != 6:
            raise InputError(f"rays: expected (n, 6), got {r.shape}")
        self._ready()
        dn = np.linalg.norm(r[:, 3:], axis=1)
        packed = np.zeros((len(r), 8), np.float32)
        packed[:, :3] = r[:, :3] - self._origin
        packed[:, 3:6] = r[:, 3:] / dn[:, None]
        packed[:, 7] = np.inf
        t, n, c, rad = self.intersect(packed)
        t = t / dn.astype(np.float32)
        with np.errstate(invalid="ignore"):
            pos = r[:, :3] + r[:, 3:] * t[:, None].astype(np.float64)
        pos[~np.isfinite(t)] = np.inf
        return {"t_hit": t, "normals": n, "colors": c, "radii": rad, "positions": pos}

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    def __repr__(self) -> str:
        return (f"MeshGeometry({len(self.vertices)} vertices, {len(self.faces)} faces, "
                f"{'smooth' if self.smooth else 'flat'})")
