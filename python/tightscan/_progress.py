"""The one progress bar of the package (``scan_parquet``, ``read_rexroth``, ``simulate`` and
``diagnose`` on the command line).

It draws on stderr, so that stdout stays the command's output (``--json``), and only on an
interactive terminal unless told: ``enabled=True``, or the environment variable
``TIGHTSCAN_PROGRESS=1`` (``0`` turns it off everywhere), e.g. to see it through a pipe.
"""

from __future__ import annotations

import os
import sys
from typing import Any

#: Forces the bar on (1) or off (0) where a caller leaves it to the terminal (``enabled=None``).
PROGRESS_ENV = "TIGHTSCAN_PROGRESS"


def progress_enabled(enabled: bool | None) -> bool:
    """Whether a bar shows: ``enabled`` when given, else ``TIGHTSCAN_PROGRESS`` when set, else
    whether stderr is a terminal.

    >>> progress_enabled(False), progress_enabled(True)
    (False, True)
    """
    if enabled is not None:
        return enabled
    forced = os.environ.get(PROGRESS_ENV, "").strip()
    if forced in ("0", "1"):
        return forced == "1"
    return sys.stderr.isatty()


def _rate_column(unit: str) -> Any:
    from rich.progress import ProgressColumn
    from rich.text import Text

    class RateColumn(ProgressColumn):
        """Throughput in ``unit``/s, from rich's moving estimate."""

        def render(self, task: Any) -> Text:
            speed = task.finished_speed or task.speed
            return Text("" if speed is None else f"{speed:,.1f} {unit}/s", style="progress.data.speed")

    return RateColumn()


class Progress:
    """A rich progress bar with throughput on stderr where :func:`progress_enabled`; nothing
    otherwise. ``unit`` names what is counted (``files``, ``tightenings`` ...)."""

    def __init__(self, description: str, total: int, enabled: bool | None, unit: str = "items") -> None:
        self.bar: Any = None
        if progress_enabled(enabled):
            from rich.console import Console
            from rich.progress import BarColumn, MofNCompleteColumn, Progress as RichProgress, TimeRemainingColumn

            self.bar = RichProgress(
                "[progress.description]{task.description}",
                BarColumn(),
                MofNCompleteColumn(),
                _rate_column(unit),
                TimeRemainingColumn(),
                # drawn as on a terminal: where it shows, it was asked for (a terminal, or forced)
                console=Console(stderr=True, force_terminal=True),
                transient=True,
            )
            self.bar.start()
            self.task = self.bar.add_task(description, total=total)

    @property
    def enabled(self) -> bool:
        return self.bar is not None

    def advance(self, n: int = 1) -> None:
        if self.bar is not None:
            self.bar.advance(self.task, n)

    def describe(self, description: str) -> None:
        """Replaces the text before the bar (e.g. with a running count of what the items hold)."""
        if self.bar is not None:
            self.bar.update(self.task, description=description)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.stop()
