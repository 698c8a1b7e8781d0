"""Encoding rendered frames as a video: ``.mp4`` (H.264 through imageio-ffmpeg) or ``.gif``.

Both writers take frames as (h, w, 3) uint8 sRGB arrays (or the PNG files written by
:func:`pointviz.render_path`) and write the video atomically: the encoder writes a hidden
temporary file beside the target, which is renamed into place only once it is complete.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from .errors import InputError, require
from .interrupt import check, stage

#: Container formats :func:`write_video` can produce, by file extension.
VIDEO_EXTENSIONS = (".mp4", ".gif")
#: H.264 with 4:2:0 chroma is what every player decodes; 4:2:0 needs even width and height.
MP4_CODEC = "libx264"
MP4_PIXEL_FORMAT = "yuv420p"
#: x264 constant rate factor: 18 is visually lossless for rendered frames and still compact.
MP4_CRF = 18
#: GIF frame durations are stored in hundredths of a second; below 2 (50 fps) browsers slow down.
GIF_MIN_DURATION_MS = 20


def check_video_path(path, overwrite: bool = False) -> Path:
    """Validate a video output path before any rendering happens.

    Parameters
    ----------
    path : str or PathLike
        Must end in one of VIDEO_EXTENSIONS; a missing folder is created.
    overwrite : bool
        Allow replacing an existing file.
    """
    from .images import check_output_path

    p = Path(path)
    if p.suffix.lower() not in VIDEO_EXTENSIONS:
        raise InputError(f"video: {p}: unsupported extension {p.suffix or '(none)'}; "
                         f"use one of {', '.join(VIDEO_EXTENSIONS)}")
    return check_output_path(p, overwrite)


def read_png(path) -> np.ndarray:
    """(h, w, 3) uint8 pixels of a PNG file (alpha dropped)."""
    iio = require("imageio.v3", "paths")
    img = np.asarray(iio.imread(path))
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    if img.dtype == np.uint16:
        img = (img.astype(np.uint32) * 255 // 65535).astype(np.uint8)
    return np.ascontiguousarray(img[:, :, :3])


def _pad_even(img: np.ndarray) -> np.ndarray:
    """Repeat the last row/column so that height and width are even (yuv420p needs it)."""
    h, w = img.shape[:2]
    return np.pad(img, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")


def _frames(frames: Iterable) -> Iterator[np.ndarray]:
    for i, f in enumerate(frames):
        check()
        img = read_png(f) if isinstance(f, (str, os.PathLike)) else np.asarray(f)
        if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
            raise InputError(f"frames[{i}]: expected (h, w, 3) uint8, got {img.shape} {img.dtype}")
        yield img


def write_video(path, frames: Iterable, fps: float, *, overwrite: bool = False) -> Path:
    """Encode frames as ``.mp4`` (H.264, yuv420p) or ``.gif``, atomically.

    Parameters
    ----------
    path : str or PathLike
        Output file; the extension picks the format.
    frames : iterable of (h, w, 3) uint8 arrays or PNG paths
        All the same size. For MP4, odd sizes are padded by one edge row/column.
    fps : float
        Frames per second (> 0).
    overwrite : bool
        Replace an existing file (otherwise FileExistsError).

    Returns
    -------
    Path
        The video written.
    """
    p = check_video_path(path, overwrite)
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"fps: expected a number > 0, got {fps!r}")
    from .files import atomic_output

    with atomic_output(p, overwrite, suffix=f".part{p.suffix}") as tmp:
        try:
            count = (_write_mp4 if p.suffix.lower() == ".mp4" else _write_gif)(tmp, _frames(frames), fps)
        except Exception:
            check()  # Ctrl-C reaches the encoder too (same process group): that is the cause
            raise
        if count == 0:
            raise InputError("frames: no frames to encode")
    return p


def _write_mp4(tmp: str, frames: Iterator[np.ndarray], fps: float) -> int:
    ffmpeg = require("imageio_ffmpeg", "paths")
    writer = None
    size = None
    count = 0
    try:
        for img in frames:
            img = _pad_even(img)
            if writer is None:
                size = img.shape[:2]
                writer = ffmpeg.write_frames(
                    tmp, (img.shape[1], img.shape[0]), fps=float(fps), codec=MP4_CODEC,
                    pix_fmt_in="rgb24", pix_fmt_out=MP4_PIXEL_FORMAT, quality=None,
                    macro_block_size=1, output_params=["-crf", str(MP4_CRF)],
                    ffmpeg_log_level="error")
                writer.send(None)  # start the generator
            elif img.shape[:2] != size:
                raise InputError(f"frames[{count}]: size {img.shape[1]}x{img.shape[0]} differs "
                                 f"from the first frame's {size[1]}x{size[0]}")
            writer.send(np.ascontiguousarray(img))
            count += 1
            if count == 1:
                stage("encoding")
    finally:
        if writer is not None:
            writer.close()
    return count


def _write_gif(tmp: str, frames: Iterator[np.ndarray], fps: float) -> int:
    iio = require("imageio.v3", "paths")
    images = list(frames)
    if not images:
        return 0
    if any(im.shape != images[0].shape for im in images):
        raise InputError("frames: every frame must have the same size")
    duration = max(GIF_MIN_DURATION_MS, round(1000.0 / fps))
    stage("encoding")
    iio.imwrite(tmp, np.stack(images), extension=".gif", plugin="pillow", duration=duration,
                loop=0)
    return len(images)

