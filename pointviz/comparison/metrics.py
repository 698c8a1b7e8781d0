"""Image-pair metrics between a method's frame and the reference frame.

Colour metrics compare the display images (tone-mapped sRGB in [0, 1]); geometric metrics use the
frames' depth, normal and alpha buffers. A pixel is *hit* when its coverage (alpha) exceeds
:data:`HIT_ALPHA`.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError, require

#: Coverage above which a pixel counts as showing geometry (half its samples hit).
HIT_ALPHA = 0.5

#: Metric names and what they mean, for the schema and the report.
METRIC_DOC = {
    "psnr": "PSNR of the display images in dB (data_range 1; inf when identical)",
    "ssim": "SSIM of the display images (scikit-image, data_range 1, RGB)",
    "flip": "mean FLIP error (LDR, 67 pixels per degree); 0 = identical",
    "depth_error": "mean |depth difference| / scene diagonal, on pixels both frames hit",
    "normal_error_deg": "mean angle between shading normals in degrees, pixels both hit",
    "iou": "silhouette IoU of the hit masks (alpha > 0.5)",
    "holes": "pixels the reference hits and the method misses, over reference-hit pixels",
}


def psnr(reference: np.ndarray, test: np.ndarray, data_range: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB (inf for identical images)."""
    mse = float(np.mean((np.asarray(reference, np.float64) - np.asarray(test, np.float64)) ** 2))
    return float("inf") if mse == 0 else float(10.0 * np.log10(data_range**2 / mse))


def ssim(reference: np.ndarray, test: np.ndarray, data_range: float = 1.0) -> float:
    """Structural similarity (scikit-image) of (h, w, 3) or (h, w) images."""
    metrics = require("skimage.metrics", "compare")
    kw = {"channel_axis": 2} if np.ndim(reference) == 3 else {}
    return float(metrics.structural_similarity(np.asarray(reference, np.float64),
                                               np.asarray(test, np.float64),
                                               data_range=data_range, **kw))


def flip(reference: np.ndarray, test: np.ndarray) -> tuple[float, np.ndarray]:
    """Mean FLIP error and its magma error map ((h, w, 3) float32 in [0, 1]) for LDR sRGB
    images in [0, 1]."""
    fe = require("flip_evaluator", "compare")
    ref = np.ascontiguousarray(np.clip(reference, 0, 1), dtype=np.float32)
    tst = np.ascontiguousarray(np.clip(test, 0, 1), dtype=np.float32)
    emap, mean, _ = fe.evaluate(ref, tst, "LDR")
    return float(mean), np.asarray(emap, dtype=np.float32)


def hit_mask(alpha: np.ndarray) -> np.ndarray:
    return np.asarray(alpha) > HIT_ALPHA


def iou(mask_a: np.ndarray, mask_b: np.ndarray) -> float:
    """Intersection over union of two boolean masks (1 when both are empty)."""
    union = np.logical_or(mask_a, mask_b).sum()
    return 1.0 if union == 0 else float(np.logical_and(mask_a, mask_b).sum() / union)


def holes(ref_mask: np.ndarray, test_mask: np.ndarray) -> float:
    """Fraction of reference-hit pixels the test misses."""
    n = int(ref_mask.sum())
    return 0.0 if n == 0 else float(np.logical_and(ref_mask, ~test_mask).sum() / n)


def normal_error_deg(n_ref: np.ndarray, n_test: np.ndarray, mask: np.ndarray) -> float:
    """Mean angle in degrees between (h, w, 3) normal buffers over ``mask`` (nan if empty)."""
    if not mask.any():
        return float("nan")
    a = n_ref[mask].astype(np.float64)
    b = n_test[mask].astype(np.float64)
    a /= np.maximum(np.linalg.norm(a, axis=1, keepdims=True), 1e-30)
    b /= np.maximum(np.linalg.norm(b, axis=1, keepdims=True), 1e-30)
    return float(np.degrees(np.arccos(np.clip((a * b).sum(axis=1), -1.0, 1.0))).mean())


def depth_error(d_ref: np.ndarray, d_test: np.ndarray, mask: np.ndarray, diagonal: float) -> float:
    """Mean |depth difference| over ``mask`` divided by ``diagonal`` (nan if empty)."""
    if not mask.any():
        return float("nan")
    if not diagonal > 0:
        raise InputError(f"diagonal: must be > 0, got {diagonal!r}")
    return float(np.mean(np.abs(d_ref[mask].astype(np.float64) - d_test[mask])) / diagonal)


def display(frame) -> np.ndarray:
    """(h, w, 3) float64 display image in [0, 1] (the frame's sRGB 8-bit output)."""
    return frame.to_srgb8().astype(np.float64) / 255.0


def compare_frames(reference, test, diagonal: float) -> tuple[dict, np.ndarray]:
    """Every metric of :data:`METRIC_DOC` for two :class:`pointviz.Frame` s of the same camera.

    Returns
    -------
    (dict, (h, w, 3) float32)
        The metrics (floats) and the FLIP error map.
    """
    if reference.color.shape != test.color.shape:
        raise InputError(f"frames: sizes differ {reference.color.shape} vs {test.color.shape}")
    ref_img, test_img = display(reference), display(test)
    rm, tm = hit_mask(reference.alpha), hit_mask(test.alpha)
    both = rm & tm & np.isfinite(reference.depth) & np.isfinite(test.depth)
    f, emap = flip(ref_img, test_img)
    out = {
        "psnr": psnr(ref_img, test_img),
        "ssim": ssim(ref_img, test_img),
        "flip": f,
        "depth_error": depth_error(reference.depth, test.depth, both, diagonal),
        "normal_error_deg": normal_error_deg(reference.normal, test.normal, both),
        "iou": iou(rm, tm),
        "holes": holes(rm, tm),
    }
    return out, emap
