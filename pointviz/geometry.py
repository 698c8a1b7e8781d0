"""The interface every renderable geometry implements: surfels (:class:`pointviz.SurfelScene`)
and triangle meshes (:class:`pointviz.meshes.MeshGeometry`). A :class:`~pointviz.scene.Scene`
renders either through it, so renderers swap by one argument and nothing is told apart by
its attributes.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Geometry(Protocol):
    """What a scene needs from one object.

    ``extent(up)`` gives the axis-aligned bounds ``lo, hi`` ((3,) float64, world units,
    including the disks' radii) and the level along unit ``up`` where a ground plane goes;
    ``add_to(render_scene, origin, material, lod_pixels, max_error, sides)`` adds the object
    to a core ``RenderScene`` whose local frame is centred on ``origin`` ((3,) float64), traced
    at the level of detail ``lod_pixels`` (pixels, or "auto" within the error budget
    ``max_error``), showing ``sides`` ("one", "two", "auto" or None: its own; see
    :mod:`pointviz.sides`), without changing the geometry (it may cache per origin).
    """

    def extent(self, up) -> tuple[np.ndarray, np.ndarray, float]: ...

    def add_to(self, render_scene, origin: np.ndarray, material, lod_pixels: float | str,
               max_error: float | None = None, sides: str | None = None) -> None: ...
