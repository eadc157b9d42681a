"""`rodctl.load_results` and `rodctl.load_run` (docs/python-api.md): the columns of results.csv
whether read from results.csv or, for a run still going, results.jsonl."""

from __future__ import annotations

import csv
import shutil
import sys

import numpy as np
import pytest

import rodctl
from rodctl.errors import UserError


@pytest.mark.slow
def test_load_results_returns_the_csv_columns_from_either_file(compare_smoke_run, tmp_path):
    with (compare_smoke_run / "results.csv").open(newline="") as fh:
        header = next(csv.reader(fh))
    frame = rodctl.load_results(compare_smoke_run)
    assert list(frame.columns) == header and len(frame) >= 2
    # A run still going has only results.jsonl: the same columns and values.
    running = tmp_path / "running"
    running.mkdir()
    shutil.copyfile(compare_smoke_run / "results.jsonl", running / "results.jsonl")
    live = rodctl.load_results(running)
    assert list(live.columns)[: len(header)] == header
    key = ["method", "target"]
    a = frame.sort_values(key).reset_index(drop=True)
    b = live.sort_values(key).reset_index(drop=True)[header]
    for column in ("scenario", "band", "outcome", "converged", "steps"):
        assert a[column].tolist() == b[column].tolist(), column
    for column in ("difficulty", "target_x", "target_y", "target_theta", "final_pixel_error"):
        np.testing.assert_allclose(a[column], b[column].astype(float), rtol=1e-9)


def test_load_results_says_what_is_missing(tmp_path, monkeypatch):
    with pytest.raises(UserError, match="no results.csv or results.jsonl"):
        rodctl.load_results(tmp_path)
    monkeypatch.setitem(sys.modules, "pandas", None)  # as if pandas were not installed
    with pytest.raises(ModuleNotFoundError, match=r"pip install pandas"):
        rodctl.load_results(tmp_path)


@pytest.mark.parametrize(
    ("name", "text", "said"),
    [
        ("results.json", '{"rows": []}', "not a results file"),
        ("summary.md", "| a | b |\n|---|---|\n| 1 | 2 | 3 | 4 |\n", "not a results file"),
        ("config.yaml", "seed: 1\n", "not a results file"),
        ("results.csv", "", "cannot be read as a results table"),
        ("results.csv", "a,b\n1,2\n1,2,3,4\n", "cannot be read as a results table"),
    ],
)
def test_load_results_refuses_a_file_that_is_not_a_results_table(tmp_path, name, text, said):
    """Found by a new-user trial: any file was read as CSV (junk columns for results.json, a
    pandas traceback for summary.md, an empty frame for a YAML)."""
    pytest.importorskip("pandas")
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(UserError, match=said) as caught:
        rodctl.load_results(path)
    assert str(path) in str(caught.value)
