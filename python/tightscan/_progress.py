"""The one progress bar of the package (``scan_parquet``, ``read_rexroth``)."""

from __future__ import annotations

import sys
from typing import Any


class Progress:
    """A rich progress bar on an interactive terminal (or when ``enabled``); nothing otherwise."""

    def __init__(self, description: str, total: int, enabled: bool | None) -> None:
        self.bar: Any = None
        if sys.stderr.isatty() if enabled is None else enabled:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress as RichProgress, TimeRemainingColumn

            self.bar = RichProgress(
                "[progress.description]{task.description}",
                BarColumn(),
                MofNCompleteColumn(),
                TimeRemainingColumn(),
                transient=True,
            )
            self.bar.start()
            self.task = self.bar.add_task(description, total=total)

    def advance(self, n: int = 1) -> None:
        if self.bar is not None:
            self.bar.advance(self.task, n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.stop()
