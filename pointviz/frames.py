"""One frame of a path as PNG bytes, and whether a frame file on disk is whole.

Shared by the serial path renderer (:mod:`pointviz.path`) and its Dask workers
(:mod:`pointviz.distributed`).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .camera import Camera

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_IEND = b"\x00\x00\x00\x00IEND\xaeB`\x82"


def frame_png(scene: Any, camera: Camera, render_kwargs: dict, cancel: Any = None) -> bytes:
    """Render one frame and encode it as 8-bit sRGB PNG bytes (what :func:`render_path` writes).

    Parameters
    ----------
    scene : Scene, SurfelScene or PointCloud
    camera : Camera
    render_kwargs : dict
        Keyword arguments of :func:`pointviz.render`.
    cancel : threading.Event or callable, optional
    """
    from .images import encode_png
    from .rendering import render

    frame = render(scene, camera, cancel=cancel, **render_kwargs)
    return encode_png(frame.to_srgb8())


def is_complete_png(path: str | os.PathLike, width: int, height: int) -> bool:
    """Whether ``path`` is a whole PNG of ``width`` x ``height`` (signature, IHDR size, IEND).

    Frames are written atomically, so this only fails for files damaged or replaced by hand.
    """
    try:
        with open(path, "rb") as f:
            head = f.read(24)
            f.seek(0, os.SEEK_END)
            if f.tell() < 24 + len(_PNG_IEND):
                return False
            f.seek(-len(_PNG_IEND), os.SEEK_END)
            tail = f.read()
    except OSError:
        return False
    if head[:8] != _PNG_SIGNATURE or head[12:16] != b"IHDR" or tail != _PNG_IEND:
        return False
    w, h = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    return (w, h) == (width, height)
