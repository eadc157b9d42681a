"""The paper's three figures (Figs. 1-3), drawn from step records alone.

Used by `rodctl simulate` (live records) and `rodctl replay` (records read back from the MCAP),
and for several methods by `rodctl compare`. matplotlib's object API with the Agg canvas is used
directly (no pyplot state), so figures can be drawn from worker processes.

One run: `shapes.png` (Fig. 1), `t1.png` (Fig. 2), `commands.png` (Fig. 3), probing steps shaded.
Several methods (`write_comparison_figures`): `shapes.png` side by side; `pixel_error.png`, every
method on one axis in the one unit all methods share (pixels; T1 is in each feature's own units,
~1 for the autoencoder against ~80 for Bezier control points, so T1 curves on one axis compare
units, not methods); `t1.png` as small multiples, one panel and one scale per method; and
`commands.png` (the pose increment Δr commanded each step, the speed limits dashed). Methods
differ by colour *and* line style and marker, so overlapping curves stay readable.

Legibility: matplotlib's constrained layout (no title overlaps another, no label is cut off),
150 dpi, log axes with several labelled ticks in plain numbers (`_log_axis`).
Speed: no `rc_context` (it re-validates every rcParam), few ticks, one artist for all transition
shapes, PNG zlib level 1 (`benchmarks/bench_plots.py` prints the time).
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, Locator, LogLocator, MaxNLocator, NullLocator

from rodctl.records import RunHeader, StepRecord

#: Shape-sequence colours, as in the paper: initial black, transitions blue, target red.
INITIAL, TRANSITION, TARGET = "black", "tab:blue", "tab:red"
AXES = ("Δx (m)", "Δy (m)", "Δθ (rad)")
PROBE_COLOR = "tab:purple"
#: Per-method styles: colour, line style and marker all differ between neighbours.
_COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:gray")
_LINES = ("-", "--", "-.", ":", (0, (5, 1, 1, 1, 1, 1)), (0, (1, 1)))
_MARKERS = ("o", "s", "^", "D", "v", "P", "X")
DPI = 150
FONT = 10  # matplotlib's default size, so no rc_context is needed


def style(i: int) -> dict:
    """Line style of the i-th method: distinct colour, dash pattern and marker."""
    return {
        "color": _COLORS[i % len(_COLORS)],
        "linestyle": _LINES[i % len(_LINES)],
        "marker": _MARKERS[i % len(_MARKERS)],
        "markersize": 3.5,
        "linewidth": 1.4,
    }


def _figure(w: float, h: float) -> Figure:
    """A figure with constrained layout: titles, labels and legends get the room they need."""
    fig = Figure(figsize=(w, h), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _title(ax: Axes, text: str, size: float = FONT) -> None:
    ax.set_title(text, fontsize=size)


def _headline(text: str, method: str, width_in: float, size: float = FONT + 1) -> str:
    """`text — method` on one line if it fits the figure's width, else the method on a second
    line (constrained layout makes room for a title's height, never for its width)."""
    one = f"{text} — {method}"
    # DejaVu Sans averages ~0.6 em a character; 90 % of the width is left for the title.
    return one if len(one) * 0.6 * size <= 0.9 * width_in * 72 else f"{text}\n{method}"


def _plain(value: float, _pos: object = None) -> str:
    """A log axis label as a plain number: 0.5, 2, 100, 1e-05."""
    return f"{value:g}"


def _log_axis(ax: Axes, values: np.ndarray) -> None:
    """A log y axis with several labelled ticks however few decades the data spans: labels
    at 1, 2, 5 per decade over a few decades, at linearly spaced values within one decade,
    at powers of ten only over many."""
    ax.set_yscale("log")
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v) & (v > 0)]
    decades = float(np.log10(v.max() / v.min())) if v.size else 0.0
    locator: Locator
    if decades > 4:
        locator = LogLocator(base=10, numticks=8)
    elif decades > 0.7:
        locator = LogLocator(base=10, subs=(1.0, 2.0, 5.0), numticks=12)
    else:
        locator = MaxNLocator(nbins=5)
    ax.yaxis.set_major_locator(locator)
    ax.yaxis.set_major_formatter(FuncFormatter(_plain))
    ax.yaxis.set_minor_locator(NullLocator())


def _ticks(ax: Axes, log_y: np.ndarray | None = None) -> None:
    """Few ticks: each one is several artists to build and draw (most of the drawing time).
    `log_y`: the values a log y axis shows (`_log_axis`)."""
    ax.xaxis.set_major_locator(MaxNLocator(nbins=6, integer=True))
    if log_y is not None:
        _log_axis(ax, log_y)
    else:
        ax.yaxis.set_major_locator(MaxNLocator(nbins=5))


def speed_limits(header: RunHeader, end: str = "gripper") -> np.ndarray | None:
    """(3,) the per-step limits on |Δx|, |Δy|, |Δθ| of one moved end from the run's config
    (`end`: "gripper", `rod.max_step`, or "x0", the second arm's `rod.clamp_arm.max_step`), or
    None when the config does not say (a synthetic run)."""
    try:
        rod = (yaml.safe_load(header.config_yaml) or {})["rod"]
        limits = rod["max_step"] if end == "gripper" else rod["clamp_arm"]["max_step"]
        out = np.asarray(limits, dtype=float).reshape(3)
    except (yaml.YAMLError, KeyError, TypeError, ValueError):
        return None
    return out if np.all(np.isfinite(out)) else None


#: savefig arguments; zlib level 1: a third of the default level's encoding time, files ~30 %
#: larger.
_SAVE: dict[str, Any] = {"dpi": DPI, "pil_kwargs": {"compress_level": 1}}

#: The file names of one run's figures, in the order `write_figures` returns them.
RUN_FIGURES = ("shapes.png", "t1.png", "commands.png")


def _save(fig: Figure, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fig.savefig(path, **_SAVE)
    except OSError as exc:
        if exc.filename is not None:
            raise
        # PIL reports a full disk without the file it was writing.
        raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from None
    return path


def _png(fig: Figure) -> bytes:
    """The figure as PNG bytes, the same bytes `_save` writes to a file."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", **_SAVE)
    return buf.getvalue()


def _probe_spans(records: Sequence[StepRecord]) -> list[tuple[int, int]]:
    """Contiguous runs of probing steps as (first, last) step numbers."""
    spans: list[tuple[int, int]] = []
    for r in records:
        if r.phase != "probe":
            continue
        if spans and spans[-1][1] == r.step - 1:
            spans[-1] = (spans[-1][0], int(r.step))
        else:
            spans.append((int(r.step), int(r.step)))
    return spans


def shade_probing(ax: Axes, spans: Sequence[tuple[int, int]], label: bool = True) -> None:
    """Shade the probing steps (each step spans ±0.5 around its number)."""
    for i, (a, b) in enumerate(spans):
        ax.axvspan(
            a - 0.5,
            b + 0.5,
            color=PROBE_COLOR,
            alpha=0.18,
            lw=0,
            label="probing" if label and i == 0 else None,
        )


def draw_shapes(
    ax: Axes,
    header: RunHeader,
    records: Sequence[StepRecord],
    every: int = 3,
    legend: bool = True,
) -> None:
    """Fig. 1: the extracted centerline every `every` frames, initial black -> blue -> target red.

    The target is a wide translucent red band under everything and the final shape a dashed
    dark-blue line on top, so a final shape lying on the target stays visible. Pixel coordinates
    with v pointing down, as the camera sees them.
    """
    ax.plot(*header.target_pixels.T, color=TARGET, lw=6.0, alpha=0.35, label="target", zorder=1)
    if records:
        mids = list(records)[every:-1:every]
        if mids:
            # One artist for every transition: NaN-separated segments.
            pts = np.concatenate(
                [np.vstack([r.extracted, [[np.nan, np.nan]]]) for r in mids], axis=0
            )
            ax.plot(*pts.T, color=TRANSITION, lw=0.7, alpha=0.45, zorder=2, label=f"every {every}")
        ax.plot(*records[0].extracted.T, color=INITIAL, lw=1.8, label="initial", zorder=3)
        ax.plot(*records[-1].extracted.T, color="navy", lw=1.6, ls="--", label="final", zorder=4)
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    ax.xaxis.set_major_locator(MaxNLocator(nbins=5))
    ax.yaxis.set_major_locator(MaxNLocator(nbins=5))
    ax.set_aspect("equal", adjustable="datalim")
    if not ax.yaxis_inverted():
        ax.invert_yaxis()
    if legend:
        ax.legend(loc="best", fontsize=FONT - 1, framealpha=0.8)


def _series(records: Sequence[StepRecord]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    steps = np.array([r.step for r in records], dtype=int)
    t1 = np.array([r.T1 for r in records], dtype=float)
    px = np.array([r.pixel_error for r in records], dtype=float)
    # the first end effector's dx, dy, dtheta (a two-end recording logs q = 6 values)
    u = np.array([np.asarray(r.u)[:3] for r in records], dtype=float).reshape(len(records), 3)
    return steps, t1, px, u


def _second_end(records: Sequence[StepRecord]) -> np.ndarray | None:
    """(K, 3) the second end's [dx, dy, dtheta] of a dual-arm run (q = 6), else None."""
    if not records or np.asarray(records[0].u).size != 6:
        return None
    return np.array([np.asarray(r.u)[3:6] for r in records], dtype=float).reshape(-1, 3)


def _log_safe(y: np.ndarray) -> np.ndarray:
    """Values for a log axis: non-positive ones hidden (NaN) rather than breaking the scale."""
    return np.where(y > 0, y, np.nan)


def write_figures(
    header: RunHeader, records: Sequence[StepRecord], out_dir: str | Path
) -> list[Path]:
    """Write shapes.png (Fig. 1), t1.png (Fig. 2) and commands.png (Fig. 3) under `out_dir`.

    (`rodctl.figure_worker`, which runs this module in its helper process, writes the same
    bytes with `save_figures`; this module does not import it back.)"""
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    paths = []
    for name, data in render_figures(header, records).items():
        paths.append(Path(out_dir) / name)
        paths[-1].write_bytes(data)
    return paths


def render_figures(header: RunHeader, records: Sequence[StepRecord]) -> dict[str, bytes]:
    """The three figures of one run as PNG bytes, by file name (`RUN_FIGURES`), written nowhere:
    `rodctl.figure_worker` draws them in a helper process and the command writes them
    (`rodctl.figure_worker.save_figures`)."""
    return RunFigures().render(header, records)


class RunFigures:
    """The three figures of one run, begun before the run is known: `RunFigures()` makes the
    figures and their axes, `render` (or `render_one` per figure) draws the run into them. The
    figure process makes them while it waits for the records. For one use: `render` once.
    (Drawing them empty first, and a warm-up figure, cost ~0.2 s of CPU during the episode for
    ~0.06 s less drawing: taken out, 2026-12-02, docs/engines.md.)
    """

    def __init__(self) -> None:
        self.shapes = _figure(5.6, 4.4)
        self.shapes_ax = self.shapes.subplots()
        self.t1 = _figure(6.4, 3.6)
        self.t1_ax = self.t1.subplots()
        # Fig. 3 of a one-arm run (a dual-arm run's has a second column: made in `render`).
        self.commands = _figure(6.4, 5.8)
        self.commands_grid = self.commands.subplots(3, 1, sharex=True, squeeze=False)

    def render(self, header: RunHeader, records: Sequence[StepRecord]) -> dict[str, bytes]:
        """The PNG bytes by file name (`render_figures`)."""
        return {name: self.render_one(name, header, records) for name in RUN_FIGURES}

    def render_one(self, name: str, header: RunHeader, records: Sequence[StepRecord]) -> bytes:
        """One figure's PNG bytes (`name` of `RUN_FIGURES`): the same bytes whichever figures
        were drawn before it, in this process or not (the figure process draws them in two)."""
        # No rc_context (it re-validates every rcParam: slow).
        if name == "shapes.png":
            fig, ax = self.shapes, self.shapes_ax
            draw_shapes(ax, header, records)
            _title(ax, _headline("Rod centerline every three frames", header.method, 5.6), FONT + 1)
            return _png(fig)
        if name == "t1.png":
            steps, t1, _px, _u = _series(records)
            fig, ax = self.t1, self.t1_ax
            shade_probing(ax, _probe_spans(records))
            ax.plot(steps, _log_safe(t1), color="tab:blue", marker="o", ms=3, lw=1.4, label="T1")
            ax.set_xlabel("step")
            ax.set_ylabel("T1 = ||s* − s|| (feature units)")
            _ticks(ax, log_y=t1)
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=FONT - 1)
            _title(ax, _headline("Deformation error T1", header.method, 6.4), FONT + 1)
            return _png(fig)
        if name == "commands.png":
            begun = (
                None if _second_end(records) is not None else (self.commands, self.commands_grid)
            )
            commands = _commands(
                {header.method: records}, speed_limits(header), speed_limits(header, "x0"), begun
            )
            return _png(commands)
        raise ValueError(f"no run figure {name!r} (one of {', '.join(RUN_FIGURES)})")


def _commands(
    runs: Mapping[str, Sequence[StepRecord]],
    limits: np.ndarray | None,
    x0_limits: np.ndarray | None = None,
    begun: tuple[Figure, Any] | None = None,
) -> Figure:
    """Fig. 3: the pose increment Δr = (Δx, Δy, Δθ) commanded each step (a displacement per
    step, applied over the step's duration), one panel per component, the speed limits
    ±`limits` dashed. Dual-arm (q = 6), a second column of panels for the x0 end, its own
    limits ±`x0_limits` dashed. With several methods the legend goes below the panels (inside,
    it would hide curves). `begun`: the figure and its (3, 1) axes, made already
    (`RunFigures`: one one-arm run)."""
    dual = any(_second_end(recs) is not None for recs in runs.values())
    single = len(runs) == 1
    if begun is not None and single and not dual:
        fig, grid = begun
    else:
        fig = _figure(9.6 if dual else 6.4, 5.8 if single else 6.4)
        grid = fig.subplots(3, 2 if dual else 1, sharex=True, squeeze=False)
    spans = sorted({s for recs in runs.values() for s in _probe_spans(recs)})
    for i, (name, recs) in enumerate(runs.items()):
        steps, _, _, u = _series(recs)
        other = _second_end(recs)
        for j in range(3):
            grid[j, 0].plot(steps, u[:, j], label=name, **style(0 if single else i))
            if dual and other is not None:
                grid[j, 1].plot(steps, other[:, j], label=name, **style(0 if single else i))
    ends = [(grid[:, 0], limits, "gripper")]
    if dual:
        ends.append((grid[:, 1], x0_limits, "x0 end (second arm)"))
    for column, (axes, lim, end) in enumerate(ends):
        if dual:
            _title(axes[0], end)
        for j, (ax, label) in enumerate(zip(axes, AXES, strict=True)):
            _command_panel(ax, spans, lim, j, label, legend_entries=column == 0 and j == 0)
        axes[-1].set_xlabel("step")
    if single:
        grid[0, 0].legend(fontsize=FONT - 1, loc="best")
    else:
        handles, labels = grid[0, 0].get_legend_handles_labels()
        fig.legend(
            handles, labels, loc="outside lower center", ncol=4, fontsize=FONT - 1, frameon=False
        )
    title = "Pose increment Δr commanded per step"  # the legend names the shading and limits
    if single:
        title = _headline(title, next(iter(runs)), 9.6 if dual else 6.4)
    fig.suptitle(title, fontsize=FONT + 1)
    return fig


def _command_panel(
    ax: Axes,
    spans: Sequence[tuple[int, int]],
    limits: np.ndarray | None,
    j: int,
    label: str,
    legend_entries: bool,
) -> None:
    """One component's panel of Fig. 3: probing shaded, the speed limit ±`limits[j]` dashed."""
    shade_probing(ax, spans, label=legend_entries)
    if limits is not None:
        for sign in (1.0, -1.0):
            ax.axhline(
                sign * limits[j],
                color="0.3",
                ls="--",
                lw=0.9,
                label="speed limit" if legend_entries and sign > 0 else None,
            )
    _ticks(ax)
    ax.set_ylabel(label)
    ax.grid(True, alpha=0.3)
    ax.axhline(0.0, color="black", lw=0.6)


def write_comparison_figures(
    runs: Mapping[str, tuple[RunHeader, Sequence[StepRecord]]], out_dir: str | Path
) -> list[Path]:
    """Figures of several methods on one target (see the module docstring):
    shapes.png, pixel_error.png, t1.png (small multiples) and commands.png."""
    out_dir = Path(out_dir)
    names = list(runs)
    n = len(names)
    if True:
        cols = min(n, 3)
        rows = -(-n // cols)
        fig = _figure(4.4 * cols, 3.9 * rows + 0.4)
        axes = fig.subplots(rows, cols, squeeze=False).ravel()
        for k, (ax, name) in enumerate(zip(axes, names, strict=False)):
            header, records = runs[name]
            draw_shapes(ax, header, records, legend=k == 0)
            _title(ax, name)
        for ax in axes[n:]:
            ax.set_visible(False)
        fig.suptitle("Rod centerline every three frames", fontsize=FONT + 2)
        paths = [_save(fig, out_dir / "shapes.png")]

        fig = _figure(7.2, 4.2)
        ax = fig.subplots()
        shown = []
        for i, name in enumerate(names):
            steps, _, px, _ = _series(runs[name][1])
            ax.plot(steps, _log_safe(px), label=name, **style(i))
            shown.append(px)
        ax.set_xlabel("step (probing included)")
        ax.set_ylabel("pixel error (px, log)")
        _ticks(ax, log_y=np.concatenate(shown))
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=FONT - 1, ncol=2)
        _title(ax, "Mean centerline distance to the target, every method", FONT + 1)
        paths.append(_save(fig, out_dir / "pixel_error.png"))

        fig = _figure(4.0 * cols, 2.8 * rows + 0.5)
        axes = fig.subplots(rows, cols, squeeze=False).ravel()
        for i, (ax, name) in enumerate(zip(axes, names, strict=False)):
            steps, t1, _, _ = _series(runs[name][1])
            shade_probing(ax, _probe_spans(runs[name][1]), label=i == 0)
            ax.plot(steps, _log_safe(t1), **style(i))
            _ticks(ax, log_y=t1)
            ax.grid(True, alpha=0.3)
            _title(ax, name)
            ax.set_xlabel("step")
        for ax in axes[n:]:
            ax.set_visible(False)
        fig.suptitle(
            "T1 = ||s* − s|| per method (each in its own feature's units)", fontsize=FONT + 1
        )
        paths.append(_save(fig, out_dir / "t1.png"))

        base = runs[names[0]][0]  # the methods share the base's rod
        commands = _commands(
            {m: runs[m][1] for m in names}, speed_limits(base), speed_limits(base, "x0")
        )
        paths.append(_save(commands, out_dir / "commands.png"))
    return paths
