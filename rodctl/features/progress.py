"""One rich progress bar shared by data collection and training (the CLI shows both)."""

from __future__ import annotations

from collections.abc import Callable


class progress_bar:
    """A rich progress bar over `total` steps, or nothing when disabled.

    Used as ``with progress_bar(enabled, "label", total) as advance: advance(note, n)``.
    """

    def __init__(self, enabled: bool, label: str, total: int) -> None:
        self.enabled, self.label, self.total = enabled, label, total

    def __enter__(self) -> Callable[..., None]:
        if not self.enabled:
            return lambda note="", n=1: None
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self._bar = Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            TextColumn("{task.fields[note]}"),
            transient=False,
        )
        self._bar.start()
        task = self._bar.add_task(self.label, total=self.total, note="")

        def advance(note: str = "", n: int = 1) -> None:
            self._bar.update(task, advance=n, note=note)

        return advance

    def __exit__(self, *exc: object) -> None:
        if self.enabled:
            self._bar.stop()
