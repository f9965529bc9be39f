"""Detection inside Dask: for users who already hold a ``dask.dataframe``.

``tightscan.scan_parquet(..., engine="dask")`` fans a Parquet scan out over a Dask cluster
itself; :func:`detect_partitions` is for a dataframe built otherwise (``dd.read_parquet``
with filters, a join with plant data ...). It needs ``pip install 'tightscan[dask]'``; the
rest of tightscan works without Dask (this module imports it only when called).

Point it at a real cluster by creating the client first:
``dask.distributed.Client("tcp://scheduler:8786")``.
"""

from __future__ import annotations

from typing import Any, Sequence

import pyarrow as pa

from . import _core
from ._api import _passthrough_list, result_schema
from .config import ConfigLike, as_dict

__all__ = ["detect_partitions", "input_schema_of"]

CHANNELS = ("angle", "torque", "time", "speed", "clamp_force")


def input_schema_of(meta: Any) -> pa.Schema:
    """The Arrow schema of a (pandas) partition, from a dataframe's ``_meta``.

    An empty pandas column of Python objects says nothing of its type: channels stored as
    objects are the contract's lists of float64, other object columns strings.
    """
    schema = pa.Schema.from_pandas(meta, preserve_index=False).remove_metadata()
    for i, f in enumerate(schema):
        t = f.type
        if f.name in CHANNELS and (pa.types.is_null(t) or pa.types.is_string(t) or pa.types.is_large_string(t)):
            schema = schema.set(i, pa.field(f.name, pa.list_(pa.float64())))
        elif pa.types.is_null(t):
            schema = schema.set(i, pa.field(f.name, pa.string()))
    return schema


def _detect_pandas(frame: Any, config: dict[str, Any] | None, pass_cols: list[str], out_schema: pa.Schema) -> Any:
    """One partition: pandas in, pandas (ArrowDtype columns) out, typed as the ``meta`` says."""
    import pandas as pd

    table = pa.Table.from_pandas(frame, preserve_index=False)
    result = _core.detect(table, config, pass_cols)
    if result.schema != out_schema:
        result = result.cast(out_schema)
    return result.to_pandas(types_mapper=pd.ArrowDtype)


def detect_partitions(
    ddf: Any,
    config: ConfigLike = None,
    passthrough: Sequence[str] | bool | None = None,
    *,
    input_schema: pa.Schema | None = None,
) -> Any:
    """Friction changes of every tightening of a ``dask.dataframe``, one row per tightening.

    Runs :func:`tightscan.detect_batch` on each partition (``map_partitions`` with the
    result schema as ``meta``, so Dask knows the output before it runs): pandas partitions
    in, pandas partitions with ``pd.ArrowDtype`` columns out, in partition order. Each
    partition must hold whole tightenings (always true in the nested layout; in the long
    layout partition by ``tightening_id``). ``input_schema`` overrides the schema read from
    the dataframe's meta (see :func:`input_schema_of`).
    """
    import pandas as pd

    schema = input_schema if input_schema is not None else input_schema_of(ddf._meta)
    out_schema = result_schema(schema, passthrough, config)
    pass_cols = _passthrough_list(passthrough, schema.names)
    meta = out_schema.empty_table().to_pandas(types_mapper=pd.ArrowDtype)
    return ddf.map_partitions(
        _detect_pandas,
        config=as_dict(config),
        pass_cols=pass_cols,
        out_schema=out_schema,
        meta=meta,
        enforce_metadata=False,
        align_dataframes=False,
    )
