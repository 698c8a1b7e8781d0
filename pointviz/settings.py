"""Every render setting in one place: its default, its range or choices, its help and its flag.

:class:`RenderSettings` is the single source of truth. :func:`pointviz.render` takes its
defaults from it and validates through it; the command line's options
(``commands/common.py``), the viewer's settings (``viewer/model.py``), path manifests
(:func:`pointviz.render_path`) and reports are derived from it. A new setting is one entry
here (a field made by :func:`setting`), plus the line of :func:`pointviz.render` that uses it.
"""

from __future__ import annotations

import math
from dataclasses import MISSING, asdict, dataclass, field, fields, replace
from typing import Any

import numpy as np

from .denoise import DENOISE_QUALITIES
from .errors import InputError

#: Named grounds: "auto" takes the look's, "none" has none (the rest are materials of
#: :data:`pointviz.scene.GROUND_MATERIALS`).
GROUNDS = ("auto", "matte", "mirror", "glossy", "none")
#: Named looks (:data:`pointviz.scene.LOOKS`), "auto" choosing from the geometry's shape.
LOOKS = ("auto", "studio", "outdoor", "flat")
#: How the disks around a hit are blended (a :class:`pointviz.SurfelScene` option).
INTERPOLATIONS = ("none", "paper", "smooth")
#: Which sides of the surfels a frame shows (:mod:`pointviz.sides`).
SIDES = ("auto", "one", "two")
#: Largest seed: the core takes an unsigned 64-bit seed; a signed bound keeps it portable.
MAX_SEED = 2**63 - 1
#: Range of a given exposure multiplier (the automatic one stays within
#: pointviz.images.EXPOSURE_RANGE): twenty stops either way are beyond any display's use.
MIN_EXPOSURE, MAX_EXPOSURE = 1e-6, 1e6
#: The automatic level of detail's default error budget: mean FLIP of the frame against full
#: detail (benchmarks/README.md, "Issue 18": measured within it on analytic scenes and scans).
DEFAULT_MAX_ERROR = 0.005


def check_int(value: Any, name: str, lo: int = 1, hi: int | None = None, note: str = "") -> int:
    """``value`` as an int in ``[lo, hi]`` (no upper bound when ``hi`` is None).

    Raises
    ------
    InputError
        Naming ``name`` and the range when ``value`` is not an integer (bools are not) or is
        out of range; ``note`` is appended to the message.
    """
    ok = (isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
          and value >= lo and (hi is None or value <= hi))
    if not ok:
        if hi is not None:
            what = f"an integer in [{lo}, {hi}]"
        elif lo == 1:
            what = "a positive integer"
        else:
            what = f"an integer >= {lo}"
        raise InputError(f"{name}: expected {what}{note}, got {value!r}")
    return int(value)


def check_lod(lod_pixels: Any = 1.0, max_error: Any = None) -> tuple:
    """The level-of-detail options of :func:`pointviz.render`, checked and normalised.

    Returns
    -------
    (float or "auto", float or None)
        ``(lod_pixels, max_error)``; for ``"auto"`` the budget defaults to DEFAULT_MAX_ERROR.

    Raises
    ------
    InputError
        For a bad threshold or budget, and for a budget given with a numeric threshold.
    """
    if isinstance(lod_pixels, str):
        if lod_pixels != "auto":
            raise InputError(f"lod_pixels: expected a number >= 0 or 'auto', got {lod_pixels!r}")
        if max_error is None:
            max_error = DEFAULT_MAX_ERROR
        if isinstance(max_error, (bool, np.bool_)) or not isinstance(
                max_error, (int, float, np.number)):
            raise InputError(f"max_error: expected a number in [0, 1], got {max_error!r}")
        if not (np.isfinite(max_error) and 0 <= max_error <= 1):
            raise InputError(f"max_error: expected a number in [0, 1] (mean FLIP), got {max_error!r}")
        return "auto", float(max_error)
    if max_error is not None:
        raise InputError(f"max_error: only applies with lod_pixels='auto' "
                         f"(got lod_pixels={lod_pixels!r})")
    if isinstance(lod_pixels, (bool, np.bool_)) or not isinstance(
            lod_pixels, (int, float, np.number)) or not (np.isfinite(lod_pixels) and lod_pixels >= 0):
        raise InputError(f"lod_pixels: expected a number >= 0 or 'auto', got {lod_pixels!r}")
    return float(lod_pixels), None


def setting(default: Any, help: str, *, lo: float | None = None, hi: float | None = None,
            choices: tuple | None = None, kind: type = int, optional: bool = False,
            flag: str | None = None, metavar: str | None = None, cli: bool = True,
            cli_default: Any = MISSING, objects: str | None = None) -> Any:
    """One render setting: a dataclass field whose metadata says how to check and offer it.

    Parameters
    ----------
    default : the value :func:`pointviz.render` uses when the setting is not given
    help : str
        One line for ``--help`` and the viewer.
    lo, hi : number, optional
        Range of an int or float setting (inclusive).
    choices : tuple, optional
        Allowed names of a str setting.
    kind : {int, float, bool, str}
    optional : bool
        None is allowed (and means what ``help`` says).
    flag : str, optional
        Command-line flag (default ``--name``). A bool setting that is on by default gets a
        ``--no-...`` flag.
    cli : bool
        Offered on the command line.
    cli_default : optional
        The command line's default when it differs from the library's, for a stated reason.
    objects : str, optional
        The type whose objects are accepted besides the named choices (a Material ground, a
        Look, a Denoiser), checked where they are used.
    """
    meta = {"help": help, "lo": lo, "hi": hi, "choices": choices, "kind": kind,
            "optional": optional, "flag": flag, "metavar": metavar, "cli": cli,
            "cli_default": cli_default, "objects": objects}
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class RenderSettings:
    """The settings of one rendered frame (what :func:`pointviz.render` takes besides the
    scene, the camera, progress and cancellation). Frozen; :meth:`replace` makes a changed,
    validated copy. Construction validates every field (InputError naming the bad one)."""

    shadows: bool = setting(True, "trace shadow rays", kind=bool, flag="--no-shadows")
    reflections: int = setting(1, "reflection bounces", lo=0, hi=16)
    spp: int = setting(4, "samples per pixel", lo=1, hi=4096)
    lod_pixels: float | str = setting(
        1.0, "level-of-detail threshold in pixels (0: full detail), or 'auto': the coarsest "
        "detail within max_error", lo=0.0, kind=float, choices=("auto",), flag="--lod",
        metavar="PIXELS|auto")
    max_error: float | None = setting(
        None, "with lod 'auto': mean FLIP the level of detail may cost the frame "
        f"(default {DEFAULT_MAX_ERROR}; 0: full detail)", lo=0.0, hi=1.0, kind=float,
        optional=True, metavar="E")
    seed: int = setting(0, "seed of the sampling pattern", lo=0, hi=MAX_SEED)
    threads: int | None = setting(None, "tracer threads (default: all cores)", lo=1, hi=1024,
                                  optional=True)
    ground: str | None = setting(
        None, "ground plane under the cloud (default: the scene's; auto for a cloud)",
        choices=GROUNDS, kind=str, optional=True, objects="pointviz.scene.Material")
    look: str | None = setting(
        None, "lighting: studio (key, fill, sky occlusion, backdrop), outdoor (sun and sky), "
        "flat (colours as scanned); auto: outdoor for terrain tiles, studio for objects "
        "(default: the scene's; auto for a cloud)", choices=LOOKS, kind=str, optional=True,
        objects="pointviz.scene.Look")
    sides: str | None = setting(
        None, "which sides of the surfels show: one (back faces culled), two, or auto: one "
        "where they close a surface, else two (default: the scene's; auto for a cloud)",
        choices=SIDES, kind=str, optional=True)
    exposure: float | None = setting(
        None, "exposure multiplier of the frame (default: the look's: automatic for studio and "
        "outdoor, 1 for flat; a camera path's frames share one, see pointviz.render_path)",
        lo=MIN_EXPOSURE, hi=MAX_EXPOSURE, kind=float, optional=True, metavar="E")
    denoise: bool | str = setting(
        False, "denoise with Open Image Denoise (the 'denoise' extra; True or a quality)",
        choices=(True, False, *DENOISE_QUALITIES), kind=bool, flag="--no-denoise",
        objects="pointviz.denoise.Denoiser",
        # final frames from the command line are denoised when the extra is installed (a
        # one-line note says how to get it otherwise)
        cli_default=True)

    def __post_init__(self) -> None:
        for f in fields(self):
            object.__setattr__(self, f.name, _check(f, getattr(self, f.name)))
        check_lod(self.lod_pixels, self.max_error)

    def replace(self, **changes: Any) -> RenderSettings:
        """A validated copy with some settings changed (TypeError for unknown names)."""
        return replace(self, **changes)

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    @classmethod
    def from_kwargs(cls, kwargs: dict, where: str) -> RenderSettings:
        """Settings from :func:`pointviz.render` keyword arguments; InputError (naming
        ``where``) for names that are not render settings."""
        unknown = set(kwargs) - set(cls.names())
        if unknown:
            raise InputError(f"{where}: unknown render option(s) {sorted(unknown)}")
        return cls(**kwargs)

    def render_kwargs(self) -> dict:
        """Keyword arguments of :func:`pointviz.render`."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def to_json(self) -> dict:
        """Every setting, JSON-safe: objects (a Material ground, a Look) by ``repr``."""
        return {k: _json_value(v) for k, v in asdict(self).items()}

    def manifest(self) -> dict:
        """Every setting that affects the image, JSON-safe (``threads`` is left out: results
        never depend on it)."""
        out = self.to_json()
        out.pop("threads")
        return out

    @classmethod
    def describe(cls, used: dict | None = None) -> list[dict]:
        """One row per setting, for reports: ``name``, ``value`` (from ``used``, a
        :meth:`to_json` dict, when given; else the default), ``default``, ``accepted`` (its
        range or choices, in words) and ``help``."""
        rows = []
        for f in fields(cls):
            default = _json_value(f.default)
            rows.append({"name": f.name, "value": default if used is None else used.get(f.name),
                         "default": default, "accepted": _accepted(f), "help": f.metadata["help"]})
        return rows


def _json_value(value: Any) -> Any:
    return value if isinstance(value, (bool, int, float, str, type(None))) else repr(value)


def _accepted(f) -> str:
    """What setting ``f`` accepts, in words (from its metadata, like :func:`_check`)."""
    m = f.metadata
    parts = []
    if m["kind"] is bool and m["choices"] is None:
        parts.append("True or False")
    elif m["kind"] in (int, float) and m["lo"] is not None:
        what, num = ("an integer", int) if m["kind"] is int else ("a number", float)
        lo, hi = f"{num(m['lo'])}", None if m["hi"] is None else f"{num(m['hi'])}"
        parts.append(f"{what} >= {lo}" if hi is None else f"{what} in [{lo}, {hi}]")
    if m["choices"] is not None:
        parts.append(", ".join(map(str, m["choices"])))
    if m["objects"]:
        parts.append(f"a {m['objects']}")
    if m["optional"]:
        parts.append("None")
    return " or ".join(parts)


def _check(f, value: Any) -> Any:
    """``value`` of setting ``f`` checked and normalised (see :func:`setting`)."""
    m = f.metadata
    if value is None and m["optional"]:
        return None
    kind = m["kind"]
    named = isinstance(value, (str, bool, np.bool_))
    numeric = kind in (int, float)  # a number, or one of the named choices ("auto")
    if m["choices"] is not None and (named or not (m["objects"] or numeric)):
        if not any(value is c or (isinstance(c, str) and value == c) for c in m["choices"]):
            also = f" or a {m['objects']}" if m["objects"] else ""
            raise InputError(f"{f.name}: expected one of "
                             f"{', '.join(map(str, m['choices']))}{also}, got {value!r}")
        return value
    if m["objects"]:
        return value  # a Material ground, a Look, a Denoiser: checked where it is used
    if kind is bool:
        if not isinstance(value, (bool, np.bool_)):
            raise InputError(f"{f.name}: expected True or False, got {value!r}")
        return bool(value)
    if kind is int:
        return check_int(value, f.name, int(m["lo"]), None if m["hi"] is None else int(m["hi"]))
    if kind is float:
        ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
            value, (bool, np.bool_)) and math.isfinite(value)
        if not ok or (m["lo"] is not None and value < m["lo"]) or (
                m["hi"] is not None and value > m["hi"]):
            rng = f">= {m['lo']:g}" if m["hi"] is None else f"in [{m['lo']:g}, {m['hi']:g}]"
            raise InputError(f"{f.name}: expected a number {rng}, got {value!r}")
        return float(value)
    raise TypeError(f"setting {f.name}: unknown kind {kind!r}")


#: The defaults, as one value.
DEFAULTS = RenderSettings()
