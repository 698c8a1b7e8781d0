"""Looks: named lighting set-ups (lights placed relative to the camera, sky light and
occlusion, backdrop, exposure), and how "auto" chooses one."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .errors import InputError
from .lights import DirectionalLight


@dataclass(frozen=True)
class Look:
    """A named lighting set-up: what makes a mostly one-colour scan readable is light.

    Lights are placed relative to the camera at render time (so every view is lit from the
    front-left), lengths relative to the scene's bounding radius.

    Parameters
    ----------
    name : str
    ambient : float
        Strength of the sky's ambient light.
    occlusion : float
        Length of the sky-visibility (ambient occlusion) rays, in bounding radii; 0: none.
    key, key_angle_deg, key_elevation : float
        Intensity, angular radius (soft shadows) and height (the up component of its direction,
        before normalisation) of the key light over the camera's left shoulder; 0: no key.
    fill : float
        Intensity of a shadowless fill light from the camera's right; 0: none.
    sky : dict or None
        Sky colours (see :class:`Scene`); None: the default blue-grey gradient.
    background : (3,) float or None
        What primary rays that miss show; None: the sky (or the backdrop's colour).
    backdrop : bool
        The ground fades into a plain background beyond BACKDROP_FADE bounding radii (a studio
        cyclorama: no horizon line), the background matching the lit ground.
    ground : str
        The ground this look uses when the scene's ground is "auto".
    auto_exposure : bool
        Expose the frame from the lit objects' mean luminance (see
        :func:`pointviz.images.auto_exposure`); else exposure 1.
    """

    name: str
    ambient: float
    occlusion: float
    key: float
    key_angle_deg: float
    key_elevation: float
    fill: float
    sky: dict | None
    background: tuple | None
    backdrop: bool
    ground: str
    auto_exposure: bool

    def lights(self, camera, up) -> list:
        """The look's lights for a camera (directions relative to the view)."""
        up = np.asarray(up, dtype=np.float64)
        fwd, right = np.asarray(camera.forward), np.asarray(camera.right)
        out = []
        if self.key > 0:
            direction = self.key_elevation * up - 0.4 * fwd - 0.7 * right
            out.append(DirectionalLight(direction=tuple(direction), intensity=self.key,
                                        angle_deg=self.key_angle_deg))
        if self.fill > 0:
            direction = 0.3 * up - 0.6 * fwd + 0.7 * right
            out.append(DirectionalLight(direction=tuple(direction), intensity=self.fill,
                                        angle_deg=0.0, shadows=False))
        return out


#: Named looks (the CLI's ``--look``). Objects default to "studio", terrain tiles to "outdoor".
LOOKS = {
    # a soft key of 12 degrees' angular size, a fill, strong sky light shaped by occlusion,
    # on a plain backdrop
    "studio": Look("studio", ambient=0.3, occlusion=0.2, key=1.4, key_angle_deg=6.0,
                   key_elevation=0.9, fill=0.2, background=None,
                   sky={"zenith": (0.95, 0.96, 1.0), "horizon": (0.9, 0.9, 0.9),
                        "below": (0.3, 0.29, 0.28)},
                   backdrop=True, ground="matte", auto_exposure=True),
    # a low sun and a blue sky: relief reads from shading and cast shadows
    "outdoor": Look("outdoor", ambient=0.8, occlusion=0.04, key=1.3, key_angle_deg=0.5,
                    key_elevation=0.8, fill=0.0, sky=None, background=(0.8, 0.82, 0.85),
                    backdrop=False, ground="none",
                    auto_exposure=True),
    # colours as scanned: even white light, no shadows
    "flat": Look("flat", ambient=1.0, occlusion=0.0, key=0.0, key_angle_deg=0.0,
                 key_elevation=1.0, fill=0.0, background=(0.9, 0.9, 0.9),
                 sky={"zenith": (1.0, 1.0, 1.0), "horizon": (1.0, 1.0, 1.0),
                      "below": (1.0, 1.0, 1.0)},
                 backdrop=False, ground="none", auto_exposure=False),
}
#: Comparisons (surfels against meshes) render every backend with one fixed exposure: an
#: exposure keyed per frame would differ between methods and enter their image errors.
COMPARE_LOOK = replace(LOOKS["studio"], auto_exposure=False)
#: Where a backdrop's ground starts fading into the background (bounding radii from the centre);
#: it reaches the background at twice this.
BACKDROP_FADE = 1.5


def default_lights(camera, up) -> list:
    """The studio look's lights: a soft key over the camera's left shoulder and a fill."""
    return LOOKS["studio"].lights(camera, up)


def resolve_look(look, geometry, up) -> Look:
    """The :class:`Look` named by ``look``; "auto" decides from the geometry's shape."""
    if isinstance(look, Look):
        return look
    if look == "auto":
        from .framing import shape_kind
        from .geometry import Geometry
        from .surfels import SurfelScene

        if isinstance(geometry, SurfelScene):
            kind = geometry.shape_kind(up)  # kept with the scene: every frame asks again
        elif isinstance(geometry, Geometry):  # a mesh: an object
            kind = "object"
        else:  # a point cloud
            kind = shape_kind(geometry.points, up)
        return LOOKS["outdoor" if kind == "terrain" else "studio"]
    if look not in LOOKS:
        raise InputError(f"look: expected one of auto, {', '.join(LOOKS)}, got {look!r}")
    return LOOKS[look]
