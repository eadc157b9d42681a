"""JSON schemas of every MCAP channel rodctl writes.

Why hand-written JSON schemas rather than foxglove-sdk's protobuf: one writer (`mcap`, already a
dependency) for the whole file keeps the bytes reproducible and the reader trivial (`json.loads`),
and Foxglove renders its well-known schemas in JSON encoding as well as protobuf; it recognises
them by the schema *name* (`foxglove.SceneUpdate`, ...).

Two sources:
- `foxglove.*` channels embed the **official** schemas, unchanged, vendored from the npm package
  `@foxglove/schemas` 2.1.0 under `foxglove_schemas/` (see its SOURCE.md). A subset would not do:
  Foxglove's JSON-schema parser skips a channel whose schema has an array without typed `items`.
- rodctl's own channels (`rodctl.*`) are written here so that they load in that parser too, whose
  rules are (Lichtblick / open-source Foxglove Studio, `mcap-support/parseJsonSchema.ts`; checked
  by `tests/logs/test_foxglove.py`):
  - every object node is `"type": "object"` with a `properties` mapping (no free-form maps);
  - every property has one `type` string among boolean, string (optionally base64), number,
    integer, object, array; or a `oneOf` whose alternatives are all numeric `const`s (an enum);
    so no `anyOf`, no type lists, no `null`;
  - every array has `items` with a `type` of boolean, string, number, integer or object: **no
    arrays of arrays**. Points are therefore arrays of `{x, y}` objects, matrices are flat
    row-major arrays with their shape beside them, and maps are arrays of `{key, value}` objects.

Non-finite numbers: JSON has no NaN or infinity, and the parser admits no nullable number, so a
non-finite value is written as `null` in its number field and listed, with its exact value, in
the message's `nonfinite` array (`codec.Encoder`). A strict validator rejects that `null`; every
finite message validates against its schema (tested). Foxglove shows the `null` as an empty value.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

#: Version of the vendored official Foxglove schemas (npm @foxglove/schemas).
FOXGLOVE_SCHEMAS_VERSION = "2.1.0"
FOXGLOVE_SCHEMA_DIR = Path(__file__).with_name("foxglove_schemas")


def official(name: str) -> dict[str, Any]:
    """The official Foxglove JSON schema `foxglove.<name>` as vendored (key order kept)."""
    path = FOXGLOVE_SCHEMA_DIR / f"{name}.json"
    return json.loads(path.read_text(encoding="utf-8"))


SCENE_UPDATE = official("SceneUpdate")
COMPRESSED_IMAGE = official("CompressedImage")
IMAGE_ANNOTATIONS = official("ImageAnnotations")
LOG = official("Log")
FRAME_TRANSFORM = official("FrameTransform")
CAMERA_CALIBRATION = official("CameraCalibration")

#: The primitive lists of a foxglove.SceneEntity (every one required, empty when unused).
PRIMITIVE_LISTS: tuple[str, ...] = tuple(
    name
    for name, prop in SCENE_UPDATE["properties"]["entities"]["items"]["properties"].items()
    if prop.get("type") == "array" and name != "metadata"
)

# ------------------------------------------------------------------------- rodctl's own schemas
_NUM_NOTE = " Non-finite values are null here and listed in `nonfinite`."


def _num(desc: str) -> dict[str, Any]:
    return {"type": "number", "description": desc + _NUM_NOTE}


def _vec(n: int | None, desc: str) -> dict[str, Any]:
    out: dict[str, Any] = {
        "type": "array",
        "items": {"type": "number"},
        "description": desc + _NUM_NOTE,
    }
    if n is not None:
        out["minItems"] = out["maxItems"] = n
    return out


def _qvec(desc: str) -> dict[str, Any]:
    """q = 3 values (one moved end: [x, y, theta]) or 6 (dual-arm: the gripper's, then the x0
    end's)."""
    out = _vec(None, desc)
    out["minItems"], out["maxItems"] = 3, 6
    return out


def _points(unit: str, desc: str) -> dict[str, Any]:
    return {
        "type": "array",
        "items": {
            "type": "object",
            "title": "rodctl.Point2",
            "properties": {
                "x": {"type": "number", "description": f"First coordinate ({unit})."},
                "y": {"type": "number", "description": f"Second coordinate ({unit})."},
            },
            "required": ["x", "y"],
        },
        "description": desc + _NUM_NOTE,
    }


_NONFINITE: dict[str, Any] = {
    "type": "array",
    "description": "The message's non-finite numbers (written as null): where and which.",
    "items": {
        "type": "object",
        "title": "rodctl.NonFinite",
        "properties": {
            "path": {
                "type": "string",
                "description": "The value's place: `field`, `field[i]` or `field[i].x`.",
            },
            "value": {"type": "string", "enum": ["NaN", "Infinity", "-Infinity"]},
        },
        "required": ["path", "value"],
    },
}

_STEP = {"type": "integer", "minimum": 0, "description": "Control step k (0 = initial)."}
_PHASE = {"type": "string", "enum": ["initial", "probe", "control"]}

ROD_STATE: dict[str, Any] = {
    "title": "rodctl.RodState",
    "description": "Simulator ground truth after one control step (world frame, y up).",
    "type": "object",
    "properties": {
        "step": _STEP,
        "sim_time": _num("Simulated time at the end of the step (s)."),
        "gripper": _vec(3, "Gripper pose [x, y, theta] (m, m, rad), world frame."),
        "centerline": _points("m", "Ground-truth centerline [{x, y}, ...] (m), clamp end first."),
        "phase": _PHASE,
        "settled": {"type": "boolean"},
        "clipped": {"type": "boolean"},
        "max_joint_gap": _num("Largest pivot-joint separation (m)."),
        "kinetic_energy": _num("Rod kinetic energy at step end (J)."),
        "events": {
            "type": "array",
            "items": {"type": "string"},
            "description": "Mid-run events applied before this step's move (run.events).",
        },
        "nonfinite": _NONFINITE,
    },
    "required": ["step", "sim_time", "gripper", "centerline", "nonfinite"],
}

CLAMP_STATE: dict[str, Any] = {
    "title": "rodctl.ClampState",
    "description": (
        "Dual-arm only (rod.arms: 2): the pose of the x0 end, held and moved by the second arm, "
        "after one control step (world frame, y up)."
    ),
    "type": "object",
    "properties": {
        "step": _STEP,
        "sim_time": _num("Simulated time at the end of the step (s)."),
        "clamp": _vec(3, "x0 end pose [x, y, theta] (m, m, rad), world frame."),
        "nonfinite": _NONFINITE,
    },
    "required": ["step", "sim_time", "clamp", "nonfinite"],
}

CAMERA_CENTERLINE: dict[str, Any] = {
    "title": "rodctl.CameraCenterline",
    "description": "Centerline seen by the camera, pixels (u right, v down).",
    "type": "object",
    "properties": {
        "step": _STEP,
        "extracted": _points("px", "Centerline extracted from the image [{x: u, y: v}, ...]."),
        "projected_truth": _points("px", "Ground truth projected by the camera model."),
        "extraction_ok": {"type": "boolean"},
        "extraction_note": {"type": "string"},
        "nonfinite": _NONFINITE,
    },
    "required": ["step", "extracted", "projected_truth", "nonfinite"],
}

CONTROL: dict[str, Any] = {
    "title": "rodctl.Control",
    "description": "Feature, Jacobian estimate and command of one control step.",
    "type": "object",
    "properties": {
        "step": _STEP,
        "u": _qvec("Applied pose increment [dx, dy, dtheta] per moved end (m, m, rad)."),
        "s": _vec(None, "Shape feature s_k (p,)."),
        "s_target": _vec(None, "Target feature s* (p,)."),
        "T1": _num("||s* - s_k||, the paper's deformation metric."),
        "J": _vec(None, "Jacobian estimate, row-major p x q (p*q,); shape in J_shape."),
        "pixel_error": _num("Mean centerline distance to target (px)."),
        "jacobian_error": _num(
            "||J - J_true||_F / ||J_true||_F: the estimate against the simulator's true "
            "Jacobian of the same feature (absent where the step has none)."
        ),
        "J_shape": {
            "type": "array",
            "items": {"type": "integer"},
            "minItems": 2,
            "maxItems": 2,
            "description": "[p, q]",
        },
        "J_singular_values": _vec(None, "Singular values of J, largest first."),
        "u_raw": _qvec("Command before saturation and workspace clipping."),
        "saturated": {"type": "array", "items": {"type": "boolean"}},
        "phase": _PHASE,
        "estimator_info": {
            "type": "array",
            "description": "Scalar diagnostics of the estimator, by name.",
            "items": {
                "type": "object",
                "title": "rodctl.NamedValue",
                "properties": {
                    "name": {"type": "string"},
                    "value": _num("The diagnostic's value."),
                },
                "required": ["name", "value"],
            },
        },
        "nonfinite": _NONFINITE,
    },
    "required": ["step", "u", "s", "s_target", "T1", "J", "pixel_error", "J_shape", "nonfinite"],
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
        "home_pose": _qvec("Moved ends' poses at the start (gripper, then x0 end) (m, m, rad)."),
        "target_centerline": _points("m", "Target centerline (m), clamp first."),
        "target_pixels": _points("px", "Target centerline as extracted (px)."),
        "target_feature": _vec(None, "s* (p,)."),
        "target_pose": _qvec("Moved ends' poses that produced the target (m, m, rad)."),
        "rod_length": _num("Rod length L (m)."),
        "numeric_env": {
            "type": "array",
            "description": "The numeric environment (CPU, BLAS, library builds): each value as "
            "JSON text.",
            "items": {
                "type": "object",
                "title": "rodctl.KeyJson",
                "properties": {"key": {"type": "string"}, "value": {"type": "string"}},
                "required": ["key", "value"],
            },
        },
        "nonfinite": _NONFINITE,
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
        "numeric_env",
        "nonfinite",
    ],
}

RUN_SUMMARY: dict[str, Any] = {
    "title": "rodctl.RunSummary",
    "description": "summary.json as logged when the run closed (its run-independent keys; "
    "non-finite numbers as the strings NaN / Infinity / -Infinity), plus the closing status.",
    "type": "object",
    "properties": {
        "closing_status": {"type": "string"},
        "status": {"type": "string"},
        "outcome": {"type": "string"},
        "method": {"type": "string"},
        "steps": {"type": "integer"},
        "converged": {"type": "boolean"},
    },
    "required": ["closing_status"],
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
        IMAGE_ANNOTATIONS,
        LOG,
        FRAME_TRANSFORM,
        CAMERA_CALIBRATION,
    )
}


def schema_bytes(schema: dict[str, Any]) -> bytes:
    """The schema as stored in MCAP: compact JSON, key order as defined (the official schemas'
    own order), so files are byte-stable and the official schemas keep their JSON value."""
    return json.dumps(schema, separators=(",", ":"), ensure_ascii=False).encode("utf-8")
