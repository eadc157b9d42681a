"""The paper's three figures (Figs. 1-3), drawn from step records alone.

Used by `rodctl simulate` (live records) and `rodctl replay` (records read back from the MCAP),
and side by side for several methods by `rodctl compare`. matplotlib's object API with the Agg
canvas is used directly (no pyplot state), so figures can be drawn from worker processes.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from rodctl.records import RunHeader, StepRecord

#: Shape-sequence colours, as in the paper: initial black, transitions blue, target red.
INITIAL, TRANSITION, TARGET = "black", "tab:blue", "tab:red"
AXES = ("Δr_x (m)", "Δr_y (m)", "Δr_θ (rad)")


def _save(fig: Figure, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=120)
    return path


def draw_shapes(ax, header: RunHeader, records: Sequence[StepRecord], every: int = 3) -> None:
    """Fig. 1: the extracted centerline every `every` frames, initial black -> blue -> target red.

    Pixel coordinates with v pointing down, as the camera sees them.
    """
    if records:
        for rec in list(records)[every::every]:
            ax.plot(*rec.extracted.T, color=TRANSITION, lw=0.8, alpha=0.6)
        ax.plot(*records[0].extracted.T, color=INITIAL, lw=2.0, label="initial")
        ax.plot(*records[-1].extracted.T, color=TRANSITION, lw=1.6, label="final")
    ax.plot(*header.target_pixels.T, color=TARGET, lw=2.0, label="target")
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    ax.set_aspect("equal", adjustable="datalim")
    if not ax.yaxis_inverted():
        ax.invert_yaxis()
    ax.legend(loc="best", fontsize=8)


def _series(records: Sequence[StepRecord]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    steps = np.array([r.step for r in records], dtype=int)
    t1 = np.array([r.T1 for r in records], dtype=float)
    u = np.array([r.u for r in records], dtype=float).reshape(len(records), 3)
    return steps, t1, u


def write_figures(
    header: RunHeader, records: Sequence[StepRecord], out_dir: str | Path
) -> list[Path]:
    """Write shapes.png (Fig. 1), t1.png (Fig. 2) and commands.png (Fig. 3) under `out_dir`."""
    return write_comparison_figures({header.method: (header, records)}, out_dir)


def write_comparison_figures(
    runs: Mapping[str, tuple[RunHeader, Sequence[StepRecord]]], out_dir: str | Path
) -> list[Path]:
    """The three figures with one column (Fig. 1) or one curve (Figs. 2, 3) per method."""
    out_dir = Path(out_dir)
    names = list(runs)
    n = len(names)

    cols = min(n, 3)
    rows = -(-n // cols)
    fig = Figure(figsize=(4.2 * cols, 3.8 * rows), layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    for ax, name in zip(axes, names, strict=False):
        header, records = runs[name]
        draw_shapes(ax, header, records)
        ax.set_title(name)
    for ax in axes[n:]:
        ax.set_visible(False)
    fig.suptitle("Rod centerline every three frames")
    paths = [_save(fig, out_dir / "shapes.png")]

    fig = Figure(figsize=(6.4, 3.6), layout="constrained")
    ax = fig.subplots()
    for name in names:
        steps, t1, _ = _series(runs[name][1])
        ax.plot(steps, t1, label=name)
    ax.set_xlabel("step")
    ax.set_ylabel("T1 = ||s* − s||")
    ax.set_yscale("log")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.suptitle("Deformation error T1")
    paths.append(_save(fig, out_dir / "t1.png"))

    fig = Figure(figsize=(6.4, 6.0), layout="constrained")
    axes = fig.subplots(3, 1, sharex=True)
    for name in names:
        steps, _, u = _series(runs[name][1])
        for i, ax in enumerate(axes):
            ax.plot(steps, u[:, i], label=name)
    for ax, label in zip(axes, AXES, strict=True):
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("step")
    axes[0].legend(fontsize=8)
    fig.suptitle("Velocity command Δr")
    paths.append(_save(fig, out_dir / "commands.png"))
    return paths
