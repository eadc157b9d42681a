"""rodctl/sensitivity.py: a knob that moves the objective is told from one that does not, list
knobs are read element by element, ties share a bin, and the chosen point is the ranking's first."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rodctl.bench.sweep import rank_groups
from rodctl.sensitivity import (
    from_sweep_folder,
    knob_sensitivity,
    knob_values,
    quantile_bins,
    sensitivity,
)


def _synthetic(n: int = 64, seed: int = 3) -> list[dict]:
    """A random search where mean steps = 20 + 10 a (+ noise), b does nothing, the weight
    vector's element 0 halves the success rate above 0.5 and element 1 does nothing."""
    gen = np.random.default_rng(seed)
    groups = []
    for i in range(n):
        a, b = float(gen.uniform(0, 1)), float(np.exp(gen.uniform(0, np.log(1e4))))
        w = [float(gen.uniform(0, 1)), float(gen.uniform(0, 1))]
        groups.append(
            {
                "point": i,
                "method": "m",
                "a": a,
                "b": b,
                "w": w,
                "success_rate": 1.0 if w[0] < 0.5 else 0.5,
                "steps_mean": 20.0 + 10.0 * a + float(gen.normal(0, 0.5)),
            }
        )
    return rank_groups(groups, ["success_rate", "steps_mean"])


def test_the_knob_that_matters_stands_out_and_the_one_that_does_not_stays_under_chance():
    ranked = _synthetic()
    rep = sensitivity(ranked, ["a", "b", "w"], ["success_rate", "steps_mean"])
    knobs = rep["methods"]["m"]["knobs"]
    assert set(knobs) == {"a", "b", "w[0]", "w[1]"}
    a, b = knobs["a"]["steps_mean"], knobs["b"]["steps_mean"]
    # 4 quantile bins of a uniform a: bin means ~ 20 + 10 * (1/8, ..., 7/8): spread ~7.5 steps
    assert a["spread"] == pytest.approx(7.5, abs=1.0) and a["spread"] > a["null95"]
    assert a["spearman"] > 0.9 and a["p"] < 1e-6
    assert b["spread"] < b["null95"] and abs(b["spearman"]) < 0.3
    assert [row["count"] for row in a["bins"]] == [16, 16, 16, 16]
    assert a["bins"][0]["low"] == knobs["a"]["low"] == min(g["a"] for g in ranked)
    # success: element 0 of the list moves it by 50 points, element 1 does not
    w0, w1 = knobs["w[0]"]["success_rate"], knobs["w[1]"]["success_rate"]
    assert w0["spread"] == pytest.approx(0.5) and w0["spearman"] < -0.8
    assert w1["spread"] < w1["null95"]
    # the chosen point is the ranking's first: full success, then fewest mean steps
    full = [g for g in ranked if g["success_rate"] == 1.0]
    assert (
        rep["methods"]["m"]["chosen"]["point"] == min(full, key=lambda g: g["steps_mean"])["point"]
    )


def test_constant_or_undefined_metrics_and_ties():
    assert quantile_bins([1, 1, 1, 2, 2, 3, 3, 3, 4, 5, 6, 7]) == [
        0,
        0,
        0,
        1,
        1,
        2,
        2,
        2,
        2,
        3,
        3,
        3,
    ]
    assert quantile_bins([5, 3, 5]) == [1, 0, 1]  # few distinct values: one bin each
    assert quantile_bins([[1, 2], "x", [1, 2]]) == [0, 1, 0]  # categories
    flat = knob_sensitivity([0.1, 0.2, 0.3, 0.4, 0.5, 0.6], [1.0] * 6)
    assert flat["spread"] == 0.0 and flat["spearman"] is None
    # points whose metric is undefined (nothing converged) are left out of it
    some = knob_sensitivity([1.0, 2.0, 3.0, 4.0], [None, 10.0, float("nan"), 12.0])
    assert some["n"] == 2 and some["spread"] == 2.0
    # a knob with one value has nothing to read and is dropped
    assert set(knob_values([{"k": 1.0, "c": 2}, {"k": 2.0, "c": 2}], ["k", "c"])) == {"k"}


def test_recomputed_from_a_sweep_folder(tmp_path):
    ranked = _synthetic(n=20)
    summary = {"ranking": ranked, "parameters": ["a", "b"], "rank_by": ["steps_mean"]}
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    lines = from_sweep_folder(tmp_path)
    got = json.loads((tmp_path / "sensitivity.json").read_text())
    assert got == json.loads(json.dumps(sensitivity(ranked, ["a", "b"], ["steps_mean"])))
    assert lines[0] == "## Sensitivity" and any(line.startswith("| a | ") for line in lines)
