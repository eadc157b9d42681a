"""The paper's three figures (Figs. 1-3), drawn from step records alone.

Used by `rodctl simulate` (live records) and `rodctl replay` (records read back from the MCAP),
and for several methods by `rodctl compare`. matplotlib's object API with the Agg canvas is used
directly (no pyplot state), so figures can be drawn from worker processes.

One run: `shapes.png` (Fig. 1), `t1.png` (Fig. 2), `commands.png` (Fig. 3), probing steps shaded.
Several methods (`write_comparison_figures`): `shapes.png` side by side; `pixel_error.png`, every
method on one axis in the one unit all methods share (pixels; T1 is in each feature's own units,
~1 for the autoencoder against ~80 for Bezier control points, so T1 curves on one axis compare
units, not methods); `t1.png` as small multiples, one panel and one scale per method; and
`commands.png`. Methods differ by colour *and* line style and marker, so overlapping curves stay
readable.

Speed: fixed margins instead of matplotlib's constrained layout, no `rc_context` (it re-validates
every rcParam), few ticks, plain-text titles, one artist for all transition shapes, 100 dpi, PNG
zlib level 1: the three figures of a run cost about half the CPU time they did (0.55-0.7 s
against 1.2-1.3 s on the shared 2-core machine, `benchmarks/bench_plots.py`).
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import LogLocator, MaxNLocator, NullLocator

from rodctl.records import RunHeader, StepRecord

#: Shape-sequence colours, as in the paper: initial black, transitions blue, target red.
INITIAL, TRANSITION, TARGET = "black", "tab:blue", "tab:red"
AXES = ("Δr_x (m)", "Δr_y (m)", "Δr_θ (rad)")
PROBE_COLOR = "tab:purple"
#: Per-method styles: colour, line style and marker all differ between neighbours.
_COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:gray")
_LINES = ("-", "--", "-.", ":", (0, (5, 1, 1, 1, 1, 1)), (0, (1, 1)))
_MARKERS = ("o", "s", "^", "D", "v", "P", "X")
DPI = 100
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


def _figure(w: float, h: float, **margins: float) -> Figure:
    fig = Figure(figsize=(w, h), dpi=DPI)
    FigureCanvasAgg(fig)
    box = {"left": 0.1, "right": 0.97, "bottom": 0.12, "top": 0.88, "hspace": 0.35, "wspace": 0.3}
    box.update(margins)
    fig.subplots_adjust(**box)
    return fig


def _title(ax: Axes, text: str, size: float = FONT) -> None:
    """An axes title as plain text: `Axes.set_title` re-measures every tick label to place it,
    which cost more than the rest of a small figure."""
    ax.text(0.5, 1.02, text, transform=ax.transAxes, ha="center", va="bottom", fontsize=size)


def _ticks(ax: Axes, log_y: bool = False) -> None:
    """Few ticks: each one is several artists to build and draw (most of the drawing time)."""
    ax.xaxis.set_major_locator(MaxNLocator(nbins=6, integer=True))
    if log_y:
        ax.set_yscale("log")
        ax.yaxis.set_major_locator(LogLocator(numticks=5))
        ax.yaxis.set_minor_locator(NullLocator())
    else:
        ax.yaxis.set_major_locator(MaxNLocator(nbins=5))


#: savefig arguments; zlib level 1: a third of the default level's encoding time, files ~30 %
#: larger.
_SAVE = {"dpi": DPI, "pil_kwargs": {"compress_level": 1}}

#: The file names of one run's figures, in the order `write_figures` returns them.
RUN_FIGURES = ("shapes.png", "t1.png", "commands.png")


def _save(fig: Figure, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, **_SAVE)
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


def draw_shapes(ax: Axes, header: RunHeader, records: Sequence[StepRecord], every: int = 3) -> None:
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
    ax.legend(loc="best", fontsize=FONT - 1, framealpha=0.8)


def _series(records: Sequence[StepRecord]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    steps = np.array([r.step for r in records], dtype=int)
    t1 = np.array([r.T1 for r in records], dtype=float)
    px = np.array([r.pixel_error for r in records], dtype=float)
    # the first end effector's dx, dy, dtheta (a two-end recording logs q = 6 values)
    u = np.array([np.asarray(r.u)[:3] for r in records], dtype=float).reshape(len(records), 3)
    return steps, t1, px, u


def _log_safe(y: np.ndarray) -> np.ndarray:
    """Values for a log axis: non-positive ones hidden (NaN) rather than breaking the scale."""
    return np.where(y > 0, y, np.nan)


def warm_up() -> None:
    """Draw a tiny throw-away figure with what the run's figures use (lines, markers, a log
    axis, a shaded span, a legend, text): the first drawing of a process loads fonts and fills
    caches, which makes the run's first `render_figures` ~0.15 s slower. The figure process
    does this while it waits for the run."""
    fig = _figure(2.0, 2.0)
    ax = fig.subplots()
    ax.plot([1, 2, 3], [1.0, 10.0, 100.0], marker="o", label="warm-up")
    _ticks(ax, log_y=True)
    shade_probing(ax, [(1, 2)])
    ax.legend(fontsize=FONT - 1)
    _title(ax, "Δr_θ (rad)", FONT + 1)
    _png(fig)


def write_figures(
    header: RunHeader, records: Sequence[StepRecord], out_dir: str | Path
) -> list[Path]:
    """Write shapes.png (Fig. 1), t1.png (Fig. 2) and commands.png (Fig. 3) under `out_dir`."""
    from rodctl.figure_worker import save_figures

    return save_figures(render_figures(header, records), out_dir)


def render_figures(header: RunHeader, records: Sequence[StepRecord]) -> dict[str, bytes]:
    """The three figures of one run as PNG bytes, by file name (`RUN_FIGURES`), written nowhere:
    `rodctl.figure_worker` draws them in a helper process and the command writes them
    (`rodctl.figure_worker.save_figures`)."""
    if True:  # one block per figure group; no rc_context (it re-validates every rcParam: slow)
        fig = _figure(5.6, 4.4, left=0.13, bottom=0.12, top=0.9)
        ax = fig.subplots()
        draw_shapes(ax, header, records)
        _title(ax, f"Rod centerline every three frames — {header.method}", FONT + 1)
        pngs = {"shapes.png": _png(fig)}

        steps, t1, px, u = _series(records)
        spans = _probe_spans(records)
        fig = _figure(6.4, 3.6, left=0.11)
        ax = fig.subplots()
        shade_probing(ax, spans)
        ax.plot(steps, _log_safe(t1), color="tab:blue", marker="o", ms=3, lw=1.4, label="T1")
        ax.set_xlabel("step")
        ax.set_ylabel("T1 = ||s* − s|| (feature units)")
        _ticks(ax, log_y=True)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=FONT - 1)
        _title(ax, f"Deformation error T1 — {header.method}", FONT + 1)
        pngs["t1.png"] = _png(fig)

        pngs["commands.png"] = _png(_commands({header.method: records}))
    return pngs


def _commands(runs: Mapping[str, Sequence[StepRecord]]) -> Figure:
    """Fig. 3; with several methods, the legend goes above the axes (it would hide curves)."""
    top = 0.92 if len(runs) == 1 else 0.84
    fig = _figure(6.4, 5.6, left=0.14, top=top, bottom=0.08, hspace=0.15)
    axes = fig.subplots(3, 1, sharex=True)
    spans = sorted({s for recs in runs.values() for s in _probe_spans(recs)})
    single = len(runs) == 1
    for i, (name, recs) in enumerate(runs.items()):
        steps, _, _, u = _series(recs)
        st = style(0 if single else i)
        if single:
            st["marker"] = "o"
        for j, ax in enumerate(axes):
            ax.plot(steps, u[:, j], label=name, **st)
    for j, (ax, label) in enumerate(zip(axes, AXES, strict=True)):
        shade_probing(ax, spans, label=j == 0)
        _ticks(ax)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
        ax.axhline(0.0, color="black", lw=0.6)
    axes[-1].set_xlabel("step")
    if single:
        axes[0].legend(fontsize=FONT - 1, loc="best")
    else:
        handles, labels = axes[0].get_legend_handles_labels()
        fig.legend(
            handles,
            labels,
            loc="upper center",
            bbox_to_anchor=(0.55, 0.955),
            ncol=4,
            fontsize=FONT - 1,
            frameon=False,
        )
    fig.suptitle("Velocity command Δr (probing shaded)", fontsize=FONT + 1)
    return fig


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
        fig = _figure(4.4 * cols, 3.9 * rows + 0.4, left=0.08, right=0.98, top=0.9, wspace=0.25)
        axes = fig.subplots(rows, cols, squeeze=False).ravel()
        for ax, name in zip(axes, names, strict=False):
            header, records = runs[name]
            draw_shapes(ax, header, records)
            _title(ax, name)
        for ax in axes[n:]:
            ax.set_visible(False)
        fig.suptitle("Rod centerline every three frames", fontsize=FONT + 2)
        paths = [_save(fig, out_dir / "shapes.png")]

        fig = _figure(7.2, 4.2, left=0.1, right=0.97)
        ax = fig.subplots()
        for i, name in enumerate(names):
            steps, _, px, _ = _series(runs[name][1])
            ax.plot(steps, _log_safe(px), label=name, **style(i))
        ax.set_xlabel("step (probing included)")
        ax.set_ylabel("pixel error (px, log)")
        _ticks(ax, log_y=True)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=FONT - 1, ncol=2)
        _title(ax, "Mean centerline distance to the target, every method", FONT + 1)
        paths.append(_save(fig, out_dir / "pixel_error.png"))

        fig = _figure(4.0 * cols, 2.8 * rows + 0.5, left=0.08, right=0.98, top=0.88, hspace=0.5)
        axes = fig.subplots(rows, cols, squeeze=False).ravel()
        for i, (ax, name) in enumerate(zip(axes, names, strict=False)):
            steps, t1, _, _ = _series(runs[name][1])
            shade_probing(ax, _probe_spans(runs[name][1]), label=i == 0)
            ax.plot(steps, _log_safe(t1), **style(i))
            _ticks(ax, log_y=True)
            ax.grid(True, alpha=0.3)
            _title(ax, name)
            ax.set_xlabel("step")
        for ax in axes[n:]:
            ax.set_visible(False)
        fig.suptitle(
            "T1 = ||s* − s|| per method (each in its own feature's units)", fontsize=FONT + 1
        )
        paths.append(_save(fig, out_dir / "t1.png"))

        paths.append(_save(_commands({m: runs[m][1] for m in names}), out_dir / "commands.png"))
    return paths
