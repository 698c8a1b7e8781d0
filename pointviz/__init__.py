"""pointviz: ray tracing of point-based geometry.

Points are disks (surfels); rays traverse a QSplat-style hierarchy with level of detail, normal-cone
culling and boxes near the top, and hit attributes are interpolated across the few disks around
each hit. Submodules are imported lazily so that ``import pointviz`` stays cheap.
"""

from __future__ import annotations

import importlib

from .errors import (
    CancelledError,
    FileFormatError,
    InputError,
    MissingDependencyError,
    PointvizError,
)

__version__ = "0.1.0"

# public name -> submodule that defines it
_LAZY = {
    "PointCloud": "cloud",
    "load": "io",
    "Camera": "camera",
    "CameraPath": "path",
    "render_path": "path",
    "SurfelScene": "surfels",
    "Scene": "scene",
    "Material": "scene",
    "DirectionalLight": "scene",
    "PointLight": "scene",
    "AreaLight": "scene",
    "render": "rendering",
    "Frame": "rendering",
    "compare": "comparison",
    "view": "viewer",
}

__all__ = sorted(
    [*_LAZY, "PointvizError", "InputError", "FileFormatError", "MissingDependencyError",
     "CancelledError", "__version__"]
)


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'pointviz' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return __all__
