"""Bad input, systematically (issue 13, item 5): Hypothesis draws valid and broken tables and
checks what the data contract promises whatever the table looks like.

- One result row per input tightening, ids in input order (nested layout).
- The same results however the table is chunked, sliced or streamed in batches.
- No exception but the documented ones: `SchemaError` for a table that breaks the contract,
  `TypeError` for something that is not a table.
- Every status has a documented code, and a repeated id is reported in every row carrying it.
- Several threads analysing at once give what one thread gives.

Examples are derandomized (the same on every run, so CI is reproducible) and few enough that
the file runs in about half a minute.
"""

from __future__ import annotations

import math
import re
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import polars as pl
import pyarrow as pa
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import tightscan

CONTRACT = (Path(__file__).resolve().parents[1] / "docs" / "data-contract.md").read_text()
STATUS_CODES = set(re.findall(r"^\| `([a-z_]+)` \|", CONTRACT.split("### Status codes")[1].split("## ")[0], re.M))

PROPERTY_SETTINGS = settings(
    max_examples=300,
    derandomize=True,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    database=None,
)

# A few real-looking curves among the tiny ones, so that the analysis itself runs too.
SIMULATED, _ = tightscan.simulate(6, seed=11)
SIMULATED_ANGLE = SIMULATED.column("angle").to_pylist()
SIMULATED_TORQUE = SIMULATED.column("torque").to_pylist()

sample_values = st.one_of(
    st.floats(-1e3, 1e3, allow_nan=False, width=32),
    st.sampled_from([math.nan, math.inf, -math.inf, 0.0, 1e308, -0.0]),
    st.none(),  # an element null
)
short_channel = st.one_of(st.none(), st.lists(sample_values, max_size=5))  # None: a list null


@st.composite
def tightening(draw: st.DrawFn) -> dict[str, Any]:
    if draw(st.integers(0, 4)) == 0:
        k = draw(st.integers(0, len(SIMULATED_ANGLE) - 1))
        angle: list[float | None] | None = list(SIMULATED_ANGLE[k])
        torque: list[float | None] | None = list(SIMULATED_TORQUE[k])
        if draw(st.booleans()) and angle:  # one broken sample in a real curve
            i = draw(st.integers(0, len(angle) - 1))
            angle[i] = draw(sample_values)
    else:
        angle = draw(short_channel)
        torque = draw(st.one_of(short_channel, st.just(None if angle is None else [1.0 + i for i, _ in enumerate(angle)])))
    if angle is not None and draw(st.integers(0, 5)) == 0:
        angle = angle[::-1]  # decreasing angle
    return {"id": draw(st.one_of(st.none(), st.integers(0, 6))), "angle": angle, "torque": torque}


ID_TYPES = ["int64", "uint8", "string", "large_string", "unicode", "dict_string", "dict_int", "absent"]


def _ids(values: list[int | None], kind: str) -> pa.Array | None:
    if kind == "absent":
        return None
    if kind in ("int64", "uint8"):
        return pa.array(values, getattr(pa, kind)())
    text = [None if v is None else (f"Schraube-{v}-ü✓" if kind == "unicode" else f"t{v}") for v in values]
    if kind == "dict_string":
        return pa.array(text).dictionary_encode()
    if kind == "dict_int":
        return pa.array(values, pa.int64()).dictionary_encode()
    return pa.array(text, pa.large_string() if kind == "large_string" else pa.string())


@st.composite
def nested_tables(draw: st.DrawFn) -> pa.Table:
    rows = draw(st.lists(tightening(), max_size=8))
    float_type = draw(st.sampled_from([pa.float64(), pa.float32()]))
    list_of = draw(st.sampled_from([pa.list_, pa.large_list]))
    columns: dict[str, pa.Array] = {}
    ids = _ids([r["id"] for r in rows], draw(st.sampled_from(ID_TYPES)))
    if ids is not None:
        columns["tightening_id"] = ids
    columns["angle"] = pa.array([r["angle"] for r in rows], list_of(float_type))
    columns["torque"] = pa.array([r["torque"] for r in rows], list_of(draw(st.sampled_from([pa.float64(), pa.float32()]))))
    if draw(st.booleans()):  # mismatched or matching optional channel
        columns["time"] = pa.array(
            [None if r["angle"] is None else [0.001 * i for i in range(len(r["angle"]) + draw(st.integers(-1, 1)) * draw(st.booleans()))] for r in rows],
            list_of(pa.float64()),
        )
    table = pa.table(columns)
    return _rechunk(table, draw(st.lists(st.integers(0, max(table.num_rows, 1)), max_size=3)))


def _rechunk(table: pa.Table, cuts: list[int]) -> pa.Table:
    """The same rows in several chunks, cut at `cuts`."""
    bounds = sorted({0, table.num_rows, *[min(c, table.num_rows) for c in cuts]})
    pieces = [table.slice(a, b - a) for a, b in zip(bounds, bounds[1:])]
    return pa.concat_tables(pieces) if pieces else table


def _plain(value: Any) -> Any:
    if isinstance(value, float) and math.isnan(value):
        return "NaN"
    return value


def _rows(table: Any) -> list[tuple[Any, ...]]:
    """Result rows, NaN comparable, dictionary ids decoded, whatever frame they came in."""
    if isinstance(table, pl.DataFrame):
        table = table.to_arrow()
    return [tuple(_plain(v) for v in row.values()) for row in table.to_pylist()]


def _detect(table: Any, **kwargs: Any) -> pa.Table | None:
    """The results, or None where the contract says SchemaError."""
    try:
        return tightscan.detect_batch(table, **kwargs)
    except tightscan.SchemaError:
        return None


def _check_statuses(result: pa.Table) -> None:
    assert {"ok", "duplicate_id", "null_tightening"} <= STATUS_CODES  # the contract was read
    ids = result.column("tightening_id").to_pylist()
    repeated = {i for i in ids if i is not None and ids.count(i) > 1}
    for tid, status in zip(ids, result.column("status").to_pylist()):
        code = status.split(":")[0]
        assert code in STATUS_CODES, status
        assert (code == "duplicate_id") == (tid in repeated), (tid, status)


@PROPERTY_SETTINGS
@given(nested_tables())
def test_nested_one_row_per_tightening_in_order_and_documented_statuses(table: pa.Table) -> None:
    result = _detect(table)
    if result is None:
        return
    assert result.num_rows == table.num_rows
    if "tightening_id" in table.column_names:
        assert result.column("tightening_id").to_pylist() == table.column("tightening_id").to_pylist()
    else:
        assert result.column("tightening_id").to_pylist() == list(range(table.num_rows))
    _check_statuses(result)


@PROPERTY_SETTINGS
@given(nested_tables(), st.integers(0, 3), st.integers(0, 3), st.integers(1, 5))
def test_nested_results_do_not_depend_on_chunks_slices_or_frames(table: pa.Table, before: int, after: int, batch_rows: int) -> None:
    result = _detect(table)
    if result is None:
        return
    expected = _rows(result)
    assert _rows(_detect(table.combine_chunks())) == expected
    # The table as a slice of a larger one (offsets into shared buffers).
    padded = pa.concat_tables([table.slice(0, min(before, table.num_rows)), table, table.slice(0, min(after, table.num_rows))]).combine_chunks()
    assert _rows(_detect(padded.slice(min(before, table.num_rows), table.num_rows))) == expected
    assert _rows(_detect(pa.RecordBatchReader.from_batches(table.schema, table.to_batches(max_chunksize=batch_rows)))) == expected
    if "dictionary" not in str(table.schema):  # polars reads dictionaries as categoricals
        frame = pl.from_arrow(table)
        assert isinstance(frame, pl.DataFrame)
        assert _rows(tightscan.detect_batch(frame.lazy(), batch_rows=batch_rows).to_arrow()) == _rows(tightscan.detect_batch(frame).to_arrow())


@st.composite
def long_tables(draw: st.DrawFn) -> pa.Table:
    """One row per sample: tightenings as runs of an id, sometimes an id coming back, sometimes
    interleaved, with or without a time column."""
    rows = draw(st.lists(tightening(), max_size=6))
    ids: list[int | None] = []
    angle: list[float | None] = []
    torque: list[float | None] = []
    for r in rows:
        n = len(r["angle"] or [])
        ids += [r["id"]] * n
        angle += list(r["angle"] or [])
        torque += list((r["torque"] or []) + [0.5] * n)[:n]
    if ids and draw(st.integers(0, 5)) == 0:  # interleave two samples
        i, j = draw(st.integers(0, len(ids) - 1)), draw(st.integers(0, len(ids) - 1))
        ids[i], ids[j] = ids[j], ids[i]
    float_type = draw(st.sampled_from([pa.float64(), pa.float32()]))
    columns: dict[str, pa.Array] = {"tightening_id": _ids(ids, draw(st.sampled_from(ID_TYPES[:-1])))}
    columns["angle"] = pa.array(angle, float_type)
    columns["torque"] = pa.array(torque, pa.float64())
    if draw(st.booleans()):
        columns["time"] = pa.array([0.001 * i for i in range(len(ids))], pa.float64())
    table = pa.table(columns)
    return _rechunk(table, draw(st.lists(st.integers(0, max(table.num_rows, 1)), max_size=3)))


@PROPERTY_SETTINGS
@given(long_tables(), st.integers(20, 500))
def test_long_layout_results_do_not_depend_on_batches_and_never_merge_ids(table: pa.Table, batch_rows: int) -> None:
    result = _detect(table)
    if result is None:
        return
    expected = _rows(result)
    assert _rows(_detect(table.combine_chunks())) == expected
    assert _rows(_detect(pa.RecordBatchReader.from_batches(table.schema, table.to_batches(max_chunksize=batch_rows)))) == expected
    if "dictionary" not in str(table.schema):
        frame = pl.from_arrow(table)
        assert isinstance(frame, pl.DataFrame)
        streamed = tightscan.detect_batch(frame.lazy(), batch_rows=batch_rows)
        assert _rows(streamed.to_arrow()) == _rows(tightscan.detect_batch(frame).to_arrow())
    # Each run of an id is its own row (a restart may split one run, never join two), in order.
    ids = table.column("tightening_id").to_pylist()
    runs = [v for k, v in enumerate(ids) if k == 0 or v != ids[k - 1]]
    out_ids = result.column("tightening_id").to_pylist()
    collapsed = [v for k, v in enumerate(out_ids) if k == 0 or v != out_ids[k - 1]]
    assert collapsed == runs
    # Every sample with an id is analysed in its tightening (null-id samples are no curve).
    counted = [n for i, n in zip(out_ids, result.column("n_samples").to_pylist()) if i is not None]
    assert sum(counted) == sum(1 for i in ids if i is not None)
    _check_statuses(result)


BROKEN_SCHEMAS = [
    {"angle": pa.array([[1, 2]], pa.list_(pa.int64())), "torque": pa.array([[1.0, 2.0]])},
    {"angle": pa.array([[1.0, 2.0]])},
    {"angle": pa.array(["x"]), "torque": pa.array([1.0])},
    {"tightening_id": pa.array([1.5]), "angle": pa.array([[1.0]]), "torque": pa.array([[1.0]])},
    {"angle": pa.array([1.0, 2.0]), "torque": pa.array([1.0, 2.0])},  # long layout without ids
    {"tightening_id": pa.array([[1]]), "angle": pa.array([[1.0]]), "torque": pa.array([[1.0]])},
]


@pytest.mark.parametrize("columns", BROKEN_SCHEMAS, ids=range(len(BROKEN_SCHEMAS)))
def test_a_table_that_breaks_the_contract_is_a_schema_error(columns: dict[str, pa.Array]) -> None:
    table = pa.table(columns)
    for data in (table, pl.from_arrow(table), table.to_pandas()):
        with pytest.raises(tightscan.SchemaError):
            tightscan.detect_batch(data)


@pytest.mark.parametrize("not_a_table", [None, 3, "angle", [[1.0]], {"angle": [[1.0]]}, object()])
def test_something_that_is_not_a_table_is_a_type_error(not_a_table: object) -> None:
    with pytest.raises(TypeError):
        tightscan.detect_batch(not_a_table)


def test_threads_at_once_give_what_one_thread_gives() -> None:
    """The engine releases the GIL and keeps no shared mutable state: four Python threads
    analysing different tables at once get exactly the serial results."""
    tables = [tightscan.simulate(60, seed=s, fault_fraction=0.5)[0] for s in range(8)]
    serial = [_rows(tightscan.detect_batch(t)) for t in tables]
    with ThreadPoolExecutor(max_workers=4) as pool:
        parallel = list(pool.map(lambda t: _rows(tightscan.detect_batch(t)), tables * 2))
    assert parallel == serial * 2


def test_all_null_dictionary_ids_regression() -> None:
    """Found by the properties above: a dictionary-encoded id column without values (every id
    null) made the engine panic; null ids are unknown, not repeated."""
    angle = pa.array([[0.0, 1.0], [0.0, 2.0]])
    ids = pa.array([None, None], pa.string()).dictionary_encode()
    assert len(ids.dictionary) == 0
    out = tightscan.detect_batch(pa.table({"tightening_id": ids, "angle": angle, "torque": angle}))
    assert out.num_rows == 2
    assert not any(s.startswith("duplicate_id") for s in out.column("status").to_pylist())
    long = pa.table({"tightening_id": pa.array([None] * 3, pa.string()).dictionary_encode(), "angle": [0.0, 1.0, 2.0], "torque": [0.0, 1.0, 2.0]})
    assert tightscan.detect_batch(long).column("status").to_pylist() == ["null_tightening: the tightening is null"]
