"""Smoke test of benches/detection_quality.py: the benchmark's whole path (both generators, ours
and every peer calibrated per cell, tables, JSON, markdown) on a tiny run, and the README blocks
it rewrites. The figures themselves are the benchmark's business (and tests/test_detection_power.py
keeps a floor under the rule's)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benches" / "detection_quality.py"


def test_quick_path_on_tiny_sets_writes_every_table(tmp_path: Path) -> None:
    pytest.importorskip("ruptures")
    pytest.importorskip("river")
    out_json, out_md = tmp_path / "dq.json", tmp_path / "dq.md"
    proc = subprocess.run(
        [sys.executable, str(BENCH), "--quick", "--n", "40", "--peer-n", "20", "--cells", "white", "--workers", "1",
         "--json", str(out_json), "--md", str(out_md), "--plot", ""],
        cwd=ROOT / "benches", capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Goals of issue 11 item 2" in proc.stdout
    record = json.loads(out_json.read_text())
    assert [(c["generator"], c["cell"]["name"]) for c in record["cells"]] == [("built-in", "white"), ("independent", "white")]
    for cell in record["cells"]:
        names = {s["name"] for s in cell["same_curves"]}
        assert {"decision rule", "binseg_linear", "pelt_linear", "ols_cusum", "pagehinkley", "adwin"} <= names
        rule = next(s for s in cell["ours_all_curves"] if s["name"] == "decision rule")
        assert rule["false_alarm"]["n"] == 40 and set(rule["groups"]) >= {"CST", "CSDT", "HDT", "abrupt"}
        assert set(rule["recall_by_onset_third"]) == {"early", "middle", "late"}
    assert {g["generator"] for g in record["goals"]} == {"built-in", "independent"}
    assert set(record["goals"][0]["decision_rule"]) == {"fa", "recall_15_45", "recall_3_15", "onset_abrupt_deg"}
    rows = record["recall_vs_magnitude"]["by_cell"]
    assert any(r["detector"] == "binseg_linear" and r["strategy"] == "HDT" for r in rows)
    assert all(len(r["recall"]) == len(record["bands"]) for r in rows)
    md = out_md.read_text()
    assert "| independent | white | 40 (20) |" in md and ("PASS" in md or "MISS" in md)


def test_readmes_carry_the_generated_block() -> None:
    sys.path.insert(0, str(ROOT / "benches"))
    try:
        import detection_quality as dq
    finally:
        sys.path.remove(str(ROOT / "benches"))
    for path in dq.README_BLOCKS:
        text = path.read_text()
        assert text.count(dq.BEGIN) == 1 and text.count(dq.END) == 1 and text.index(dq.BEGIN) < text.index(dq.END), path


def test_rewrite_block_replaces_only_between_the_markers(tmp_path: Path) -> None:
    sys.path.insert(0, str(ROOT / "benches"))
    try:
        import detection_quality as dq
    finally:
        sys.path.remove(str(ROOT / "benches"))
    page = tmp_path / "README.md"
    page.write_text(f"head\n{dq.BEGIN}\nold figures\n{dq.END}\ntail\n")
    assert dq.rewrite_block(page, "| new |\n")
    assert page.read_text() == f"head\n{dq.BEGIN}\n| new |\n{dq.END}\ntail\n"
    other = tmp_path / "other.md"
    other.write_text("no markers\n")
    assert not dq.rewrite_block(other, "x\n") and other.read_text() == "no markers\n"
    twice = tmp_path / "twice.md"
    twice.write_text(f"`{dq.BEGIN}` named in prose\n{dq.BEGIN}\nold\n{dq.END}\n")
    assert not dq.rewrite_block(twice, "x\n")


def test_size_grid_counts_each_rule_detector_against_its_share() -> None:
    """benches/size_grid.py's per-detector rates: only the rule's detectors, only decided
    curves, and the rule's alarms between the largest detector's and their sum (the rule is
    `any`). At alpha 0.1 (the largest the L1 boundary, reported beside the rule, is tabled for)
    a cell of 80 clean curves has alarms to count."""
    sys.path.insert(0, str(ROOT / "benches"))
    import size_grid

    grid = [("CST", 2000.0, 0.1, ("white", "white", 0.0)), ("HDT", 2000.0, 0.1, ("t4", "t4", 0.0))]
    rows = size_grid.run("built-in simulator", 80, 0.1, grid)
    for row in rows:
        assert set(row["fired"]) == set(row["shares"]) == {"break", "cusum"}
        assert sum(row["shares"].values()) == pytest.approx(0.1)
        assert row["false_alarms"] > 0
        assert max(row["fired"].values()) <= row["false_alarms"] <= sum(row["fired"].values()) <= 2 * row["decided"]
    table = size_grid.detector_table(rows).splitlines()
    assert table[0] == "| generator | noise | rate | break (share 7.50) | cusum (share 2.50) | rule |"
    assert len(table) == 2 + 2  # header, rule, one row per noise
    white = next(r for r in rows if r["noise"] == "white")
    assert table[2].endswith(f"| {100 * white['false_alarms'] / white['decided']:.2f} |")
