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


# ---------------------------------------------------------------------------------------------
# --json, --quiet, --config, progress (issue 14)

SCAN_KEYS = {
    "command", "version", "destination", "files", "resumed_files", "tightenings", "samples", "changes",
    "status_counts", "skipped_files", "seconds", "engine", "by_strategy", "exit_code", "config",
}


def test_scan_json_is_alone_on_stdout_and_quiet_prints_nothing(
    tmp_path: Path, curves: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    _, faulty = curves
    out = tmp_path / "res.parquet"
    assert main(["scan", str(faulty), "-o", str(out), "--json", "--fail-on-change"]) == EXIT_CHANGES
    captured = capsys.readouterr()
    doc = json.loads(captured.out)  # the whole of stdout is one JSON document
    assert set(doc) == SCAN_KEYS
    assert doc["command"] == "scan" and doc["tightenings"] == 12 and doc["changes"] == _changes(out) > 0
    assert doc["exit_code"] == EXIT_CHANGES and sum(doc["status_counts"].values()) == 12
    assert doc["config"]["decision"]["alpha"] == tightscan.DecisionConfig().alpha
    assert "tightenings" in captured.err  # the table for people went to stderr

    assert main(["scan", str(faulty), "-o", str(out), "--quiet"]) == EXIT_OK
    assert capsys.readouterr() == ("", "")
    assert main(["scan", str(faulty), "-o", str(out), "--quiet", "--json"]) == EXIT_OK
    captured = capsys.readouterr()
    assert json.loads(captured.out)["tightenings"] == 12 and captured.err == ""


def test_simulate_json_counts_what_it_wrote(tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TIGHTSCAN_PROGRESS", "1")  # a bar on stderr must not reach stdout
    out = tmp_path / "sim.parquet"
    assert main(["simulate", "-n", "30", "-o", str(out), "--seed", "4", "--json"]) == EXIT_OK
    doc = json.loads(capsys.readouterr().out)
    assert set(doc) == {"command", "version", "output", "truth", "seed", "tightenings", "samples", "with_change", "seconds"}
    truth = pq.read_table(doc["truth"])
    assert doc["tightenings"] == 30 == pq.read_metadata(out).num_rows
    assert doc["with_change"] == sum(truth.column("has_change").to_pylist())
    assert doc["samples"] == sum(len(t) for t in pq.read_table(out, columns=["torque"]).column(0).to_pylist())
    assert main(["simulate", "-n", "5", "-o", str(out), "-q"]) == EXIT_OK
    assert capsys.readouterr() == ("", "")


def test_simulation_in_steps_is_the_one_call_simulation(tmp_path: Path) -> None:
    """Progress steps and row-group chunks split the simulator's calls, never its data."""
    from tightscan.cli import write_simulation

    n, kwargs = 23, {"with_clamp_force": True, "with_yield": True, "runout": 0.01}
    curves, truth = tightscan.simulate(n, seed=9, **kwargs)  # type: ignore[arg-type]
    for chunk, step in [(10, 3), (23, 23), (8, 1)]:
        out, truth_out = tmp_path / f"c{chunk}-{step}.parquet", tmp_path / f"t{chunk}-{step}.parquet"
        counts = write_simulation(n, 9, str(out), str(truth_out), chunk=chunk, step=step, **kwargs)
        assert pq.read_table(out).equals(curves) and pq.read_table(truth_out).equals(truth)
        assert pq.read_metadata(out).num_row_groups == -(-n // chunk)  # a row group per chunk, as before
        assert counts["tightenings"] == n


def test_import_json_names_the_failures(tmp_path: Path, rexroth_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    runs = tmp_path / "runs"
    runs.mkdir()
    for p in sorted((rexroth_dir / "runs").glob("*.json"))[:3]:
        (runs / p.name).write_bytes(p.read_bytes())
    (runs / "broken.json").write_text(json.dumps({"cycle": 1, "tightening steps": []}))
    out = tmp_path / "t.parquet"
    assert main(["import", "rexroth", str(runs), "-o", str(out), "--json"]) == EXIT_DATA
    captured = capsys.readouterr()
    doc = json.loads(captured.out)
    assert set(doc) == {
        "command", "version", "output", "runs", "imported", "failed", "skipped", "failure_codes",
        "first_failures", "duplicates", "exit_code",
    }
    assert (doc["runs"], doc["imported"], doc["failed"], doc["exit_code"]) == (4, 3, 1, EXIT_DATA)
    assert doc["first_failures"][0]["file"] == "broken.json" and doc["failure_codes"] == {"no_steps": 1}
    assert "1 of 4 files failed to import" in captured.err  # the error is still on stderr
    assert main(["import", "rexroth", str(runs / "broken.json"), "-o", str(out), "--quiet"]) == EXIT_DATA
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.startswith("tightscan: error: ")  # quiet keeps errors


def test_diagnose_json_to_stdout_or_to_a_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = tmp_path / "clean.parquet"
    assert main(["simulate", "-n", "40", "-o", str(data), "--fault-fraction", "0", "--seed", "5", "-q"]) == EXIT_OK
    quick = ["--max-effects", "1", "--folds", "3", "--grouping-factors"]
    assert main(["diagnose", str(data), "--json", *quick]) == EXIT_OK
    captured = capsys.readouterr()
    doc = json.loads(captured.out)
    assert {"model", "rmse_before", "rmse_after", "effects", "unexplained_structure"} <= set(doc)
    assert doc["tightenings"] == 40 and "declared model" in captured.err
    out = tmp_path / "d.json"
    assert main(["diagnose", str(data), "--json", str(out), "--quiet", *quick]) == EXIT_OK
    assert capsys.readouterr() == ("", "")
    assert json.loads(out.read_text())["rmse_before"] == doc["rmse_before"]  # same seed, same document
    assert main(["diagnose", str(data), "--json", "-", "-q", *quick]) == EXIT_OK
    assert json.loads(capsys.readouterr().out)["rmse_after"] == doc["rmse_after"]


def test_config_show_reads_back_as_the_defaults(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["config", "--show"]) == EXIT_OK
    text = capsys.readouterr().out
    path = tmp_path / "defaults.toml"
    path.write_text(text)
    assert tightscan.config_from_toml(path) == tightscan.DetectConfig()
    assert main(["config", "--show", "--config", str(path)]) == EXIT_OK
    assert capsys.readouterr().out == text


def test_config_file_with_flags_over_it(tmp_path: Path, curves: tuple[Path, Path], capsys: pytest.CaptureFixture[str]) -> None:
    from tightscan.cli import _config, build_parser

    path = tmp_path / "c.toml"
    path.write_text("[cusum]\nkappa = 1\nthreshold = 6.5\n[decision]\nalpha = 0.05\nrule = \"2-of-n\"\n[residual_tests]\nkde = true\n")
    args = build_parser().parse_args(["scan", "x.parquet", "-o", "r.parquet", "--config", str(path), "--kappa", "0.7"])
    config = _config(args)
    assert config.cusum.kappa == 0.7 and config.cusum.threshold == 6.5  # the flag wins, the file fills the rest
    assert (config.decision.alpha, config.decision.rule, config.residual_tests.kde) == (0.05, "2-of-n", True)
    assert config.zone == tightscan.DetectConfig().zone
    args = build_parser().parse_args(["scan", "x.parquet", "-o", "r.parquet", "--config", str(path), "--arl0", "500"])
    assert (_config(args).cusum.arl0, _config(args).cusum.threshold) == (500.0, None)

    clean, _ = curves
    out = tmp_path / "r.parquet"
    assert main(["scan", str(clean), "-o", str(out), "--config", str(path), "--json", "-q"]) == EXIT_OK
    used = json.loads(capsys.readouterr().out)["config"]
    assert used["cusum"]["kappa"] == 1.0 and used["decision"]["rule"] == "2-of-n"
    assert set(pq.read_table(out, columns=["cusum_threshold"]).column(0).to_pylist()) <= {6.5, None}


def test_unknown_config_key_names_the_key_and_the_file(tmp_path: Path, curves: tuple[Path, Path], capsys: pytest.CaptureFixture[str]) -> None:
    clean, _ = curves
    out = str(tmp_path / "r.parquet")
    cases = {
        "[cusum]\nkapa = 1\n": ["cusum.kapa", "kappa, arl0, threshold"],
        "[cusums]\nkappa = 1\n": ["[cusums]", "cusum"],
        "[cusum]\nkappa = \"big\"\n": ["cusum.kappa", "wrong type"],
        "[cusum\n": ["not valid TOML"],
    }
    for i, (text, named) in enumerate(cases.items()):
        path = tmp_path / f"bad{i}.toml"
        path.write_text(text)
        assert main(["scan", str(clean), "-o", out, "--config", str(path)]) == EXIT_USAGE
        err = capsys.readouterr().err
        assert len(err.splitlines()) == 1 and str(path) in err and all(n in err for n in named), err
    assert main(["scan", str(clean), "-o", out, "--config", str(tmp_path / "missing.toml")]) == EXIT_DATA
    assert "missing.toml" in capsys.readouterr().err
