"""Monitoring across tightenings: per-tightening features, per group, in production order.

Friction drifts between tightenings too (a station's lubricant runs low, a re-used thread
wears). :func:`monitor_sequence` takes the per-tightening results of :func:`detect_batch` (or
any table with numeric feature columns), splits them into groups (station, tool, joint
position, thread ...), orders each group, and runs a self-starting CUSUM and L1 sign
monitoring (Rust, ``tightscan_core::sequence``) over each feature, each at ``alpha`` per group
and feature.

>>> import pyarrow as pa, tightscan
>>> t = pa.table({"station": ["a"] * 40, "n": list(range(40)),
...               "torque_rate": [1.0 + 0.01 * (i % 3) + (0.3 if i >= 25 else 0.0) for i in range(40)]})
>>> m = tightscan.monitor_sequence(t, by=["station"], order_by="n", features=["torque_rate"])
>>> m.groups.column("first_alarm_order").to_pylist()
[25]
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from . import _core
from .exceptions import SchemaError

__all__ = ["SequenceMonitor", "monitor_sequence", "DEFAULT_FEATURES"]

#: Features monitored by default, when present: the friction signal, the rundown torque, and
#: the angle from snug to the peak (`clamp_angle`, derived), which grows when friction falls.
DEFAULT_FEATURES = ("mu_tot", "torque_rate", "prevailing_torque", "clamp_angle")


@dataclass(frozen=True)
class SequenceMonitor:
    """Result of :func:`monitor_sequence`.

    ``tightenings``: one row per (tightening, feature): the group columns, the order column,
    ``row`` (the tightening's row in the input), ``feature``, ``value``, ``z`` (self-starting standardised value), ``cusum`` (max of the two
    sides), ``cusum_alarm`` / ``l1_alarm`` (true from the first alarm of the group on).

    ``groups``: one row per (group, feature): ``n``, ``cusum_threshold``, the order value of the
    first CUSUM alarm, its side and change-start estimate, of the first L1 alarm, and
    ``first_alarm_order`` (the earlier of the two), plus the reference median and sd.
    """

    tightenings: pa.Table
    groups: pa.Table

    def _alarmed_groups(self) -> int:
        if "first_alarm_order" not in self.groups.column_names:
            return 0
        return int(self.groups.num_rows - self.groups.column("first_alarm_order").null_count)

    def __repr__(self) -> str:
        return (
            f"SequenceMonitor(tightenings={self.tightenings.num_rows:,} rows, groups={self.groups.num_rows:,} rows, "
            f"groups with an alarm={self._alarmed_groups():,})"
        )

    def _repr_html_(self) -> str:
        """For notebooks: one row per (group, feature), the groups with an alarm first."""
        from ._html import grid_table

        groups = self.groups
        if "first_alarm_order" in groups.column_names and groups.num_rows:
            order = pc.sort_indices(pc.is_null(groups.column("first_alarm_order")))
            groups = groups.take(order)
        shown = 20
        rows = [list(r.values()) for r in groups.slice(0, shown).to_pylist()]
        title = (
            f"monitor_sequence: {self.groups.num_rows:,} (group, feature) rows, "
            f"{self._alarmed_groups():,} with an alarm"
        )
        return grid_table(title, groups.column_names, rows, more=max(groups.num_rows - shown, 0))


def _column(table: pa.Table, name: str) -> pa.ChunkedArray:
    if name not in table.column_names:
        raise SchemaError(f"column {name!r} is missing (table has: {', '.join(table.column_names)})", name)
    return table.column(name)


def monitor_sequence(
    results: Any,
    by: Sequence[str] | None = None,
    order_by: str | None = None,
    features: Sequence[str] | None = None,
    *,
    training: int = 10,
    alpha: float = 0.05,
    kappa: float = 0.5,
    gamma: float = 0.25,
) -> SequenceMonitor:
    """Monitors per-tightening ``features`` within each group of ``by``, in ``order_by`` order.

    ``results``: a pyarrow Table or anything with the Arrow PyCapsule interface (polars in gives
    polars tables out). ``features`` default to those of :data:`DEFAULT_FEATURES` present with
    at least one value (``clamp_angle`` = ``peak_angle - snug_angle``). Rows keep their input
    order within a group when ``order_by`` is None. Missing values are skipped, not imputed.
    The first ``training`` values of each group and feature are its in-control reference.
    """
    polars_in = type(results).__module__.startswith("polars")
    table = results.to_arrow() if polars_in else pa.table(results) if not isinstance(results, pa.Table) else results
    if "clamp_angle" not in table.column_names and {"peak_angle", "snug_angle"} <= set(table.column_names):
        table = table.append_column(
            "clamp_angle", pc.subtract(table.column("peak_angle"), table.column("snug_angle"))
        )
    by = list(by or [])
    for name in by:
        _column(table, name)
    if features is None:
        features = [f for f in DEFAULT_FEATURES if f in table.column_names and table.column(f).null_count < len(table)]
        if not features:
            raise SchemaError(f"none of the default features {DEFAULT_FEATURES} is in the table", "features")
    features = list(features)
    for name in features:
        column = _column(table, name)
        if not (pa.types.is_floating(column.type) or pa.types.is_integer(column.type)):
            raise SchemaError(f"feature {name!r} must be numeric, got {column.type}", name)

    order = np.arange(len(table))
    if order_by is not None:
        _column(table, order_by)
        order = np.asarray(pc.sort_indices(table.select([*by, order_by]), sort_keys=[(c, "ascending") for c in [*by, order_by]]))
    elif by:
        # Stable sort by the group keys keeps input order within a group.
        order = np.asarray(pc.sort_indices(table.select(by), sort_keys=[(c, "ascending") for c in by]))
    sorted_table = table.take(pa.array(order))
    if by:
        keys = [tuple(r.values()) for r in sorted_table.select(by).to_pylist()]
    else:
        keys = [()] * len(sorted_table)
    bounds = [0] + [i for i in range(1, len(keys)) if keys[i] != keys[i - 1]] + [len(keys)]
    order_column = sorted_table.column(order_by).to_pylist() if order_by is not None else list(range(len(sorted_table)))

    tight_rows: dict[str, list[Any]] = {k: [] for k in ["feature", "value", "z", "cusum", "cusum_alarm", "l1_alarm"]}
    tight_index: list[int] = []
    group_rows: dict[str, list[Any]] = {
        k: []
        for k in [
            "feature", "n", "reference_median", "reference_sd", "cusum_threshold", "cusum_alarm_order",
            "cusum_side", "cusum_change_order", "l1_alarm_order", "first_alarm_order",
        ]
    }
    group_index: list[int] = []
    for feature in features:
        values = np.asarray(sorted_table.column(feature).to_numpy(zero_copy_only=False), dtype=float)
        for lo, hi in zip(bounds[:-1], bounds[1:]):
            m = _core.monitor_series(values[lo:hi].tolist(), training, alpha, kappa, gamma)
            n = hi - lo
            cusum_at, l1_at = m["cusum_alarm"], m["l1_alarm"]
            for k in range(n):
                tight_index.append(lo + k)
                tight_rows["feature"].append(feature)
                tight_rows["value"].append(values[lo + k])
                tight_rows["z"].append(m["z"][k])
                tight_rows["cusum"].append(m["cusum"][k])
                tight_rows["cusum_alarm"].append(cusum_at is not None and k >= cusum_at)
                tight_rows["l1_alarm"].append(l1_at is not None and k >= l1_at)

            def at(k: int | None, lo: int = lo) -> Any:
                return None if k is None else order_column[lo + k]

            alarms = [a for a in (cusum_at, l1_at) if a is not None]
            group_index.append(lo)
            group_rows["feature"].append(feature)
            group_rows["n"].append(n)
            group_rows["reference_median"].append(m["reference_median"])
            group_rows["reference_sd"].append(m["reference_sd"])
            group_rows["cusum_threshold"].append(m["threshold"])
            group_rows["cusum_alarm_order"].append(at(cusum_at))
            group_rows["cusum_side"].append(m["cusum_side"])
            group_rows["cusum_change_order"].append(at(m["cusum_change"]))
            group_rows["l1_alarm_order"].append(at(l1_at))
            group_rows["first_alarm_order"].append(at(min(alarms)) if alarms else None)

    keep = [*by] + ([order_by] if order_by is not None else [])
    rows = pa.array(tight_index, type=pa.int64())
    columns: dict[str, Any] = {name: sorted_table.column(name).take(rows) for name in keep}
    # The tightening's row in the input, so results can be joined back.
    columns["row"] = pa.array(order[np.asarray(tight_index, dtype=np.int64)], type=pa.int64())
    for name, values_list in tight_rows.items():
        columns[name] = pa.array(values_list, type=pa.float64() if name in ("value", "z", "cusum") else None)
    tightenings = pa.table(columns)
    group_columns: dict[str, Any] = {name: sorted_table.column(name).take(pa.array(group_index, type=pa.int64())) for name in by}
    for name, values_list in group_rows.items():
        group_columns[name] = pa.array(values_list)
    groups = pa.table(group_columns)
    if polars_in:
        import polars as pl

        tight_pl: Any = pl.from_arrow(tightenings)
        groups_pl: Any = pl.from_arrow(groups)
        return SequenceMonitor(tight_pl, groups_pl)
    return SequenceMonitor(tightenings, groups)
