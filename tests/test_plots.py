"""The figures: drawn from records alone, probing marked, compared methods distinguishable."""

from __future__ import annotations

import cv2

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
