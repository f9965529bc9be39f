"""Frames in, same frames out (issue 13, item 2): pandas gives pandas, polars gives polars, a
polars LazyFrame streams batch by batch, duckdb and other Arrow streams give pyarrow; every
kind's result has the types `tightscan.result_schema` announces, and the same values."""

from __future__ import annotations

import duckdb
import pandas as pd
import polars as pl
import pyarrow as pa
import pyarrow.compute as pc
import pytest

import tightscan


@pytest.fixture(scope="module")
def curves() -> pa.Table:
    table, _ = tightscan.simulate(40, seed=7)
    return table.append_column("station", pa.array([f"S{i % 3}" for i in range(table.num_rows)]))


@pytest.fixture(scope="module")
def expected(curves: pa.Table) -> pa.Table:
    return tightscan.detect_batch(curves, passthrough=["station"])


def _long(curves: pa.Table) -> pa.Table:
    """The long layout (one row per sample) of the nested table."""
    lengths = pc.list_value_length(curves.column("angle")).to_pylist()
    ids = [i for i, n in zip(curves.column("tightening_id").to_pylist(), lengths) for _ in range(n)]
    station = [s for s, n in zip(curves.column("station").to_pylist(), lengths) for _ in range(n)]
    return pa.table(
        {
            "tightening_id": pa.array(ids, pa.int64()),
            "angle": pc.list_flatten(curves.column("angle")),
            "torque": pc.list_flatten(curves.column("torque")),
            "station": station,
        }
    )


def test_pandas_in_gives_pandas_out_with_arrow_dtypes(curves: pa.Table, expected: pa.Table) -> None:
    frame = curves.to_pandas()  # list channels as object columns of NumPy arrays
    frame.index = pd.RangeIndex(100, 100 + len(frame))
    out = tightscan.detect_batch(frame, passthrough=["station"])
    assert isinstance(out, pd.DataFrame)
    assert all(isinstance(t, pd.ArrowDtype) for t in out.dtypes)
    assert list(out.index) == list(frame.index)  # nested layout: one row per input row, aligned
    assert out["status"].tolist() == expected.column("status").to_pylist()
    assert pa.Table.from_pandas(out, preserve_index=False).equals(expected.cast(pa.Table.from_pandas(out, preserve_index=False).schema))


def test_pandas_with_arrow_dtypes_and_passthrough_true(curves: pa.Table, expected: pa.Table) -> None:
    frame = curves.to_pandas(types_mapper=pd.ArrowDtype)
    out = tightscan.detect_batch(frame, passthrough=True)
    arrow_out = tightscan.detect_batch(curves, passthrough=True)
    assert list(out.columns) == arrow_out.column_names
    assert {"station", "strategy", "thread"} <= set(out.columns)
    assert "__index_level_0__" not in out.columns
    assert out["change_detected"].tolist() == expected.column("change_detected").to_pylist()
    assert out["station"].tolist() == curves.column("station").to_pylist()


def test_polars_in_gives_polars_out(curves: pa.Table, expected: pa.Table) -> None:
    out = tightscan.detect_batch(pl.from_arrow(curves), passthrough=["station"])
    assert isinstance(out, pl.DataFrame)
    assert out["status"].to_list() == expected.column("status").to_pylist()
    assert out["torque_rate"].to_list() == expected.column("torque_rate").to_pylist()


@pytest.mark.parametrize("batch_rows", [1, 7, 1_000_000])
def test_lazyframe_streams_nested_batches(curves: pa.Table, expected: pa.Table, batch_rows: int) -> None:
    lazy = pl.from_arrow(curves).lazy()
    out = tightscan.detect_batch(lazy, passthrough=["station"], batch_rows=batch_rows)
    assert isinstance(out, pl.DataFrame)
    assert out["tightening_id"].to_list() == expected.column("tightening_id").to_pylist()
    assert out["status"].to_list() == expected.column("status").to_pylist()
    assert out["change_angle"].to_list() == expected.column("change_angle").to_pylist()


@pytest.mark.parametrize("batch_rows", [50, 977, 10_000_000])
def test_lazyframe_long_layout_keeps_each_tightening_whole(curves: pa.Table, expected: pa.Table, batch_rows: int) -> None:
    """Batches cut tightenings in the middle; each still gives one row, computed on all of
    its samples (the values equal the nested run's)."""
    lazy = pl.from_arrow(_long(curves)).lazy()
    out = tightscan.detect_batch(lazy, passthrough=["station"], batch_rows=batch_rows)
    assert out.height == curves.num_rows
    assert out["n_samples"].to_list() == expected.column("n_samples").to_pylist()
    assert out["status"].to_list() == expected.column("status").to_pylist()
    assert out["station"].to_list() == expected.column("station").to_pylist()
    assert out["torque_rate"].to_list() == expected.column("torque_rate").to_pylist()


def test_lazyframe_from_a_parquet_scan(curves: pa.Table, expected: pa.Table, tmp_path: pytest.TempPathFactory) -> None:
    import pyarrow.parquet as pq

    path = f"{tmp_path}/long.parquet"
    pq.write_table(_long(curves), path, row_group_size=500)
    out = tightscan.detect_batch(pl.scan_parquet(path).filter(pl.col("station") != "S1"), batch_rows=300)
    keep = [s != "S1" for s in expected.column("station").to_pylist()]
    assert out["tightening_id"].to_list() == expected.filter(pa.array(keep)).column("tightening_id").to_pylist()
    assert out["status"].to_list() == expected.filter(pa.array(keep)).column("status").to_pylist()


def test_lazyframe_repeated_id_in_a_later_batch_is_flagged_in_both_rows(curves: pa.Table) -> None:
    ids = list(range(curves.num_rows))
    ids[-1] = ids[0]  # the last tightening reuses the first one's id
    table = curves.set_column(0, "tightening_id", pa.array(ids, pa.int64()))
    out = tightscan.detect_batch(pl.from_arrow(table).lazy(), batch_rows=5)
    status = out["status"].to_list()
    assert status[0].startswith("duplicate_id: tightening_id 0 appears 2 times; as a curve: ")
    assert status[-1].startswith("duplicate_id: tightening_id 0 appears 2 times; as a curve: ")
    assert status == tightscan.detect_batch(table).column("status").to_pylist()


def test_lazyframe_passthrough_true_names_the_columns_from_the_plan(curves: pa.Table) -> None:
    out = tightscan.detect_batch(pl.from_arrow(curves).lazy(), passthrough=True, batch_rows=16)
    assert out.columns == tightscan.detect_batch(curves, passthrough=True).column_names
    assert out["station"].to_list() == curves.column("station").to_pylist()


def test_lazyframe_without_collect_batches_streams_in_slices(curves: pa.Table, expected: pa.Table) -> None:
    """Older polars (before collect_batches): one streaming collect per slice, same results."""
    from tightscan._api import _lazy_batches

    class OldLazyFrame:  # what an older polars LazyFrame offers, nothing more
        def __init__(self, frame: pl.LazyFrame) -> None:
            self.frame = frame

        def slice(self, offset: int, length: int) -> pl.LazyFrame:
            return self.frame.slice(offset, length)

    lazy = pl.from_arrow(_long(curves)).lazy()
    pieces = list(_lazy_batches(OldLazyFrame(lazy), 4_000))
    assert len(pieces) > 1 and max(p.num_rows for p in pieces) <= 4_000
    assert pa.concat_tables(pieces).equals(lazy.collect().to_arrow())


def test_empty_lazyframe_gives_the_empty_result(curves: pa.Table) -> None:
    out = tightscan.detect_batch(pl.from_arrow(curves.slice(0, 0)).lazy())
    assert out.height == 0 and "status" in out.columns


def test_duckdb_relation_gives_pyarrow(curves: pa.Table, expected: pa.Table) -> None:
    con = duckdb.connect()
    con.register("curves", curves)
    relation = con.sql("select * from curves order by tightening_id")
    out = tightscan.detect_batch(relation, passthrough=True)
    assert isinstance(out, pa.Table)
    assert out.column("status").to_pylist() == expected.column("status").to_pylist()
    assert out.column("station").to_pylist() == expected.column("station").to_pylist()
    con.close()


def test_record_batch_reader_and_capsule_objects_give_pyarrow(curves: pa.Table, expected: pa.Table) -> None:
    class Capsule:  # any object with the Arrow C stream interface, nothing else
        def __init__(self, table: pa.Table) -> None:
            self.table = table

        def __arrow_c_stream__(self, requested_schema: object = None) -> object:
            return self.table.__arrow_c_stream__(requested_schema)

    reader = pa.RecordBatchReader.from_batches(curves.schema, curves.to_batches(max_chunksize=6))
    for data in (reader, Capsule(curves)):
        out = tightscan.detect_batch(data, passthrough=["station"])
        assert isinstance(out, pa.Table)
        assert out.equals(expected)


def test_not_a_table_is_a_type_error() -> None:
    with pytest.raises(TypeError, match="needs an Arrow table"):
        tightscan.detect_batch([1, 2, 3])
    with pytest.raises(TypeError):
        tightscan.detect_batch({"angle": [[1.0]], "torque": [[1.0]]})


def test_result_schema_is_every_frame_kinds_output_type(curves: pa.Table) -> None:
    """`result_schema` is what Dask's `meta=` and writers opened ahead need: each frame kind's
    output has exactly its types, as that kind of frame spells them."""
    schema = tightscan.result_schema(curves.schema, ["station"])
    empty = schema.empty_table()
    arrow_out = tightscan.detect_batch(curves, passthrough=["station"])
    assert arrow_out.schema == schema
    duck = duckdb.connect()
    duck.register("curves", curves)
    # duckdb hands over its own input schema (every column nullable): announced from it alike.
    relation = duck.sql("select * from curves")
    assert tightscan.detect_batch(relation, passthrough=["station"]).schema == tightscan.result_schema(relation, ["station"])
    duck.close()
    pandas_in = curves.to_pandas()
    pandas_out = tightscan.detect_batch(pandas_in, passthrough=["station"])
    pandas_meta = tightscan.result_schema(pandas_in, ["station"]).empty_table().to_pandas(types_mapper=pd.ArrowDtype)
    assert pandas_out.dtypes.to_dict() == pandas_meta.dtypes.to_dict()
    assert list(pandas_out.columns) == schema.names
    polars_meta = pl.from_arrow(empty)
    assert isinstance(polars_meta, pl.DataFrame)
    assert tightscan.detect_batch(pl.from_arrow(curves), passthrough=["station"]).schema == polars_meta.schema
    assert tightscan.detect_batch(pl.from_arrow(curves).lazy(), passthrough=["station"]).schema == polars_meta.schema
    assert tightscan.result_schema(pl.from_arrow(curves).lazy(), ["station"]).names == schema.names
    # The schema of a polars input (large_list, string_view ids) is announced alike.
    polars_in = pl.from_arrow(curves)
    assert isinstance(polars_in, pl.DataFrame)
    from_polars = tightscan.result_schema(polars_in.to_arrow().schema, ["station"])
    assert tightscan.detect_batch(polars_in.to_arrow(), passthrough=["station"]).schema == from_polars


def test_categorical_ids_of_pandas_and_polars_are_ids(curves: pa.Table) -> None:
    """pandas and polars categoricals reach the engine dictionary-encoded; a repeated one is
    reported like any other id, also across the batches of a LazyFrame."""
    names = ["a", "b", "a"] + [f"n{i}" for i in range(curves.num_rows - 3)]
    frame = pl.from_arrow(curves)
    assert isinstance(frame, pl.DataFrame)
    frame = frame.with_columns(pl.Series("tightening_id", names).cast(pl.Categorical))
    first = 'duplicate_id: tightening_id "a" appears 2 times; as a curve: '
    for out in (tightscan.detect_batch(frame), tightscan.detect_batch(frame.lazy(), batch_rows=2)):
        status = out["status"].to_list()
        assert status[0].startswith(first) and status[2].startswith(first) and not status[1].startswith("duplicate_id")
    pandas_frame = curves.to_pandas()
    pandas_frame["tightening_id"] = pd.Categorical(names)
    status = tightscan.detect_batch(pandas_frame)["status"].tolist()
    assert status[0].startswith(first) and status[2].startswith(first)
