"""Denoising of final frames with Intel Open Image Denoise (``pyoidn``, CPU).

The denoiser is guided by the frame's albedo and normal buffers, so that what the tracer
resolved (silhouettes, albedo edges, the objects seen in mirrors) stays sharp while Monte Carlo
noise (soft shadows, sky occlusion, glossy reflections) is removed.
"""

from __future__ import annotations

import numpy as np

from .errors import InputError, MissingDependencyError

#: The optional dependency and the extra that installs it.
DENOISE_MODULE = "pyoidn"
DENOISE_EXTRA = "denoise"
#: Filter qualities of Open Image Denoise. "high" (the default for final frames) is its best;
#: "fast" took about 0.6x the time on 2 CPU cores for 0.3-0.8 dB less (benchmarks/bench_denoise.py).
DENOISE_QUALITIES = ("high", "balanced", "fast")
DENOISE_QUALITY = "high"


def check_available():
    """Import pyoidn, or raise MissingDependencyError naming the extra to install."""
    try:
        import pyoidn
    except ImportError:
        raise MissingDependencyError(
            f"denoise=True needs Intel Open Image Denoise ({DENOISE_MODULE}); install it with: "
            f"pip install 'pointviz[{DENOISE_EXTRA}]'  (or render with denoise=False / "
            f"--no-denoise)") from None
    return pyoidn


def denoise_image(color: np.ndarray, albedo: np.ndarray | None = None,
                  normal: np.ndarray | None = None, quality: str = DENOISE_QUALITY) -> np.ndarray:
    """Denoise linear HDR radiance.

    Parameters
    ----------
    color : (h, w, 3) float32
        Linear radiance (non-negative).
    albedo : (h, w, 3) float32, optional
        Base colour in [0, 1], same shape.
    normal : (h, w, 3) float32, optional
        Unit normals (any fixed frame), zero where nothing was hit.
    quality : {"high", "balanced", "fast"}

    Returns
    -------
    (h, w, 3) float32
    """
    pyoidn = check_available()
    if quality not in DENOISE_QUALITIES:
        raise InputError(f"denoise: expected True, False or one of {DENOISE_QUALITIES}, got {quality!r}")
    color = np.asarray(color, dtype=np.float32)
    if color.ndim != 3 or color.shape[2] != 3 or min(color.shape[:2]) == 0:
        raise InputError(f"color: expected an (h, w, 3) image, got shape {color.shape}")
    if not np.isfinite(color).all():
        raise InputError("color: contains NaN or inf")
    guides = {}
    for name, img in (("albedo", albedo), ("normal", normal)):
        if img is None:
            continue
        img = np.asarray(img, dtype=np.float32)
        if img.shape != color.shape:
            raise InputError(f"{name}: expected shape {color.shape}, got {img.shape}")
        if not np.isfinite(img).all():
            raise InputError(f"{name}: contains NaN or inf")
        guides[name] = np.ascontiguousarray(img)
    if "normal" in guides and "albedo" not in guides:
        raise InputError("normal: Open Image Denoise needs the albedo too when given normals")
    out = pyoidn.denoise(np.ascontiguousarray(np.maximum(color, 0.0)), guides.get("albedo"),
                         guides.get("normal"), hdr=True, quality=quality)
    return np.maximum(out, 0.0)


def denoise_quality(denoise) -> str | None:
    """The filter quality asked for by ``render(denoise=...)`` (True: DENOISE_QUALITY), or None."""
    if denoise is False or denoise is None:
        return None
    if denoise is True:
        return DENOISE_QUALITY
    if denoise in DENOISE_QUALITIES:
        return denoise
    raise InputError(f"denoise: expected True, False or one of {DENOISE_QUALITIES}, got {denoise!r}")


def denoise_frame(frame, quality: str = DENOISE_QUALITY) -> None:
    """Denoise ``frame.color`` in place (guided by its albedo and normals); the tracer's
    colour moves to ``frame.noisy_color`` and the time to ``frame.stats["denoise_seconds"]``."""
    import time

    t0 = time.perf_counter()
    noisy = frame.color
    frame.color = denoise_image(noisy, frame.albedo, frame.normal, quality)
    frame.noisy_color = noisy
    frame.stats["denoise_seconds"] = time.perf_counter() - t0
