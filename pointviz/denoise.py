"""Denoising of final frames with Intel Open Image Denoise (``pyoidn``, CPU).

The denoiser is guided by the frame's albedo and normal buffers, so that what the tracer
resolved (silhouettes, albedo edges, the objects seen in mirrors) stays sharp while Monte Carlo
noise (soft shadows, sky occlusion, glossy reflections) is removed.

One :class:`Denoiser` holds an Open Image Denoise device and filter: creating them and running
the first frame through them loads the network's weights (about 10 % of a 480x360 frame's
denoising time, benchmarks/bench_denoise.py), so frames reuse one. ``render(denoise=True)`` uses
:func:`shared_denoiser`, one per (quality, threads); a caller that renders many frames may pass
its own :class:`Denoiser` instead.
"""

from __future__ import annotations

import math
import threading
import time
import weakref

import numpy as np

from .errors import InputError, MissingDependencyError

#: The optional dependency and the extra that installs it.
DENOISE_MODULE = "pyoidn"
DENOISE_EXTRA = "denoise"
#: Filter qualities of Open Image Denoise. On the CPU "balanced" runs the same network as
#: "high"; "fast" is a smaller one.
DENOISE_QUALITIES = ("high", "balanced", "fast")
#: The default, chosen on benchmarks/bench_denoise.py (480x360, 2 cores): "fast" takes about half
#: the CPU time of "high" (0.26 s vs 0.50 s; the 4-spp frame itself 0.68 s), so a denoised 4-spp
#: frame costs 1.33x the 4-spp frame's wall time instead of 1.84x (issue 14's budget: 1.5x), and
#: scores 0.29 dB less (46.22 vs 46.51 dB mean over 4 seeds; 16 spp: 46.01). On the dragon's scans
#: the two differ by 0.6/255 per pixel on average, not visibly. "high" stays one argument away.
DENOISE_QUALITY = "fast"
#: OIDN's "cleanAux" (the guides are noise-free) stays off, although the tracer's albedo and
#: normals are first-hit quantities, antialiased only: with it OIDN picks networks trained on
#: noise-free guides that cost 2.4x the CPU time at "high" and score 0.7-1 dB *lower* on the
#: soft-shadow benchmark (4-spp antialiasing at silhouettes is not what they were trained on).
DENOISE_CLEAN_AUX = False


#: Open Image Denoise's C API values used here (oidn.h).
OIDN_DEVICE_TYPE_CPU = 1
OIDN_FORMAT_FLOAT3 = 3
OIDN_QUALITIES = {"fast": 4, "balanced": 5, "high": 6}

_LIBRARIES: dict = {}  # the C API loaded from each folder: a library is loaded once a process
_LIBRARIES_LOCK = threading.Lock()


def check_available():
    """The Open Image Denoise library that ``pyoidn`` installs, loaded (once), or raise
    MissingDependencyError naming the extra to install.

    The library is called through ctypes, not through pyoidn's own wrapper: importing pyoidn
    parses its C declarations with cffi, ~0.03 s of pure Python under Python's lock, which the
    render command would pay beside its reading of the input (the denoiser is set up on a
    worker thread meanwhile). The calls are the ones pyoidn makes."""
    folder = _library_folder()
    with _LIBRARIES_LOCK:
        if folder not in _LIBRARIES:
            _LIBRARIES[folder] = _load_library(folder)
        return _LIBRARIES[folder]


def _missing() -> MissingDependencyError:
    return MissingDependencyError(
        f"denoise=True needs Intel Open Image Denoise ({DENOISE_MODULE}); install it with: "
        f"pip install 'pointviz[{DENOISE_EXTRA}]'  (or render with denoise=False / "
        f"--no-denoise)")


def _library_folder() -> str:
    """The folder of pyoidn's bundled libraries (found without importing pyoidn)."""
    import importlib.util
    import os

    try:
        spec = importlib.util.find_spec(DENOISE_MODULE)
    except (ImportError, ValueError):
        spec = None
    if spec is None or not spec.submodule_search_locations:
        raise _missing()
    return os.path.join(list(spec.submodule_search_locations)[0], "oidn",
                        "bin" if os.name == "nt" else "lib")


def _load_library(folder: str):
    """ctypes handle of the ``OpenImageDenoise`` library in ``folder`` (where pyoidn itself
    loads it from), its functions typed."""
    import ctypes
    import os
    import sys

    windows = os.name == "nt"
    suffix = ".dll" if windows else ".dylib" if sys.platform == "darwin" else ".so"
    prefix = "" if windows else "lib"
    names = ["OpenImageDenoise_device_cpu", "OpenImageDenoise"] if windows else ["OpenImageDenoise"]
    try:
        for name in names:  # (Windows: the device library first, as pyoidn loads them)
            lib = ctypes.CDLL(os.path.join(folder, prefix + name + suffix))
    except OSError as exc:
        raise MissingDependencyError(
            f"{_missing()} ({DENOISE_MODULE} is installed but its library did not load: "
            f"{exc})") from None
    p, s, i = ctypes.c_void_p, ctypes.c_char_p, ctypes.c_int
    size = ctypes.c_size_t
    for name, args, res in (
            ("oidnNewDevice", [i], p), ("oidnSetDeviceInt", [p, s, i], None),
            ("oidnCommitDevice", [p], None), ("oidnReleaseDevice", [p], None),
            ("oidnGetDeviceError", [p, ctypes.POINTER(s)], i),
            ("oidnNewFilter", [p, s], p), ("oidnReleaseFilter", [p], None),
            ("oidnSetFilterBool", [p, s, ctypes.c_bool], None),
            ("oidnSetFilterInt", [p, s, i], None), ("oidnSetFilterFloat", [p, s, ctypes.c_float], None),
            ("oidnSetSharedFilterImage", [p, s, p, i, size, size, size, size, size], None),
            ("oidnUnsetFilterImage", [p, s], None),
            ("oidnCommitFilter", [p], None), ("oidnExecuteFilter", [p], None)):
        fn = getattr(lib, name)
        fn.argtypes, fn.restype = args, res
    return lib


def _check_quality(quality) -> str:
    if quality not in DENOISE_QUALITIES:
        raise InputError(f"denoise: expected True, False or one of {DENOISE_QUALITIES}, got {quality!r}")
    return quality


def _check_buffers(color, albedo, normal):
    """float32 C-contiguous (h, w, 3) buffers (copied only when they are not already)."""
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
    # HDR input must be non-negative; np.maximum writes a fresh contiguous array
    return np.maximum(color, np.float32(0.0)), guides


def _release(lib, flt, device):
    lib.oidnReleaseFilter(flt)
    lib.oidnReleaseDevice(device)


class Denoiser:
    """An Open Image Denoise CPU device and ray-tracing filter, reused across frames.

    Parameters
    ----------
    quality : {"high", "balanced", "fast"}
    threads : int, optional
        Worker threads of the device (default: all cores, as the renderer's).
    clean_aux : bool
        Tell the filter the albedo and normal guides are noise-free (see DENOISE_CLEAN_AUX).

    Calls are serialised (one filter); :meth:`close` (or ``with``) frees the device early,
    otherwise it is freed with the object.
    """

    def __init__(self, quality: str = DENOISE_QUALITY, threads: int | None = None,
                 clean_aux: bool = DENOISE_CLEAN_AUX):
        lib = self._lib = check_available()
        self.quality = _check_quality(quality)
        if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 0):
            raise InputError(f"threads: expected an int >= 0 or None, got {threads!r}")
        self.threads = threads or None
        self.clean_aux = bool(clean_aux)
        self._lock = threading.Lock()
        self._device = lib.oidnNewDevice(OIDN_DEVICE_TYPE_CPU)
        if not self._device:
            raise RuntimeError("Open Image Denoise device creation failed")
        if self.threads:
            lib.oidnSetDeviceInt(self._device, b"numThreads", self.threads)
        lib.oidnCommitDevice(self._device)
        self._check("device creation")
        self._filter = lib.oidnNewFilter(self._device, b"RT")
        self._check("filter creation")
        lib.oidnSetFilterBool(self._filter, b"hdr", True)
        lib.oidnSetFilterBool(self._filter, b"cleanAux", self.clean_aux)
        lib.oidnSetFilterInt(self._filter, b"quality", OIDN_QUALITIES[self.quality])
        self._bound: tuple = ()
        self._finalizer = weakref.finalize(self, _release, lib, self._filter, self._device)

    def _check(self, what: str) -> None:
        import ctypes

        message = ctypes.c_char_p()
        self._lib.oidnGetDeviceError(self._device, ctypes.byref(message))
        if message.value:  # (as pyoidn: an error is its message)
            raise RuntimeError(f"Open Image Denoise {what} failed: "
                               f"{message.value.decode(errors='replace')}")

    def __call__(self, color: np.ndarray, albedo: np.ndarray | None = None,
                 normal: np.ndarray | None = None, exposure: float | None = None) -> np.ndarray:
        """Denoise linear HDR radiance.

        Parameters
        ----------
        color : (h, w, 3) float32
            Linear radiance (negative values are clamped to 0).
        albedo : (h, w, 3) float32, optional
            Base colour in [0, 1], same shape.
        normal : (h, w, 3) float32, optional
            Unit normals (any fixed frame), zero where nothing was hit; needs ``albedo``.
        exposure : float, optional
            The scale the frame is displayed at (``tonemap(color * exposure)``): the filter's
            input scale, so that its perceptual weighting matches the picture the user sees.
            None: Open Image Denoise's own estimate from the image.

        Returns
        -------
        (h, w, 3) float32
        """
        if not self._finalizer.alive:
            raise InputError("denoiser: used after close()")
        if exposure is not None and not (math.isfinite(exposure) and exposure > 0):
            raise InputError(f"exposure: expected a finite number > 0, got {exposure!r}")
        color, guides = _check_buffers(color, albedo, normal)
        out = np.empty_like(color)
        images = {"color": color, **guides, "output": out}
        lib = self._lib
        with self._lock:
            flt = self._filter
            for name in set(self._bound) - set(images):
                lib.oidnUnsetFilterImage(flt, name.encode())
            for name, img in images.items():  # shared host images, tightly packed
                lib.oidnSetSharedFilterImage(flt, name.encode(), img.ctypes.data,
                                             OIDN_FORMAT_FLOAT3, img.shape[1], img.shape[0],
                                             0, 0, 0)
            self._bound = tuple(images)
            lib.oidnSetFilterFloat(flt, b"inputScale",
                                   float(exposure) if exposure is not None else math.nan)
            lib.oidnCommitFilter(flt)
            self._check("filter setup")
            lib.oidnExecuteFilter(flt)
            self._check("filtering")
        return np.maximum(out, np.float32(0.0), out=out)

    def close(self) -> None:
        """Free the device and filter now (later calls raise InputError)."""
        with self._lock:
            self._finalizer()

    def __enter__(self) -> "Denoiser":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


_SHARED: dict = {}
_SHARED_LOCK = threading.Lock()


def shared_denoiser(quality: str = DENOISE_QUALITY, threads: int | None = None) -> Denoiser:
    """The process's denoiser for (quality, threads), created on first use.

    The module's process state, with the loaded library (:func:`check_available`): what it
    caches is the network's weights loaded into a device, which every frame of a run would
    otherwise load again.
    """
    key = (_check_quality(quality), threads or None)
    with _SHARED_LOCK:
        den = _SHARED.get(key)
        if den is None:
            den = _SHARED[key] = Denoiser(*key)
        return den


def prepare_in_background(quality: str = DENOISE_QUALITY,
                          threads: int | None = None) -> threading.Thread:
    """Create the shared denoiser for (quality, threads) (:func:`shared_denoiser`) on a daemon
    thread while the caller does other work: the command line starts it before it reads its
    input, so that loading Open Image Denoise and creating the device (which runs without
    Python's lock) overlap the reading instead of delaying the frame. Errors are left to the
    first real call, which raises them where they belong (a missing ``pyoidn`` included).
    Returns the started thread."""
    def work():
        try:
            shared_denoiser(quality, threads)
        except Exception:  # noqa: BLE001 - the first real call reports it
            pass

    thread = threading.Thread(target=work, name="pointviz-denoiser-setup", daemon=True)
    thread.start()
    return thread


def denoise_image(color: np.ndarray, albedo: np.ndarray | None = None,
                  normal: np.ndarray | None = None, quality: str = DENOISE_QUALITY,
                  exposure: float | None = None, threads: int | None = None) -> np.ndarray:
    """Denoise linear HDR radiance with the shared denoiser (see :meth:`Denoiser.__call__`).

    Parameters
    ----------
    color, albedo, normal : (h, w, 3) float32
    quality : {"high", "balanced", "fast"}
    exposure : float, optional
    threads : int, optional

    Returns
    -------
    (h, w, 3) float32
    """
    check_available()
    return shared_denoiser(quality, threads)(color, albedo, normal, exposure)


def denoise_quality(denoise) -> str | None:
    """The filter quality asked for by ``render(denoise=...)`` (True: DENOISE_QUALITY), or None."""
    if denoise is False or denoise is None:
        return None
    if denoise is True:
        return DENOISE_QUALITY
    if isinstance(denoise, Denoiser):
        return denoise.quality
    if isinstance(denoise, str) and denoise in DENOISE_QUALITIES:
        return denoise
    raise InputError(f"denoise: expected True, False, a Denoiser or one of {DENOISE_QUALITIES}, "
                     f"got {denoise!r}")


def denoise_frame(frame, denoise=True, threads: int | None = None) -> None:
    """Denoise ``frame.color`` in place, guided by its albedo and normals and displayed at
    ``frame.exposure``; the tracer's colour moves to ``frame.noisy_color`` and the time to
    ``frame.stats["denoise_seconds"]``.

    ``denoise`` is True, a quality name or a :class:`Denoiser`.
    """
    t0 = time.perf_counter()
    den = denoise if isinstance(denoise, Denoiser) else shared_denoiser(denoise_quality(denoise), threads)
    noisy = frame.color
    frame.color = den(noisy, frame.albedo, frame.normal, exposure=frame.exposure)
    frame.noisy_color = noisy
    frame.stats["denoise_seconds"] = time.perf_counter() - t0
