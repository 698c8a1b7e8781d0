"""Surface appearance: :class:`Material` and the named ground materials."""

from __future__ import annotations

from dataclasses import dataclass

from . import _core
from .values import in_range as _in_range
from .values import rgb as _rgb


@dataclass(frozen=True)
class Material:
    """Surface appearance (linear RGB).

    Parameters
    ----------
    color : (3,) float
        Base colour; multiplied by per-point colours when ``use_point_colors`` and the cloud has
        them.
    diffuse, specular : float
        Lambert and Blinn–Phong weights; ``shininess`` is the lobe exponent.
    mirror : float in [0, 1]
        Reflectivity; ``roughness`` > 0 blurs reflections (glossy).
    checker, checker_size : optional
        Ground only: second colour and cell size of a checkerboard.
    """

    color: tuple = (0.7, 0.7, 0.7)
    use_point_colors: bool = True
    diffuse: float = 1.0
    specular: float = 0.15
    shininess: float = 48.0
    mirror: float = 0.0
    roughness: float = 0.0
    checker: tuple | None = None
    checker_size: float = 0.0

    def __post_init__(self):
        _rgb(self.color, "material.color")
        _in_range(self.mirror, "material.mirror", 0.0, 1.0)
        _in_range(self.roughness, "material.roughness", 0.0, 1.0)
        _in_range(self.diffuse, "material.diffuse", 0.0, 10.0)
        _in_range(self.specular, "material.specular", 0.0, 10.0)
        _in_range(self.shininess, "material.shininess", 0.0, 1e4)
        _in_range(self.checker_size, "material.checker_size", 0.0, 1e30)

    @classmethod
    def matte(cls, color=(0.8, 0.8, 0.8), **kw) -> Material:
        return cls(color=color, specular=0.05, **kw)

    @classmethod
    def glossy(cls, color=(0.8, 0.8, 0.8), **kw) -> Material:
        return cls(color=color, specular=0.4, shininess=96.0, mirror=0.25, roughness=0.08, **kw)

    @classmethod
    def reflective(cls, color=(0.9, 0.9, 0.9), mirror=0.85, **kw) -> Material:
        return cls(color=color, specular=0.0, mirror=mirror, **kw)

    def to_core(self) -> _core.Material:
        m = _core.Material()
        m.base_color = _rgb(self.color, "material.color")
        m.use_point_colors = bool(self.use_point_colors)
        m.diffuse = float(self.diffuse)
        m.specular = float(self.specular)
        m.shininess = float(self.shininess)
        m.mirror = float(self.mirror)
        m.roughness = float(self.roughness)
        if self.checker is not None and self.checker_size > 0:
            m.checker = _rgb(self.checker, "material.checker")
            m.checker_size = float(self.checker_size)
        return m


#: Ground presets by name (the CLI's ``--ground``).
GROUND_MATERIALS = {
    "matte": Material(color=(0.35, 0.35, 0.34), specular=0.02, use_point_colors=False),
    "mirror": Material(color=(0.6, 0.6, 0.62), specular=0.0, mirror=0.6, use_point_colors=False),
    "glossy": Material(color=(0.7, 0.7, 0.7), specular=0.2, mirror=0.3, roughness=0.05,
                       use_point_colors=False),
}
