"""What each detector computed along one tightening: the statistics behind a result row.

A result row reports each detector's extreme (the CUSUM's largest statistic, the break scan's
sup-LR ...). To see *where* along the curve the evidence grew, :func:`detector_traces` runs the
engine's own analysis of one tightening again and keeps the per-block and per-split values:
the same window, noise model, whitening, standardisation and thresholds as
:func:`tightscan.detect_batch` (the Rust steps that make the row record the traces), so a trace
crosses its limit exactly where the row says its detector fired.

>>> import tightscan
>>> curves, _ = tightscan.simulate(5, seed=3)
>>> t = tightscan.detector_traces(curves, 0)
>>> t.status, t.cusum is not None, len(t.breaks.angle) == len(t.breaks.lr)
('ok', True, True)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from . import _core
from ._api import _is_long_layout
from ._tables import as_arrow, rows_of
from .config import ConfigLike, as_dict
from .exceptions import InvalidParameterError

__all__ = ["detector_traces", "DetectorTraces", "CusumTrace", "L1Trace", "BreakTrace", "KdeTrace"]

F64 = np.ndarray


def _array(values: Any) -> F64:
    return np.asarray(values, dtype=np.float64)


@dataclass(frozen=True)
class CusumTrace:
    """The two-sided CUSUM of the standardised block torque rates: ``upper`` (S+) and ``lower``
    (S-) after each monitored block (``angle``: the block's last sample), the standardised rates
    ``z`` fed to it, and the threshold h (an alarm where a path first exceeds it) and drift
    kappa, all in sigma units."""

    angle: F64
    z: F64
    upper: F64
    lower: F64
    threshold: float
    kappa: float


@dataclass(frozen=True)
class L1Trace:
    """The L1 sign-residual monitoring of the block torque rates: ``statistic`` |Q(m, k)| (the
    cumulated signs of the monitored blocks about the training median) against ``boundary``
    g(m, k, gamma) = c sqrt(m) (1 + k/m) (k/(m + k))^gamma, k = 1, 2, ... monitored blocks after
    m = ``training``; an alarm at the first k where the statistic reaches the boundary."""

    angle: F64
    statistic: F64
    boundary: F64
    critical_value: float
    gamma: float
    training: int


@dataclass(frozen=True)
class BreakTrace:
    """The break scan's likelihood-ratio profile LR_k = n ln(RSS_0 / (RSS_left + RSS_right)) over
    every admissible split (``angle``: the split's first right-hand sample, the change start it
    would report). ``critical_value`` is the table's (white noise) at the scan's alpha;
    ``decision_value`` the level the profile must pass, higher where the noise model's
    uncertainty widens the test. ``significant``: the maximum passed it; ``scan_alarm``: and its
    jump exceeded an encoder step; ``tail_alarm``, ``head_alarm``: the end-of-window or
    start-of-window test fired; ``episode``: the episode scan's best stretch (first and last
    angle; ``None`` where no stretch was admissible), ``episode_alarm``: that scan fired."""

    angle: F64
    lr: F64
    critical_value: float
    decision_value: float
    significant: bool
    scan_alarm: bool
    tail_alarm: bool
    head_alarm: bool
    episode: tuple[float, float] | None = None
    episode_alarm: bool = False


@dataclass(frozen=True)
class KdeTrace:
    """Gaussian kernel densities (on ``grid``, residual units) of the elastic line's whitened
    residuals: ``before``, the reference (first ``residual_training_fraction`` of the tested
    window, angles ``before_angles``), and ``after``, the part the kernel-density test found most
    different (its peak window; all of the rest when the test is off, ``tested`` False), with
    the test's bandwidth."""

    grid: F64
    before: F64
    after: F64
    bandwidth: float
    before_angles: tuple[float, float]
    after_angles: tuple[float, float]
    tested: bool


@dataclass(frozen=True)
class DetectorTraces:
    """The traces of one tightening and its result row (``result``, as
    :func:`tightscan.detect_batch` gives it). A detector that did not run (a window too short
    for its blocks, the KDE test's residuals when the line could not be fitted) has ``None``; a
    tightening that could not be analysed has its ``status`` and no traces."""

    tightening_id: Any
    status: str
    result: dict[str, Any] = field(repr=False)
    cusum: CusumTrace | None = None
    l1: L1Trace | None = None
    breaks: BreakTrace | None = None
    kde: KdeTrace | None = None


def _row_number(table: pa.Table, tightening_id: Any) -> int:
    """The tightening's row in the table ``detect`` would see (the permutations of the
    kernel-density test are seeded with it): its row in the nested layout, the number of
    tightenings before it in the long one."""
    ids = table.column("tightening_id")
    mask = pc.fill_null(pc.equal(ids, pa.scalar(tightening_id, type=ids.type)), False)
    first = int(pc.index(mask, True).as_py())
    if not _is_long_layout(table.schema) or first == 0:
        return first
    head = ids.slice(0, first + 1)
    changed = pc.fill_null(pc.not_equal(head.slice(1), head.slice(0, first)), True)
    return int(pc.sum(changed).as_py() or 0)


def detector_traces(curves: Any, tightening_id: Any, config: ConfigLike = None) -> DetectorTraces:
    """What each detector computed along tightening ``tightening_id`` of ``curves`` (either layout
    of the data contract; pyarrow, pandas, polars), with ``config`` as given to
    :func:`tightscan.detect_batch` (the traces are of the results made with the same config).

    The engine analyses that one tightening with the steps and settings of the batch and keeps
    what the row only summarises: the CUSUM paths with the threshold (:class:`CusumTrace`), the
    L1 monitoring statistic with its gamma boundary (:class:`L1Trace`), the break scan's
    likelihood-ratio profile with its critical value (:class:`BreakTrace`), the residual
    densities before and after (:class:`KdeTrace`); ``result`` is the row ``detect_batch`` gives
    for the tightening in ``curves``.

    With ``kde=True`` the kernel-density test's permutations are seeded by the tightening's
    row, as ``detect_batch`` seeds them in a table of one record batch (a table in several
    batches numbers the rows of each batch from 0, and its KDE p-values may differ).

    A malformed tightening (channels of different lengths, nulls, too short ...) gives its
    ``status`` and no traces; an id not in ``curves`` raises
    :class:`~tightscan.InvalidParameterError`, a table without the channels
    :class:`~tightscan.SchemaError`.

    >>> import tightscan
    >>> curves, _ = tightscan.simulate(5, seed=3)
    >>> t = tightscan.detector_traces(curves, 0)
    >>> bool((np.maximum(t.cusum.upper, t.cusum.lower) > t.cusum.threshold).any()) == t.result["cusum_alarm"]
    True
    """
    table = as_arrow(curves, "curves")
    if "tightening_id" not in table.column_names and not _is_long_layout(table.schema):
        # detect_batch numbers such rows from 0: the id is the row
        if not (isinstance(tightening_id, int) and 0 <= tightening_id < table.num_rows):
            raise InvalidParameterError(
                f"tightening_id {tightening_id!r} is not a row of the curves (no 'tightening_id' column; {table.num_rows} rows)",
                "tightening_id",
            )
        rows, row_number = table.slice(tightening_id, 1), tightening_id
    else:
        rows = rows_of(table, tightening_id, "curves")
        row_number = _row_number(table, tightening_id)
        if not _is_long_layout(table.schema):
            rows = rows.slice(0, 1)  # a repeated id: the first row, as plot.tightening_curve reads it
    result_table, raw = _core.detector_traces(rows, row_number, as_dict(config))
    result: dict[str, Any] = result_table.to_pylist()[0]
    c, l1, b, k = raw["cusum"], raw["l1"], raw["breaks"], raw["kde"]
    return DetectorTraces(
        tightening_id=result["tightening_id"],
        status=result["status"],
        result=result,
        cusum=None
        if c is None
        else CusumTrace(_array(c["angle"]), _array(c["z"]), _array(c["upper"]), _array(c["lower"]), c["threshold"], c["kappa"]),
        l1=None
        if l1 is None
        else L1Trace(_array(l1["angle"]), _array(l1["statistic"]), _array(l1["boundary"]), l1["critical_value"], l1["gamma"], l1["training"]),
        breaks=None
        if b is None
        else BreakTrace(
            _array(b["angle"]), _array(b["lr"]), b["critical_value"], b["decision_value"], b["significant"], b["scan_alarm"], b["tail_alarm"], b["head_alarm"],
            None if b["episode"] is None else (float(b["episode"][0]), float(b["episode"][1])), b["episode_alarm"],
        ),
        kde=None
        if k is None
        else KdeTrace(
            _array(k["grid"]), _array(k["before"]), _array(k["after"]), k["bandwidth"], tuple(k["before_angles"]), tuple(k["after_angles"]), k["tested"]
        ),
    )
