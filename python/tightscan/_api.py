"""The Python API: a thin, typed facade over the Rust engine (`tightscan._core`)."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any, Iterable, Iterator, NamedTuple, Sequence, TypeVar, Union, overload

import pyarrow as pa
import pyarrow.compute as pc

from . import _core
from ._metadata import scan_metadata, with_metadata
from .config import ConfigLike, as_dict
from .exceptions import SchemaError

if TYPE_CHECKING:
    import pandas
    import polars

__all__ = [
    "detect_batch",
    "simulate",
    "cusum_threshold",
    "cusum_arl",
    "result_schema",
    "result_columns",
    "ResultColumn",
]

PathLike = Union[str, "os.PathLike[str]"]


def _frame_kind(obj: object) -> str:
    """``"pandas"``, ``"polars"``, ``"polars_lazy"`` or ``"arrow"`` (anything else)."""
    module = type(obj).__module__.split(".")[0]
    name = type(obj).__name__
    if module == "polars" and name in ("DataFrame", "LazyFrame"):
        return "polars" if name == "DataFrame" else "polars_lazy"
    if module == "pandas" and name == "DataFrame":
        return "pandas"
    return "arrow"


def _passthrough_list(passthrough: Sequence[str] | bool | None, columns: Sequence[str]) -> list[str]:
    """`True` passes through every column that is not a channel or the id."""
    if passthrough is None or passthrough is False:
        return []
    if passthrough is True:
        reserved = {"tightening_id", "angle", "torque", "time", "speed", "clamp_force"}
        return [c for c in columns if c not in reserved]
    if isinstance(passthrough, str):
        return [passthrough]
    return list(passthrough)


class ResultColumn(NamedTuple):
    """One column of the result table: its name, Arrow type, unit ('' when none) and meaning."""

    name: str
    type: str
    unit: str
    meaning: str


class ResultColumns(list[ResultColumn]):
    """The list of :func:`result_columns`, shown as a table in a notebook."""

    def _repr_html_(self) -> str:
        from ._html import grid_table

        return grid_table(f"{len(self)} result columns", ["column", "type", "unit", "meaning"], self)


def result_columns() -> list[ResultColumn]:
    """Every column :func:`detect_batch` returns (after ``tightening_id`` and before any
    pass-through column), in order, with its Arrow type, unit and meaning.

    The one source of these is the engine's schema (``crates/tightscan-core``);
    ``docs/data-contract.md`` lists the same columns in the same order, which a test checks.

    >>> import tightscan
    >>> cols = tightscan.result_columns()
    >>> cols[0].name, cols[0].type
    ('status', 'Utf8')
    >>> [c.unit for c in cols if c.name == "torque_rate"]
    ['Nm/deg']
    """
    return ResultColumns(ResultColumn(*c) for c in _core.result_columns())


def result_schema(
    input_schema: Any,
    passthrough: Sequence[str] | bool | None = None,
    config: ConfigLike = None,
) -> pa.Schema:
    """The Arrow schema of :func:`detect_batch`'s results for input of ``input_schema``.

    Engines that need the output type before they run (``dask.dataframe.map_partitions``'s
    ``meta``, a Parquet writer opened ahead of the first batch) get it here, from the same
    place the engine builds its rows. ``input_schema`` is a ``pyarrow.Schema`` or the input
    itself (a pyarrow Table, a pandas or polars DataFrame or LazyFrame, a duckdb relation): the
    types of pass-through columns and ids are those of the input as :func:`detect_batch` sees
    it, so give the frame when its Arrow types are not known (pandas strings, duckdb's
    nullable columns). ``passthrough`` as in :func:`detect_batch`. The result of a pandas or
    polars input has this schema as that library spells it
    (``schema.empty_table().to_pandas(types_mapper=pd.ArrowDtype)``, ``pl.from_arrow(...)``).

    >>> import tightscan
    >>> curves, _ = tightscan.simulate(5, seed=1)
    >>> schema = tightscan.result_schema(curves.schema)
    >>> schema.names == tightscan.detect_batch(curves).column_names
    True
    """
    kind = _frame_kind(input_schema)
    if kind == "pandas":  # the types detect_batch converts a pandas frame to
        input_schema = pa.Schema.from_pandas(input_schema, preserve_index=False)
    elif kind == "polars_lazy":
        input_schema = input_schema.head(0).collect().to_arrow().schema
    if not isinstance(input_schema, pa.Schema):
        if isinstance(input_schema, (pa.Table, pa.RecordBatch)):
            input_schema = input_schema.schema
        elif hasattr(input_schema, "__arrow_c_schema__") or hasattr(input_schema, "__arrow_c_stream__"):
            input_schema = pa.schema(input_schema) if hasattr(input_schema, "__arrow_c_schema__") else pa.RecordBatchReader.from_stream(input_schema).schema
        else:
            raise TypeError(f"result_schema needs a pyarrow.Schema or an Arrow table, not {type(input_schema).__name__}")
    pass_cols = _passthrough_list(passthrough, input_schema.names)
    schema: pa.Schema = _core.result_schema(input_schema, as_dict(config), pass_cols)
    return schema


def _column_names(data: Any, kind: str) -> list[str] | None:
    if isinstance(data, (pa.Table, pa.RecordBatch)):
        return list(data.schema.names)
    if kind == "polars_lazy":
        return list(data.collect_schema().names())
    if isinstance(data, pa.RecordBatchReader):
        return list(data.schema.names)
    columns = getattr(data, "columns", None)  # pandas, polars, duckdb relations
    return [str(c) for c in columns] if columns is not None else None


def _is_long_layout(schema: pa.Schema) -> bool:
    if "angle" not in schema.names:
        return False  # the engine names the missing column
    angle = schema.field("angle").type
    return not (pa.types.is_list(angle) or pa.types.is_large_list(angle) or pa.types.is_list_view(angle))


_Rows = TypeVar("_Rows", pa.Table, pa.RecordBatch)


def _hold_back_last_tightening(table: _Rows) -> tuple[_Rows, _Rows]:
    """Long layout: the last tightening of a batch may go on in the next one; keep it back.
    Shared by the LazyFrame stream here and the Parquet scan (``_scan.py``)."""
    if table.num_rows == 0 or "tightening_id" not in table.column_names:
        return table, table.slice(0, 0)
    ids = table.column("tightening_id")
    last = ids[len(ids) - 1]
    same = pc.is_null(ids) if not last.is_valid else pc.fill_null(pc.equal(ids, last), False)
    other = pc.indices_nonzero(pc.invert(same))
    cut = other[len(other) - 1].as_py() + 1 if len(other) else 0
    return table.slice(0, cut), table.slice(cut)


def _lazy_batches(frame: Any, batch_rows: int) -> Iterator[pa.Table]:
    """A polars LazyFrame as Arrow tables of about ``batch_rows`` rows, never all at once."""
    if hasattr(frame, "collect_batches"):  # polars >= 1.34: the streaming engine's batches
        for chunk in frame.collect_batches(chunk_size=batch_rows, maintain_order=True):
            yield chunk.to_arrow()
        return
    offset = 0  # older polars: one streaming collect per slice
    while True:
        chunk = frame.slice(offset, batch_rows).collect(engine="streaming")
        if chunk.height == 0:
            return
        yield chunk.to_arrow()
        offset += chunk.height


def _detect_lazy(frame: Any, cfg: dict[str, Any] | None, pass_cols: list[str], batch_rows: int) -> pa.Table:
    """Streams a LazyFrame through the engine: memory holds one input batch (plus, in the long
    layout, the tightening that runs on into the next) and the results, not the whole input."""
    results: list[pa.Table] = []
    first_row = 0
    carry: pa.Table | None = None
    long_layout: bool | None = None

    def run(table: pa.Table) -> None:
        nonlocal first_row
        if table.num_rows == 0:
            return
        result = _core.detect(table, cfg, pass_cols, first_row)
        first_row += table.num_rows
        results.append(result)

    for table in _lazy_batches(frame, batch_rows):
        if long_layout is None:
            long_layout = _is_long_layout(table.schema)
        if long_layout:
            if carry is not None and carry.num_rows:
                table = pa.concat_tables([carry, table])
            table, carry = _hold_back_last_tightening(table)
        run(table)
    if carry is not None:
        run(carry)
    if not results:  # no rows: the engine still checks the schema and gives the empty result
        return _core.detect(frame.head(0).collect().to_arrow(), cfg, pass_cols, 0)
    # A repeated id may sit in two batches: flag it over the whole result, as one call would.
    flagged: pa.Table = _core.flag_duplicate_ids(pa.concat_tables(results))
    return flagged


# The frame kind in is the kind out: these tell a type checker so (a polars LazyFrame gives an
# eager polars DataFrame, see the docstring), and anything else Arrow gives a pyarrow Table.
@overload
def detect_batch(
    data: "polars.DataFrame | polars.LazyFrame",
    config: ConfigLike = None,
    *,
    passthrough: Sequence[str] | bool | None = None,
    batch_rows: int = 65_536,
) -> "polars.DataFrame": ...
@overload
def detect_batch(
    data: "pandas.DataFrame",
    config: ConfigLike = None,
    *,
    passthrough: Sequence[str] | bool | None = None,
    batch_rows: int = 65_536,
) -> "pandas.DataFrame": ...
@overload
def detect_batch(
    data: Any,
    config: ConfigLike = None,
    *,
    passthrough: Sequence[str] | bool | None = None,
    batch_rows: int = 65_536,
) -> pa.Table: ...
def detect_batch(
    data: Any,
    config: ConfigLike = None,
    *,
    passthrough: Sequence[str] | bool | None = None,
    batch_rows: int = 65_536,
) -> "pa.Table | pandas.DataFrame | polars.DataFrame":
    """Detect friction changes in every tightening of a table.

    Layout and units follow the data contract (docs/data-contract.md): one row per tightening
    with list channels ``angle`` [deg] and ``torque`` [Nm], or one row per sample. The result
    comes back as the kind of frame that came in, so that it fits the pipeline it came from:

    - pandas DataFrame: a pandas DataFrame of ``pd.ArrowDtype`` columns (no precision lost to
      NumPy: nullable ints and bools stay so). In the nested layout it keeps the input's index,
      one result row per input row, so ``df.join(results)`` lines up and Dask partitions keep
      their divisions.
    - polars DataFrame: a polars DataFrame.
    - polars LazyFrame: streamed batch by batch (``collect_batches``, ``batch_rows`` rows at a
      time), so a ``scan_parquet`` plan larger than memory can be analysed; a tightening of the
      long layout that spans two batches stays whole. Returns a polars **DataFrame**: the
      results are small (one row of scalars per tightening) and complete only at the end (a
      repeated id in a later batch changes the status of an earlier row), so a LazyFrame would
      only pretend to be lazy; call ``.lazy()`` on it to go on lazily.
    - anything else with the Arrow PyCapsule interface (pyarrow Table, RecordBatch or
      RecordBatchReader, a duckdb relation, ...): a pyarrow Table.

    Returns one row per input tightening, in input order. A malformed tightening gets a row
    whose ``status`` says what is wrong, a repeated ``tightening_id`` is reported in every row
    that carries it (``duplicate_id``); a malformed table raises :class:`SchemaError` naming the
    column, and an object that is not a table raises ``TypeError``.
    :func:`result_schema` gives the Arrow schema of the result before the run.

    The results record how they were made (the version, alpha, the rule's shares and the full
    effective config) as JSON under the schema metadata key ``b"tightscan"`` of the pyarrow
    Table, in ``attrs["tightscan"]`` of a pandas DataFrame; polars frames cannot carry it
    (:func:`tightscan.scan_metadata` gives it). :func:`tightscan.results_metadata` reads it.

    ``passthrough`` copies input columns to the results (``True``: every non-channel column).
    The result columns (``status``, ``change_detected``, ``change_angle``, ``detectors_fired``,
    ``torque_rate``, ``mu_tot``, each detector's statistic ...) are listed with their types,
    units and meanings by :func:`result_columns`.

    >>> import tightscan
    >>> curves, truth = tightscan.simulate(200, seed=1)
    >>> results = tightscan.detect_batch(curves)
    >>> results.num_rows
    200
    >>> statuses = results.column("status").to_pylist()
    >>> statuses.count("ok") > 180   # the others say why, e.g. 'too_short: ...'
    True
    """
    kind = _frame_kind(data)
    if kind == "arrow" and not (hasattr(data, "__arrow_c_stream__") or hasattr(data, "__arrow_c_array__")):
        raise TypeError(
            f"detect_batch needs an Arrow table (pyarrow, pandas, polars, duckdb ...), not {type(data).__name__}"
        )
    if batch_rows < 1:
        raise ValueError(f"batch_rows must be at least 1, got {batch_rows}")
    pass_cols: list[str] = []
    if passthrough is True:
        names = _column_names(data, kind)
        if names is None:
            raise TypeError("passthrough=True needs a table whose columns can be listed; name the columns instead")
        pass_cols = _passthrough_list(True, names)
    else:
        pass_cols = _passthrough_list(passthrough, [])
    cfg = as_dict(config)
    if kind == "polars_lazy":
        import polars as pl

        lazy_frame: Any = pl.from_arrow(_detect_lazy(data, cfg, pass_cols, batch_rows))
        return lazy_frame
    if kind == "pandas":
        import pandas as pd

        # pandas' own Arrow export carries the index as a column in some versions; the
        # contract's columns are the frame's columns, so convert without it.
        try:
            table = pa.Table.from_pandas(data, preserve_index=False)
        except (pa.ArrowInvalid, pa.ArrowTypeError) as e:  # e.g. an object column of mixed types
            raise SchemaError(f"the pandas DataFrame does not convert to Arrow: {e}") from e
        result = _core.detect(table, cfg, pass_cols)
        frame: Any = result.to_pandas(types_mapper=pd.ArrowDtype)
        if not _is_long_layout(table.schema) and len(frame) == len(data):
            frame.index = data.index
        frame.attrs["tightscan"] = scan_metadata(cfg)
        return frame
    result = with_metadata(_core.detect(data, cfg, pass_cols), scan_metadata(cfg))
    if kind == "polars":
        import polars as pl

        polars_frame: Any = pl.from_arrow(result)
        return polars_frame
    return result


def simulate(
    n: int,
    *,
    seed: int = 0,
    fault_fraction: float | None = None,
    strategies: Sequence[str] | None = None,
    fault_kinds: Sequence[str] | None = None,
    fault_components: Sequence[str] | None = None,
    magnitude_range: tuple[float, float] | None = None,
    onset_fraction_range: tuple[float, float] | None = None,
    mu_th_range: tuple[float, float] | None = None,
    mu_b_range: tuple[float, float] | None = None,
    joint_stiffness_range: tuple[float, float] | None = None,
    elastic_angle_range: tuple[float, float] | None = None,
    with_yield: bool = False,
    yield_preload_range: tuple[float, float] | None = None,
    yield_gradient_ratio: float | None = None,
    speed_friction: float | None = None,
    torque_lowpass_ms: float | None = None,
    inertia: float | None = None,
    pressure_friction: float | None = None,
    prevailing_torque_nm: float | None = None,
    runout: float | None = None,
    threads: Sequence[str] | None = None,
    torque_noise: float | None = None,
    clamp_force_noise: float | None = None,
    angle_resolution_deg: float | None = None,
    sample_rate_hz: float | None = None,
    with_clamp_force: bool = False,
    first_id: int = 0,
) -> tuple[pa.Table, pa.Table]:
    """Simulate ``n`` labelled tightenings (Rust, parallel, reproducible by ``seed``).

    Returns ``(tightenings, truth)``: the tightenings in the nested contract layout, and per
    tightening the ground truth (``has_change``, ``fault_kind``, ``magnitude``,
    ``onset_angle``, ``mu_th``, ``mu_b``, ``mu_tot``, ``joint_stiffness``, ``yield_angle``,
    ``prevailing_torque``, ``effects`` ...). Unset parameters take the simulator's defaults.

    Ranges are ``(lo, hi)`` drawn uniformly per tightening; equal ends fix the value:
    ``onset_fraction_range`` (fault onset as a fraction of the elastic zone, default
    (0.30, 0.85)), ``mu_th_range`` / ``mu_b_range`` (thread / head friction, default
    (0.10, 0.20)), ``joint_stiffness_range`` [kN/deg] (default: derived from the thread size
    through ``elastic_angle_range`` [deg], default (20, 120), hard to soft).
    ``with_yield`` adds a yield zone: the bolt yields at ``yield_preload_range`` (fraction of
    the fault-free final preload, default (0.80, 0.95)) and the gradient falls to
    ``yield_gradient_ratio`` (default 0.15) of the elastic one.

    Effects, all off (0) by default: ``speed_friction`` a in mu (1 + a ln(v / 30 rpm)),
    ``torque_lowpass_ms`` [ms] first-order low-pass of the torque channel, ``inertia``
    J [kg m^2] adding J * angular acceleration to the measured torque, ``pressure_friction``
    c in mu (1 + c (F / F_target - 1)), ``prevailing_torque_nm`` [Nm] of a locking element
    (the target is raised by it), ``runout`` r in torque * (1 + r sin(angle + phase)).

    >>> curves, truth = simulate(20, seed=1, runout=0.02, with_yield=True)
    >>> truth.column("effects")[0].as_py()
    'runout'
    """
    params: dict[str, Any] = {
        "n": n,
        "seed": seed,
        "fault_fraction": fault_fraction,
        "strategies": list(strategies) if strategies is not None else None,
        "fault_kinds": list(fault_kinds) if fault_kinds is not None else None,
        "fault_components": list(fault_components) if fault_components is not None else None,
        "magnitude_range": tuple(magnitude_range) if magnitude_range is not None else None,
        "onset_fraction_range": tuple(onset_fraction_range) if onset_fraction_range is not None else None,
        "mu_th_range": tuple(mu_th_range) if mu_th_range is not None else None,
        "mu_b_range": tuple(mu_b_range) if mu_b_range is not None else None,
        "joint_stiffness_range": tuple(joint_stiffness_range) if joint_stiffness_range is not None else None,
        "elastic_angle_range": tuple(elastic_angle_range) if elastic_angle_range is not None else None,
        "with_yield": with_yield,
        "yield_preload_range": tuple(yield_preload_range) if yield_preload_range is not None else None,
        "yield_gradient_ratio": yield_gradient_ratio,
        "speed_friction": speed_friction,
        "torque_lowpass_ms": torque_lowpass_ms,
        "inertia": inertia,
        "pressure_friction": pressure_friction,
        "prevailing_torque_nm": prevailing_torque_nm,
        "runout": runout,
        "threads": list(threads) if threads is not None else None,
        "torque_noise": torque_noise,
        "clamp_force_noise": clamp_force_noise,
        "angle_resolution_deg": angle_resolution_deg,
        "sample_rate_hz": sample_rate_hz,
        "with_clamp_force": with_clamp_force,
        "first_id": first_id,
    }
    return _core.simulate(params)


def cusum_threshold(arl0: float, kappa: float, two_sided: bool = True) -> float:
    """CUSUM threshold h (sigma units) whose in-control ARL is ``arl0``, by Siegmund's
    approximation (METHODS.md section 2).

    >>> round(cusum_threshold(469.1, 0.5), 2)
    5.0
    """
    return _core.cusum_threshold(arl0, kappa, two_sided)


def cusum_arl(h: float, kappa: float, shift: float = 0.0, two_sided: bool = True) -> float:
    """Average run length of the CUSUM for a mean shift of ``shift`` sigma (Siegmund).

    >>> round(cusum_arl(4.0, 0.5), 1)
    169.0
    """
    return _core.cusum_arl(h, kappa, shift, two_sided)


def _iter_chunks(n: int, chunk: int) -> Iterable[tuple[int, int]]:
    start = 0
    while start < n:
        yield start, min(chunk, n - start)
        start += chunk
