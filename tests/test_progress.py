"""The progress bar: off where stderr is no terminal (pytest's capture, a pipe, a log file),
on when forced (``enabled=True`` or TIGHTSCAN_PROGRESS=1), always on stderr, with throughput."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from tightscan._progress import PROGRESS_ENV, Progress, _rate_column, progress_enabled

REPO = Path(__file__).resolve().parents[1]


def test_off_when_stderr_is_not_a_terminal(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(PROGRESS_ENV, raising=False)
    assert not sys.stderr.isatty()  # pytest captures it
    assert not progress_enabled(None)
    assert not Progress("x", 3, None).enabled


def test_forced_on_by_the_caller_or_the_environment(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv(PROGRESS_ENV, "1")
    assert progress_enabled(None) and not progress_enabled(False)  # an explicit False (--no-progress) wins
    monkeypatch.setenv(PROGRESS_ENV, "0")
    assert not progress_enabled(None) and progress_enabled(True)
    bar = Progress("counting", 3, True, unit="files")
    assert bar.enabled
    bar.advance(3)
    bar.close()
    assert capsys.readouterr().out == ""  # the bar never writes to stdout


def test_throughput_column_reads_items_per_second() -> None:
    column = _rate_column("tightenings")
    assert column.render(SimpleNamespace(finished_speed=None, speed=1234.56)).plain == "1,234.6 tightenings/s"
    assert column.render(SimpleNamespace(finished_speed=None, speed=None)).plain == ""


def test_forced_bar_goes_to_stderr_and_json_stays_clean(tmp_path: Path) -> None:
    """Through a pipe, with the bar forced on: stdout is the JSON alone, the bar is on stderr."""
    env = dict(os.environ, PYTHONPATH=str(REPO / "python"), TIGHTSCAN_PROGRESS="1", COLUMNS="120")
    out = tmp_path / "s.parquet"
    done = subprocess.run(
        [sys.executable, "-m", "tightscan", "simulate", "-n", "1200", "-o", str(out), "--json"],
        capture_output=True, text=True, env=env, timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["tightenings"] == 1200
    assert "simulating" in done.stderr and "wrote 1,200 tightenings" in done.stderr


def test_quiet_turns_a_forced_bar_off(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    from tightscan.cli import main

    monkeypatch.setenv(PROGRESS_ENV, "1")
    assert main(["simulate", "-n", "10", "-o", str(tmp_path / "s.parquet"), "--quiet"]) == 0
    assert capsys.readouterr() == ("", "")
    assert main(["simulate", "-n", "10", "-o", str(tmp_path / "s.parquet")]) == 0
    assert "simulating" in capsys.readouterr().err  # and without --quiet the forced bar draws


def test_diagnose_bar_reaches_its_total(monkeypatch: pytest.MonkeyPatch) -> None:
    """The stages of diagnose add up to the bar's total, however many rounds the loop needs."""
    import tightscan

    module = sys.modules["tightscan.diagnose"]
    bars: list[list[int]] = []

    class Recording(Progress):
        def __init__(self, description: str, total: int, enabled: bool | None, unit: str = "items") -> None:
            super().__init__(description, total, False)
            bars.append([total, 0])

        def advance(self, n: int = 1) -> None:
            bars[-1][1] += n

    monkeypatch.setattr(module, "Progress", Recording)
    curves, _ = tightscan.simulate(40, seed=5, fault_fraction=0.0)
    for max_effects in (0, 2):
        tightscan.diagnose(curves, max_effects=max_effects, folds=3, grouping_factors=None, progress=True)
    assert bars == [[4, 4], [6, 6]]
