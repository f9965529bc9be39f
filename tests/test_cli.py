"""Exit codes of the command line (README, "Exit codes"): 0 done, 1 changes found with
`--fail-on-change`, 2 usage, 3 data; errors are one line on stderr naming the file or column."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import tightscan

from tightscan.cli import EXIT_CHANGES, EXIT_DATA, EXIT_OK, EXIT_USAGE, main

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def curves(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A clean set (no change found in it, fixed seed) and a set of large friction changes."""
    d = tmp_path_factory.mktemp("cli")
    clean, faulty = d / "clean.parquet", d / "faulty.parquet"
    assert main(["simulate", "-n", "12", "-o", str(clean), "--seed", "3", "--fault-fraction", "0"]) == EXIT_OK
    args = ["simulate", "-n", "12", "-o", str(faulty), "--seed", "3", "--fault-fraction", "1", "--magnitude-range", "0.3", "0.3"]
    assert main(args) == EXIT_OK
    return clean, faulty


def _changes(results: Path) -> int:
    return sum(v is True for v in pq.read_table(results, columns=["change_detected"]).column(0).to_pylist())


def test_fail_on_change(tmp_path: Path, curves: tuple[Path, Path], capsys: pytest.CaptureFixture[str]) -> None:
    clean, faulty = curves
    out = tmp_path / "res.parquet"
    assert main(["scan", str(faulty), "-o", str(out), "--no-progress"]) == EXIT_OK  # changes alone are no failure
    assert _changes(out) > 0
    assert main(["scan", str(faulty), "-o", str(out), "--no-progress", "--fail-on-change"]) == EXIT_CHANGES
    assert main(["scan", str(clean), "-o", str(out), "--no-progress", "--fail-on-change"]) == EXIT_OK
    assert _changes(out) == 0
    capsys.readouterr()


def test_usage_errors_exit_2(tmp_path: Path, curves: tuple[Path, Path], capsys: pytest.CaptureFixture[str]) -> None:
    clean, _ = curves
    with pytest.raises(SystemExit) as e:
        main(["scan", str(clean), "-o", str(tmp_path / "r.parquet"), "--no-such-option"])
    assert e.value.code == EXIT_USAGE
    with pytest.raises(SystemExit) as e:
        main(["scan", str(clean)])  # -o is required
    assert e.value.code == EXIT_USAGE
    capsys.readouterr()
    assert main(["scan", str(clean), "-o", str(tmp_path / "r.parquet"), "--kappa", "-1"]) == EXIT_USAGE
    assert capsys.readouterr().err == "tightscan: error: parameter 'kappa': must be >= 0, got -1\n"


def test_data_errors_exit_3_naming_the_file_or_column(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "missing.parquet"
    assert main(["scan", str(missing), "-o", str(tmp_path / "r.parquet")]) == EXIT_DATA
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and str(missing) in err

    no_torque = tmp_path / "no_torque.parquet"
    pq.write_table(pa.table({"tightening_id": [1], "angle": [[0.0, 1.0, 2.0]]}), no_torque)
    assert main(["scan", str(no_torque), "-o", str(tmp_path / "r.parquet"), "--no-progress"]) == EXIT_DATA
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "torque" in err

    runs = tmp_path / "runs"
    runs.mkdir()
    (runs / "Ch_1.json").write_text(json.dumps({"cycle": 1, "tightening steps": []}))
    assert main(["import", "rexroth", str(runs), "-o", str(tmp_path / "t.parquet"), "--no-progress"]) == EXIT_DATA
    assert "1 of 1 files failed to import (first: Ch_1.json: no_steps" in capsys.readouterr().err
    labels = tmp_path / "labels.csv"
    assert main(["import", "rexroth", str(runs), "-o", str(tmp_path / "t.parquet"), "--labels", str(labels)]) == EXIT_DATA
    assert str(labels) in capsys.readouterr().err


def test_no_traceback_from_the_installed_command(tmp_path: Path) -> None:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO / "python"), os.environ.get("PYTHONPATH", "")]))
    done = subprocess.run(
        [sys.executable, "-m", "tightscan", "scan", str(tmp_path / "gone.parquet"), "-o", str(tmp_path / "r.parquet")],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert done.returncode == EXIT_DATA
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr
    assert done.stderr.startswith("tightscan: error: ") and "gone.parquet" in done.stderr


def test_version_is_printed_and_exits_zero(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"tightscan {tightscan.__version__}"
