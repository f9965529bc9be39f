"""Tables as the figures and traces read them: any Arrow-capable frame as a pyarrow Table, and
one tightening's rows of it."""

from __future__ import annotations

from typing import Any

import pyarrow as pa
import pyarrow.compute as pc

from ._api import _frame_kind
from .exceptions import InvalidParameterError, SchemaError


def as_arrow(data: Any, what: str) -> pa.Table:
    """A pyarrow Table of ``data`` (pyarrow, pandas, polars, anything with the Arrow C stream)."""
    if isinstance(data, pa.Table):
        return data
    if isinstance(data, pa.RecordBatch):
        return pa.Table.from_batches([data])
    kind = _frame_kind(data)
    if kind == "pandas":
        return pa.Table.from_pandas(data, preserve_index=False)
    if kind == "polars":
        table: pa.Table = data.to_arrow()
        return table
    if kind == "polars_lazy":
        table = data.collect().to_arrow()
        return table
    if hasattr(data, "__arrow_c_stream__"):
        return pa.table(data)
    raise TypeError(f"{what} must be an Arrow table (pyarrow, pandas, polars ...), not {type(data).__name__}")


def rows_of(table: pa.Table, tightening_id: Any, what: str) -> pa.Table:
    if "tightening_id" not in table.column_names:
        raise SchemaError(f"the {what} have no 'tightening_id' column", "tightening_id")
    ids = table.column("tightening_id")
    try:
        mask = pc.equal(ids, pa.scalar(tightening_id, type=ids.type))
    except (pa.ArrowInvalid, pa.ArrowTypeError, pa.ArrowNotImplementedError, TypeError) as e:
        raise InvalidParameterError(
            f"tightening_id {tightening_id!r} does not fit the {what}' id type {ids.type}", "tightening_id"
        ) from e
    rows = table.filter(pc.fill_null(mask, False))
    if rows.num_rows == 0:
        sample = ", ".join(repr(v) for v in ids.slice(0, 5).to_pylist())
        raise InvalidParameterError(
            f"tightening_id {tightening_id!r} is not in the {what} ({table.num_rows} rows; ids such as {sample})",
            "tightening_id",
        )
    return rows
