"""One exposure for every frame of a camera path.

A single frame's automatic exposure keys the objects' mean luminance (pointviz.images.
auto_exposure). Along a path that mean changes with what the objects show (an orbit of the
dragon's scans: 0.34 to 0.66, up to 11 % between views 5 degrees apart), and with one exposure
per frame everything else, the studio backdrop first, brightens and darkens with it: a video
that pumps. A photographer shooting a turntable fixes the exposure; so does
:func:`pointviz.render_path`, with the value metered here once for the whole path (unless the
render settings give one).
"""

from __future__ import annotations

import math
from typing import Any

from ..camera import Camera

#: Views metered along a path (evenly spaced by frame, the first and the last included; every
#: frame of a shorter path).
METER_VIEWS = 9


def meter_cameras(cameras: list[dict]) -> list[Camera]:
    """The views :func:`path_exposure` meters: METER_VIEWS of ``cameras`` (camera dicts, one per
    frame) evenly spaced by frame."""
    n = len(cameras)
    k = min(n, METER_VIEWS)
    picks = sorted({round(i * (n - 1) / (k - 1)) for i in range(k)}) if k > 1 else [0]
    return [Camera.from_dict(cameras[i]) for i in picks]


def path_exposure(scene: Any, cameras: list[dict], render_kwargs: dict, cancel: Any = None) -> float:
    """The exposure every frame of a path shares: the geometric mean of the automatic exposures
    of the views :func:`meter_cameras` picks (halfway, in stops, between the brightest and the
    darkest view's own), each the one :func:`pointviz.render` would give that view on its own
    (:func:`pointviz.rendering.metered_exposure`: a small full-detail pass of it, whatever the
    frames' level of detail, samples or denoiser). 1 when the look has no automatic exposure
    (flat).

    A deterministic function of the scene, the cameras and the image settings (``threads``
    does not enter), so a resumed or distributed render finds the same value.
    """
    from .. import rendering
    from ..settings import RenderSettings

    # the settings in full (validated; what metering reads of them)
    kw = RenderSettings.from_kwargs(render_kwargs, "render_path").render_kwargs()
    logs = [math.log(rendering.metered_exposure(scene, cam, cancel=cancel, **kw))
            for cam in meter_cameras(cameras)]
    return math.exp(math.fsum(logs) / len(logs))
