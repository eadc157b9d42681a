"""The quasi-static engine's snaps against the code they replaced, on real snap steps (issue 24:
the snaps dominated data collection and the suite's hard-targets scenario).

Collects, in the runs that produce them, the state at the start of every control step whose
continuation failed a try (the state, the multipliers, the end poses before and after, the
tangent predictor's columns): `train-encoder` collection walks (`collect_chunk`) on the default
rod, the heavy rod, the s-shape config and the dual-arm rod, and episodes of the suite's
hard-targets scenario (its targets and the suite's methods, `rodctl compare` in this process).
Then runs, from each state, the step as it is now (`QuasiStaticChain._solve_to`) and as it was
before the continuation's tries after a failure were made to give up early
(`rodctl/sim/flow_reference.py`, `reference_solve_to`, with the same flow), and prints: how often
both end at the same equilibrium (largest joint distance <= 1e-6 L; also <= 1e-9 L and exactly),
with the same number of snaps, and what each cost before the flow, in the flow and in all (CPU
time in this process).

`--flows` compares instead, from the start state of every gradient flow, the current flow with
the flow it replaced (`reference_flow`; where it stops unconverged, again with
`--reference-cap` steps; where it does not converge at all, the flow integrated finely,
`accurate_flow`, is the judge).

    .venv/bin/python benchmarks/bench_snap.py [--walks 3] [--samples 1500] [--hard-targets 5]
        [--flows] [--save STATES.npz] [--states STATES.npz]

`--save` writes the collected states (an .npz of arrays; tests/sim/data/snap_states.npz holds a
few flow states for `tests/sim/test_snap_flow.py`); `--states` reads such a file instead of
collecting.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import yaml  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from rodctl.sim.flow_reference import (  # noqa: E402
    accurate_flow,
    reference_flow,
    reference_solve_to,
)
from rodctl.sim.quasistatic import QuasiStaticChain  # noqa: E402

#: Same equilibrium: the largest joint distance at most this fraction of L.
SAME = 1e-6
#: The continuation's failing tries before a snap's flow: at least this many times less CPU.
GOAL = 5.0
CONFIGS = (
    "configs/default.yaml",
    "configs/heavy-rod.yaml",
    "configs/s-shape.yaml",
    "configs/scenarios/dual-arm-yu2023.yaml",  # both ends move (rod.arms: 2)
)
#: The chain's constructor arguments a state records.
PARAMS = ("length", "bending_stiffness", "mass_per_length", "segments", "gravity", "clamp_pose")


def capture(run: Any) -> list[dict[str, Any]]:
    """The start state of every flow while `run()` runs (the flow itself runs as shipped)."""
    states: list[dict[str, Any]] = []
    flow = QuasiStaticChain._flow

    def recording(self: QuasiStaticChain, theta, lam, grip, clamp):  # noqa: ANN001, ANN202
        state = {p: np.asarray(getattr(self, p), dtype=float) for p in PARAMS}
        state.update(theta=theta.copy(), lam=lam.copy(), grip=grip.copy(), clamp=clamp.copy())
        state["gripped"] = np.asarray(self.gripped)
        states.append(state)
        return flow(self, theta, lam, grip, clamp)

    QuasiStaticChain._flow = recording  # type: ignore[method-assign]
    try:
        run()
    finally:
        QuasiStaticChain._flow = flow  # type: ignore[method-assign]
    return states


def capture_steps(run: Any) -> list[dict[str, Any]]:
    """The start state of every control step whose continuation failed a try (it snapped, or
    went on after a halved sub-step) while `run()` runs (the steps themselves run as
    shipped)."""
    states: list[dict[str, Any]] = []
    solve, patience = QuasiStaticChain._solve_to, QuasiStaticChain._patience
    tries = [0]

    def counting(self, *args):  # noqa: ANN001, ANN002, ANN202
        tries[0] += 1
        return patience(self, *args)

    def recording(self: QuasiStaticChain, grip, clamp):  # noqa: ANN001, ANN202
        state = {p: np.asarray(getattr(self, p), dtype=float) for p in PARAMS}
        state.update(
            gripped=np.asarray(self.gripped),
            theta=self.theta.copy(),
            lam=self.lam.copy(),
            grip0=self._grip.copy(),
            clamp0=self._clamp.copy(),
            straight=np.asarray(self._maybe_straight),
            grip=grip.copy(),
            clamp=clamp.copy(),
        )
        tangent = self.__dict__.get("_tangent")
        if tangent is not None and tangent[0] is self.theta and tangent[1] == self._model().key:
            (s, aw, cols) = tangent[2]
            state.update(tan_s=np.array(s), tan_aw=np.array(aw), tan_cols=np.array(cols))
        tries[0], snaps = 0, self.snaps
        ok = solve(self, grip, clamp)
        if tries[0] > 1 or self.snaps > snaps:
            states.append(state)
        return ok

    QuasiStaticChain._solve_to = recording  # type: ignore[method-assign]
    QuasiStaticChain._patience = counting  # type: ignore[method-assign]
    try:
        run()
    finally:
        QuasiStaticChain._solve_to = solve  # type: ignore[method-assign]
        QuasiStaticChain._patience = patience  # type: ignore[method-assign]
    return states


def walk_states(walks: int, samples: int, capture: Any = capture) -> list[dict[str, Any]]:
    from rodctl.config import load_config  # noqa: PLC0415
    from rodctl.training.collection import collect_chunk  # noqa: PLC0415

    states = []
    for path in CONFIGS:
        cfg = load_config(REPO / path, ["rod.engine=quasistatic"]).model_dump_json()
        for seed in range(walks):
            got = capture(lambda: collect_chunk(cfg, samples, np.random.SeedSequence(seed)))  # noqa: B023
            for s in got:
                s["source"] = f"walk {path} seed {seed}"
            states += got
    return states


def hard_target_states(targets: int, capture: Any = capture) -> list[dict[str, Any]]:
    from rodctl.bench.compare import run_compare  # noqa: PLC0415

    suite = yaml.safe_load((REPO / "configs/benchmarks/suite.yaml").read_text())
    base = dict(suite["base"], logging={"mcap": False, "rerun": False, "figures": False})
    cfg = {
        "name": "snap-hard-targets",
        "seed": 0,
        "base": base,
        "methods": suite["methods"],
        "targets": dict(suite["scenarios"]["hard-targets"]["targets"], count=targets),
        "workers": 1,
    }
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "hard.yaml"
        path.write_text(yaml.safe_dump(cfg, sort_keys=False))
        run = lambda: run_compare(str(path), [], tmp, progress=False, workers=1)  # noqa: E731
        states = capture(run)
    for s in states:
        s["source"] = "hard-targets episode"
    return states


def chain_of(state: dict[str, Any]) -> QuasiStaticChain:
    kwargs = {p: state[p] for p in PARAMS}
    kwargs["segments"] = int(state["segments"])
    kwargs["gravity"] = tuple(state["gravity"].tolist())
    kwargs["gripped"] = bool(state["gripped"])
    return QuasiStaticChain(**kwargs)


def chain_at(state: dict[str, Any]) -> QuasiStaticChain:
    """A chain in the state a control step started from (`capture_steps`)."""
    chain = chain_of(state)
    chain.theta, chain.lam = state["theta"].copy(), state["lam"].copy()
    chain._grip, chain._clamp = state["grip0"].copy(), state["clamp0"].copy()
    chain._maybe_straight = bool(state["straight"])
    if "tan_s" in state:
        left = (tuple(state["tan_s"].tolist()), tuple(state["tan_aw"].tolist()))
        chain._tangent = (chain.theta, chain._model().key, (*left, state["tan_cols"].copy()))
    return chain


def compare_step(state: dict[str, Any]) -> dict[str, Any]:
    """The step as it was and as it is, from one state: where each ends, and its cost."""
    out: dict[str, Any] = {}
    ends = []
    for name, solve in (("ref", reference_solve_to), ("new", QuasiStaticChain._solve_to)):
        chain = chain_at(state)
        flow, in_flow = chain._flow, [0.0]

        def timed(*args, _flow=flow, _in=in_flow):  # noqa: ANN002, ANN202
            t0 = time.process_time()
            try:
                return _flow(*args)
            finally:
                _in[0] += time.process_time() - t0

        chain._flow = timed  # type: ignore[method-assign]
        t0 = time.process_time()
        ok = solve(chain, state["grip"].copy(), state["clamp"].copy())
        cpu = time.process_time() - t0
        ends.append(chain._points(chain.theta, chain._clamp))
        out.update(
            {
                f"{name}_ok": ok,
                f"{name}_snaps": chain.snaps,
                f"{name}_cpu": cpu,
                f"{name}_flow_cpu": in_flow[0],
                f"{name}_newton": chain.newton_iterations,
                f"{name}_theta": chain.theta,
            }
        )
    out["distance"] = float(np.max(np.abs(ends[0] - ends[1]))) / float(state["length"])
    out["exact"] = out["ref_theta"].tobytes() == out["new_theta"].tobytes()
    return out


def report_steps(rows: list[dict[str, Any]]) -> None:
    """Print how the steps compare (`compare_step`)."""
    n = len(rows)
    snapped = [r for r in rows if r["ref_snaps"]]
    dist = np.array([r["distance"] for r in rows])
    print(
        f"{n} step states ({sum('walk' in r['source'] for r in rows)} from walks): "
        f"{len(snapped)} snapped as before ({sum(r['ref_snaps'] for r in rows)} snaps), "
        f"{n - len(snapped)} went on after a halved sub-step"
    )
    print(
        f"same equilibrium at the end of the step (<= {SAME:g} L): {int(np.sum(dist <= SAME))} "
        f"of {n}; <= 1e-9 L: {int(np.sum(dist <= 1e-9))}; bit-identical angles: "
        f"{sum(r['exact'] for r in rows)}; largest distance {dist.max():.2e} L; the same "
        f"number of snaps: {sum(r['ref_snaps'] == r['new_snaps'] for r in rows)} of {n}; the "
        f"same converged flag: {sum(r['ref_ok'] == r['new_ok'] for r in rows)} of {n}"
    )
    for label, part in (
        ("before the flow", lambda r, k: r[f"{k}_cpu"] - r[f"{k}_flow_cpu"]),
        ("in the flow", lambda r, k: r[f"{k}_flow_cpu"]),
        ("the whole step", lambda r, k: r[f"{k}_cpu"]),
    ):
        for group, sel in (("snapping steps", snapped), ("all steps", rows)):
            if not sel or (label == "in the flow" and group == "all steps"):
                continue
            ref = 1e3 * np.array([part(r, "ref") for r in sel])
            new = 1e3 * np.array([part(r, "new") for r in sel])
            ratio = ref.sum() / max(new.sum(), 1e-9)
            goal = ""
            if label == "before the flow" and group == "snapping steps":
                goal = f"   (goal >= {GOAL:g}x: {'met' if ratio >= GOAL else 'NOT met'})"
            print(
                f"CPU ms {label:<16} {group:<15} before: median {np.median(ref):7.2f} total "
                f"{ref.sum():9.1f}; now: median {np.median(new):7.2f} total {new.sum():8.1f}; "
                f"ratio of totals {ratio:5.1f}x{goal}"
            )
    newton = [(r["ref_newton"], r["new_newton"]) for r in snapped]
    if newton:
        print(
            "Newton iterations a snapping step, median: before "
            f"{np.median([a for a, _ in newton]):.0f}, now {np.median([b for _, b in newton]):.0f}"
        )
    for r in rows:
        if r["distance"] > SAME or r["ref_snaps"] != r["new_snaps"] or r["ref_ok"] != r["new_ok"]:
            keep = ("source", "distance", "ref_snaps", "new_snaps", "ref_ok", "new_ok")
            print(f"  DIFFERENT: { {k: r[k] for k in keep} }")


def compare(state: dict[str, Any], reference_cap: int) -> dict[str, Any]:
    """Both flows from one state: their ends, how far apart, and their cost."""
    args = (state["theta"], state["lam"], state["grip"], state["clamp"])
    ref_chain = chain_of(state)
    t0 = time.process_time()
    ref = reference_flow(ref_chain, *(a.copy() for a in args))
    ref_cpu = time.process_time() - t0
    capped = not ref[2]
    if capped:
        theta, lam, grip, clamp = (a.copy() for a in args)
        ref = reference_flow(chain_of(state), theta, lam, grip, clamp, max_steps=reference_cap)
    judge = "previous flow"
    if not ref[2]:  # it does not converge at all: integrate the flow finely instead
        judge = "fine flow"
        ref = accurate_flow(chain_of(state), *(a.copy() for a in args))
    new_chain = chain_of(state)
    t0 = time.process_time()
    new = new_chain._flow(*(a.copy() for a in args))
    new_cpu = time.process_time() - t0
    clamp = state["clamp"]
    ends = (new_chain._points(ref[0], clamp), new_chain._points(new[0], clamp))
    start = new_chain._points(state["theta"], clamp)
    return {
        "distance": float(np.max(np.abs(ends[0] - ends[1]))) / new_chain.length,
        "moved": float(np.max(np.abs(ends[1] - start))) / new_chain.length,
        "ref_converged": ref[2],
        "ref_capped": capped,
        "judge": judge,
        "new_converged": new[2],
        "new_stable": new[2] and new_chain.stable(new[0], new[1], state["grip"], clamp),
        "ref_solves": ref[3],
        "new_solves": new_chain.flow_steps + new_chain.newton_iterations,
        "ref_cpu": ref_cpu,
        "new_cpu": new_cpu,
    }


def save(path: str, states: list[dict[str, Any]]) -> None:
    arrays: dict[str, Any] = {
        f"{i}/{k}": np.asarray(v) for i, s in enumerate(states) for k, v in s.items()
    }
    np.savez_compressed(path, **arrays)


def load(path: str) -> list[dict[str, Any]]:
    with np.load(path) as npz:
        by_case: dict[int, dict[str, Any]] = {}
        for key in npz.files:
            i, name = key.split("/", 1)
            by_case.setdefault(int(i), {})[name] = npz[key]
    for s in by_case.values():
        s["source"] = str(s.get("source", "stored"))
    return [by_case[i] for i in sorted(by_case)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--walks", type=int, default=3, help="collection walks per config")
    ap.add_argument("--samples", type=int, default=1500, help="shapes per walk")
    ap.add_argument("--hard-targets", type=int, default=5, help="targets x the suite's methods")
    ap.add_argument("--flows", action="store_true", help="compare the flows, not the steps")
    ap.add_argument("--reference-cap", type=int, default=100_000)
    ap.add_argument("--save", help="write the collected states to this .npz")
    ap.add_argument("--states", help="read the states from this .npz instead of collecting")
    args = ap.parse_args()
    print(f"load average before: {os.getloadavg()}")
    how = capture if args.flows else capture_steps
    if args.states:
        states = load(args.states)
    else:
        states = walk_states(args.walks, args.samples, how)
        states += hard_target_states(args.hard_targets, how)
    if args.save:
        save(args.save, states)
    if not states:
        print("no state collected")
        return
    if args.flows:
        rows = [dict(compare(s, args.reference_cap), source=s["source"]) for s in states]
        report_flows(rows, args.reference_cap)
    else:
        report_steps([dict(compare_step(s), source=s["source"]) for s in states])
    print(f"load average after: {os.getloadavg()}")


def report_flows(rows: list[dict[str, Any]], reference_cap: int) -> None:
    """Print how the flows compare (`compare`)."""
    n = len(rows)
    dist = np.array([r["distance"] for r in rows])
    same = int(np.sum(dist <= SAME))
    print(f"{n} flow start states ({sum('walk' in r['source'] for r in rows)} from walks)")
    print(
        f"same equilibrium (<= {SAME:g} L): {same} of {n}; <= 1e-9 L: {int(np.sum(dist <= 1e-9))}"
        f"; largest distance {dist.max():.2e} L; median rod motion in the flow "
        f"{np.median([r['moved'] for r in rows]):.3f} L"
    )
    capped = sum(r["ref_capped"] for r in rows)
    fine = [r for r in rows if r["judge"] == "fine flow"]
    print(
        f"previous flow: {capped} of {n} stopped unconverged (its 4,000-step cap, or its τ "
        f"collapsed); with {reference_cap} steps {capped - len(fine)} of them converged; "
        f"the other {len(fine)} were judged by the flow integrated finely (τ <= 4/k), which "
        f"converged on {sum(r['ref_converged'] for r in fine)}. Current flow: "
        f"{sum(r['new_stable'] for r in rows)} of {n} converged to a stable state"
    )
    for key, label in (("solves", "KKT solves a flow"), ("cpu", "CPU ms a flow")):
        ref = np.array([r[f"ref_{key}"] for r in rows], dtype=float)
        new = np.array([r[f"new_{key}"] for r in rows], dtype=float)
        scale = 1e3 if key == "cpu" else 1.0
        print(
            f"{label:<18} previous (as shipped, capped): median {scale * np.median(ref):8.1f}  "
            f"total {scale * ref.sum():10.1f}; current: median {scale * np.median(new):7.1f}  "
            f"total {scale * new.sum():8.1f}; ratio of totals {ref.sum() / new.sum():5.1f}x"
        )
    for r in rows:
        if r["distance"] > SAME or not r["new_stable"]:
            print(f"  DIFFERENT: {r}")


if __name__ == "__main__":
    main()
