"""detect_batch: one row per tightening, in order, for every accepted input kind and layout."""

from __future__ import annotations

import numpy as np
import polars as pl
import pyarrow as pa
import pyarrow.compute as pc
import pytest

import tightscan


def test_one_row_per_tightening_in_order(simulated: tuple[pa.Table, pa.Table]) -> None:
    curves, _ = simulated
    shuffled = curves.take(np.random.default_rng(0).permutation(curves.num_rows))
    out = tightscan.detect_batch(shuffled)
    assert isinstance(out, pa.Table)
    assert out.num_rows == curves.num_rows
    assert out.column("tightening_id").equals(shuffled.column("tightening_id"))
    names = [c[0] for c in tightscan._core.result_columns()]
    assert out.column_names == ["tightening_id", *names]


def test_record_batch_reader_and_chunks_give_the_same_result(simulated: tuple[pa.Table, pa.Table]) -> None:
    curves, _ = simulated
    whole = tightscan.detect_batch(curves.combine_chunks())
    chunked = pa.Table.from_batches(curves.to_batches(max_chunksize=37))
    assert tightscan.detect_batch(chunked).equals(whole)
    reader = pa.RecordBatchReader.from_batches(curves.schema, curves.to_batches(max_chunksize=100))
    assert tightscan.detect_batch(reader).equals(whole)
    batch = curves.combine_chunks().to_batches()[0]
    assert tightscan.detect_batch(batch).equals(whole)


def test_polars_in_polars_out(simulated: tuple[pa.Table, pa.Table]) -> None:
    curves, _ = simulated
    frame = pl.from_arrow(curves.slice(0, 50))
    assert isinstance(frame, pl.DataFrame)
    out = tightscan.detect_batch(frame, passthrough=["strategy"])
    assert isinstance(out, pl.DataFrame)
    assert out.height == 50
    assert out["tightening_id"].to_list() == frame["tightening_id"].to_list()
    expected = tightscan.detect_batch(curves.slice(0, 50))
    assert out["change_detected"].to_list() == expected.column("change_detected").to_pylist()


def test_string_ids_and_float64_channels_are_kept() -> None:
    curves, _ = tightscan.simulate(20, seed=1)
    ids = pa.array([f"run-{i:03d}" for i in range(20)])
    f64 = pa.large_list(pa.float64())
    table = pa.table(
        {
            "tightening_id": ids,
            "angle": curves.column("angle").cast(f64),
            "torque": curves.column("torque").cast(f64),
        }
    )
    out = tightscan.detect_batch(table)
    assert out.column("tightening_id").to_pylist() == ids.to_pylist()
    same = tightscan.detect_batch(curves.select(["angle", "torque"]))
    np.testing.assert_allclose(
        out.column("torque_rate").to_numpy(zero_copy_only=False),
        same.column("torque_rate").to_numpy(zero_copy_only=False),
        rtol=1e-6,
    )


def _long(curves: pa.Table) -> pa.Table:
    lengths = pc.list_value_length(curves.column("angle")).to_numpy()
    return pa.table(
        {
            "tightening_id": np.repeat(curves.column("tightening_id").to_numpy(), lengths),
            "angle": pc.list_flatten(curves.column("angle")),
            "torque": pc.list_flatten(curves.column("torque")),
            "strategy": np.repeat(curves.column("strategy").to_numpy(zero_copy_only=False), lengths),
        }
    )


def test_long_layout_matches_nested(simulated: tuple[pa.Table, pa.Table]) -> None:
    curves, _ = simulated
    curves = curves.slice(0, 40)
    nested = tightscan.detect_batch(curves.select(["tightening_id", "angle", "torque"]))
    long = _long(curves)
    out = tightscan.detect_batch(long, passthrough=["strategy"])
    assert out.column("tightening_id").equals(nested.column("tightening_id"))
    assert out.column("change_detected").equals(nested.column("change_detected"))
    assert out.column("strategy").to_pylist() == curves.column("strategy").to_pylist()
    # A tightening split across record batches is still one row.
    reader = pa.RecordBatchReader.from_batches(long.schema, long.to_batches(max_chunksize=333))
    assert tightscan.detect_batch(reader).column("tightening_id").equals(nested.column("tightening_id"))


def test_long_layout_interleaved_ids_are_not_merged() -> None:
    """A tightening is a run of contiguous samples: an id coming back is a second tightening
    under it, with its own row, and every row of a repeated id says so (never one merged curve)."""
    table = pa.table(
        {
            "tightening_id": [7, 3, 7, 3, 9],
            "angle": [0.0, 0.0, 1.0, 1.0, 0.0],
            "torque": [0.0, 0.0, 1.0, 1.0, 0.0],
        }
    )
    out = tightscan.detect_batch(table)
    assert out.column("tightening_id").to_pylist() == [7, 3, 7, 3, 9]
    assert out.column("n_samples").to_pylist() == [1, 1, 1, 1, 1]
    status = out.column("status").to_pylist()
    assert [s.split(":")[0] for s in status] == ["duplicate_id"] * 4 + ["too_short"]
    assert status[0].startswith("duplicate_id: tightening_id 7 appears 2 times; as a curve: too_short")


def test_long_layout_second_curve_under_one_id_is_split_and_flagged(simulated: tuple[pa.Table, pa.Table]) -> None:
    """Two recordings under one id, one after the other (the clock starts over): two rows,
    each analysed on its own samples, both `duplicate_id`; the nested run of the same curves
    gives the same values."""
    curves, _ = simulated
    pair = curves.slice(0, 2).select(["tightening_id", "angle", "torque", "time"])
    lengths = pc.list_value_length(pair.column("angle")).to_pylist()
    long = pa.table(
        {
            "tightening_id": pa.array(["bolt-1"] * sum(lengths)),
            **{c: pc.list_flatten(pair.column(c)) for c in ("angle", "torque", "time")},
        }
    )
    same_id = pair.set_column(0, "tightening_id", pa.array(["bolt-1", "bolt-1"]))
    for columns in (["tightening_id", "angle", "torque", "time"], ["tightening_id", "angle", "torque"]):
        out = tightscan.detect_batch(long.select(columns))
        nested = tightscan.detect_batch(same_id.select(columns))
        assert out.column("n_samples").to_pylist() == lengths
        assert out.column("status").to_pylist() == nested.column("status").to_pylist()
        assert out.column("torque_rate").to_pylist() == nested.column("torque_rate").to_pylist()
    assert all(s.startswith('duplicate_id: tightening_id "bolt-1" appears 2 times') for s in nested.column("status").to_pylist())


def test_nested_duplicate_ids_keep_their_rows_and_are_flagged(simulated: tuple[pa.Table, pa.Table]) -> None:
    curves, _ = simulated
    curves = curves.slice(0, 6)
    ids = pa.array(["a", "b", "a", None, None, "c"])
    plain = tightscan.detect_batch(curves)
    out = tightscan.detect_batch(curves.set_column(0, "tightening_id", ids))
    status = out.column("status").to_pylist()
    for i in (0, 2):
        assert status[i] == f'duplicate_id: tightening_id "a" appears 2 times; as a curve: {plain.column("status")[i].as_py()}'
    for i in (1, 3, 4, 5):  # unique and null ids are left alone
        assert status[i] == plain.column("status")[i].as_py()
    assert out.column("change_angle").equals(plain.column("change_angle"))  # the analysis is kept
    # The same over chunks: the repeat is counted over the whole table.
    chunked = pa.Table.from_batches(curves.set_column(0, "tightening_id", ids).to_batches(max_chunksize=1))
    assert tightscan.detect_batch(chunked).column("status").to_pylist() == status


def test_passthrough_true_copies_metadata(simulated: tuple[pa.Table, pa.Table]) -> None:
    curves, _ = simulated
    out = tightscan.detect_batch(curves.slice(0, 5), passthrough=True)
    for name in ("strategy", "thread", "target_torque"):
        assert out.column(name).equals(curves.slice(0, 5).column(name))


def test_config_forms_agree(simulated: tuple[pa.Table, pa.Table]) -> None:
    curves, _ = simulated
    curves = curves.slice(0, 100)
    strict = tightscan.CusumConfig(arl0=100.0)
    a = tightscan.detect_batch(curves, strict)
    b = tightscan.detect_batch(curves, tightscan.DetectConfig(cusum=strict))
    c = tightscan.detect_batch(curves, {"arl0": 100.0})
    assert a.equals(b) and b.equals(c)
    h = a.column("cusum_threshold").drop_null()[0].as_py()
    assert h == pytest.approx(tightscan.cusum_threshold(100.0, 0.5))
    # A lower ARL0 alarms at least as often as the default.
    default = tightscan.detect_batch(curves)
    assert pc.sum(a.column("change_detected")).as_py() >= pc.sum(default.column("change_detected")).as_py()


def test_cusum_threshold_and_arl() -> None:
    assert tightscan.cusum_arl(5.0, 0.5) == pytest.approx(469.1, abs=0.1)
    assert tightscan.cusum_arl(4.0, 0.5, shift=1.0) == pytest.approx(8.34, abs=0.01)
    assert tightscan.cusum_threshold(tightscan.cusum_arl(8.0, 0.25), 0.25) == pytest.approx(8.0)
    with pytest.raises(tightscan.InvalidParameterError) as e:
        tightscan.cusum_threshold(1.0, 0.5)
    assert e.value.parameter == "arl0"


def test_simulate_is_reproducible_and_labelled() -> None:
    a, ta = tightscan.simulate(50, seed=9)
    b, tb = tightscan.simulate(50, seed=9)
    assert a.equals(b) and ta.equals(tb)
    c, _ = tightscan.simulate(50, seed=10)
    assert not a.equals(c)
    assert set(ta.column_names) >= {"tightening_id", "has_change", "fault_kind", "magnitude", "onset_angle"}
    assert ta.column("tightening_id").equals(a.column("tightening_id"))


def test_simulate_ranges_yield_and_effects() -> None:
    curves, truth = tightscan.simulate(
        30,
        seed=2,
        mu_th_range=(0.08, 0.09),
        mu_b_range=(0.15, 0.15),
        joint_stiffness_range=(0.5, 0.5),
        onset_fraction_range=(0.4, 0.4),
        with_yield=True,
        speed_friction=0.05,
        runout=0.01,
        prevailing_torque_nm=1.0,
    )
    assert all(0.08 <= m <= 0.09 for m in truth.column("mu_th").to_pylist())
    assert set(truth.column("mu_b").to_pylist()) == {0.15}
    assert set(truth.column("joint_stiffness").to_pylist()) == {0.5}
    assert set(truth.column("effects").to_pylist()) == {"speed_friction,prevailing_torque_nm,runout"}
    assert truth.column("runout_phase").null_count == 0
    assert truth.column("yield_angle").null_count < 30
    assert {"mu_tot", "thread", "prevailing_torque"} <= set(truth.column_names)
    assert truth.column("thread").equals(curves.column("thread"))
    _, plain = tightscan.simulate(30, seed=2)
    assert set(plain.column("effects").to_pylist()) == {""}
    assert plain.column("yield_angle").null_count == 30
    with pytest.raises(tightscan.InvalidParameterError) as e:
        tightscan.simulate(5, runout=1.5)
    assert e.value.parameter == "runout"
    with pytest.raises(tightscan.InvalidParameterError) as e:
        tightscan.simulate(5, mu_th_range=(0.2, 0.1))
    assert e.value.parameter == "mu_th_range"
