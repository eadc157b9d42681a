"""The summary statistics of a study's episodes: per method (compare, suite) and per group
(sweep), the quantiles they are built from, and the table they are read in.

Steps to converge, smoothness and path length are taken over converged episodes only: a run that
wanders until the step limit accumulates them without bound. The paired comparisons between
methods, with their tests, are `rodctl.bench.comparisons`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from rodctl.outcome import Outcome

#: Episode outcomes, in the order the summary lists them ("error": the episode raised); a
#: comparison's episodes are closed-loop (never "completed") and none counts as "interrupted".
OUTCOMES = tuple(o.value for o in Outcome if o not in (Outcome.COMPLETED, Outcome.INTERRUPTED))


def quantiles(values: Sequence[float]) -> tuple[float | None, float | None, float | None]:
    """(q25, median, q75) of the values, or Nones when there are none."""
    if not values:
        return None, None, None
    q = np.percentile(np.asarray(values, dtype=float), [25, 50, 75])
    return float(q[0]), float(q[1]), float(q[2])


def summarize(rows: Sequence[dict[str, Any]], methods: Sequence[str], bands: Sequence[str]) -> dict:
    """Per-method statistics over the episodes.

    Steps to converge are taken over converged episodes only; `paired_*` restricts them to the
    targets every method converged on, the fair basis for "who converges fastest". Smoothness
    (summed ||u_k - u_{k-1}||) and path length are over converged episodes too, since a run that
    wanders until the step limit accumulates both without bound.
    """
    by_target: dict[int, set[str]] = {}
    for r in rows:
        if r["outcome"] == "converged":
            by_target.setdefault(r["target"], set()).add(r["method"])
    common = {t for t, ms in by_target.items() if set(methods) <= ms}
    out: dict[str, Any] = {"common_targets": len(common), "methods": {}}
    for m in methods:
        mine = [r for r in rows if r["method"] == m]
        conv = [r for r in mine if r["outcome"] == "converged"]
        q25, med, q75 = quantiles([r["steps_to_converge"] for r in conv])
        p25, pmed, p75 = quantiles([r["steps_to_converge"] for r in conv if r["target"] in common])
        stats: dict[str, Any] = {
            "episodes": len(mine),
            "converged": len(conv),
            "success_rate": len(conv) / len(mine) if mine else None,
            "outcomes": {o: sum(r["outcome"] == o for r in mine) for o in OUTCOMES},
            "steps_median": med,
            "steps_q25": q25,
            "steps_q75": q75,
            "paired_steps_median": pmed,
            "paired_steps_q25": p25,
            "paired_steps_q75": p75,
            "smoothness_median": quantiles([r["smoothness"] for r in conv])[1],
            "path_length_median": quantiles([r["path_length"] for r in conv])[1],
            "final_pixel_error_median": quantiles(
                [r["final_pixel_error"] for r in mine if r.get("final_pixel_error") is not None]
            )[1],
            "bands": {},
        }
        for b in bands:
            rb = [r for r in mine if r["band"] == b]
            cb = [r for r in rb if r["outcome"] == "converged"]
            stats["bands"][b] = {
                "episodes": len(rb),
                "success_rate": len(cb) / len(rb) if rb else None,
                "steps_median": quantiles([r["steps_to_converge"] for r in cb])[1],
            }
        out["methods"][m] = stats
    return out


def fmt(v: Any, spec: str = ".0f") -> str:
    return "–" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, spec)


def fmt_steps(v: Any) -> str:
    """A median or quartile of step counts: whole numbers as such, else its fraction (6.5,
    23.75: quartiles of counts are quarters), not rounded to a whole step (`.0f` showed the
    median 6.5 as 6 and 7.5 as 8)."""
    text = fmt(v, ".2f")
    return text.rstrip("0").rstrip(".") if "." in text else text


def summary_rows(summary: dict, bands: Sequence[str]) -> tuple[list[str], list[list[str]]]:
    """The summary table as a header and string rows (shared by the terminal and summary.md).

    Band cells read "success % / median steps"; the last column counts stalled / pinned /
    step-limit / failed (diverged, lost the rod, raised) episodes.
    """
    header = [
        "method",
        "success",
        "steps [IQR]",
        "paired steps",
        "smooth.",
        "path m",
        "final px",
        *bands,
        "stall/pin/limit/fail",
    ]
    lines = []
    for m, s in summary["methods"].items():
        rate = s["success_rate"]
        o = s["outcomes"]
        lines.append(
            [
                m,
                f"{s['converged']}/{s['episodes']} ({fmt(None if rate is None else 100 * rate)}%)",
                f"{fmt_steps(s['steps_median'])} [{fmt_steps(s['steps_q25'])}-"
                f"{fmt_steps(s['steps_q75'])}]",
                f"{fmt_steps(s['paired_steps_median'])} [{fmt_steps(s['paired_steps_q25'])}-"
                f"{fmt_steps(s['paired_steps_q75'])}]",
                fmt(s["smoothness_median"], ".3f"),
                fmt(s["path_length_median"], ".3f"),
                fmt(s["final_pixel_error_median"], ".2f"),
                *[
                    f"{fmt(None if bs['success_rate'] is None else 100 * bs['success_rate'])}% / "
                    f"{fmt_steps(bs['steps_median'])}"
                    for bs in (s["bands"][b] for b in bands)
                ],
                f"{o['stalled']}/{o.get('pinned', 0)}/{o['step_limit']}/"
                f"{o['diverged'] + o['lost_tracking'] + o['error']}",
            ]
        )
    return header, lines


def band_names(edges: Sequence[float]) -> list[str]:
    """The names of the difficulty bands that `edges` make: easy / medium / hard for two edges,
    else band0..bandN (`CompareTarget.band`)."""
    n = len(edges) + 1
    return ["easy", "medium", "hard"] if n == 3 else [f"band{i}" for i in range(n)]
