"""What the Open3D preview's pixels show: the scene view's post-processing is off, and the colours
handed to Open3D are encoded so that the window shows the intended sRGB values.

Filament's post-processing (tone mapping, colour grading, dithering) is a full-screen pass on
every redraw (on the software rasteriser its cost did not measurably change the redraws' waits,
benchmarks/README.md, issue 17), and it re-maps every colour: the live view's ray-traced frames,
shown as the scene's background image, came out ~10 levels off their own pixels (tone-mapped a
second time), and Open3D's ``set_color_grading`` does not change that. With it off, Open3D writes the shader's output to the
window as it is (measured under Xvfb/lavapipe, a ramp of every 8-bit value):

* a background image is an sRGB texture, decoded to linear by the sampler and not encoded again:
  byte ``u`` shows as ``srgb_to_linear(u)``. :data:`IMAGE_LUT` picks, for every wanted value, the
  byte that shows closest to it (within one level; 0.29 levels on average);
* a background or material colour parameter is taken as sRGB and linearised the same way:
  :func:`background_color` encodes it once more;
* per-point (and per-vertex) colours of the unlit shader are shown as they are:
  :func:`point_colors` maps the preview's linear, pre-shaded colours to display values as the
  ray tracer's frames are (``images.to_srgb8``: ACES filmic, then sRGB);
* a lit material's output is written linear, unencoded: the preview draws nothing lit (its
  ground quad is unlit, shaded beforehand like the points).
"""

from __future__ import annotations

import numpy as np

from ..images import linear_to_srgb, srgb_to_linear, tonemap

#: Open3D post-processing of the preview's view. False (the default): off, and the functions below
#: encode the colours; True: on, and the colours handed over unencoded (for comparisons: the live
#: frames then show as they did before, ~10 levels off).
POST_PROCESSING = False


def _image_lut() -> np.ndarray:
    shown = srgb_to_linear(np.arange(256) / 255.0) * 255.0    # what byte u shows as
    want = np.arange(256, dtype=np.float64)
    return np.abs(shown[None, :] - want[:, None]).argmin(axis=1).astype(np.uint8)


#: Background-image byte to upload for each 8-bit value the window should show.
IMAGE_LUT = _image_lut()


def background_image(pixels: np.ndarray) -> np.ndarray:
    """(h, w, 3) uint8 sRGB pixels -> the bytes to hand to ``set_background`` so that the window
    shows them (contiguous)."""
    if POST_PROCESSING:
        return np.ascontiguousarray(pixels)
    return np.ascontiguousarray(IMAGE_LUT[np.asarray(pixels, dtype=np.uint8)])


def background_color(rgba) -> list:
    """An sRGB colour (r, g, b, a) in [0, 1] -> the colour parameter that shows as it."""
    c = np.asarray(rgba, dtype=np.float64)
    if POST_PROCESSING:
        return [float(x) for x in c]
    return [*(float(x) for x in linear_to_srgb(c[:3])), float(c[3])]


def point_colors(linear: np.ndarray) -> np.ndarray:
    """Linear (n, 3) colours in [0, 1] -> the display values the unlit points are given."""
    if POST_PROCESSING:
        return np.asarray(linear, dtype=np.float64)
    return linear_to_srgb(tonemap(linear)).astype(np.float64)


__all__ = ["IMAGE_LUT", "POST_PROCESSING", "background_color", "background_image",
           "point_colors"]
