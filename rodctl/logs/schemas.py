"""JSON schemas of every MCAP channel rodctl writes.

Why hand-written JSON schemas rather than foxglove-sdk's protobuf: one writer (`mcap`, already a
dependency) for the whole file keeps the bytes reproducible and the reader trivial (`json.loads`),
and Foxglove renders its well-known schemas in JSON encoding as well as protobuf; it recognises
them by the schema *name* (`foxglove.SceneUpdate`, …), so those names are exact. The Foxglove
schemas below are the subset of the official ones (foxglove/foxglove-sdk
`schemas/jsonschema/*.json`) covering the fields rodctl writes, with the same `required` lists, so
every message we write validates against the official schema too.

`real` (a float64 that may be non-finite) follows `codec.encode_real`: a number, `null` for NaN,
or the strings "Infinity" / "-Infinity".
"""

from __future__ import annotations

import json
from typing import Any

_REAL: dict[str, Any] = {
    "anyOf": [{"type": "number"}, {"type": "null"}, {"enum": ["Infinity", "-Infinity"]}],
}


def _vec(n: int | None, desc: str) -> dict[str, Any]:
    out: dict[str, Any] = {"type": "array", "items": _REAL, "description": desc}
    if n is not None:
        out["minItems"] = out["maxItems"] = n
    return out


def _points(desc: str) -> dict[str, Any]:
    return {"type": "array", "items": _vec(2, "point"), "description": desc}


_STEP = {"type": "integer", "minimum": 0, "description": "Control step k (0 = initial)."}

ROD_STATE: dict[str, Any] = {
    "title": "rodctl.RodState",
    "description": "Simulator ground truth after one control step (world frame, y up).",
    "type": "object",
    "properties": {
        "step": _STEP,
        "sim_time": {**_REAL, "description": "Simulated time at the end of the step (s)."},
        "gripper": _vec(3, "Gripper pose [x, y, theta] (m, m, rad), world frame."),
        "centerline": _points("Ground-truth centerline [[x, y], ...] (m), clamp end first."),
        "phase": {"type": "string", "enum": ["initial", "probe", "control"]},
        "settled": {"type": "boolean"},
        "clipped": {"type": "boolean"},
        "max_joint_gap": {**_REAL, "description": "Largest pivot-joint separation (m)."},
        "kinetic_energy": {**_REAL, "description": "Rod kinetic energy at step end (J)."},
    },
    "required": ["step", "sim_time", "gripper", "centerline"],
}

CAMERA_CENTERLINE: dict[str, Any] = {
    "title": "rodctl.CameraCenterline",
    "description": "Centerline seen by the camera, pixels (u right, v down).",
    "type": "object",
    "properties": {
        "step": _STEP,
        "extracted": _points("Centerline extracted from the image [[u, v], ...] (px)."),
        "projected_truth": _points("Ground truth projected by the camera model (px)."),
        "extraction_ok": {"type": "boolean"},
        "extraction_note": {"type": "string"},
    },
    "required": ["step", "extracted", "projected_truth"],
}

CONTROL: dict[str, Any] = {
    "title": "rodctl.Control",
    "description": "Feature, Jacobian estimate and command of one control step.",
    "type": "object",
    "properties": {
        "step": _STEP,
        "u": _vec(3, "Applied pose increment [dx, dy, dtheta] (m, m, rad)."),
        "s": _vec(None, "Shape feature s_k (p,)."),
        "s_target": _vec(None, "Target feature s* (p,)."),
        "T1": {**_REAL, "description": "||s* - s_k||, the paper's deformation metric."},
        "J": _vec(None, "Jacobian estimate, row-major p x q (p*q,)."),
        "pixel_error": {**_REAL, "description": "Mean centerline distance to target (px)."},
        "J_shape": {"type": "array", "items": {"type": "integer"}, "minItems": 2, "maxItems": 2},
        "J_singular_values": _vec(None, "Singular values of J, largest first."),
        "u_raw": _vec(3, "Command before saturation and workspace clipping."),
        "saturated": {"type": "array", "items": {"type": "boolean"}},
        "phase": {"type": "string"},
        "estimator_info": {"type": "object", "additionalProperties": _REAL},
    },
    "required": ["step", "u", "s", "s_target", "T1", "J", "pixel_error"],
}

RUN_HEADER: dict[str, Any] = {
    "title": "rodctl.RunHeader",
    "description": "What is fixed for a whole run (rodctl.records.RunHeader).",
    "type": "object",
    "properties": {
        "format_version": {"type": "string"},
        "method": {"type": "string"},
        "config_yaml": {"type": "string"},
        "image_size": {
            "type": "array",
            "items": {"type": "integer"},
            "minItems": 2,
            "maxItems": 2,
            "description": "[width, height] (px)",
        },
        "clamp_pose": _vec(3, "Clamp pose [x, y, theta] (m, m, rad)."),
        "home_pose": _vec(3, "Gripper pose at the start (m, m, rad)."),
        "target_centerline": _points("Target centerline (m), clamp first."),
        "target_pixels": _points("Target centerline as extracted (px)."),
        "target_feature": _vec(None, "s* (p,)."),
        "target_pose": _vec(3, "Gripper pose that produced the target (m, m, rad)."),
        "rod_length": {**_REAL, "description": "Rod length L (m)."},
    },
    "required": [
        "format_version",
        "method",
        "config_yaml",
        "image_size",
        "clamp_pose",
        "home_pose",
        "target_centerline",
        "target_pixels",
        "target_feature",
        "target_pose",
        "rod_length",
    ],
}

RUN_SUMMARY: dict[str, Any] = {
    "title": "rodctl.RunSummary",
    "description": "summary.json as logged when the run closed, plus the closing status.",
    "type": "object",
    "properties": {"closing_status": {"type": "string"}},
    "required": ["closing_status"],
}

# ------------------------------------------------------------------ Foxglove well-known (subset)
_TIME = {
    "type": "object",
    "title": "time",
    "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
    },
}
_DURATION = {
    "type": "object",
    "title": "duration",
    "properties": {
        "sec": {"type": "integer"},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
    },
}


def _xyz(title: str, names: tuple[str, ...] = ("x", "y", "z")) -> dict[str, Any]:
    return {
        "title": title,
        "type": "object",
        "properties": {n: {"type": "number"} for n in names},
        "required": list(names),
    }


_COLOR = _xyz("foxglove.Color", ("r", "g", "b", "a"))
_POSE = {
    "title": "foxglove.Pose",
    "type": "object",
    "properties": {
        "position": _xyz("foxglove.Vector3"),
        "orientation": _xyz("foxglove.Quaternion", ("x", "y", "z", "w")),
    },
    "required": ["position", "orientation"],
}
_LINE = {
    "title": "foxglove.LinePrimitive",
    "type": "object",
    "properties": {
        "type": {
            "title": "foxglove.LineType",
            "oneOf": [
                {"title": "LINE_STRIP", "const": 0},
                {"title": "LINE_LOOP", "const": 1},
                {"title": "LINE_LIST", "const": 2},
            ],
        },
        "pose": _POSE,
        "thickness": {"type": "number"},
        "scale_invariant": {"type": "boolean"},
        "points": {"type": "array", "items": _xyz("foxglove.Point3")},
        "color": _COLOR,
        "colors": {"type": "array", "items": _COLOR},
        "indices": {"type": "array", "items": {"type": "integer", "minimum": 0}},
    },
    "required": [
        "type",
        "pose",
        "thickness",
        "scale_invariant",
        "points",
        "color",
        "colors",
        "indices",
    ],
}
_ARROW = {
    "title": "foxglove.ArrowPrimitive",
    "type": "object",
    "properties": {
        "pose": _POSE,
        "shaft_length": {"type": "number"},
        "shaft_diameter": {"type": "number"},
        "head_length": {"type": "number"},
        "head_diameter": {"type": "number"},
        "color": _COLOR,
    },
    "required": ["pose", "shaft_length", "shaft_diameter", "head_length", "head_diameter", "color"],
}
#: The primitive lists of a foxglove.SceneEntity (every one required, empty when unused).
PRIMITIVE_LISTS = (
    "arrows",
    "cubes",
    "spheres",
    "cylinders",
    "lines",
    "triangles",
    "texts",
    "models",
)
_ENTITY = {
    "title": "foxglove.SceneEntity",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "id": {"type": "string"},
        "lifetime": _DURATION,
        "frame_locked": {"type": "boolean"},
        "metadata": {
            "type": "array",
            "items": {
                "title": "foxglove.KeyValuePair",
                "type": "object",
                "properties": {"key": {"type": "string"}, "value": {"type": "string"}},
                "required": ["key", "value"],
            },
        },
        **{name: {"type": "array"} for name in PRIMITIVE_LISTS},
        "arrows": {"type": "array", "items": _ARROW},
        "lines": {"type": "array", "items": _LINE},
    },
    "required": [
        "timestamp",
        "frame_id",
        "id",
        "lifetime",
        "frame_locked",
        "metadata",
        *PRIMITIVE_LISTS,
    ],
}
SCENE_UPDATE: dict[str, Any] = {
    "title": "foxglove.SceneUpdate",
    "description": "An update to the entities displayed in a 3D scene",
    "type": "object",
    "properties": {
        "deletions": {"type": "array", "items": {"type": "object"}},
        "entities": {"type": "array", "items": _ENTITY},
    },
    "required": ["deletions", "entities"],
}

COMPRESSED_IMAGE: dict[str, Any] = {
    "title": "foxglove.CompressedImage",
    "description": "A compressed image",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "data": {"type": "string", "contentEncoding": "base64"},
        "format": {"type": "string"},
    },
    "required": ["timestamp", "frame_id", "data", "format"],
}

LOG: dict[str, Any] = {
    "title": "foxglove.Log",
    "description": "A log message",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "level": {
            "title": "foxglove.LogLevel",
            "oneOf": [
                {"title": t, "const": i}
                for i, t in enumerate(("UNKNOWN", "DEBUG", "INFO", "WARNING", "ERROR", "FATAL"))
            ],
        },
        "message": {"type": "string"},
        "name": {"type": "string"},
        "file": {"type": "string"},
        "line": {"type": "integer", "minimum": 0},
    },
    "required": ["timestamp", "level", "message", "name", "file", "line"],
}

#: Every schema by name, as registered in the MCAP file.
ALL: dict[str, dict[str, Any]] = {
    s["title"]: s
    for s in (
        ROD_STATE,
        CAMERA_CENTERLINE,
        CONTROL,
        RUN_HEADER,
        RUN_SUMMARY,
        SCENE_UPDATE,
        COMPRESSED_IMAGE,
        LOG,
    )
}


def schema_bytes(schema: dict[str, Any]) -> bytes:
    """The schema as stored in MCAP: compact, key order fixed, so files are byte-stable."""
    return json.dumps(schema, separators=(",", ":"), sort_keys=True).encode("utf-8")
