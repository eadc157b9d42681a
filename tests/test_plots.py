"""The figures: drawn from records alone, probing marked, compared methods distinguishable."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rodctl import plots
from rodctl.logs.synthetic import SyntheticRun


def _size(path):
    img = cv2.imread(str(path))
    return img.shape[1], img.shape[0]


def test_run_figures_are_written_at_a_legible_size(tmp_path):
    run = SyntheticRun(seed=1, image_every=0)
    records = run.records(20)
    paths = plots.write_figures(run.header, records, tmp_path)
    assert [p.name for p in paths] == ["shapes.png", "t1.png", "commands.png"]
    for p in paths:
        w, h = _size(p)
        assert w >= 540 and h >= 350, p.name


def test_probing_spans_come_from_the_records_phase():
    records = SyntheticRun(seed=1, image_every=0).records(12)
    assert plots._probe_spans(records) == [(1, 3)]  # steps 1-3 probe
    records[6].phase = "probe"
    assert plots._probe_spans(records) == [(1, 3), (6, 6)]
    assert plots._probe_spans(records[4:6]) == []


def test_method_styles_differ_in_colour_dashes_and_marker():
    styles = [plots.style(i) for i in range(6)]
    for key in ("color", "linestyle", "marker"):
        values = [repr(s[key]) for s in styles]
        assert len(set(values)) == 6, key


@pytest.mark.slow
def test_comparison_figures_include_pixel_error_in_one_unit(tmp_path):
    runs = {}
    for i, name in enumerate(("paper", "ma2022", "aghajanzadeh2022", "akf-pinv")):
        run = SyntheticRun(seed=i, image_every=0)
        runs[name] = (run.header, run.records(10 + i))
    paths = plots.write_comparison_figures(runs, tmp_path)
    names = [p.name for p in paths]
    assert names == ["shapes.png", "pixel_error.png", "t1.png", "commands.png"]
    w, _ = _size(tmp_path / "t1.png")
    assert w >= 3 * 350  # small multiples, three a row


def _with_limits(run, limits=(0.01, 0.01, 0.05)):
    import yaml

    cfg = yaml.safe_load(run.header.config_yaml)
    cfg["rod"]["max_step"] = list(limits)
    run.header.config_yaml = yaml.safe_dump(cfg)
    return run


def _drawn_figures(monkeypatch):
    """Every Figure the plotting functions save, drawn (so layout and text extents are final)."""
    figures = []
    for name in ("_png", "_save"):
        original = getattr(plots, name)

        def keep(fig, *args, _original=original):
            figures.append(fig)
            return _original(fig, *args)

        monkeypatch.setattr(plots, name, keep)
    return figures


def _texts(fig):
    """The figure's titles, legends and axis labels that are shown, as (what, bbox)."""
    r = fig.canvas.get_renderer()
    out = []
    if fig._suptitle is not None:
        out.append(("suptitle", fig._suptitle.get_window_extent(r)))
    out += [("figure legend", leg.get_window_extent(r)) for leg in fig.legends]
    for ax in fig.axes:
        if not ax.get_visible():
            continue
        for what, text in (("title", ax.title), ("x label", ax.xaxis.label)):
            if text.get_text() and text.get_visible():
                out.append((f"{what} {text.get_text()!r}", text.get_window_extent(r)))
        if ax.yaxis.label.get_text():
            out.append(("y label", ax.yaxis.label.get_window_extent(r)))
    return out


@pytest.mark.slow
def test_no_title_or_legend_overlaps_another_and_nothing_is_cut_off(tmp_path, monkeypatch):
    figures = _drawn_figures(monkeypatch)
    run = _with_limits(SyntheticRun(seed=1, image_every=0))
    run.header.method = "autoencoder/windowed_ls/mfac"  # a long name must not run off the top
    plots.write_figures(run.header, run.records(20), tmp_path / "one")
    runs = {}
    for i, name in enumerate(("paper", "ma2022", "aghajanzadeh2022", "akf-pinv")):
        r = _with_limits(SyntheticRun(seed=i, image_every=0))
        runs[name] = (r.header, r.records(10 + i))
    plots.write_comparison_figures(runs, tmp_path / "cmp")
    assert len(figures) == 7
    for fig in figures:
        assert fig.dpi >= 150
        texts = _texts(fig)
        box = fig.bbox
        for what, bb in texts:
            inside = bb.x0 >= box.x0 - 1 and bb.x1 <= box.x1 + 1
            inside = inside and bb.y0 >= box.y0 - 1 and bb.y1 <= box.y1 + 1
            assert inside, f"{what} is cut off: {bb} outside {box}"
        tops = [(w, b) for w, b in texts if w in ("suptitle", "figure legend") or w[:5] == "title"]
        for i, (wa, a) in enumerate(tops):
            for wb, b in tops[i + 1 :]:
                assert not a.overlaps(b), f"{wa} overlaps {wb}"


def _labelled_ticks(ax):
    lo, hi = sorted(ax.get_ylim())
    ticks = [t for t in ax.yaxis.get_major_ticks() if lo <= t.get_loc() <= hi]
    return [t.label1.get_text() for t in ticks if t.label1.get_text()]


def test_log_axes_label_several_ticks_whatever_the_span():
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    for values in ([0.3, 5.0], [8.2, 9.6], [1.0, 3e5], [0.004, 0.3]):
        fig = Figure()
        FigureCanvasAgg(fig)
        ax = fig.subplots()
        y = np.geomspace(*values, 20)
        ax.plot(np.arange(20), y)
        plots._log_axis(ax, y)
        fig.canvas.draw()
        labels = _labelled_ticks(ax)
        assert len(labels) >= 3, (values, labels)
        assert all("10^" not in s and "$" not in s for s in labels), labels  # plain numbers


def test_commands_draw_the_speed_limits_and_call_the_command_a_pose_increment():
    run = _with_limits(SyntheticRun(seed=1, image_every=0), (0.01, 0.02, 0.05))
    fig = plots._commands({"m": run.records(12)}, plots.speed_limits(run.header))
    title = fig._suptitle.get_text()
    assert "Pose increment" in title and "velocity" not in title.lower()
    labels = fig.axes[0].get_legend_handles_labels()[1]
    assert "speed limit" in labels and "probing" in labels
    for ax, limit in zip(fig.axes, (0.01, 0.02, 0.05), strict=True):
        levels = {
            round(float(line.get_ydata()[0]), 6) for line in ax.lines if line.get_ls() == "--"
        }
        assert levels == {limit, -limit}
    assert plots.speed_limits(SyntheticRun(seed=1, image_every=0).header) is None  # not known


def _dashed_levels(ax):
    """The levels of the speed-limit lines (grey, dashed; a method's line may be dashed too)."""
    return {
        round(float(line.get_ydata()[0]), 6)
        for line in ax.lines
        if line.get_ls() == "--" and line.get_color() == "0.3"
    }


@pytest.mark.parametrize("methods", [1, 2])
def test_dual_arm_commands_show_both_ends_each_with_its_own_speed_limit(methods):
    """q = 6: a column of panels per end (one run and a compare of several methods alike), the
    x0 end's limits those of rod.clamp_arm, not the gripper's."""
    run = SyntheticRun(seed=2, image_every=0, arms=2)
    header = run.header
    runs = {
        f"m{i}": SyntheticRun(seed=2 + i, image_every=0, arms=2).records(12) for i in range(methods)
    }
    fig = plots._commands(runs, plots.speed_limits(header), plots.speed_limits(header, "x0"))
    assert len(fig.axes) == 6
    left, right = fig.axes[0::2], fig.axes[1::2]  # row-major: gripper column, x0 end column
    assert right[0].get_title() == "x0 end (second arm)" and left[0].get_title() == "gripper"
    for j in range(3):
        assert _dashed_levels(left[j]) == {v * s for v in [(0.02, 0.02, 0.1)[j]] for s in (1, -1)}
        assert _dashed_levels(right[j]) == {
            v * s for v in [(0.005, 0.005, 0.02)[j]] for s in (1, -1)
        }
        for i, recs in enumerate(runs.values()):  # every method's x0 end is drawn, as logged
            drawn = [ln for ln in right[j].lines if ln.get_label() == f"m{i}"]
            assert len(drawn) == 1
            assert np.array_equal(drawn[0].get_ydata(), [r.u[3 + j] for r in recs])


def test_methods_with_equal_results_stay_apart_in_the_success_figure():
    from rodctl.bench.compare import success_axes

    rows = [
        {"method": m, "difficulty": d, "outcome": "converged", "steps_to_converge": 6}
        for m in ("a", "b", "c")
        for d in (0.2, 0.5, 0.8)
    ]
    ax = success_axes(rows, ["a", "b", "c"]).axes[0]
    xs = [tuple(line.get_xdata()[~np.isnan(line.get_ydata())]) for line in ax.lines]
    assert len(set(xs)) == 3  # all at 100 %, side by side rather than on top of each other
    assert len({line.get_marker() for line in ax.lines}) == 3
