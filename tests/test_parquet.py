"""scan_parquet and the CLI: streaming Parquet in and out, errors naming the file."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import tightscan
from tightscan.cli import main


def test_scan_matches_detect_batch(tmp_path: Path, simulated: tuple[pa.Table, pa.Table]) -> None:
    curves, _ = simulated
    for i, part in enumerate([curves.slice(0, 250), curves.slice(250)]):
        pq.write_table(part, tmp_path / f"part-{i}.parquet", row_group_size=64)
    out = tmp_path / "results.parquet"
    summary = tightscan.scan_parquet(tmp_path, out, passthrough=["strategy"], batch_size=50, progress=False)
    results = pq.read_table(out)
    expected = tightscan.detect_batch(curves, passthrough=["strategy"])
    assert results.num_rows == curves.num_rows == summary.tightenings
    assert results.equals(expected)
    assert summary.files == 2
    assert summary.changes == sum(bool(x) for x in expected.column("change_detected").to_pylist())


def test_scan_long_layout_streams_tightenings_across_batches(tmp_path: Path) -> None:
    curves, _ = tightscan.simulate(30, seed=3)
    import numpy as np
    import pyarrow.compute as pc

    lengths = pc.list_value_length(curves.column("angle")).to_numpy()
    long = pa.table(
        {
            "tightening_id": np.repeat(curves.column("tightening_id").to_numpy(), lengths),
            "angle": pc.list_flatten(curves.column("angle")),
            "torque": pc.list_flatten(curves.column("torque")),
        }
    )
    src = tmp_path / "long.parquet"
    pq.write_table(long, src, row_group_size=777)
    out = tmp_path / "r.parquet"
    tightscan.scan_parquet(src, out, batch_size=500, progress=False)
    results = pq.read_table(out)
    expected = tightscan.detect_batch(curves.select(["tightening_id", "angle", "torque"]))
    assert results.column("tightening_id").equals(expected.column("tightening_id"))
    assert results.column("change_detected").equals(expected.column("change_detected"))


def test_missing_and_unreadable_files_are_named(tmp_path: Path) -> None:
    with pytest.raises(tightscan.DataFileError) as e:
        tightscan.scan_parquet(tmp_path / "nope.parquet", tmp_path / "o.parquet")
    assert "nope.parquet" in str(e.value)
    broken = tmp_path / "broken.parquet"
    broken.write_bytes(b"PAR1 this is not parquet")
    with pytest.raises(tightscan.DataFileError) as e:
        tightscan.scan_parquet(broken, tmp_path / "o.parquet")
    assert e.value.path == str(broken)


def test_scan_schema_error_names_column(tmp_path: Path) -> None:
    src = tmp_path / "bad.parquet"
    pq.write_table(pa.table({"angle": pa.array([[1.0]], pa.list_(pa.float64()))}), src)
    with pytest.raises(tightscan.SchemaError) as e:
        tightscan.scan_parquet(src, tmp_path / "o.parquet")
    assert e.value.column == "torque"


def test_cli_simulate_scan_and_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = tmp_path / "sim.parquet"
    assert main(["simulate", "-n", "120", "-o", str(data), "--seed", "4"]) == 0
    assert pq.read_metadata(data).num_rows == 120
    assert (tmp_path / "sim-truth.parquet").exists()
    out = tmp_path / "res.parquet"
    assert main(["scan", str(data), "-o", str(out), "--no-progress"]) == 0
    assert pq.read_metadata(out).num_rows == 120
    assert "tightenings" in capsys.readouterr().out
    assert main(["scan", str(tmp_path / "missing.parquet"), "-o", str(out)]) == 3  # a data error
    assert "missing.parquet" in capsys.readouterr().err
    assert main(["scan", str(data), "-o", str(out), "--kappa", "-1"]) == 2


def test_cli_demo_runs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["demo", "-n", "300", "--dir", str(tmp_path), "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "by strategy" in text and "recall" in text
    assert pq.read_metadata(tmp_path / "results.parquet").num_rows == 300


def test_long_layout_split_handles_empty_batches() -> None:
    from tightscan._api import _hold_back_last_tightening as _split_trailing_tightening

    empty = pa.record_batch({"tightening_id": pa.array([], pa.int64()), "angle": pa.array([], pa.float64())})
    done, carry = _split_trailing_tightening(empty)
    assert done.num_rows == 0 and carry.num_rows == 0
    batch = pa.record_batch({"tightening_id": [1, 1, 2, 2], "angle": [0.0, 1.0, 0.0, 1.0]})
    done, carry = _split_trailing_tightening(batch)
    assert done.column(0).to_pylist() == [1, 1] and carry.column(0).to_pylist() == [2, 2]


def test_cli_simulate_effects_and_ranges(tmp_path: Path) -> None:
    data = tmp_path / "fx.parquet"
    args = ["simulate", "-n", "25", "-o", str(data), "--mu-th-range", "0.11", "0.11", "--with-yield"]
    args += ["--effect", "runout=0.02", "--effect", "torque_lowpass_ms=3", "--joint-stiffness-range", "0.4", "0.6"]
    assert main(args) == 0
    truth = pq.read_table(tmp_path / "fx-truth.parquet")
    assert set(truth.column("mu_th").to_pylist()) == {0.11}
    assert set(truth.column("effects").to_pylist()) == {"torque_lowpass_ms,runout"}
    assert all(0.4 <= k <= 0.6 for k in truth.column("joint_stiffness").to_pylist())
    with pytest.raises(SystemExit):
        main(["simulate", "-n", "5", "-o", str(data), "--effect", "bogus=1"])
    assert main(["simulate", "-n", "5", "-o", str(data), "--effect", "runout=2"]) == 2
