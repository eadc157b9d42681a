"""Foxglove compatibility of run.mcap: every channel's schema loads in Foxglove's open-source
JSON-schema channel parser, and every foxglove.* message validates against the official schema.

`parse_json_schema` below re-implements the rules of that parser (Lichtblick / the former
open-source Foxglove Studio, `packages/mcap-support/src/parseJsonSchema.ts`): Foxglove skips a
channel whose schema it throws on, and then shows nothing of it. The parser is not published on
npm, so it is ported here rule by rule, and the port is checked to reject each schema form that
made channels unloadable before (so these tests can fail).
"""

from __future__ import annotations

import json
from typing import Any

import jsonschema
import numpy as np
import pytest
from mcap.reader import make_reader

from rodctl.logs import schemas
from rodctl.logs.mcap import CHANNELS

_SCALARS = {"boolean": "bool", "number": "float64", "integer": "float64"}


class Unsupported(ValueError):
    """Where the Foxglove parser throws (the channel is then skipped)."""


def parse_json_schema(root: dict[str, Any], root_name: str) -> dict[str, list[dict[str, Any]]]:
    """Datatypes (type name -> fields) as Foxglove's parser derives them, or `Unsupported`."""
    datatypes: dict[str, list[dict[str, Any]]] = {}

    def add(schema: Any, name: str, key_path: list[str]) -> None:
        if not isinstance(schema, dict) or schema.get("type") != "object":
            raise Unsupported(f'expected "type": "object" for schema {name}')
        props = schema.get("properties")
        if not isinstance(props, dict):  # Object.entries(undefined) throws
            raise Unsupported(f"{name}: object without properties")
        fields: list[dict[str, Any]] = []
        for field, fs in props.items():
            where = ".".join([*key_path, field])
            if not isinstance(fs, dict):
                raise Unsupported(f"{where}: not a schema")
            if isinstance(fs.get("oneOf"), list):
                alts = fs["oneOf"]
                if not all(
                    isinstance(a, dict)
                    and isinstance(a.get("const"), (int, float))
                    and not isinstance(a.get("const"), bool)
                    for a in alts
                ):
                    raise Unsupported(f"{where}: oneOf alternatives must have number values")
                fields += [{"name": a.get("title"), "constant": a["const"]} for a in alts]
                fields.append({"name": field, "type": "uint32"})
                continue
            t = fs.get("type")
            t = t if isinstance(t, str) else repr(t)  # a type list matches no case: throws
            if t in _SCALARS:
                fields.append({"name": field, "type": _SCALARS[t]})
            elif t == "string":
                enc = fs.get("contentEncoding")
                if enc is None:
                    fields.append({"name": field, "type": "string"})
                elif enc == "base64":
                    fields.append({"name": field, "type": "uint8", "isArray": True})
                else:
                    raise Unsupported(f"{where}: unsupported contentEncoding {enc!r}")
            elif t == "object":
                nested = f"{name}.{field}"
                add(fs, nested, [*key_path, field])
                fields.append({"name": field, "type": nested, "isComplex": True})
            elif t == "array":
                items = fs.get("items")
                if not isinstance(items, dict):  # itemSchema.type of undefined throws
                    raise Unsupported(f"{where}: array without an items schema")
                it = items.get("type")
                it = it if isinstance(it, str) else repr(it)
                if it in _SCALARS:
                    fields.append({"name": field, "type": _SCALARS[it], "isArray": True})
                elif it == "string":
                    if items.get("contentEncoding") is not None:
                        raise Unsupported(f"{where}: contentEncoding on array items")
                    fields.append({"name": field, "type": "string", "isArray": True})
                elif it == "object":
                    nested = f"{name}.{field}"
                    add(items, nested, [*key_path, field])
                    fields.append(
                        {"name": field, "type": nested, "isComplex": True, "isArray": True}
                    )
                else:
                    raise Unsupported(f"{where}: unsupported array item type {it!r}")
            else:
                raise Unsupported(f"{where}: unsupported type {t!r}")
        datatypes[name] = fields

    add(root, root_name, [])
    return datatypes


def _file_schemas(path) -> dict[str, tuple[str, dict[str, Any]]]:
    """topic -> (schema name, schema) as registered in an MCAP file."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    out = {}
    for ch in summary.channels.values():
        s = summary.schemas[ch.schema_id]
        assert s.encoding == "jsonschema" and ch.message_encoding == "json", ch.topic
        out[ch.topic] = (s.name, json.loads(s.data))
    return out


def test_every_channel_in_the_file_loads_in_foxglove_parser(mcap_file):
    registered = _file_schemas(mcap_file)
    assert set(registered) == {topic for topic, _ in CHANNELS}
    for topic, (name, schema) in registered.items():
        datatypes = parse_json_schema(schema, name)  # raises where Foxglove would skip
        assert name in datatypes, topic


def test_parsed_datatypes_expose_the_contract_fields(mcap_file):
    """What a Foxglove user can plot: e.g. /rod/state.centerline[:].x, /control.J[:]."""
    registered = _file_schemas(mcap_file)
    name, schema = registered["/rod/state"]
    types = parse_json_schema(schema, name)
    fields = {f["name"]: f for f in types[name]}
    assert fields["centerline"]["isArray"] and fields["centerline"]["isComplex"]
    assert [f["name"] for f in types[f"{name}.centerline"]] == ["x", "y"]
    assert fields["sim_time"]["type"] == "float64" and fields["gripper"]["isArray"]
    name, schema = registered["/control"]
    fields = {f["name"]: f for f in parse_json_schema(schema, name)[name]}
    assert fields["J"] == {"name": "J", "type": "float64", "isArray": True}
    assert {"T1", "pixel_error", "u", "s", "s_target", "estimator_info"} <= set(fields)
    name, schema = registered["/log"]
    fields = [f["name"] for f in parse_json_schema(schema, name)[name]]
    assert "WARNING" in fields and "level" in fields  # the enum constants


@pytest.mark.parametrize(
    "prop",
    [
        {"type": "array", "items": {"type": "array", "items": {"type": "number"}}},
        {"type": "array"},
        {"anyOf": [{"type": "number"}, {"type": "null"}]},
        {"type": "array", "items": {"anyOf": [{"type": "number"}, {"type": "null"}]}},
        {"type": "object", "additionalProperties": {"type": "number"}},
        {"type": ["number", "null"]},
        {"type": "null"},
        {"oneOf": [{"const": "a"}, {"const": "b"}]},
        {"type": "string", "contentEncoding": "base32"},
    ],
    ids=[
        "nested-arrays",
        "array-without-items",
        "untyped-anyOf",
        "anyOf-items",
        "free-form-map",
        "type-list",
        "null",
        "string-oneOf",
        "base32",
    ],
)
def test_parser_port_rejects_what_foxglove_skips(prop):
    with pytest.raises(Unsupported):
        parse_json_schema({"type": "object", "properties": {"f": prop}}, "t")
    nested = {"type": "object", "properties": {"o": {"type": "object", "properties": {"f": prop}}}}
    with pytest.raises(Unsupported):
        parse_json_schema(nested, "t")


def test_parser_port_rejects_the_old_scene_update_subset():
    """Format 1 embedded a SceneUpdate subset with `cubes: {"type": "array"}` (no items)."""
    old = json.loads(json.dumps(schemas.SCENE_UPDATE))
    old["properties"]["entities"]["items"]["properties"]["cubes"] = {"type": "array"}
    with pytest.raises(Unsupported, match="cubes"):
        parse_json_schema(old, "foxglove.SceneUpdate")


def test_every_schema_constant_loads_and_is_valid_json_schema():
    for name, schema in schemas.ALL.items():
        jsonschema.Draft7Validator.check_schema(schema)
        parse_json_schema(schema, name)


def test_foxglove_schemas_are_the_official_ones_embedded_unchanged(mcap_file):
    for topic, (name, schema) in _file_schemas(mcap_file).items():
        if not name.startswith("foxglove."):
            assert name.startswith("rodctl."), topic
            continue
        vendored = schemas.FOXGLOVE_SCHEMA_DIR / f"{name.removeprefix('foxglove.')}.json"
        official = json.loads(vendored.read_text(encoding="utf-8"))
        assert schema == official, topic
        assert official["title"] == name
        assert official["$comment"] == "Generated by https://github.com/foxglove/foxglove-sdk"
    source = (schemas.FOXGLOVE_SCHEMA_DIR / "SOURCE.md").read_text(encoding="utf-8")
    assert f"`@foxglove/schemas` **{schemas.FOXGLOVE_SCHEMAS_VERSION}**" in source


def test_every_foxglove_message_validates_against_the_official_schema(mcap_file):
    seen: dict[str, int] = {}
    with open(mcap_file, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if not schema.name.startswith("foxglove."):
                continue
            official = schemas.official(schema.name.removeprefix("foxglove."))
            msg = json.loads(message.data)
            jsonschema.validate(msg, official, cls=jsonschema.Draft7Validator)
            if "timestamp" in msg:  # foxglove.* times are the message's log time
                t = msg["timestamp"]
                assert t["sec"] * 10**9 + t["nsec"] == message.log_time, channel.topic
            seen[channel.topic] = seen.get(channel.topic, 0) + 1
    assert set(seen) == {
        "/world/rod",
        "/world/target",
        "/world/gripper",
        "/camera/image",
        "/camera/annotations",
        "/log",
        "/tf",
        "/camera/calibration",
    }
    assert seen["/camera/image"] == seen["/camera/annotations"]
    assert seen["/tf"] == seen["/camera/calibration"] == 1  # no camera_bump: placed once


def _project(transform, calibration, world_xy):
    """Pixels of world points (z = 0) as Foxglove computes them from /tf and the calibration."""
    from scipy.spatial.transform import Rotation

    q = transform["rotation"]
    to_world = Rotation.from_quat([q["x"], q["y"], q["z"], q["w"]]).as_matrix()
    t = np.array([transform["translation"][k] for k in "xyz"])
    pts = np.column_stack([world_xy, np.zeros(len(world_xy))])
    cam = (pts - t) @ to_world  # = R_world->camera @ (p - t), row by row
    uvw = cam @ np.array(calibration["K"]).reshape(3, 3).T
    return uvw[:, :2] / uvw[:, 2:]


def test_the_camera_foxglove_places_sees_what_the_camera_saw():
    """/tf and /camera/calibration project the world onto the pixels rodctl's camera gives,
    at the start and after a camera_bump."""
    import yaml

    from rodctl.config import ExperimentConfig, dump_config
    from rodctl.logs.mcap import camera_views
    from rodctl.vision.camera import Camera

    cfg = ExperimentConfig.model_validate(
        {
            "camera": {"tilt_deg": 10.0, "azimuth_deg": 5.0},
            "run": {"events": [{"type": "camera_bump", "at_step": 4, "tilt_deg": 6.0}]},
        }
    )
    views = camera_views(dump_config(cfg))
    assert sorted(views) == [0, 4]
    world = np.column_stack([np.linspace(0.0, 0.5, 7), np.linspace(-0.05, 0.1, 7)])
    camera = Camera(cfg.camera)
    for step in (0, 4):
        if step == 4:
            camera.set_pose(tilt_deg=16.0)
        transform, calibration = views[step]
        assert transform["parent_frame_id"] == "world" and calibration["frame_id"] == "camera"
        assert transform["child_frame_id"] == "camera"
        assert (calibration["width"], calibration["height"]) == (camera.width, camera.height)
        np.testing.assert_allclose(
            _project(transform, calibration, world), camera.project(world), atol=1e-6
        )
    assert views[0][0] != views[4][0] and views[0][1] == views[4][1]  # intrinsics stay
    assert camera_views(yaml.safe_dump({"camera": {"width": -3}})) == {}  # no camera, no views
