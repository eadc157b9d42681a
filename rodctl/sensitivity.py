"""How far a sweep's result moves across each swept knob's range (`rodctl sweep`'s sensitivity).

A random search varies every knob at once, so one knob's effect is read by pooling over the
others: the sweep's points are put into quantile bins of the knob's value and the ranking metric
is averaged per bin. Per (method, knob, metric):

- **spread**: the largest minus the smallest bin mean (success rate in [0, 1], steps in steps):
  how far the result moves from the knob's worst part of its range to its best;
- **null95**: the 95th percentile of that spread when the metric's values are shuffled among the
  points (seeded permutations): the spread a knob that does nothing shows by chance with this many
  points. A spread above it says the knob matters; below it the data cannot tell;
- **spearman**: the rank correlation of the knob's value with the metric over the points (and its
  p-value), which says in which direction it moves (None when either is constant).

A list-valued knob (the seven MFAC weights, the QP's R diagonal) is read element by element,
`key[i]`; a knob whose values are neither numbers nor equal-length lists of numbers is a category
(one bin per value, no correlation). Points whose metric is undefined (mean steps when nothing
converged) are left out of that metric. Quantile bins use the values' ranks, so the result does
not depend on whether the knob was drawn on a log scale, and tied values share a bin.

`write_sensitivity` writes sensitivity.json into a sweep folder and returns the summary.md lines;
`rodctl/bench/sweep.py`'s report calls it.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import rankdata, spearmanr

from rodctl.runs import jsonable, write_json_atomic

#: Quantile bins per knob (a 65-point sweep: ~16 points a bin).
BINS = 4
#: Permutations of the metric for the chance spread.
PERMUTATIONS = 500


def knob_values(groups: list[dict[str, Any]], keys: list[str]) -> dict[str, list[Any]]:
    """Each knob's value per group, list-valued keys split into their elements (`key[i]`).

    A knob is numeric (floats) when every value is a number; a key whose values are all lists of
    numbers of one length gives one numeric knob per element; anything else stays as it is (a
    category). Knobs with a single value over all groups are dropped (nothing to read).
    """
    out: dict[str, list[Any]] = {}
    for key in keys:
        values: list[Any] = [g.get(key) for g in groups]
        if (
            values
            and all(_is_number_list(v) for v in values)
            and len({len(v) for v in values}) == 1
        ):
            for i in range(len(values[0])):
                out[f"{key}[{i}]"] = [float(v[i]) for v in values]
        elif all(_is_number(v) for v in values):
            out[key] = [float(v) for v in values]
        else:
            out[key] = values
    return {k: v for k, v in out.items() if len({json.dumps(jsonable(x)) for x in v}) > 1}


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _is_number_list(v: Any) -> bool:
    return isinstance(v, list | tuple) and bool(v) and all(_is_number(x) for x in v)


def quantile_bins(values: list[Any], bins: int = BINS) -> list[int]:
    """The bin (0 = lowest values) of each value: `bins` groups of near-equal size by rank, tied
    values in one bin; one bin per distinct value when there are at most `bins` of them.
    Categories (not numbers) get one bin per value, in order of first appearance."""
    if not all(_is_number(v) for v in values):
        labels = [json.dumps(jsonable(v)) for v in values]
        order = list(dict.fromkeys(labels))
        return [order.index(x) for x in labels]
    distinct = sorted(set(values))
    if len(distinct) <= bins:
        return [distinct.index(v) for v in values]
    ranks = rankdata(values, method="average")  # 1..n, ties share their mean rank
    n = len(values)
    return [min(bins - 1, int((r - 0.5) / n * bins)) for r in ranks]


def _spread(metric: np.ndarray, labels: np.ndarray, n_bins: int) -> float:
    """max - min of the bin means (bins with no point left out)."""
    sums = np.bincount(labels, weights=metric, minlength=n_bins)
    counts = np.bincount(labels, minlength=n_bins)
    means = sums[counts > 0] / counts[counts > 0]
    return float(means.max() - means.min())


def knob_sensitivity(
    values: list[Any], metric: list[float | None], *, bins: int = BINS, seed: int = 0
) -> dict[str, Any]:
    """The sensitivity of one metric to one knob (module docstring): bins, spread, chance
    spread (`null95`), Spearman's rho and its p-value."""
    kept = [(v, m) for v, m in zip(values, metric, strict=True) if _defined(m)]
    out: dict[str, Any] = {"n": len(kept), "bins": [], "spread": None, "null95": None}
    out.update(spearman=None, p=None)
    if len(kept) < 2:
        return out
    vals = [v for v, _ in kept]
    ys = np.array([float(m) for _, m in kept if m is not None])
    labels = np.array(quantile_bins(vals, bins))
    n_bins = int(labels.max()) + 1
    numeric = all(_is_number(v) for v in vals)
    for b in range(n_bins):
        mine = [i for i in range(len(vals)) if labels[i] == b]
        if not mine:
            continue
        row: dict[str, Any] = {"count": len(mine), "mean": float(ys[mine].mean())}
        if numeric:
            row.update(low=min(vals[i] for i in mine), high=max(vals[i] for i in mine))
        else:
            row["value"] = vals[mine[0]]
        out["bins"].append(row)
    if len(out["bins"]) < 2:
        return out
    out["spread"] = _spread(ys, labels, n_bins)
    gen = np.random.default_rng(seed)
    null = [_spread(gen.permutation(ys), labels, n_bins) for _ in range(PERMUTATIONS)]
    out["null95"] = float(np.quantile(null, 0.95))
    if numeric and np.ptp(ys) > 0 and len(set(vals)) > 1:
        res = spearmanr(vals, ys)
        out["spearman"], out["p"] = float(res.statistic), float(res.pvalue)
    return out


def _defined(m: Any) -> bool:
    return m is not None and not (isinstance(m, float) and math.isnan(m))


def sensitivity(
    ranked: list[dict[str, Any]], keys: list[str], metrics: list[str], *, bins: int = BINS
) -> dict[str, Any]:
    """Per method, each knob's sensitivity for each metric, and the chosen point.

    `ranked`: the sweep's groups best first (`rank_groups`), one per (point, method), each with
    the point's swept values and the metrics. The chosen point of a method is its first group:
    best by `metrics` in order, ties kept in point order (the sort is stable).
    """
    out: dict[str, Any] = {"objective": metrics, "bins": bins, "permutations": PERMUTATIONS}
    methods: dict[str, Any] = {}
    for name in dict.fromkeys(g["method"] for g in ranked):
        groups = sorted((g for g in ranked if g["method"] == name), key=lambda g: g["point"])
        knobs = knob_values(groups, keys)
        methods[name] = {
            "points": len(groups),
            "chosen": _point(min(groups, key=lambda g: g["rank"]), keys, metrics),
            "knobs": {
                knob: {
                    "low": _low_high(vals)[0],
                    "high": _low_high(vals)[1],
                    **{
                        m: knob_sensitivity(vals, [g.get(m) for g in groups], bins=bins, seed=j)
                        for j, m in enumerate(metrics)
                    },
                }
                for knob, vals in knobs.items()
            },
        }
    out["methods"] = methods
    return out


def _low_high(vals: list[Any]) -> tuple[Any, Any]:
    if all(_is_number(v) for v in vals):
        return min(vals), max(vals)
    return None, None


def _point(g: dict[str, Any], keys: list[str], metrics: list[str]) -> dict[str, Any]:
    return {"point": g["point"], **{k: g.get(k) for k in keys}, **{m: g.get(m) for m in metrics}}


def _num(v: Any, scale: float = 1.0, spec: str = ".3g") -> str:
    return "–" if not _defined(v) else format(v * scale, spec)


def markdown_lines(report: dict[str, Any]) -> list[str]:
    """The summary.md section: per method, one row per knob and a column pair per metric."""
    metrics = report["objective"]
    lines = [
        "## Sensitivity",
        "",
        f"Per knob: the points in {report['bins']} quantile bins of its value; **spread** = "
        "largest minus smallest bin mean of the metric (success rate in percentage points), "
        f"**chance** = the 95th percentile of the spread over {report['permutations']} "
        "shufflings of the metric among the points (a spread above it: the knob matters), "
        "rho = Spearman's rank correlation of knob and metric. Chosen: best by "
        f"{', '.join(metrics)} in order, ties in point order.",
        "",
    ]
    for name, m in report["methods"].items():
        chosen = m["chosen"]
        lines += [f"**{name}** ({m['points']} points; chosen: point {chosen['point']})", ""]
        header = ["knob", "range"]
        for metric in metrics:
            header += [f"{metric}: spread", "chance", "rho"]
        lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        for knob, k in m["knobs"].items():
            rng = "categories" if k["low"] is None else f"{k['low']:.3g}–{k['high']:.3g}"
            row = [knob, rng]
            for metric in metrics:
                s = k[metric]
                scale = 100.0 if metric == "success_rate" else 1.0
                spread = _num(s["spread"], scale)
                if _defined(s["spread"]) and _defined(s["null95"]) and s["spread"] > s["null95"]:
                    spread = f"**{spread}**"
                row += [spread, _num(s["null95"], scale), _num(s["spearman"], 1.0, "+.2f")]
            lines.append("| " + " | ".join(row) + " |")
        lines.append("")
    return lines


def write_sensitivity(
    folder: str | Path, ranked: list[dict[str, Any]], keys: list[str], metrics: list[str]
) -> list[str]:
    """Write `folder`/sensitivity.json; return the summary.md lines of the section."""
    report = sensitivity(ranked, keys, metrics)
    write_json_atomic(Path(folder) / "sensitivity.json", report)
    return markdown_lines(report)


def from_sweep_folder(folder: str | Path) -> list[str]:
    """Recompute sensitivity.json from a finished sweep's summary.json (its ranking); return the
    summary.md section's lines (for a sweep run before this module existed)."""
    summary = json.loads((Path(folder) / "summary.json").read_text(encoding="utf-8"))
    return write_sensitivity(folder, summary["ranking"], summary["parameters"], summary["rank_by"])


__all__ = [
    "from_sweep_folder",
    "knob_sensitivity",
    "knob_values",
    "markdown_lines",
    "quantile_bins",
    "sensitivity",
    "write_sensitivity",
]
