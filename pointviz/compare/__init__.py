"""Quality comparison: surfels against meshes reconstructed from the same points, all rendered by
the one shading code (surfels natively, meshes through :class:`MeshGeometry` and embreex), scored
against a reference frame, and charted speed against accuracy.

``pointviz.compare(input, ...)`` runs everything and writes the report; ``pointviz compare`` is
the command line.
"""

from __future__ import annotations

from .mesh import MeshGeometry
from .run import Settings, compare

__all__ = ["MeshGeometry", "Settings", "compare"]


class _CallablePackage(__import__("types").ModuleType):
    """Importing a submodule (``pointviz.compare.mesh``) binds ``pointviz.compare`` to this
    package, shadowing the lazily exported function of the same name; making the package
    callable keeps ``pointviz.compare(...)`` working either way."""

    def __call__(self, *args, **kwargs):
        return compare(*args, **kwargs)


__import__("sys").modules[__name__].__class__ = _CallablePackage
