"""The Python API: a thin, typed facade over the Rust engine (`tightscan._core`)."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any, Iterable, Sequence, Union

import pyarrow as pa

from . import _core
from .config import ConfigLike, as_dict

if TYPE_CHECKING:
    import polars

__all__ = [
    "detect_batch",
    "simulate",
    "cusum_threshold",
    "cusum_arl",
    "result_schema",
]

PathLike = Union[str, "os.PathLike[str]"]


def _is_polars(obj: object) -> bool:
    return type(obj).__module__.split(".")[0] == "polars" and type(obj).__name__ == "DataFrame"


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


def result_schema(
    input_schema: Any,
    passthrough: Sequence[str] | bool | None = None,
    config: ConfigLike = None,
) -> pa.Schema:
    """The Arrow schema of :func:`detect_batch`'s results for input of ``input_schema``.

    Engines that need the output type before they run (``dask.dataframe.map_partitions``'s
    ``meta``, a Parquet writer opened ahead of the first batch) get it here, from the same
    place the engine builds its rows. ``input_schema`` is a ``pyarrow.Schema`` or anything
    with one (a Table, a polars DataFrame); ``passthrough`` as in :func:`detect_batch`.

    >>> import tightscan
    >>> curves, _ = tightscan.simulate(5, seed=1)
    >>> schema = tightscan.result_schema(curves.schema)
    >>> schema.names == tightscan.detect_batch(curves).column_names
    True
    """
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


def detect_batch(
    data: Any,
    config: ConfigLike = None,
    *,
    passthrough: Sequence[str] | bool | None = None,
) -> "pa.Table | polars.DataFrame":
    """Detect friction changes in every tightening of a table.

    ``data`` is anything that speaks the Arrow PyCapsule interface: a pyarrow Table,
    RecordBatch or RecordBatchReader, a polars DataFrame, a duckdb result. Layout and units
    follow the data contract (docs/data-contract.md): one row per tightening with list
    channels ``angle`` [deg] and ``torque`` [Nm], or one row per sample.

    Returns one row per input tightening, in input order: a polars DataFrame for polars input,
    else a pyarrow Table. A malformed tightening gets a row whose ``status`` says what is wrong;
    a malformed table raises :class:`SchemaError` naming the column.

    ``passthrough`` copies input columns to the results (``True``: every non-channel column).

    >>> import tightscan
    >>> curves, truth = tightscan.simulate(200, seed=1)
    >>> results = tightscan.detect_batch(curves)
    >>> results.num_rows
    200
    >>> statuses = results.column("status").to_pylist()
    >>> statuses.count("ok") > 180   # the others say why, e.g. 'too_short: ...'
    True
    """
    polars_in = _is_polars(data)
    if not (hasattr(data, "__arrow_c_stream__") or hasattr(data, "__arrow_c_array__")):
        raise TypeError(
            f"detect_batch needs an Arrow table (pyarrow, polars, duckdb ...), not {type(data).__name__}"
        )
    pass_cols: list[str] = []
    if passthrough is True:
        names = data.schema.names if isinstance(data, (pa.Table, pa.RecordBatch)) else getattr(data, "columns", None)
        if names is None:
            raise TypeError("passthrough=True needs a pyarrow or polars table; name the columns instead")
        pass_cols = _passthrough_list(True, list(names))
    else:
        pass_cols = _passthrough_list(passthrough, [])
    result = _core.detect(data, as_dict(config), pass_cols)
    if polars_in:
        import polars as pl

        frame: Any = pl.from_arrow(result)
        return frame
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
