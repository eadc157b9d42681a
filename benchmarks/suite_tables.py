"""The tables of a results page from a finished suite run (results/*/README.md).

Reads the suite folder's results.csv and statistics.json (what `rodctl compare
configs/benchmarks/suite.yaml` writes) and prints, as Markdown: the steps-to-converge table
(the reference's success and median steps; every method's paired difference with its interval,
Holm-adjusted p and whether it replicated, and its success), the counts the findings quote
(significant and replicated tests, diagnoses of the reference's and the oracle's failures,
episodes that finished before an event, errors by scenario), and, given an earlier run's
statistics.json (`--before`), every pooled test whose verdict changed between the two.

    python benchmarks/suite_tables.py runs/20261202-181029_suite [--before old/statistics.json.gz]
        [--export results/NEW/]

`--export DIR` also writes what a results page ships: episodes.csv.gz (the columns of
`EPISODE_COLUMNS` for every episode) and statistics.json.gz.
"""

from __future__ import annotations

import argparse
import csv
import gzip
import io
import json
from collections import Counter, defaultdict
from pathlib import Path
from statistics import median
from typing import Any


def _load_json(path: Path) -> dict[str, Any]:
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as f:
        return json.load(f)


def statistics_path(folder: Path) -> Path:
    """A suite folder's statistics.json, or a results page's statistics.json.gz."""
    path = folder / "statistics.json"
    return path if path.is_file() else folder / "statistics.json.gz"


def load_statistics(folder: Path) -> dict[str, Any]:
    return _load_json(statistics_path(folder))


def _rows(folder: Path) -> list[dict[str, str]]:
    path = folder / "results.csv"
    if not path.is_file():
        path = folder / "episodes.csv.gz"
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt", newline="") as f:
        return list(csv.DictReader(f))


def _fmt_p(p: float) -> str:
    return format(p, ".2g")


def _cell(test: dict[str, Any] | None, success: str) -> str:
    """One method's cell: 'mean [low, high] (R), adj. p x (success)'."""
    if not test or not test.get("n"):
        return f"— ({success})"
    body = f"{test['mean']:+.2f} [{test['ci_low']:+.2f}, {test['ci_high']:+.2f}]"
    if test.get("p_adjusted") is None:
        return f"{body} ({success})"
    if test.get("significant"):
        body = f"**{body}**" + (" R" if test.get("replicated") else " not R")
    return f"{body}, adj. p {_fmt_p(test['p_adjusted'])} ({success})"


def _success(rows: list[dict[str, str]]) -> str:
    if not rows:
        return "0 %"
    return f"{100 * sum(r['outcome'] == 'converged' for r in rows) / len(rows):.0f} %"


#: The results pages' column order (methods not listed follow in the run's order).
ORDER = ("ma2022", "ma2022-wls", "broyden-mfac", "akf-pinv", "yu2023", "oracle", "aghajanzadeh2022")


def steps_table(stats: dict[str, Any], rows: list[dict[str, str]]) -> list[str]:
    ref = stats["reference"]
    by = defaultdict(list)
    for r in rows:
        by[r["scenario"], r["method"]].append(r)
    scenarios = list(stats["scenarios"])
    run = list(next(iter(stats["scenarios"].values()))["methods"])
    methods = [m for m in ORDER if m in run] + [m for m in run if m not in ORDER]
    head = f"| scenario | {ref}: success, median steps | " + " | ".join(
        f"{m} − {ref} (its success)" for m in methods
    )
    out = [head + " |", "|" + "---|" * (2 + len(methods))]
    for sc in scenarios:
        mine = by[sc, ref]
        conv = [int(r["steps_to_converge"]) for r in mine if r["outcome"] == "converged"]
        med = f"{median(conv):g}" if conv else "—"
        cells = [f"{_success(mine)}, {med}"]
        for m in methods:
            test = stats["scenarios"][sc]["methods"][m]["metrics"].get("steps_to_converge")
            cells.append(_cell(test, _success(by[sc, m])))
        out.append(f"| {sc} | " + " | ".join(cells) + " |")
    return out


def counts(stats: dict[str, Any], rows: list[dict[str, str]]) -> list[str]:
    corr = stats["correction"]
    findings = stats["findings"]
    rep = sum(f["replicated"] for f in findings)
    out = [
        f"pooled tests {corr['pooled_tests']}; significant {len(findings)}; replicated {rep}",
        "not replicated: "
        + "; ".join(
            f"{f['scenario']} {f['method']} {f['metric']} {f['mean']:+.2f}"
            for f in findings
            if not f["replicated"]
        ),
    ]
    ref = stats["reference"]
    for sc, s in stats["scenarios"].items():
        for m in (ref, "oracle"):
            d = {k: v for k, v in s["diagnosis"].get(m, {}).items() if v}
            fails = Counter(
                r["outcome"]
                for r in rows
                if r["scenario"] == sc and r["method"] == m and r["outcome"] != "converged"
            )
            if d or fails:
                out.append(f"{sc} {m}: outcomes {dict(fails)}; diagnoses {d}")
        before = {k: v for k, v in s.get("finished_before_event", {}).items() if v}
        if before:
            out.append(f"{sc}: finished before the event {before}")
    bad = ("error", "diverged")
    errors = Counter((r["scenario"], r["outcome"]) for r in rows if r["outcome"] in bad)
    out.append(f"error/diverged episodes: {dict(errors)}")
    return out


def changes(stats: dict[str, Any], before: dict[str, Any]) -> list[str]:
    """Pooled tests whose verdict (not significant / significant / replicated) changed."""

    def verdicts(s: dict[str, Any]) -> dict[tuple, tuple[str, float]]:
        out = {}
        for sc, v in s["scenarios"].items():
            for m, mv in v["methods"].items():
                for metric, t in mv["metrics"].items():
                    if t.get("p_adjusted") is None:
                        continue
                    kind = (
                        "replicated"
                        if t.get("significant") and t.get("replicated")
                        else "significant, not replicated"
                        if t.get("significant")
                        else "not significant"
                    )
                    out[sc, m, metric] = (kind, t["mean"])
        return out

    now, then = verdicts(stats), verdicts(before)
    lines = []
    for key in sorted(set(now) | set(then)):
        a, b = then.get(key), now.get(key)
        if a is None or b is None or a[0] != b[0] or (a[1] > 0) != (b[1] > 0):
            show = lambda v: "absent" if v is None else f"{v[0]} ({v[1]:+.2f})"  # noqa: E731
            lines.append(f"{' / '.join(key)}: {show(a)} -> {show(b)}")
    return lines


#: The columns of a results page's episodes.csv.gz: what recomputing its statistics needs.
EPISODE_COLUMNS = (
    "scenario", "seed", "method", "target", "band", "outcome", "steps", "steps_to_converge",
    "final_pixel_error", "probe_steps", "pose_steps", "smoothness_translation",
    "smoothness_rotation", "finished_before_event", "diagnosis",
)  # fmt: skip


def _gzip(path: Path, data: bytes) -> None:
    """Write `data` gzipped with no timestamp: the same bytes for the same run."""
    with open(path, "wb") as raw, gzip.GzipFile(fileobj=raw, mode="wb", mtime=0) as gz:
        gz.write(data)


def export(rows: list[dict[str, str]], stats_path: Path, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    text = io.StringIO()
    writer = csv.DictWriter(text, EPISODE_COLUMNS, extrasaction="ignore")
    writer.writeheader()
    writer.writerows(rows)
    _gzip(out / "episodes.csv.gz", text.getvalue().encode())
    data = stats_path.read_bytes()
    _gzip(out / "statistics.json.gz", gzip.decompress(data) if stats_path.suffix == ".gz" else data)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path, help="the suite's folder (results.csv, statistics.json)")
    ap.add_argument("--before", type=Path, help="an earlier run's statistics.json(.gz)")
    ap.add_argument("--export", type=Path, help="write episodes.csv.gz and statistics.json.gz here")
    args = ap.parse_args()
    stats_path = statistics_path(args.folder)
    stats = _load_json(stats_path)
    rows = _rows(args.folder)
    print("\n".join(steps_table(stats, rows)))
    print()
    print("\n".join(counts(stats, rows)))
    if args.export:
        export(rows, stats_path, args.export)
    if args.before:
        print()
        print("\n".join(changes(stats, _load_json(args.before))) or "no verdict changed")


if __name__ == "__main__":
    main()
