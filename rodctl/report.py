"""report.html for every compare and every suite: the summary, a verdict per comparison, figures.

A plain `rodctl compare` and a suite write the same kind of report: summary.md rendered as HTML
(markdown-it-py, the CommonMark parser rich already depends on, with GitHub's pipe tables), a
one-line verdict for each method against the reference (the paired difference in steps to
converge with its confidence interval, and whether it is significant), the paired tables, then
the figures. The statistics are `rodctl.statistics` and `rodctl.bench.comparisons`; this
module only renders them.

Figures come in reading order (`FIGURES`: the overview across targets first, then the one
target drawn side by side, from the error every method shares to the commands), each captioned
with the target it shows. They are embedded (the page opens from disk with no network and can
be mailed alone), shown at their natural size up to the page's width, and each is a link to its
PNG file beside the report, which opens it at full size.
"""

from __future__ import annotations

import base64
import html
import json
import os
from collections.abc import Sequence
from pathlib import Path

from rodctl.statistics import PairedDifference

#: The figures of a compare folder, in the order the report shows them, with their captions
#: (`{target}` names the target drawn). Files not listed follow, alphabetically.
FIGURES = (
    (
        "success_vs_difficulty.png",
        "Success rate and median steps to converge against target difficulty, every target.",
    ),
    (
        "pixel_error.png",
        "Mean centerline distance to {target}, every method on one axis (pixels: the one unit "
        "all methods share).",
    ),
    (
        "shapes.png",
        "The rod's centerline every three frames on the way to {target}, one panel per method.",
    ),
    (
        "t1.png",
        "Deformation error T1 on {target}, one panel per method, each in its own feature's units.",
    ),
    (
        "commands.png",
        "Pose increment Δr commanded on {target}, every method; dashed: the speed limits.",
    ),
)

#: The metric a verdict is about: the first one the paired tables show.
VERDICT_METRIC = ("steps_to_converge", "steps")

_MINUS = "\u2212"


def markdown_table(header: Sequence[str], lines: Sequence[Sequence[str]]) -> str:
    """A GitHub-flavoured markdown table."""
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(line) + " |" for line in lines]
    return "\n".join(out)


def render_markdown(text: str) -> str:
    """CommonMark with pipe tables as HTML; raw HTML in the text is escaped, not passed on."""
    from markdown_it import MarkdownIt

    return MarkdownIt("commonmark", {"html": False}).enable("table").render(text)


def _signed(v: float, spec: str = ".1f") -> str:
    return format(v, "+" + spec).replace("-", _MINUS)


def verdict(method: str, ref: str, d: PairedDifference, unit: str = "steps") -> str:
    """One line: e.g. "ma2022 −1.0 steps [−3.5, +0.9], not significant (p = 0.41, 24 paired
    targets)": the mean paired difference against `ref` and its 95 % interval. Lower is better
    for every paired metric."""
    if d.n == 0 or d.mean is None:
        return f"{method}: no target that both it and {ref} converged on, nothing to compare"
    assert d.ci_low is not None and d.ci_high is not None  # set with the mean (statistics.py)
    head = f"{method} {_signed(d.mean)} {unit} [{_signed(d.ci_low)}, {_signed(d.ci_high)}]"
    n = f"{d.n} paired target{'s' if d.n != 1 else ''}"
    if d.p_value is None:
        # rodctl.statistics: fewer than 6 non-zero differences cannot reach p < 0.05.
        return f"{head}, not significant ({n}, {d.wins + d.losses} differing: too few to test)"
    # Significance is read on the Holm-adjusted p (rodctl.statistics); the raw p is shown beside.
    adj = d.p_value if d.p_adjusted is None else d.p_adjusted
    p = f"p = {adj:.2g} adjusted, raw {d.p_value:.2g}, {n}"
    if d.significant():
        return f"{head}, significant ({p})"
    return f"{head}, not significant ({p})"


def verdict_lines(ref: str, paired: dict[str, dict[str, PairedDifference]]) -> list[str]:
    """The verdicts (`VERDICT_METRIC`) as a markdown list, one line per method, introduced by
    what they measure."""
    if not paired:
        return []
    metric, unit = VERDICT_METRIC
    lines = [
        f"Verdict, steps to converge against **{ref}** (method minus reference on the targets "
        "both converged on: mean [bootstrap 95 % interval]):",
        "",
    ]
    # A metric no episode has a value for (no episode converged) is not in the table at all.
    none = PairedDifference(0, None, None, None, None, 0, 0, 0)
    lines += [f"- {verdict(m, ref, per.get(metric, none), unit)}" for m, per in paired.items()]
    return lines + [""]


# --- figures ----------------------------------------------------------------------------------


def describe_target(folder: Path) -> str:
    """What the side-by-side figures of a compare folder show, from its results.json, e.g.
    "target 3 (difficulty 0.41, gripper at x 0.512 m, y 0.030 m, θ +0.10 rad)"."""
    try:
        data = json.loads((folder / "results.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return "the figure target"
    index = data.get("figure_target")
    target = next((t for t in data.get("targets", []) if t.get("index") == index), None)
    if target is None:
        return "the figure target"
    x, y, th = target["pose"][:3]
    other = ""
    if len(target["pose"]) == 6:  # dual-arm: the x0 end's pose too
        cx, cy, cth = target["pose"][3:]
        other = f"; x0 end at x {cx:.3f} m, y {cy:.3f} m, θ {cth:+.2f} rad"
    return (
        f"target {index} (difficulty {target['difficulty']:.2f}, gripper at x {x:.3f} m, "
        f"y {y:.3f} m, θ {th:+.2f} rad{other})"
    )


def ordered_figures(figures: Path) -> list[tuple[Path, str]]:
    """The PNGs of a figures/ folder in reading order, each with its caption template."""
    known = dict(FIGURES)
    present = {p.name: p for p in figures.glob("*.png")} if figures.is_dir() else {}
    out = [(present[name], caption) for name, caption in FIGURES if name in present]
    out += [
        (p, p.stem.replace("_", " ")) for name, p in sorted(present.items()) if name not in known
    ]
    return out


def _figure_html(path: Path, caption: str, report_dir: Path) -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    href = Path(os.path.relpath(path, report_dir)).as_posix()
    alt = html.escape(path.stem.replace("_", " "))
    return (
        f'<figure><a href="{html.escape(href)}" title="open at full size">'
        f'<img alt="{alt}" src="data:image/png;base64,{data}"></a>'
        f"<figcaption>{html.escape(caption)}</figcaption></figure>"
    )


# --- the page ---------------------------------------------------------------------------------

_CSS = """
body { font-family: system-ui, sans-serif; max-width: 1400px; margin: 2em auto; padding: 0 1em;
       color: #222; line-height: 1.45; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.9em; display: block;
        overflow-x: auto; max-width: 100%; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.5em; text-align: right; white-space: nowrap; }
th:first-child, td:first-child { text-align: left; }
code { background: #f3f3f3; padding: 0 0.2em; }
figure { margin: 1.5em 0; }
figure img { display: block; max-width: 100%; height: auto; border: 1px solid #e4e4e4; }
figure a { cursor: zoom-in; }
figcaption { font-size: 0.9em; color: #444; margin-top: 0.3em; }
"""


def write_report_html(
    path: Path, title: str, markdown: str, figure_sets: Sequence[tuple[str | None, Path]]
) -> Path:
    """One HTML file that opens from disk with no network: `markdown` rendered, then for each
    (heading, compare folder) of `figure_sets` the folder's figures in reading order."""
    body = [render_markdown(markdown)]
    for heading, folder in figure_sets:
        figures = ordered_figures(folder / "figures")
        if not figures:
            continue
        target = describe_target(folder)
        body.append(f"<h2>Figures{': ' + html.escape(heading) if heading else ''}</h2>")
        for fig, caption in figures:
            text = caption.format(target=target)
            if heading:
                text = f"{heading}: {text}"
            body.append(_figure_html(fig, text, path.parent))
    page = (
        '<!doctype html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{html.escape(title)}</title>\n<style>{_CSS}</style></head><body>\n"
        + "\n".join(body)
        + "\n</body></html>\n"
    )
    path.write_text(page, encoding="utf-8")
    return path
