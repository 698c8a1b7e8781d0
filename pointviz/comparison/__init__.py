"""Quality comparison: surfels against meshes reconstructed from the same points, all rendered by
the one shading code (surfels natively, meshes through :class:`MeshGeometry` and embreex), scored
against a reference frame, and charted speed against accuracy.

``pointviz.compare(input, ...)`` runs everything and writes the report; ``pointviz compare`` is
the command line. (The package is not called ``compare``: importing a submodule would then
replace the ``pointviz.compare`` function with the package.)
"""

from __future__ import annotations

from ..meshes import MeshGeometry
from .run import Settings, compare

__all__ = ["MeshGeometry", "Settings", "compare"]

