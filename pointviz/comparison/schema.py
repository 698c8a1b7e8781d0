"""The documented JSON schema of ``metrics.json`` and a validator (``jsonschema`` when installed,
else a small built-in one covering the keywords the schema uses)."""

from __future__ import annotations

import math

from ..errors import InputError
from .metrics import METRIC_DOC

SCHEMA_ID = "pointviz.compare/1"

_NUM = {"type": ["number", "null"]}  # NaN/inf are written as null (JSON has neither)

SCHEMA = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "pointviz compare metrics",
    "description": "One entry per method and setting: preprocessing/render seconds and every "
                   "image metric against the reference frame.",
    "type": "object",
    "required": ["schema", "input", "reference", "image", "entries"],
    "properties": {
        "schema": {"type": "string", "enum": [SCHEMA_ID]},
        "input": {"type": "string", "description": "input file or generated shape name"},
        "points": {"type": "integer", "minimum": 1},
        "reference": {
            "type": "object", "required": ["kind"],
            "properties": {"kind": {"type": "string",
                                    "enum": ["mesh", "analytic", "surfels-full-detail"]},
                           "description": {"type": "string"},
                           "vertices": {"type": "integer", "minimum": 0},
                           "note": {"type": "string",
                                    "description": "caveat the report shows (a coarse mesh)"}},
        },
        "load_seconds": {"type": "number", "minimum": 0,
                         "description": "reading the input, shared by every method (not in "
                                        "first_image)"},
        "image": {"type": "object", "required": ["width", "height", "spp"],
                  "properties": {"width": {"type": "integer", "minimum": 1},
                                 "height": {"type": "integer", "minimum": 1},
                                 "spp": {"type": "integer", "minimum": 1}}},
        "render": {"type": "object",
                   "description": "the render settings of every frame (pointviz.RenderSettings, "
                                  "one key per field); lod_pixels varies per entry (its "
                                  "settings), the reference without a mesh has 4x the spp"},
        "camera": {"type": "object"},
        "entries": {
            "type": "array", "minItems": 1,
            "items": {
                "type": "object",
                "required": ["method", "label", "settings", "times", "metrics", "images"],
                "properties": {
                    "method": {"type": "string",
                               "enum": ["discs", "surfels-paper", "surfels-smooth", "poisson",
                                        "ball-pivoting", "alpha-shape"]},
                    "label": {"type": "string"},
                    "settings": {"type": "object"},
                    "times": {
                        "type": "object",
                        "required": ["preprocess", "render", "first_image"],
                        "properties": {"preprocess": {"type": "number", "minimum": 0},
                                       "render": {"type": "number", "minimum": 0},
                                       "first_image": {"type": "number", "minimum": 0},
                                       "steps": {"type": "object"},
                                       "render_in_core": {"type": "number", "minimum": 0}},
                    },
                    "metrics": {"type": "object", "required": sorted(METRIC_DOC),
                                "properties": {k: dict(_NUM, description=v)
                                               for k, v in METRIC_DOC.items()}},
                    "images": {"type": "object", "required": ["frame", "flip"],
                               "properties": {"frame": {"type": "string"},
                                              "flip": {"type": "string"}}},
                    "geometry": {"type": "object"},
                },
            },
        },
        "stability": {"type": "object"},
    },
}

_TYPES = {"object": dict, "array": list, "string": str, "boolean": bool, "null": type(None)}


def _is_type(value, t: str) -> bool:
    if t == "integer":
        return isinstance(value, int) and not isinstance(value, bool)
    if t == "number":
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    return isinstance(value, _TYPES[t])


def _errors(value, schema: dict, path: str):
    types = schema.get("type")
    if types is not None:
        types = [types] if isinstance(types, str) else types
        if not any(_is_type(value, t) for t in types):
            yield f"{path or '/'}: expected {' or '.join(types)}, got {type(value).__name__}"
            return
    if "enum" in schema and value not in schema["enum"]:
        yield f"{path or '/'}: {value!r} is not one of {schema['enum']}"
    if "minimum" in schema and isinstance(value, (int, float)) and not (value >= schema["minimum"]):
        yield f"{path or '/'}: {value!r} is below the minimum {schema['minimum']}"
    if isinstance(value, dict):
        for key in schema.get("required", []):
            if key not in value:
                yield f"{path or '/'}: missing required key {key!r}"
        for key, sub in schema.get("properties", {}).items():
            if key in value:
                yield from _errors(value[key], sub, f"{path}/{key}")
    if isinstance(value, list):
        if len(value) < schema.get("minItems", 0):
            yield f"{path or '/'}: fewer than {schema['minItems']} items"
        if "items" in schema:
            for i, item in enumerate(value):
                yield from _errors(item, schema["items"], f"{path}/{i}")


def builtin_errors(document) -> list[str]:
    """Every violation of :data:`SCHEMA` found by the built-in validator (empty when valid)."""
    return list(_errors(document, SCHEMA, ""))


def validate(document) -> None:
    """Raise :class:`InputError` listing the violations of :data:`SCHEMA`, if any."""
    try:
        import jsonschema
    except ImportError:
        errs = builtin_errors(document)
    else:
        v = jsonschema.Draft202012Validator(SCHEMA)
        errs = [f"/{'/'.join(map(str, e.absolute_path))}: {e.message}"
                for e in v.iter_errors(document)]
    if errs:
        raise InputError("metrics.json does not match its schema: " + "; ".join(errs[:5]))


def json_safe(value):
    """``value`` with NaN/inf floats replaced by None (strict JSON), recursively."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value
