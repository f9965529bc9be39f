"""Results record how they were made (issue 14): the version, alpha, the full effective detector
config and the rule's shares, under the schema metadata key b"tightscan" of detect_batch's
table and of every Parquet file `tightscan scan` writes; `tightscan report` shows them."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import pyarrow.parquet as pq
import pytest

import tightscan
from tightscan import DetectConfig, config_from_toml
from tightscan.cli import EXIT_OK, main


def test_detect_batch_records_version_alpha_config_and_shares() -> None:
    curves, _ = tightscan.simulate(6, seed=2)
    results = tightscan.detect_batch(curves)
    record = json.loads(results.schema.metadata[tightscan.RESULTS_METADATA_KEY])
    assert record == tightscan.results_metadata(results)
    assert record["version"] == tightscan.__version__
    assert record["alpha"] == 0.01 and record["rule"] == "any" and record["detectors"] == ["break", "cusum"]
    assert record["config"] == DetectConfig().to_dict()
    # the union bound's split: break 3 parts, CUSUM 1
    assert record["shares"] == pytest.approx({"break": 0.0075, "cusum": 0.0025})
    assert sum(record["shares"].values()) == pytest.approx(record["alpha"])
    # the derived threshold is the one for the most blocks a window monitors (30); a window with
    # fewer gets the lower threshold for its own count
    thresholds = results.select(["cusum_blocks", "cusum_threshold"]).to_pylist()
    assert all(r["cusum_threshold"] <= record["derived"]["cusum_threshold"] for r in thresholds if r["cusum_threshold"] is not None)
    assert all(r["cusum_threshold"] == record["derived"]["cusum_threshold"] for r in thresholds if r["cusum_blocks"] == 30)

    given = tightscan.detect_batch(curves, {"kappa": 0.75, "alpha": 0.02, "detectors": ["break", "cusum", "l1"]})
    record = tightscan.results_metadata(given)
    assert record is not None
    assert record["config"]["kappa"] == 0.75 and record["alpha"] == 0.02
    assert record["shares"] == pytest.approx({"break": 0.012, "cusum": 0.004, "l1": 0.004})
    # pandas keeps it in attrs; polars cannot carry it (documented): scan_metadata gives it
    frame = tightscan.detect_batch(curves.to_pandas(), {"kappa": 0.75})
    assert tightscan.results_metadata(frame)["config"]["kappa"] == 0.75
    assert tightscan.scan_metadata({"kappa": 0.75})["config"] == tightscan.results_metadata(frame)["config"]


def test_scan_writes_the_record_and_report_shows_it(tmp_path: Path) -> None:
    pytest.importorskip("tightscan.report", reason="the report needs matplotlib and Jinja2")
    curves = tmp_path / "curves.parquet"
    assert main(["simulate", "-n", "8", "-o", str(curves), "--seed", "5", "--no-progress"]) == EXIT_OK
    shown = tmp_path / "defaults.toml"
    with contextlib.redirect_stdout(io.StringIO()) as out:
        assert main(["config", "--show"]) == EXIT_OK
    shown.write_text(out.getvalue())
    user = tmp_path / "user.toml"
    user.write_text("[cusum]\nkappa = 0.8\n\n[decision]\nalpha = 0.02\n")

    results = tmp_path / "results.parquet"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["scan", str(curves), "-o", str(results), "--no-progress", "--config", str(user)]) == EXIT_OK
    record = json.loads(pq.read_schema(results).metadata[b"tightscan"])
    expected = config_from_toml(shown).to_dict()  # what `config --show` prints, read back
    expected.update(kappa=0.8, alpha=0.02)  # and the user's values
    assert record["config"] == expected
    assert record["alpha"] == 0.02 and record["version"] == tightscan.__version__
    assert record["shares"] == pytest.approx({"break": 0.015, "cusum": 0.005})
    assert tightscan.results_metadata(results) == record
    assert tightscan.results_metadata(tightscan.read_results(results)) == record

    # a directory of results: each file carries it
    out_dir = tmp_path / "out"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["scan", str(curves), "-o", str(out_dir), "--no-progress"]) == EXIT_OK
    files = [p for p in out_dir.rglob("*.parquet") if "_tightscan" not in p.parts]
    assert files and all(json.loads(pq.read_schema(f).metadata[b"tightscan"])["alpha"] == 0.01 for f in files)

    report = tmp_path / "report.html"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["report", str(results), "-o", str(report), "--worst", "0"]) == EXIT_OK
    html = report.read_text()
    assert 'id="recorded-alpha"' in html and "<b>0.02</b>" in html
    assert 'id="decision-rule"' in html and 'id="config"' in html
    for key, value in (("kappa", "0.8"), ("alpha", "0.02"), ("break_min_jump_steps", "1.5"), ("detectors", "break, cusum")):
        assert f"<th>{key}</th><td><code>{value}</code></td>" in html, key
    assert "share of alpha: break</th><td>0.015" in html
