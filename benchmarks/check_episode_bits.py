"""Fingerprints of the shipped configs' episodes, to check that a speed-up changed no bit.

Runs each config's episode in this process (logging off, `--workers 1` in spirit) on both
engines and hashes every field of every step record (arrays by dtype, shape and bytes, floats
by their 8 bytes, strings and dicts by their repr), the header's arrays and the summary without
its timing fields. `--save FILE` writes the fingerprints; `--check FILE` recomputes them and
names the first record and field that differ (exit 1), so a change meant to be a pure speed-up
(issue 24: fixedla, the AKF, the step record) can be shown to be one.

    python benchmarks/check_episode_bits.py --save /tmp/before.json
    ... change the code ...
    python benchmarks/check_episode_bits.py --check /tmp/before.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import struct
import sys
from dataclasses import fields
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from rodctl.config import load_config  # noqa: E402
from rodctl.config.loading import ConfigError  # noqa: E402
from rodctl.env import ShapeServoEnv  # noqa: E402
from rodctl.episode import EpisodeFailed, run_episode  # noqa: E402
from rodctl.method import Method  # noqa: E402
from rodctl.training import prepare_feature  # noqa: E402

#: The configs checked: the default, a heavy rod, dual-arm, the events, the other methods.
CONFIGS = (
    "configs/default.yaml",
    "configs/heavy-rod.yaml",
    "configs/scenarios/dual-arm.yaml",
    "configs/scenarios/dual-arm-yu2023.yaml",
    "configs/hard-bend.yaml",
    "configs/s-shape.yaml",
    "configs/oracle.yaml",
    "configs/ma2022.yaml",
    "configs/yu2023.yaml",
    "configs/aghajanzadeh2022.yaml",
    "configs/fourier.yaml",
    "configs/camera-noise.yaml",
    "configs/event-stiffness.yaml",
    "configs/event-weight.yaml",
    "configs/event-clamp-move.yaml",
    "configs/event-grasp-slip.yaml",
    "configs/event-noise.yaml",
    "configs/event-occluder.yaml",
    "configs/event-camera-bump.yaml",
    "configs/table.yaml",
    "configs/scripted.yaml",
)

#: Summary values that are clocks, not results.
_TIMING = {"wall_time_s", "steps_per_s", "setup_time_s", "time_per_step_ms"}


def _feed(h: Any, value: Any) -> None:
    """Hash `value` exactly: its type, and its bytes (arrays, floats) or its repr."""
    if isinstance(value, np.ndarray):
        h.update(f"nd{value.dtype.str}{value.shape}".encode())
        h.update(np.ascontiguousarray(value).tobytes())
    elif isinstance(value, float | np.floating):
        h.update(b"f" + struct.pack("<d", float(value)))
    elif isinstance(value, dict):
        h.update(b"{")
        for k in sorted(value):
            h.update(repr(k).encode())
            _feed(h, value[k])
        h.update(b"}")
    elif isinstance(value, list | tuple):
        h.update(b"[")
        for v in value:
            _feed(h, v)
        h.update(b"]")
    else:
        h.update(f"{type(value).__name__}:{value!r}".encode())


def _digest(value: Any) -> str:
    h = hashlib.sha256()
    _feed(h, value)
    return h.hexdigest()[:20]


def fingerprint(path: str, engine: str) -> dict[str, Any]:
    """{"records": [{field: hash}], "summary": hash, "header": hash} of one episode."""
    sets = ["logging.mcap=false", "logging.rerun=false", "logging.figures=false"]
    try:
        cfg = load_config(path, [*sets, f"rod.engine={engine}"])
    except ConfigError as exc:  # e.g. the table with the quasi-static engine: refused
        return {"refused": _digest(str(exc)), "outcome": "refused by validation"}
    prepare_feature(cfg)  # a `checkpoint: auto` encoder, trained once and cached
    env, method = ShapeServoEnv(cfg), Method.from_config(cfg)
    try:
        result = run_episode(env, method, sinks=[], run_id="bits")
    except EpisodeFailed as exc:
        result = exc.result
    records = [
        {f.name: _digest(getattr(r, f.name)) for f in fields(r) if f.name != "image"}
        for r in result.records
    ]
    s = result.summary
    summary = {f.name: getattr(s, f.name) for f in fields(s) if f.name not in _TIMING}
    summary["extra"] = {k: v for k, v in s.extra.items() if k not in _TIMING}
    header = result.header
    head = (
        {f.name: getattr(header, f.name) for f in fields(header) if f.name != "numeric_env"}
        if header is not None
        else None
    )
    return {
        "records": records,
        "summary": _digest(summary),
        "header": _digest(head),
        "outcome": f"{s.outcome} after {s.steps} steps",
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = ap.add_mutually_exclusive_group(required=True)
    group.add_argument("--save", metavar="FILE")
    group.add_argument("--check", metavar="FILE")
    ap.add_argument("--configs", nargs="*", default=list(CONFIGS))
    args = ap.parse_args()
    got: dict[str, Any] = {}
    for path in args.configs:
        for engine in ("pymunk", "quasistatic"):
            key = f"{path} {engine}"
            got[key] = fingerprint(path, engine)
            print(f"{key}: {got[key]['outcome']}", flush=True)
    if args.save:
        with open(args.save, "w") as fh:
            json.dump(got, fh, indent=0)
        return 0
    with open(args.check) as fh:
        want = json.load(fh)
    bad = 0
    for key, fp in got.items():
        ref = want.get(key)
        if ref is None:
            print(f"{key}: not in {args.check}")
            bad += 1
            continue
        if fp == ref:
            continue
        bad += 1
        if "records" not in fp or "records" not in ref:
            print(f"{key}: {fp['outcome']}, expected {ref['outcome']}")
            continue
        if len(fp["records"]) != len(ref["records"]):
            print(f"{key}: {len(fp['records'])} records, expected {len(ref['records'])}")
        for k, (a, b) in enumerate(zip(fp["records"], ref["records"], strict=False)):
            diff = [name for name in a if a[name] != b.get(name)]
            if diff:
                print(f"{key}: record {k} differs in {diff}")
                break
        for part in ("summary", "header"):
            if fp[part] != ref[part]:
                print(f"{key}: the {part} differs")
    print("bit-identical" if not bad else f"{bad} episodes differ")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
