"""Real exports as they come (issue 13 item 6): unfastening (loosening) curves of a cordless
nutrunner in the Rexroth JSON family, with one step, channels angle/torque/time only and torque
mostly negative, in nested directories with upper-case names, some with `NaN` / `Infinity`
tokens and duplicate cycles. The real 4,565 files are not here, so ``loosening_export`` builds
such documents from real rexroth-s01 runs: their sampling (angle, time, backlash, repeated
samples) and torque noise are measured ones, only the shape is turned into a loosening."""

from __future__ import annotations

import json
import math
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pytest

import tightscan
from tightscan.cli import main
from tightscan.rexroth import DuplicateRunWarning, import_summary, read_rexroth, rexroth_files

BREAKAWAY_NM = (-2.6, -2.4)  # most negative torque of the generated curves
END_NM = 0.07  # where the run-out ends, slightly positive as in the real files


def loosening_export(run: dict[str, Any], cycle: int, seed: int, *, bare_keys: bool = False) -> dict[str, Any]:
    """A loosening export built from the real tightening ``run``: its steps joined into one
    step, the torque mirrored in time and sign (breakaway first, then the run-out), scaled so
    that the breakaway lies in ``BREAKAWAY_NM`` and shifted so that the curve ends at
    ``END_NM``; angle and time as measured; no gradient or redundant channels."""
    rng = np.random.default_rng(seed)
    steps = run["tightening steps"]
    angle = np.concatenate([s["graph"]["angle values"] for s in steps])
    time = np.concatenate([s["graph"]["time values"] for s in steps])
    torque = -np.concatenate([s["graph"]["torque values"] for s in steps])[::-1]
    breakaway = rng.uniform(*BREAKAWAY_NM)
    # The affine map that takes the mirrored curve's minimum to the breakaway and its last
    # sample to END_NM (the real torque noise is scaled with it, by about 1.8).
    scale = (breakaway - END_NM) / (torque.min() - torque[-1])
    torque = np.round(np.minimum(scale * (torque - torque[-1]) + END_NM, END_NM), 3)
    keys = ("angle", "torque", "time") if bare_keys else ("angle values", "torque values", "time values")
    graph = dict(zip(keys, (angle.tolist(), torque.tolist(), time.tolist())))
    return {
        "format": "channel",
        "result": "OK",
        "prg name": "Loosen",
        "cycle": cycle,
        "date": "2024-03-01 08:00:00",
        "nominal torque": 6,
        "tool serial": 4711,
        "tightening steps": [{"name": "Loosening", "speed": 300, "result": "OK", "graph": graph}],
    }


@pytest.fixture(scope="module")
def export_dir(tmp_path_factory: pytest.TempPathFactory, rexroth_dir: Path) -> Path:
    """12 loosening exports, as a nutrunner's share holds them: nested by day, upper-case
    names, one with bare channel keys, one with a `NaN` and one with an `Infinity` token, and
    cycle 7003 exported twice; plus a file that is not an export."""
    root = tmp_path_factory.mktemp("loosening")
    runs = sorted((rexroth_dir / "runs").glob("*.json"))[:12]
    for k, path in enumerate(runs):
        doc = loosening_export(json.loads(path.read_text()), 7000 + k, seed=k, bare_keys=k == 5)
        day = root / f"2024-03-0{1 + k % 3}" / ("station-b" if k % 2 else "station-a")
        day.mkdir(parents=True, exist_ok=True)
        graph = doc["tightening steps"][0]["graph"]
        if k == 8:
            graph["torque values"][40] = math.nan
        if k == 9:
            graph["angle values"][3] = math.inf
        if k == 10:
            doc["cycle"] = 7003  # the same run exported twice
        name = f"CH_{7000 + k:012d}.JSON" if k % 2 else f"Ch_{7000 + k:012d}.json"
        (day / name).write_text(json.dumps(doc))  # json writes NaN and Infinity as bare tokens
    (root / "export.log").write_text("nutrunner export log")
    return root


def _import(export_dir: Path) -> pa.Table:
    with pytest.warns(DuplicateRunWarning, match=r"1 runs are imported from more than one file .*7003"):
        return read_rexroth(export_dir, progress=False)


def test_the_generated_curves_look_like_the_real_loosening_files(export_dir: Path) -> None:
    table = _import(export_dir)
    ok = table.filter(pc.equal(table.column("import_status"), "ok"))
    for row in ok.to_pylist():
        torque = np.array(row["torque"])
        assert BREAKAWAY_NM[0] - 0.01 <= torque.min() <= BREAKAWAY_NM[1] + 0.01
        assert torque[-1] == torque.max() == END_NM
        assert (torque < 0).mean() > 0.8  # mostly negative
        assert row["n_steps"] == 1 and np.ptp(torque) > 2  # it varies


def test_loosening_exports_import_as_they_come(export_dir: Path) -> None:
    found = rexroth_files(export_dir)
    assert len(found.paths) == 12 and [Path(p).name for p in found.skipped] == ["export.log"]
    assert found.names[0] == "2024-03-01/station-a/Ch_000000007000.json"  # below the directory, sorted
    assert sum(n.endswith(".JSON") for n in found.names) == 6

    table = _import(export_dir)
    assert table.num_rows == 12
    assert table.column("file_name").to_pylist() == list(found.names)
    status = dict(zip(table.column("tightening_id").to_pylist(), table.column("import_status").to_pylist()))
    assert status[7008] == "bad_values: step 1 'Loosening' torque values[40] is NaN, not a finite number"
    assert status[7009] == "bad_values: step 1 'Loosening' angle values[3] is Infinity, not a finite number"
    assert Counter(status.values())["ok"] == 9  # 11 ids: 7003 twice
    # Only angle and torque are required: no gradient is a null list, not a rejection.
    ok = table.filter(pc.equal(table.column("import_status"), "ok"))
    assert ok.num_rows == 10 and ok.column("gradient").null_count == 10
    assert ok.column("time").null_count == 0 and ok.column("angle").null_count == 0
    bare = ok.filter(pc.equal(ok.column("tightening_id"), 7005)).to_pylist()[0]  # `angle`, not `angle values`
    assert len(bare["angle"]) == len(bare["torque"]) == len(bare["time"]) > 100
    # The duplicate run keeps both rows, marked.
    dup = table.filter(table.column("duplicate_id"))
    assert dup.column("tightening_id").to_pylist() == [7003, 7003]
    assert table.column("duplicate_id").to_pylist().count(True) == 2
    summary = import_summary(table, found.skipped)
    assert (summary.imported, summary.failed, summary.skipped) == (10, 2, 1)
    assert summary.failure_codes == {"bad_values": 2}
    assert list(summary.duplicates) == [7003] and len(summary.duplicates[7003]) == 2


def test_loosening_curves_get_their_own_status(export_dir: Path) -> None:
    table = _import(export_dir)
    results = tightscan.detect_batch(table, passthrough=["import_status"])
    assert isinstance(results, pa.Table) and results.num_rows == table.num_rows
    repeated = table.column("duplicate_id").to_pylist()
    for status, imported, duplicate in zip(results.column("status").to_pylist(), table.column("import_status").to_pylist(), repeated):
        if imported == "ok":
            # The fixture's duplicated cycle: the engine names the repeat, then the curve's own status.
            if duplicate:
                assert status.startswith("duplicate_id: tightening_id ") and " appears 2 times; as a curve: " in status, status
                status = status.split("; as a curve: ", 1)[1]
            assert status.startswith("loosening: torque falls (peak |torque| -2."), status
            assert "detection applies to tightening curves" in status
        else:
            assert status.startswith("null_tightening"), status
    assert results.column("change_detected").null_count == table.num_rows
    assert results.column("snug_angle").null_count == table.num_rows


def test_the_engine_sees_the_sign_convention_and_the_range() -> None:
    # The same loosening curve, negated, is a tightening-shaped curve again: the status says so.
    angle = np.linspace(0.0, 100.0, 400)
    loosening = -2.5 * np.exp(-angle / 20.0) + 0.07 * angle / 100.0 + 0.002 * np.sin(angle * 7.0)
    falling = 2.0 - 0.015 * angle + 0.002 * np.sin(angle * 7.0)  # positive, but falls: varies
    table = pa.table({"tightening_id": [1, 2], "angle": [angle.tolist()] * 2, "torque": [loosening.tolist(), falling.tolist()]})
    results = tightscan.detect_batch(table)
    assert isinstance(results, pa.Table)
    status = results.column("status").to_pylist()
    assert status[0].startswith("loosening: torque falls (peak |torque| -2.500 Nm at 0.00 deg is negative)"), status[0]
    assert status[1].startswith("no_elastic_zone: torque varies but never rises"), status[1]


def test_optional_and_required_channels(tmp_path: Path, rexroth_dir: Path) -> None:
    run = json.loads((rexroth_dir / "runs" / "Ch_000001596334.json").read_text())
    no_time = loosening_export(run, 1, seed=1)
    del no_time["tightening steps"][0]["graph"]["time values"]
    (tmp_path / "Ch_1.json").write_text(json.dumps(no_time))
    no_torque = loosening_export(run, 2, seed=2)
    del no_torque["tightening steps"][0]["graph"]["torque values"]
    (tmp_path / "Ch_2.json").write_text(json.dumps(no_torque))
    # A real tightening whose second step lost its gradient: the row's gradient is null.
    partial = json.loads(json.dumps(run))
    partial["cycle"] = 3
    del partial["tightening steps"][1]["graph"]["gradient values"]
    (tmp_path / "Ch_3.json").write_text(json.dumps(partial))
    rows = read_rexroth(tmp_path, progress=False).to_pylist()
    assert [r["import_status"] for r in rows] == ["ok", "missing_field: step 1 'Loosening' has no 'torque values'", "ok"]
    assert rows[0]["time"] is None and rows[0]["gradient"] is None and len(rows[0]["angle"]) > 100
    assert rows[2]["gradient"] is None and rows[2]["time"] is not None and rows[2]["n_steps"] == 4


def test_cli_import_reports_failures_and_duplicates(tmp_path: Path, export_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "loosening.parquet"
    assert main(["import", "rexroth", str(export_dir), "-o", str(out), "--no-progress"]) == 3
    captured = capsys.readouterr()
    assert "12 Rexroth runs written to" in captured.out
    assert "10 imported, 2 failed (bad_values: 2), 1 files skipped (not *.json)" in captured.out
    assert "failed: 2024-03-03/station-a/Ch_000000007008.json: bad_values: step 1 'Loosening' torque values[40] is NaN" in captured.out
    err = captured.err.splitlines()
    assert err[0].startswith("warning: 1 runs come from more than one file (column duplicate_id): 7003: ")
    assert "2024-03-01/station-b/CH_000000007003.JSON" in err[0] and "2024-03-02/station-a/Ch_000000007010.json" in err[0]
    assert err[1].startswith("tightscan: error: 2 of 12 files failed to import")
    assert len(err) == 2


def test_non_finite_tokens_are_bad_values_in_any_step(tmp_path: Path, rexroth_dir: Path) -> None:
    text = (rexroth_dir / "runs" / "Ch_000001596334.json").read_text()
    for k, token in enumerate(["NaN", "-Infinity", "1e400"]):
        doc = json.loads(text)
        doc["cycle"] = k
        doc["tightening steps"][2]["graph"]["torque values"][5] = "TOKEN"
        (tmp_path / f"Ch_{k}.json").write_text(json.dumps(doc).replace('"TOKEN"', token))
    status = read_rexroth(tmp_path, progress=False).column("import_status").to_pylist()
    step = "bad_values: step 3 'Pre-tightening' torque values[5] is"
    assert status == [f"{step} NaN, not a finite number", f"{step} -Infinity, not a finite number", f"{step} Infinity, not a finite number"]
