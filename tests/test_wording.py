"""What the commands say matches what they did: the compare bar's rate, the header of an invalid
config's error (every --set shown), and replay --verify's count of records."""

from __future__ import annotations

import pytest
from rich.console import Console
from rich.progress import Progress

from rodctl.config import ConfigError, load_config
from rodctl.display import RateColumn
from rodctl.replay import VerifyResult


def _rate_after(times: list[float], start: int = 0) -> str:
    """The rate column after one unit of work finished at each of `times` (s after the start)."""
    clock = [0.0]
    progress = Progress(
        RateColumn("episodes"), console=Console(file=None, quiet=True), get_time=lambda: clock[0]
    )
    task = progress.add_task(
        "episodes", total=start + len(times), completed=start, done_before=start
    )
    for t in times:
        clock[0] = t
        progress.update(task, advance=1)
    return str(RateColumn("episodes").render(progress.tasks[task]))


def test_two_episodes_in_one_second_show_two_a_second():
    # Two workers finish together after 1 s, 3 ms apart: rich's own speed said 313 episodes/s.
    assert _rate_after([1.0, 1.003]) == "1.99 episodes/s"
    assert _rate_after([]) == "-"


def test_a_resumed_compare_counts_only_the_episodes_it_ran():
    # Resumed with 8 of 10 done: 2 episodes in 4 s is 0.5 a second, not 10 / 4.
    assert _rate_after([2.0, 4.0], start=8) == "0.50 episodes/s"


def test_an_invalid_config_names_every_set_override():
    with pytest.raises(ConfigError) as err:
        load_config(
            "configs/default.yaml", ["rod.engine=quasistatic", "rod.table_friction=slippery"]
        )
    assert "with --set rod.engine=quasistatic --set rod.table_friction=slippery" in str(err.value)


@pytest.mark.parametrize(
    ("records", "phrase"),
    [
        (12, "12 records (the initial frame and 11 steps)"),
        (2, "2 records (the initial frame and 1 step)"),
    ],
)
def test_verify_counts_records_as_the_initial_frame_and_the_steps(records, phrase):
    same = VerifyResult(verdict="identical", steps=records, tolerance=0.0)
    assert same.report()[0] == f"verify: OK, {phrase} identical"
    close = VerifyResult(verdict="within_tolerance", steps=records, tolerance=1e-9)
    assert close.report()[0].startswith(f"verify: OK within tolerance 1e-09: {phrase}, ")
