"""Lights: directional (a soft sun), point (or spherical) and parallelogram area lights."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import _core
from .errors import InputError
from .values import in_range as _in_range
from .values import rgb as _rgb
from .values import unit as _unit


@dataclass(frozen=True)
class DirectionalLight:
    """Light from far away. ``direction`` points toward the light; ``angle_deg`` is its angular
    radius (0: hard shadows; the sun is 0.27)."""

    direction: tuple = (0.4, 1.0, 0.6)
    color: tuple = (1.0, 1.0, 1.0)
    intensity: float = 1.0
    angle_deg: float = 2.0
    shadows: bool = True

    def to_core(self) -> _core.Light:
        light = _core.Light()
        light.cast_shadows = bool(self.shadows)
        light.type = _core.LightType.directional
        light.direction = tuple(_unit(self.direction, "light.direction"))
        light.color = tuple(np.asarray(_rgb(self.color, "light.color")) * float(self.intensity))
        light.angle = np.radians(_in_range(self.angle_deg, "light.angle_deg", 0.0, 45.0))
        return light


@dataclass(frozen=True)
class PointLight:
    """Light from a point (``radius`` > 0: a spherical light, soft shadows); inverse-square."""

    position: tuple = (0.0, 2.0, 0.0)
    color: tuple = (1.0, 1.0, 1.0)
    intensity: float = 1.0
    radius: float = 0.0

    def to_core(self, origin) -> _core.Light:
        light = _core.Light()
        light.type = _core.LightType.point
        light.position = tuple(np.asarray(self.position, dtype=np.float64) - origin)
        light.color = tuple(np.asarray(_rgb(self.color, "light.color")) * float(self.intensity))
        light.radius = _in_range(self.radius, "light.radius", 0.0, 1e30)
        return light


@dataclass(frozen=True)
class AreaLight:
    """A parallelogram light with corner ``corner`` and edges ``edge_u``, ``edge_v``: soft
    shadows. ``intensity`` is the total, as for a point light at the same place."""

    corner: tuple = (-0.5, 2.0, -0.5)
    edge_u: tuple = (1.0, 0.0, 0.0)
    edge_v: tuple = (0.0, 0.0, 1.0)
    color: tuple = (1.0, 1.0, 1.0)
    intensity: float = 1.0

    def to_core(self, origin) -> _core.Light:
        light = _core.Light()
        light.type = _core.LightType.area
        light.position = tuple(np.asarray(self.corner, dtype=np.float64) - origin)
        light.edge_u = tuple(np.asarray(self.edge_u, dtype=np.float64))
        light.edge_v = tuple(np.asarray(self.edge_v, dtype=np.float64))
        if not np.linalg.norm(np.cross(light.edge_u, light.edge_v)) > 0:
            raise InputError("light.edge_u, light.edge_v: must span a parallelogram")
        light.color = tuple(np.asarray(_rgb(self.color, "light.color")) * float(self.intensity))
        return light
