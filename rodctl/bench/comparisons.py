"""Paired comparisons of methods against a reference: what a plain compare and a suite test.

One test is method − reference on one metric over the targets both converged on (paired by
target set and target), Holm-adjusted over its family (rodctl.statistics: docs/statistics.md);
a suite pools several target seeds and calls a significant finding replicated when every seed
agrees in direction. `write_compare_report` writes a plain compare's statistics.json and
report.html; a suite's are written by rodctl.bench.suite from the same pieces.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeGuard

from rodctl.report import markdown_table, verdict_lines, write_report_html
from rodctl.runs import write_json_atomic
from rodctl.statistics import PairedDifference, adjust, paired_difference

#: Metrics compared paired by target: (column, label, unit, which episodes count).
#: `excess_steps` (steps − pose_steps) and `event_steps_to_converge` (steps − the event's step)
#: are not tested: pose_steps and the event's step are the same for every method on a target,
#: so their paired differences are those of `steps_to_converge`, the same test counted again
#: (it would inflate the Holm family and list one finding two or three times). results.csv
#: keeps both columns.
PAIRED_METRICS = (
    ("steps_to_converge", "steps to converge", "steps"),
    ("near_origin_steps", "final approach (below 2x tolerance to converged)", "steps"),
    ("smoothness_translation", "smoothness, translation", "speed limits"),
    ("smoothness_rotation", "smoothness, rotation", "speed limits"),
    ("event_peak_error", "peak error after the event", "px"),
)


def present_metrics(rows: Sequence[dict[str, Any]]) -> tuple[tuple[str, str, str], ...]:
    """The paired metrics some episode of `rows` has a value for (the event metrics only
    where an event happened)."""
    return tuple(m for m in PAIRED_METRICS if any(r.get(m[0]) is not None for r in rows))


#: Significance level of every claim, after Holm's correction (rodctl.statistics).
ALPHA = 0.05


def seeds_of(rows: Sequence[dict[str, Any]]) -> list[Any]:
    """The target seeds of `rows`, in numeric order."""
    return sorted({r.get("seed") for r in rows}, key=lambda s: (s is None, s or 0))


def pair_key(row: dict[str, Any]) -> tuple[Any, int]:
    """What pairs two methods' episodes: the same target of the same target set (seed)."""
    return (row.get("seed"), row["target"])


def _usable(row: dict[str, Any] | None) -> TypeGuard[dict[str, Any]]:
    """An episode that counts in the paired comparisons: it exists and, in a scenario with a
    mid-run event, the event reached it (one that ended first is reported apart)."""
    return row is not None and not row.get("finished_before_event")


def _paired_raw(
    rows: Sequence[dict[str, Any]],
    methods: Sequence[str],
    reference: str,
    metrics: Sequence[tuple[str, str, str]],
) -> dict[str, dict[str, PairedDifference]]:
    by = {(r["method"], pair_key(r)): r for r in rows}
    targets = sorted({pair_key(r) for r in rows}, key=lambda k: (k[0] is None, k[0] or 0, k[1]))

    def value(method: str, t: tuple, col: str) -> float | None:
        r = by.get((method, t))
        if not _usable(r) or r.get("outcome") != "converged":
            return None
        v = r.get(col)
        # A non-finite value carries no difference (inf - inf is NaN, which would make every
        # Holm-adjusted p of the family 1).
        return None if v is None or not math.isfinite(float(v)) else float(v)

    out: dict[str, dict[str, PairedDifference]] = {}
    for m in methods:
        if m == reference:
            continue
        out[m] = {
            col: paired_difference(
                [value(m, t, col) for t in targets], [value(reference, t, col) for t in targets]
            )
            for col, _, _ in metrics
        }
    return out


def success_pairs(
    rows: Sequence[dict[str, Any]], method: str, reference: str
) -> tuple[int, int, int]:
    """(targets only the method converged on, both, only the reference), over the targets
    whose episodes of both methods the event reached (all targets when there is no event)."""
    by = {(r["method"], pair_key(r)): r for r in rows}
    conv = {k for k, r in by.items() if r.get("outcome") == "converged"}
    targets = [
        t
        for t in {pair_key(r) for r in rows}
        if _usable(by.get((method, t))) and _usable(by.get((reference, t)))
    ]
    only_m = sum((method, t) in conv and (reference, t) not in conv for t in targets)
    both = sum((method, t) in conv and (reference, t) in conv for t in targets)
    only_r = sum((method, t) not in conv and (reference, t) in conv for t in targets)
    return only_m, both, only_r


@dataclass
class Comparison:
    """One test of a suite: method - reference on one metric in one scenario, pooled over the
    seeds and on each seed alone."""

    scenario: str
    method: str
    metric: str
    label: str
    unit: str
    pooled: PairedDifference
    per_seed: dict[int, PairedDifference]

    @property
    def significant(self) -> bool:
        return self.pooled.significant(ALPHA)

    @property
    def disagreeing_seeds(self) -> list[int]:
        """The seeds whose mean difference does not have the pooled one's sign (or none)."""
        want = self.pooled.direction
        return [s for s, d in self.per_seed.items() if d.direction != want]

    @property
    def replicated(self) -> bool:
        """Significant pooled, after correction, and every one of >= 2 seeds agrees in sign."""
        return self.significant and len(self.per_seed) >= 2 and not self.disagreeing_seeds

    @property
    def verdict(self) -> str:
        if not self.significant:
            return "not significant"
        if self.replicated:
            return "replicated"
        if len(self.per_seed) < 2:
            return "not replicated (one seed)"
        seeds = ", ".join(str(s) for s in self.disagreeing_seeds)
        return f"not replicated (seed {seeds} disagrees in direction)"


def suite_comparisons(
    rows: Sequence[dict[str, Any]], methods: Sequence[str], reference: str, scenarios: Sequence[str]
) -> list[Comparison]:
    """Every comparison of the suite, pooled and per seed, Holm-adjusted.

    Two kinds of family: the pooled tests of every scenario, method and metric (the ones a
    finding rests on) are one family; the tests of one seed alone are another (what a suite
    run on that seed only would report). One seed: the pooled test is that seed's.
    """
    seeds = seeds_of(rows)
    out: list[Comparison] = []
    for name in scenarios:
        mine = [r for r in rows if r["scenario"] == name]
        metrics = present_metrics(mine)
        pooled = _paired_raw(mine, methods, reference, metrics)
        if len(seeds) > 1:
            per = {
                s: _paired_raw([r for r in mine if r.get("seed") == s], methods, reference, metrics)
                for s in seeds
            }
        else:
            per = {s: pooled for s in seeds}
        for m, cells in pooled.items():
            for col, label, unit in metrics:
                out.append(
                    Comparison(
                        name, m, col, label, unit, cells[col], {s: per[s][m][col] for s in seeds}
                    )
                )
    for d, c in zip(adjust([c.pooled for c in out]), out, strict=True):
        c.pooled = d
    for s in seeds:
        family = adjust([c.per_seed[s] for c in out])
        for d, c in zip(family, out, strict=True):
            c.per_seed[s] = c.pooled if len(seeds) == 1 else d
    return out


def difference_json(d: PairedDifference) -> dict[str, Any]:
    return vars(d) | {"significant": d.significant(ALPHA)}


#: What the paired tables of a plain compare show (its summary.md).
PAIRED_NOTE = (
    "Paired differences are *method minus reference* over the targets both converged on: "
    "the mean, its BCa bootstrap 95 % confidence interval, the raw Wilcoxon signed-rank p, the "
    "p adjusted by Holm's correction over every test of this compare (*adj.*) and "
    "wins/ties/losses (lower is better for every metric). **bold**: significant after "
    f"correction (adjusted p < {ALPHA} and the interval excludes 0). Method: docs/statistics.md."
)


def paired_statistics(
    rows: Sequence[dict[str, Any]], methods: Sequence[str], ref: str
) -> tuple[list[str], dict[str, Any]]:
    """Every method against `ref` on the episodes of one plain compare: the summary.md lines (a
    verdict per method, then the paired table) and statistics.json (for every method but the
    reference, each paired metric's difference with raw and Holm-adjusted p, and `success`:
    `success_pairs`). The tests of the compare are one family, as a suite's pooled tests are."""
    name = "compare"
    tagged = [{**r, "scenario": name} for r in rows]
    comparisons = suite_comparisons(tagged, methods, ref, [name])
    paired = {
        m: {c.metric: c.pooled for c in comparisons if c.method == m} for m in methods if m != ref
    }
    md = verdict_lines(ref, paired) + paired_markdown(
        tagged, methods, ref, comparisons, seeds_of(tagged), family="this compare's tests"
    )
    stats = {
        m: {col: difference_json(d) for col, d in per.items()}
        | {"success": success_pairs(tagged, m, ref)}
        for m, per in paired.items()
    }
    return md, stats


def paired_markdown(
    rows: Sequence[dict[str, Any]],
    methods: Sequence[str],
    ref: str,
    comparisons: Sequence[Comparison],
    seeds: Sequence[Any],
    family: str = "the suite",
) -> list[str]:
    """The paired table; `family`: what the p-values were adjusted over ("the suite", or a plain
    compare's own tests, where replication across seeds does not apply)."""
    suite = family == "the suite"

    metrics = list(dict.fromkeys((c.metric, c.label) for c in comparisons))
    by = {(c.method, c.metric): c for c in comparisons}
    header = ["method", "converged only / both / only ref"] + [lbl for _, lbl in metrics]
    lines = []
    for m in methods:
        if m == ref:
            continue
        om, both, orf = success_pairs(rows, m, ref)
        cells = [m, f"{om} / {both} / {orf}"]
        for col, _ in metrics:
            c = by[(m, col)]
            text = c.pooled.describe(c.unit)
            verdict = f"; {c.verdict}" if suite else ""
            cells.append(f"**{text}**{verdict}" if c.significant else text)
        lines.append(cells)
    pooled = "pooled over the seeds, " if len(seeds) > 1 else ""
    out = [f"Paired against **{ref}** ({pooled}Holm-adjusted over {family}):", ""]
    out += [markdown_table(header, lines), ""]
    if len(seeds) < 2:
        return out
    header = ["method", "seed"] + [lbl for _, lbl in metrics]
    lines = []
    for m in methods:
        if m == ref:
            continue
        for s in seeds:
            cells = [m, str(s)]
            for col, _ in metrics:
                d = by[(m, col)].per_seed[s]
                text = d.describe(by[(m, col)].unit)
                cells.append(f"**{text}**" if d.significant(ALPHA) else text)
            lines.append(cells)
    out += ["Per seed (each seed's tests Holm-adjusted as one family):", ""]
    return [*out, markdown_table(header, lines), ""]


def write_compare_report(folder: Path, cfg: Any, rows: Sequence[dict[str, Any]]) -> None:
    """A plain compare's statistics.json and report.html, and its summary.md's paired section.

    statistics.json has the shape of one scenario's entry in a suite's: for every method but the
    reference, each paired metric's difference (`rodctl.statistics.PairedDifference` as a
    mapping) and `success` (targets only the method / both / only the reference converged on).
    """
    methods = list(cfg.methods)
    md_path = folder / "summary.md"
    md = md_path.read_text(encoding="utf-8").rstrip("\n").split("\n")
    if len(methods) > 1:
        paired_md, stats = paired_statistics(rows, methods, cfg.reference_method)
        # After the summary table, before the methods' descriptions: read at a glance.
        at = md.index("## Methods") if "## Methods" in md else len(md)
        md[at:at] = ["## Paired against the reference", "", PAIRED_NOTE, "", *paired_md]
    else:
        stats = {}
    text = "\n".join(md).rstrip("\n") + "\n"
    md_path.write_text(text, encoding="utf-8")
    write_json_atomic(folder / "statistics.json", stats)
    write_report_html(folder / "report.html", f"rodctl compare {cfg.name}", text, [(None, folder)])
