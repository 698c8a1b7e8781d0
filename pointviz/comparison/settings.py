"""The sizes and sweeps of a comparison run, and the fixed scene every method is rendered in.

Its own module: the run, the stability sweeps and the report all read it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..settings import DEFAULTS, RenderSettings

#: Without a reference mesh the reference is the surfels at full detail with this many times
#: the run's samples per pixel (less noise than any frame it scores).
REFERENCE_SPP_FACTOR = 4


@dataclass
class Settings:
    """Sizes and sweeps of a run. :meth:`full` for reports, :meth:`quick` for tests (< 60 s)."""

    width: int = 640
    height: int = 480
    spp: int = DEFAULTS.spp
    lods: tuple = (0.0, 1.0, 2.0, 4.0)
    poisson_depths: tuple = (6, 7, 8, 9, 10)
    max_points: int | None = None      # subsample larger inputs (uniformly, seeded)
    generated_points: int = 200_000    # points of a generated shape
    alpha_max_points: int = 300_000    # alpha shapes need a Delaunay tetrahedralisation
    bpa_max_points: int = 600_000
    seed: int = DEFAULTS.seed
    up: tuple | None = None            # "up" of the scene; compare() sets the cloud's hint
    extra: dict = field(default_factory=dict)

    @classmethod
    def full(cls) -> Settings:
        return cls()

    @classmethod
    def quick(cls) -> Settings:
        return cls(width=160, height=120, spp=1, lods=(0.0, 2.0), poisson_depths=(6, 7),
                   max_points=20_000, generated_points=12_000)

    def render_settings(self, lod: float = 0.0, spp: int | None = None) -> RenderSettings:
        """The render settings of every comparison frame: the run's samples and seed,
        self-shadows and no reflections (nothing to reflect without a ground), at level of
        detail ``lod`` (0: full detail; a mesh has none). The report lists them."""
        return RenderSettings(spp=spp or self.spp, lod_pixels=float(lod), reflections=0,
                              seed=self.seed, shadows=True)


def render_geometry(geometry, camera, settings: Settings, lod: float = 0.0, spp=None, up=None):
    """One frame of one geometry with the comparison's fixed scene: no ground (so alpha and
    depth are the object's), sky, default lights, self-shadows (:meth:`Settings.render_settings`).
    ``up`` (the cloud's hint) must be passed for every backend alike: a mesh has no hint, and
    the sky and the default light follow it."""
    from ..rendering import render
    from ..scene import COMPARE_LOOK, Scene

    scene = Scene([geometry], ground="none", up=up if up is not None else settings.up,
                  look=COMPARE_LOOK)
    return render(scene, camera, **settings.render_settings(lod, spp).render_kwargs())
