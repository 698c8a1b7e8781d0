"""Triangle meshes as a render backend: embreex closest-hit and occlusion queries behind the
callback-geometry interface, so a mesh renders with exactly the camera, lights, materials and
shading of the surfel renderer (``pointviz.render(Scene([MeshGeometry(...)]), camera)``).

The renderer calls :meth:`MeshGeometry.intersect` and :meth:`MeshGeometry.occluded` with rays in
the scene's local frame (world minus the origin the scene passes to :meth:`MeshGeometry.add_to`);
the Embree scene is built there, in float32, once per origin (:class:`LocalMesh`).
"""

from __future__ import annotations

import time

import numpy as np

from .cloud import vertex_normals
from .errors import InputError, require

#: Embree (through embreex) takes a finite ``tfar``; rays with ``tmax = inf`` get this instead.
#: It is embreex's own default and far beyond any scene (pointviz re-centres scenes on the origin).
EMBREE_FAR = 1e37

#: Frames (origins) whose Embree scene a mesh keeps: a render and the mesh's own frame.
MESH_FRAMES_KEPT = 2
#: Colour of a mesh without vertex colours: white, so the material's base colour shows, exactly
#: as for a cloud without colours.
DEFAULT_COLOR = (1.0, 1.0, 1.0)


class MeshGeometry:
    """A triangle mesh rendered through embreex (Embree 4).

    Parameters
    ----------
    vertices : (v, 3) array_like of float
        Positions (world coordinates, float64; each frame of :meth:`local` is float32).
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
        self._frames: dict[bytes, LocalMesh] = {}
        self.build_seconds = 0.0

    def __reduce__(self):
        """Pickle as the arrays: the Embree scenes are rebuilt where the mesh is used."""
        return (_mesh, (self.vertices, self.faces, self.vertex_colors, self.smooth, self.name))

    # -- the callback-geometry protocol ------------------------------------------------------
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) float64 (3,) axis-aligned bounds of the vertices faces use."""
        used = self.vertices[np.unique(self.faces)]
        return used.min(axis=0), used.max(axis=0)

    def extent(self, up) -> tuple[np.ndarray, np.ndarray, float]:
        """Bounds and the ground level along unit ``up``: the lowest corner of the bounds
        (see :class:`pointviz.geometry.Geometry`)."""
        lo, hi = (np.asarray(v, dtype=np.float64) for v in self.bounds())
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                            for z in (lo[2], hi[2])])
        return lo, hi, float(np.min(corners @ np.asarray(up, dtype=np.float64)))

    def local(self, origin=None) -> LocalMesh:
        """The mesh in the frame centred on ``origin`` (default: the centre of its bounds),
        with its Embree scene: built once per origin and kept (the last MESH_FRAMES_KEPT)."""
        if origin is None:
            lo, hi = self.bounds()
            origin = 0.5 * (lo + hi)
        origin = np.asarray(origin, dtype=np.float64).reshape(3)
        key = origin.tobytes()
        hit = self._frames.pop(key, None)
        if hit is None:
            hit = LocalMesh(self, origin)
            self.build_seconds = hit.build_seconds
        self._frames[key] = hit  # most recent last
        while len(self._frames) > MESH_FRAMES_KEPT:
            self._frames.pop(next(iter(self._frames)))
        return hit

    def add_to(self, render_scene, origin, material, lod_pixels: float | str,
               max_error: float | None = None, sides: str | None = None) -> None:
        """Add the mesh (as callbacks of its frame at ``origin``) to a core RenderScene (a
        mesh has no level of detail, and its triangles show both sides)."""
        render_scene.add_callback(self.local(origin), material)

    def intersect(self, rays):
        """Closest hits of (n, 8) rays in the frame of :meth:`local` ``()``: see
        :meth:`LocalMesh.intersect`."""
        return self.local().intersect(rays)

    def occluded(self, rays) -> np.ndarray:
        """Any hit of (n, 8) rays in the frame of :meth:`local` ``()``."""
        return self.local().occluded(rays)

    # -- convenience -------------------------------------------------------------------------
    def cast_rays(self, rays) -> dict:
        """World-space closest hits for (n, 6) rays (origin, direction): ``t_hit``, ``normals``,
        ``positions`` (float64), like :meth:`pointviz.SurfelScene.cast_rays`."""
        r = np.asarray(rays, dtype=np.float64)
        if r.ndim != 2 or r.shape[1] != 6:
            raise InputError(f"rays: expected (n, 6), got {r.shape}")
        frame = self.local()
        dn = np.linalg.norm(r[:, 3:], axis=1)
        packed = np.zeros((len(r), 8), np.float32)
        packed[:, :3] = r[:, :3] - frame.origin
        packed[:, 3:6] = r[:, 3:] / dn[:, None]
        packed[:, 7] = np.inf
        t, n, c, rad = frame.intersect(packed)
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


def _mesh(vertices, faces, vertex_colors, smooth, name) -> MeshGeometry:
    return MeshGeometry(vertices, faces, vertex_colors, smooth=smooth, name=name)


class LocalMesh:
    """A :class:`MeshGeometry` in the frame centred on ``origin``, with its Embree scene (built
    here, in float32): the callback geometry the core renderer queries. Immutable."""

    def __init__(self, mesh: MeshGeometry, origin: np.ndarray) -> None:
        self.mesh = mesh
        self.origin = origin
        rtcore_scene = require("embreex.rtcore_scene", "compare")
        mesh_construction = require("embreex.mesh_construction", "compare")
        t0 = time.perf_counter()
        scene = rtcore_scene.EmbreeScene()
        local = np.ascontiguousarray(mesh.vertices - origin, dtype=np.float32)
        self._triangles = mesh_construction.TriangleMesh(scene, local, mesh.faces)
        # embreex commits (builds the BVH) on the first query: make that happen here
        scene.run(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32))
        self.build_seconds = time.perf_counter() - t0
        self._scene = scene

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
        scene = self._scene
        m = self.mesh
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
            tri = m.faces[prim]
            if m.smooth:
                vn = m.vertex_normals
                nn = w * vn[tri[:, 0]] + u * vn[tri[:, 1]] + v * vn[tri[:, 2]]
                ln = np.linalg.norm(nn, axis=1, keepdims=True)
                bad = ~(ln[:, 0] > 1e-12)
                nn = np.where(bad[:, None], m.face_normals[prim], nn / np.maximum(ln, 1e-30))
            else:
                nn = m.face_normals[prim]
            normals[idx] = nn
            if m.vertex_colors is not None:
                vc = m.vertex_colors
                colors[idx] = w * vc[tri[:, 0]] + u * vc[tri[:, 1]] + v * vc[tri[:, 2]]
            radii[idx] = m.face_scale[prim]
        return t, normals, colors, radii

    def occluded(self, rays) -> np.ndarray:
        """Any hit in each ray's [tmin, tmax]: (n,) bool, C-contiguous."""
        scene = self._scene
        o, d, _, far = self._split(rays)
        out = np.zeros(len(o), dtype=bool)
        live = far > 0
        if live.any():
            res = scene.run(o[live], d[live], dists=np.ascontiguousarray(far[live]),
                            query="OCCLUDED")
            out[live] = np.asarray(res) >= 0
        return out
