"""The mesh backend lives in :mod:`pointviz.meshes` (the viewer renders meshes too)."""

from ..meshes import MeshGeometry

__all__ = ["MeshGeometry"]
