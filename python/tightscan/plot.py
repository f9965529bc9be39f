"""Figures of tightenings, detectors, sequences, diagnoses and the detection benchmark.

Engineers judge a tightening by looking at it: these draw what the engine found on the curve it
found it in. Every function returns a :class:`matplotlib.figure.Figure` built without pyplot's
global state (safe in servers, threads and notebooks; nothing is shown), so the caller decides
whether to ``fig.savefig(...)`` it or let a notebook display it. Needs matplotlib
(``pip install 'tightscan[report]'``); ``import tightscan`` does not import it.

>>> import tightscan
>>> from tightscan.plot import plot_tightening
>>> curves, _ = tightscan.simulate(20, seed=3)
>>> results = tightscan.detect_batch(curves)
>>> fig = plot_tightening(curves, results, 0)
>>> fig.axes[0].get_xlabel()
'angle [deg]'
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Sequence, Union

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from ._api import _is_long_layout
from ._tables import as_arrow as _as_arrow, rows_of as _rows_of
from .config import ConfigLike
from .exceptions import DataFileError, InvalidParameterError, SchemaError

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from .diagnose.result import Diagnosis

__all__ = [
    "plot_tightening",
    "plot_detectors",
    "plot_sequence",
    "plot_diagnosis_residual",
    "plot_diagnosis_evidence",
    "plot_spectrum",
    "plot_detection_quality",
    "tightening_curve",
    "result_row",
    "friction_feature",
]

F64 = np.ndarray
PathLike = Union[str, "os.PathLike[str]"]

#: Detectors in the order the engine names them, with the colour each keeps in every figure.
DETECTOR_COLOURS = {"break": "tab:red", "cusum": "tab:purple", "l1": "tab:orange", "kde": "tab:brown", "shewhart": "tab:gray"}
_PHASE_COLOURS = {"rundown": "#e8e8e8", "alignment": "#fff2cc", "elastic window": "#dbeafe", "yield": "#fde2e2"}


def _new_figure(width: float, height: float) -> Figure:
    try:
        from matplotlib.figure import Figure
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("tightscan.plot needs matplotlib: pip install 'tightscan[report]'") from e
    return Figure(figsize=(width, height), layout="constrained")


def _legend(ax: Axes, **kwargs: Any) -> None:
    """A legend when something is labelled (matplotlib warns on an empty one)."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(**kwargs)


def tightening_curve(curves: Any, tightening_id: Any) -> dict[str, F64]:
    """The channels of one tightening as float arrays (``angle``, ``torque`` and, when the table
    has them, ``time``, ``speed``, ``clamp_force``), from either layout of the data contract:
    one row per tightening with list channels, or one row per sample.

    Raises :class:`~tightscan.InvalidParameterError` when the id is not in the table.

    >>> import tightscan
    >>> curves, _ = tightscan.simulate(3, seed=1)
    >>> c = tightening_curve(curves, 2)
    >>> sorted(c), c["angle"].shape == c["torque"].shape
    (['angle', 'speed', 'time', 'torque'], True)
    """
    table = _as_arrow(curves, "curves")
    for name in ("angle", "torque"):
        if name not in table.column_names:
            raise SchemaError(f"the curves have no {name!r} column", name)
    rows = _rows_of(table, tightening_id, "curves")
    channels = [c for c in ("angle", "torque", "time", "speed", "clamp_force") if c in table.column_names]
    out: dict[str, F64] = {}
    long_layout = _is_long_layout(table.schema)
    for name in channels:
        column = rows.column(name)
        if long_layout:
            values = column.to_numpy(zero_copy_only=False)
        else:  # nested: the first row carrying the id (a repeated id is the engine's duplicate_id)
            values = np.asarray(column[0].as_py() or [], dtype=np.float64)
        out[name] = np.asarray(values, dtype=np.float64)
    return out


def result_row(results: Any, tightening_id: Any) -> dict[str, Any]:
    """One tightening's result row as a dict (the first, should the id repeat).

    >>> import tightscan
    >>> curves, _ = tightscan.simulate(3, seed=1)
    >>> result_row(tightscan.detect_batch(curves), 1)["status"]
    'ok'
    """
    rows = _rows_of(_as_arrow(results, "results"), tightening_id, "results")
    row: dict[str, Any] = rows.slice(0, 1).to_pylist()[0]
    return row


def _num(row: Mapping[str, Any], key: str) -> float | None:
    v = row.get(key)
    if v is None:
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def _fired(row: Mapping[str, Any]) -> list[str]:
    text = row.get("detectors_fired") or ""
    return [d for d in str(text).split(",") if d]


def _local_slope(x: F64, y: F64, half_width: int) -> F64:
    """Least-squares slope of y on x over a centred window of samples (prefix sums): the torque
    rate as the curve shows it, without the noise a sample-to-sample difference amplifies."""
    n = len(x)
    if n < 3:
        return np.full(n, np.nan)
    x0 = x - x.mean()
    cs = {k: np.concatenate([[0.0], np.cumsum(v)]) for k, v in {"1": np.ones(n), "x": x0, "y": y, "xx": x0 * x0, "xy": x0 * y}.items()}
    i = np.arange(n)
    lo, hi = np.clip(i - half_width, 0, n), np.clip(i + half_width + 1, 0, n)

    def s(k: str) -> F64:
        return np.asarray(cs[k][hi] - cs[k][lo])

    m, sx, sy, sxx, sxy = s("1"), s("x"), s("y"), s("xx"), s("xy")
    var = sxx - sx * sx / m
    with np.errstate(invalid="ignore", divide="ignore"):
        slope = (sxy - sx * sy / m) / var
    # a window that barely advances in angle (a pause, a controller step) gives no slope worth
    # drawing: its spread is a small fraction of the typical window's
    typical = float(np.nanmedian(var)) if np.any(var > 0) else 0.0
    return np.asarray(np.where(var > max(0.05 * typical, 1e-300), slope, np.nan))


def _torque_at(curve: Mapping[str, F64], angle: float) -> float:
    a, t = curve["angle"], curve["torque"]
    if len(a) == 0:
        return float("nan")
    k = int(np.argmin(np.abs(a - angle)))
    return float(t[k])


def _shade_phases(ax: Axes, row: Mapping[str, Any], angle: F64) -> list[str]:
    """Shades rundown, alignment, the elastic window and the yield zone from the result row's
    angles; returns the phases drawn. Rundown runs to the snug angle (where the elastic line
    meets the prevailing torque), alignment from snug to the start of the elastic window."""
    if len(angle) == 0:
        return []
    first, last = float(np.nanmin(angle)), float(np.nanmax(angle))
    snug, e0, e1, yld = (_num(row, k) for k in ("snug_angle", "elastic_start_angle", "elastic_end_angle", "yield_angle"))
    spans: list[tuple[str, float | None, float | None]] = [
        ("rundown", first, snug),
        ("alignment", snug, e0),
        ("elastic window", e0, e1),
        ("yield", yld, last if yld is not None else None),
    ]
    drawn = []
    for name, lo, hi in spans:
        if lo is None or hi is None or hi <= lo:
            continue
        ax.axvspan(lo, hi, color=_PHASE_COLOURS[name], alpha=0.8, lw=0, zorder=0, label=name, gid=f"phase:{name}")
        drawn.append(name)
    return drawn


def plot_tightening(curves: Any, results: Any, tightening_id: Any, *, ax: Axes | None = None) -> Figure:
    """Torque against angle of one tightening with what the engine found in it.

    Drawn: the phases shaded from the result row (rundown up to the snug angle, alignment up to
    the elastic window, the elastic window, the yield zone from ``yield_angle`` when the curve
    yields), the fitted elastic line (``prevailing_torque + torque_rate (angle - snug_angle)``),
    the tested window's ends, and for a detected change its onset (``change_angle``, a dashed
    line labelled with ``detectors_fired``) and each firing detector's own change estimate
    (``<detector>_change_angle``, or its alarm angle). On a second axis the torque rate along the
    curve (a local least-squares slope of the measured torque); on a third the clamp force when
    the curves have it. A row without a change gets no change markers.

    ``curves``: the tightenings in either contract layout; ``results``: :func:`detect_batch`'s
    rows for them (any Arrow table). ``ax``: draw into this Axes (its figure is returned),
    else a new figure. An id missing from either table raises
    :class:`~tightscan.InvalidParameterError`.
    """
    curve = tightening_curve(curves, tightening_id)
    row = result_row(results, tightening_id)
    if ax is None:
        fig = _new_figure(9.0, 4.8)
        ax = fig.add_subplot()
    else:
        from matplotlib.figure import Figure as _Figure

        parent = ax.figure  # a SubFigure's own .figure is the root figure
        fig = parent if isinstance(parent, _Figure) else parent.figure
    angle, torque = curve["angle"], curve["torque"]
    _shade_phases(ax, row, angle)
    ax.plot(angle, torque, color="k", lw=0.9, label="torque", gid="torque")

    rate, snug, prevailing = _num(row, "torque_rate"), _num(row, "snug_angle"), _num(row, "prevailing_torque")
    e1 = _num(row, "elastic_end_angle")
    if rate is not None and snug is not None and prevailing is not None:
        end = e1 if e1 is not None else float(np.nanmax(angle))
        xs = np.array([snug, end])
        ax.plot(xs, prevailing + rate * (xs - snug), color="tab:blue", lw=1.4, ls="-", label=f"elastic line ({rate:.4g} Nm/deg)", gid="elastic_line")
    for key in ("tested_start_angle", "tested_end_angle"):
        v = _num(row, key)
        if v is not None:
            ax.axvline(v, color="tab:blue", lw=0.6, ls=":", gid=key)

    fired = _fired(row)
    change = _num(row, "change_angle")
    if row.get("change_detected") and change is not None:
        label = f"change onset {change:.1f} deg ({', '.join(fired) or 'rule'})"
        ax.axvline(change, color="tab:red", lw=1.3, ls="--", label=label, gid="change_onset")
        ax.plot([change], [_torque_at(curve, change)], marker="v", ms=10, color="tab:red", ls="none", gid="change_onset_marker")
        for det in fired:
            where = _num(row, f"{det}_change_angle") or _num(row, f"{det}_alarm_angle")
            if where is None:
                continue
            ax.plot([where], [_torque_at(curve, where)], marker="o", ms=7, mfc="none", mew=1.6,
                    color=DETECTOR_COLOURS.get(det, "k"), ls="none", label=f"{det} at {where:.1f} deg", gid=f"detector:{det}")
    ax.set_xlabel("angle [deg]")
    ax.set_ylabel("torque [Nm]")
    status = str(row.get("status") or "")
    verdict = "change detected" if row.get("change_detected") else ("no change" if row.get("change_detected") is False else "not decided")
    ax.set_title(f"tightening {tightening_id}: {verdict} (status {status.split(':')[0]})", fontsize=10)

    handles, labels = ax.get_legend_handles_labels()
    if len(angle) >= 3:
        rate_ax = ax.twinx()
        half = max(2, len(angle) // 80)
        rate_ax.plot(angle, _local_slope(angle, torque, half), color="tab:green", lw=0.7, alpha=0.8, label="torque rate (local slope)", gid="torque_rate")
        rate_ax.set_ylabel("torque rate [Nm/deg]", color="tab:green")
        rate_ax.tick_params(axis="y", colors="tab:green")
        finite = _local_slope(angle, torque, half)
        finite = finite[np.isfinite(finite)]
        if len(finite):
            lo, hi = np.percentile(finite, [1, 99.5])
            pad = 0.1 * max(hi - lo, 1e-9)
            rate_ax.set_ylim(min(lo, 0.0) - pad, hi + pad)
        h2, l2 = rate_ax.get_legend_handles_labels()
        handles, labels = handles + h2, labels + l2
        if "clamp_force" in curve and np.any(np.isfinite(curve["clamp_force"])):
            force_ax = ax.twinx()
            force_ax.spines["right"].set_position(("axes", 1.12))
            force_ax.plot(angle, curve["clamp_force"], color="tab:cyan", lw=0.8, label="clamp force", gid="clamp_force")
            force_ax.set_ylabel("clamp force [kN]", color="tab:cyan")
            force_ax.tick_params(axis="y", colors="tab:cyan")
            h3, l3 = force_ax.get_legend_handles_labels()
            handles, labels = handles + h3, labels + l3
    ax.legend(handles, labels, loc="upper left", fontsize=7, framealpha=0.85)
    if snug is not None and len(angle):
        peak = float(np.nanmax(angle))
        span = max(peak - snug, 1e-6)
        ax.set_xlim(max(float(np.nanmin(angle)), snug - 1.5 * span), peak + 0.05 * span)
        shown = (angle >= snug - 1.5 * span)
        if shown.any():
            top = float(np.nanmax(torque[shown]))
            ax.set_ylim(min(0.0, float(np.nanmin(torque[shown]))), 1.08 * top)
    return fig


def _onset(ax: Axes, row: Mapping[str, Any]) -> None:
    """The detected change's onset, as the results report it, on a panel over angle."""
    onset = _num(row, "change_angle")
    if row.get("change_detected") and onset is not None:
        ax.axvline(onset, color="k", ls="--", lw=1.2, label=f"detected onset {onset:.1f} deg", gid="change_onset")


def _alarm_and_onset(ax: Axes, row: Mapping[str, Any], detector: str, fired: bool = True) -> None:
    """A detector's own alarm angle (when it fired) and the rule's detected onset, on a panel
    over angle."""
    alarm = _num(row, f"{detector}_alarm_angle")
    if fired and alarm is not None:
        ax.axvline(alarm, color=DETECTOR_COLOURS[detector], ls=":", lw=1.2, label=f"alarm {alarm:.1f} deg", gid=f"{detector}_alarm_angle")
    _onset(ax, row)
    ax.set_xlabel("angle [deg]")


def _not_run(ax: Axes, what: str, status: str) -> None:
    ax.text(0.5, 0.5, f"{what} did not run on this tightening\n(status: {status})", ha="center", va="center", transform=ax.transAxes, fontsize=8, gid="not_run")
    ax.set_xticks([])
    ax.set_yticks([])


def plot_detectors(curves: Any, results: Any, tightening_id: Any, *, config: ConfigLike = None) -> Figure:
    """What each detector computed along one tightening, four panels, from the engine's own
    traces (:func:`tightscan.detector_traces`: the statistics the decision used, on the
    whitened window with its noise model, not a recomputation from the raw curve).

    1. CUSUM: the upper and lower paths S+ and S- over the monitored blocks' angles, with the
       threshold h; an alarm where a path first exceeds it.
    2. L1 monitoring: the statistic |Q(m, k)| with its gamma boundary
       g(m, k, gamma) = c sqrt(m) (1 + k/m) (k/(m+k))^gamma; an alarm where it first reaches it.
    3. Break scan: the likelihood-ratio profile over the candidate break points with its
       critical value (and, where the noise model's uncertainty raises it, the level the scan
       decides on), and the split at its maximum.
    4. Kernel densities of the line residuals: the reference before and the part after it
       that the kernel-density test found most different.

    Panels 1 to 3 mark the detected onset (``change_angle`` of the results) and each
    detector's alarm. The traces are computed with ``config``; by default the configuration
    the results record (:func:`tightscan.results_metadata`), else the defaults: give the
    config the results were made with, or the traces are of another analysis.

    >>> import tightscan
    >>> curves, _ = tightscan.simulate(5, seed=3)
    >>> fig = plot_detectors(curves, tightscan.detect_batch(curves), 1)
    >>> [ax.get_title(loc="left") for ax in fig.axes]
    ['CUSUM', 'L1 monitoring', 'break scan', 'residual densities']
    """
    from ._metadata import results_metadata
    from .traces import detector_traces

    row = result_row(results, tightening_id)
    if config is None:
        recorded = results_metadata(results)
        config = recorded.get("config") if recorded else None
    traces = detector_traces(curves, tightening_id, config)
    status = traces.status
    fig = _new_figure(11.0, 7.0)
    (ax_cusum, ax_l1), (ax_break, ax_kde) = fig.subplots(2, 2)

    # 1. CUSUM paths and threshold
    ax_cusum.set_title("CUSUM", loc="left", fontsize=9)
    c = traces.cusum
    if c is not None and len(c.angle):
        ax_cusum.plot(c.angle, c.upper, ".-", ms=3, lw=0.9, color=DETECTOR_COLOURS["cusum"], label="S+ (rate up)", gid="cusum:upper")
        ax_cusum.plot(c.angle, c.lower, ".-", ms=3, lw=0.9, color="tab:cyan", label="S- (rate down)", gid="cusum:lower")
        ax_cusum.axhline(c.threshold, color="k", ls=":", lw=1, label=f"threshold h = {c.threshold:.3g}", gid="cusum:threshold")
        _alarm_and_onset(ax_cusum, row, "cusum", fired=bool(row.get("cusum_alarm")))
        ax_cusum.set_ylabel("statistic [sigma]")
        ax_cusum.set_title(f"kappa {c.kappa:.3g}; max {max(float(np.max(c.upper)), float(np.max(c.lower))):.3g}", loc="right", fontsize=8)
        _legend(ax_cusum, fontsize=7)
    else:
        _not_run(ax_cusum, "the CUSUM", status)

    # 2. L1 statistic and gamma boundary
    ax_l1.set_title("L1 monitoring", loc="left", fontsize=9)
    m = traces.l1
    if m is not None and len(m.angle):
        ax_l1.plot(m.angle, m.statistic, ".-", ms=3, lw=0.9, color=DETECTOR_COLOURS["l1"], label="|Q(m, k)|", gid="l1:statistic")
        ax_l1.plot(m.angle, m.boundary, color="k", ls=":", lw=1, label=f"boundary g(m, k, {m.gamma:.2g}), c = {m.critical_value:.3g}", gid="l1:boundary")
        _alarm_and_onset(ax_l1, row, "l1")
        ax_l1.set_ylabel("cumulated signs")
        ax_l1.set_title(f"m = {m.training} training blocks", loc="right", fontsize=8)
        _legend(ax_l1, fontsize=7)
    else:
        _not_run(ax_l1, "L1 monitoring", status)

    # 3. break scan's LR profile
    ax_break.set_title("break scan", loc="left", fontsize=9)
    b = traces.breaks
    if b is not None and len(b.angle):
        ax_break.plot(b.angle, b.lr, lw=0.9, color=DETECTOR_COLOURS["break"], label="LR over the split point", gid="break:lr")
        ax_break.axhline(b.critical_value, color="k", ls=":", lw=1, label=f"critical value {b.critical_value:.3g}", gid="break:critical_value")
        if b.decision_value > b.critical_value * (1 + 1e-9):
            ax_break.axhline(b.decision_value, color="k", ls="-.", lw=1, label=f"with the noise model's uncertainty {b.decision_value:.3g}", gid="break:decision_value")
        top = int(np.argmax(b.lr))
        ax_break.plot([b.angle[top]], [b.lr[top]], "v", color=DETECTOR_COLOURS["break"], ms=7, label=f"maximum at {b.angle[top]:.1f} deg", gid="break:split")
        _onset(ax_break, row)
        ax_break.set_xlabel("angle [deg]")
        ax_break.set_ylabel("likelihood ratio")
        verdict = "alarm" if b.scan_alarm else "significant, within an encoder step" if b.significant else "no alarm"
        ends = [name for name, fired in (("end", b.tail_alarm), ("start", b.head_alarm), ("episode", b.episode_alarm)) if fired]
        if b.episode_alarm and b.episode is not None:
            ax_break.axvspan(*b.episode, color=DETECTOR_COLOURS["break"], alpha=0.15, label=f"episode {b.episode[0]:.1f}-{b.episode[1]:.1f} deg", gid="break:episode")
        ax_break.set_title(verdict + "".join(f"; {name} test: alarm" for name in ends), loc="right", fontsize=8)
        _legend(ax_break, fontsize=7)
    else:
        _not_run(ax_break, "the break scan", status)

    # 4. densities before and after
    ax_kde.set_title("residual densities", loc="left", fontsize=9)
    k = traces.kde
    if k is not None:
        (b0, b1), (a0, a1) = k.before_angles, k.after_angles
        ax_kde.plot(k.grid, k.before, color="tab:blue", label=f"reference {b0:.1f}-{b1:.1f} deg", gid="kde:before")
        ax_kde.plot(k.grid, k.after, color="tab:red", label=f"{'most different' if k.tested else 'after'} {a0:.1f}-{a1:.1f} deg", gid="kde:after")
        ax_kde.set_xlabel("whitened residual [Nm]")
        ax_kde.set_ylabel("density")
        kde_p = _num(row, "kde_p_value")
        note = f"KDE test p = {kde_p:.3g}" if k.tested and kde_p is not None else "KDE test off (kde=True runs it)"
        ax_kde.set_title(f"{note}; bandwidth {k.bandwidth:.3g}", loc="right", fontsize=8)
        _legend(ax_kde, fontsize=7)
    else:
        _not_run(ax_kde, "the residual densities", status)

    fired = ", ".join(_fired(row)) or "none"
    title = f"tightening {tightening_id}: detectors fired: {fired}"
    if traces.result.get("change_detected") != row.get("change_detected"):
        title += " (these traces decide otherwise: the results were made with another config)"
    fig.suptitle(title, fontsize=10)
    return fig


def friction_feature(columns: Sequence[str], table: pa.Table | None = None) -> str:
    """The friction proxy to monitor: ``mu_tot`` when it has values, else ``torque_rate``."""
    if "mu_tot" in columns and (table is None or table.column("mu_tot").null_count < table.num_rows):
        return "mu_tot"
    if "torque_rate" in columns:
        return "torque_rate"
    raise SchemaError("neither mu_tot nor torque_rate is in the table: name the feature", "feature")


def plot_sequence(
    per_tightening: Any,
    by: Sequence[str] | str | None = None,
    order_by: str | None = None,
    feature: str | None = None,
    *,
    training: int = 10,
    alpha: float = 0.05,
    max_groups: int = 12,
) -> Figure:
    """A control chart per group: ``feature`` (default: the friction proxy, ``mu_tot`` where it
    has values, else ``torque_rate``) in ``order_by`` order, with
    :func:`tightscan.monitor_sequence`'s reference (median of the first ``training`` values,
    the training stretch shaded), limits at the reference median +- 3 reference sd, and the
    first CUSUM and L1 alarms (vertical lines; values after the first alarm in red).

    One to three groups get a second row with the self-starting CUSUM statistic against its
    threshold h; more groups are drawn as small multiples of the values alone, at most
    ``max_groups`` of them (those with the earliest alarms first).

    >>> import pyarrow as pa
    >>> t = pa.table({"station": ["a"] * 40, "n": list(range(40)),
    ...               "torque_rate": [1.0 + 0.01 * (i % 3) + (0.3 if i >= 25 else 0.0) for i in range(40)]})
    >>> fig = plot_sequence(t, by="station", order_by="n")
    >>> [line.get_gid() for line in fig.axes[0].get_lines() if line.get_gid() == "first_alarm"]
    ['first_alarm']
    """
    from .sequence import monitor_sequence

    table = _as_arrow(per_tightening, "per_tightening")
    by_list = [by] if isinstance(by, str) else list(by or [])
    if feature is None:
        feature = friction_feature(table.column_names, table)
    monitor = monitor_sequence(table, by=by_list, order_by=order_by, features=[feature], training=training, alpha=alpha)
    groups = monitor.groups.to_pylist()
    tight = monitor.tightenings
    keys = [tuple(g[c] for c in by_list) for g in groups]
    order_col = order_by

    # the groups with the earliest alarms are the ones to see first
    def rank(i: int) -> tuple[int, Any]:
        first = groups[i]["first_alarm_order"]
        return (0, str(first)) if first is not None else (1, str(keys[i]))

    shown = sorted(range(len(groups)), key=rank)[:max_groups]
    shown.sort(key=lambda i: (groups[i]["first_alarm_order"] is None, str(keys[i])))
    with_cusum = len(shown) <= 3
    cols = min(len(shown), 4) if not with_cusum else max(len(shown), 1)
    rows = (len(shown) + cols - 1) // cols if shown else 1
    fig = _new_figure(max(4.0 * cols, 7.0), (3.0 if not with_cusum else 5.5) * rows)
    grid = fig.subplots(rows * (2 if with_cusum else 1), cols, squeeze=False)
    key_columns = [tight.column(c).to_pylist() for c in by_list]
    tkeys = list(zip(*key_columns)) if by_list else [()] * tight.num_rows
    values_all = np.asarray(tight.column("value").to_numpy(zero_copy_only=False), dtype=float)
    cusum_all = np.asarray(tight.column("cusum").to_numpy(zero_copy_only=False), dtype=float)
    order_all = tight.column(order_col).to_numpy(zero_copy_only=False) if order_col is not None else None
    for slot in range(rows * cols):
        r, c = divmod(slot, cols)
        ax = grid[r * (2 if with_cusum else 1), c]
        if slot >= len(shown):
            ax.set_visible(False)
            if with_cusum:
                grid[r * 2 + 1, c].set_visible(False)
            continue
        g = groups[shown[slot]]
        key = keys[shown[slot]]
        sel = np.array([k == key for k in tkeys], dtype=bool)
        values = values_all[sel]
        x = order_all[sel] if order_all is not None else np.arange(int(sel.sum()))
        med, sd = g["reference_median"], g["reference_sd"]
        first = g["first_alarm_order"]
        position = np.arange(len(values))
        if order_all is None:
            first_pos = first
        else:
            hits = [i for i, v in enumerate(x.tolist()) if v == first] if first is not None else []
            first_pos = hits[0] if hits else None
        n_train = min(training, len(values))
        if n_train:
            ax.axvspan(x[0], x[n_train - 1], color="#eeeeee", lw=0, zorder=0, label=f"reference ({n_train})")
        dense = len(values) > 300  # thousands of points: dots, a line would be a black band
        ax.plot(x, values, "." if dense else ".-", ms=1.5 if dense else 3, lw=0.6, color="k", label=feature, gid="values")
        if first_pos is not None:
            after = position >= first_pos
            ax.plot(x[after], values[after], ".", ms=1.5 if dense else 4, color="tab:red", ls="none", label="after the first alarm", gid="after_alarm")
        if med is not None and math.isfinite(med):
            ax.axhline(med, color="tab:blue", lw=1, label="reference median", gid="centre")
            if sd is not None and math.isfinite(sd) and sd > 0:
                for sign in (-1, 1):
                    ax.axhline(med + sign * 3 * sd, color="tab:blue", ls="--", lw=0.8, gid="limit", label="+-3 reference sd" if sign > 0 else None)
        for kind, colour in (("cusum_alarm_order", "tab:purple"), ("l1_alarm_order", "tab:orange")):
            at = g[kind]
            if at is not None:
                ax.axvline(at, color=colour, lw=1.2, ls=":", label=f"{kind.split('_')[0].upper()} alarm", gid=kind)
        if first is not None:
            ax.axvline(first, color="tab:red", lw=1.4, label=f"first alarm at {first}", gid="first_alarm")
        title = ", ".join(f"{c}={v}" for c, v in zip(by_list, key)) or "all tightenings"
        ax.set_title(f"{title} (n={g['n']})", fontsize=9)
        ax.set_ylabel(feature, fontsize=8)
        ax.tick_params(labelsize=7)
        if slot == 0 or with_cusum:
            _legend(ax, fontsize=6, loc="best")
        if with_cusum:
            cax = grid[r * 2 + 1, c]
            cax.plot(x, cusum_all[sel], color="tab:purple", lw=0.9, label="CUSUM (larger side)", gid="cusum")
            hh = g["cusum_threshold"]
            if hh is not None and math.isfinite(hh):
                cax.axhline(hh, color="k", ls="--", lw=1, label=f"threshold h = {hh:.3g}", gid="cusum_threshold")
            cax.set_xlabel(order_col or "order in the group", fontsize=8)
            cax.set_ylabel("CUSUM [sd]", fontsize=8)
            cax.tick_params(labelsize=7)
            _legend(cax, fontsize=6)
        else:
            ax.set_xlabel(order_col or "order in the group", fontsize=7)
    if len(groups) > len(shown):
        fig.suptitle(f"{feature}: {len(shown)} of {len(groups)} groups (earliest alarms first)", fontsize=10)
    return fig


# ---------------------------------------------------------------------------------------------
# Diagnose


def plot_diagnosis_residual(diagnosis: Diagnosis, which: str = "before") -> Figure:
    """Residuals of the declared model (``which="before"``) or of the model with the effects the
    diagnosis added (``"after"``), out of sample: the mean residual across tightenings along the
    rundown stretch and along the elastic window (in noise sd), and the per-tightening RMSE
    histogram. Needs the :class:`~tightscan.diagnose.Diagnosis` object (its ``plot_data``): the
    JSON document does not carry the samples."""
    if which not in ("before", "after"):
        raise InvalidParameterError(f"which must be 'before' or 'after', not {which!r}", "which")
    p = diagnosis.plot_data
    if not p:
        raise InvalidParameterError("this diagnosis carries no plot data (it was read from JSON?)", "diagnosis")
    e = p["e_before" if which == "before" else "e_after"]
    seg, pos, gid = p["seg"], p["pos"], p["gid"]
    sig = p["sigma_t"][gid]
    z = e / np.where(sig > 0, sig, 1.0)
    fig = _new_figure(15, 4.2)
    axes = fig.subplots(1, 3)
    for ax, sv, title, rng in ((axes[0], 1, "rundown stretch", (-1, 0)), (axes[1], 0, "elastic window", (0, 1))):
        m = seg == sv
        if not m.any():
            ax.set_visible(False)
            continue
        bins = np.linspace(rng[0], rng[1], 41)
        k = np.clip(np.digitize(pos[m], bins) - 1, 0, 39)
        cnt = np.bincount(k, minlength=40)
        mean = np.bincount(k, weights=z[m], minlength=40) / np.maximum(cnt, 1)
        sq = np.bincount(k, weights=z[m] ** 2, minlength=40) / np.maximum(cnt, 1)
        q = np.sqrt(np.maximum(sq - mean**2, 0))
        mid = (bins[1:] + bins[:-1]) / 2
        ax.fill_between(mid, mean - q, mean + q, alpha=0.25, label="mean +- sd across tightenings")
        ax.plot(mid, mean, lw=2, label="mean residual", gid="mean_residual")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_title(f"{title}: residual / noise sd ({which})", fontsize=9)
        ax.set_xlabel("position in the stretch (0 = start of the elastic window)" if sv == 0 else "position before the gap to snug")
        _legend(ax, fontsize=8)
    ax = axes[2]
    rb, ra = p["rb"], p["ra"]
    hi = float(np.percentile(np.r_[rb, ra], 99))
    bins = np.linspace(0, hi if hi > 0 else 1.0, 60)
    ax.hist(rb, bins=bins, alpha=0.5, label=f"before (median {np.median(rb):.3g} Nm)")
    if which == "after":
        ax.hist(ra, bins=bins, alpha=0.5, label=f"after (median {np.median(ra):.3g} Nm)")
    ax.set_title("per-tightening out-of-sample RMSE [Nm]", fontsize=9)
    _legend(ax, fontsize=8)
    rmse = diagnosis.rmse_before if which == "before" else diagnosis.rmse_after
    fig.suptitle(f"residual {which}: RMSE {rmse:.4g} Nm (out of sample)")
    return fig


def plot_diagnosis_evidence(diagnosis: Diagnosis) -> Figure:
    """The evidence of a diagnosis: RMSE as effects are added, each within-tightening effect's
    residual against the candidate signal (binned partial residual: what the effect predicts
    against what the residual before it shows), the rundown periodogram, and up to three
    between-tightening findings against their covariate."""
    p, d = diagnosis.plot_data, diagnosis
    l1 = [e for e in d.effects if e.level == "within_tightening"]
    l2 = [e for e in d.effects if e.level == "between_tightenings"]
    panels: list[tuple[str, Any]] = [("rmse", None)]
    panels += [("partial", e) for e in l1[:4]]
    if p.get("periodogram") is not None:
        panels.append(("periodogram", None))
    panels += [("level2", e) for e in l2[:3] if e.name in p.get("level2", {})]
    cols = min(4, len(panels))
    rows = (len(panels) + cols - 1) // cols
    fig = _new_figure(4.6 * cols, 3.9 * rows)
    axes = fig.subplots(rows, cols, squeeze=False)
    for ax in axes.flat[len(panels):]:
        ax.set_visible(False)
    for ax, (kind, e) in zip(axes.flat, panels):
        if kind == "rmse":
            names = ["declared"] + [x.name for x in l1]
            vals = [d.rmse_before] + [x.rmse_after for x in l1]
            ax.bar(range(len(vals)), vals, color=["gray"] + ["C0"] * len(l1))
            ax.set_xticks(range(len(vals)))
            ax.set_xticklabels(names, rotation=30, ha="right", fontsize=7)
            ax.set_ylabel("out-of-sample RMSE [Nm]")
            ax.set_title("level 1: RMSE as effects are added", fontsize=9)
            nf = d.details.get("noise_floor_estimate")
            if nf:
                ax.axhline(nf, color="k", ls="--", lw=1, label="noise estimate")
                _legend(ax, fontsize=7)
        elif kind == "partial":
            mx, my, _ = p.get("partial", {}).get(e.name, (np.zeros(0), np.zeros(0), None))
            ax.plot(mx, my, "o", ms=3, label="residual before it, binned", gid="partial_residual")
            if len(mx):
                lim = [float(min(mx.min(), my.min())), float(max(mx.max(), my.max()))]
                ax.plot(lim, lim, "k--", lw=1, label="what the effect predicts")
            ax.set_xlabel("effect's contribution [Nm] (tightening's own line removed)", fontsize=7)
            ax.set_ylabel("residual [Nm]")
            ax.set_title(f"{e.name} (gain {100 * e.evidence.get('rmse_gain', float('nan')):.1f} %)", fontsize=9)
            _legend(ax, fontsize=7)
        elif kind == "periodogram":
            per, power = p["periodogram"]
            ax.loglog(per, power)
            ticks = [t for t in (5, 10, 20, 45, 90, 180, 360, 720) if per.min() <= t <= per.max()]
            ax.set_xticks(ticks)
            ax.set_xticklabels([str(t) for t in ticks])
            ax.minorticks_off()
            ax.set_xlabel("period [deg]")
            ax.set_ylabel("mean normalised power")
            ax.set_title("periodogram, rundown before the declared stretch", fontsize=9)
        else:
            x, y, ckind = p["level2"][e.name]
            if ckind == "numeric":
                ax.plot(x, y, ".", ms=2, alpha=0.25)
                u = np.unique(x[np.isfinite(x)])
                if len(u) <= 30:
                    med = [np.median(y[x == v]) for v in u]
                    ax.plot(u, med, "r-o", ms=3, lw=2, label="median per value")
                    _legend(ax, fontsize=7)
                elif "slope" in e.parameters:
                    xs = np.linspace(np.nanmin(x), np.nanmax(x), 50)
                    ax.plot(xs, np.nanmean(y) + e.parameters["slope"]["value"] * (xs - np.nanmean(x)), "r", lw=2)
            else:
                labs = sorted(set(x.tolist()))
                ax.boxplot([y[x == lab] for lab in labs], showfliers=False)
                ax.set_xticks(range(1, len(labs) + 1))
                ax.set_xticklabels(labs, rotation=30, fontsize=7)
            lo, hi = np.nanpercentile(y, [1, 99])
            ax.set_ylim(lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo))
            ax.set_title(e.name, fontsize=9)
            ax.set_xlabel(e.parameters.get("covariate", ""))
            ax.set_ylabel(e.rmse_unit)
    return fig


def _read_json(path: PathLike) -> dict[str, Any]:
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, ValueError) as e:
        raise DataFileError(f"cannot read {os.fspath(path)} as JSON: {e}", os.fspath(path)) from e
    if not isinstance(doc, dict):
        raise DataFileError(f"{os.fspath(path)} holds no JSON object", os.fspath(path))
    return doc


def _diagnosis_document(diagnosis: Diagnosis | Mapping[str, Any] | PathLike) -> dict[str, Any]:
    if isinstance(diagnosis, (str, os.PathLike)):
        doc: dict[str, Any] = _read_json(diagnosis)
        return doc
    if isinstance(diagnosis, Mapping):
        return dict(diagnosis)
    return diagnosis.to_dict()


def plot_spectrum(diagnosis: Diagnosis | Mapping[str, Any] | PathLike) -> Figure:
    """The residual spectrum's peaks: power ratio over the background against period, one panel
    per axis searched (angle, time), each peak marked with the effect that explains it (or
    'unexplained'), and the averaged rundown periodogram behind them when the
    :class:`~tightscan.diagnose.Diagnosis` object is given (the JSON document holds the peaks
    only). ``diagnosis``: the object, its ``to_dict()``, or the path of ``diagnose --json``'s
    file."""
    doc = _diagnosis_document(diagnosis)
    spectrum = doc.get("spectrum") or {}
    peaks = list(spectrum.get("peaks") or [])
    axes_info = spectrum.get("axes") or {}
    domains = sorted({str(q.get("domain")) for q in peaks} | set(axes_info)) or ["angle"]
    fig = _new_figure(5.5 * len(domains), 3.8)
    axes = fig.subplots(1, len(domains), squeeze=False)[0]
    curve = None
    plot_data = getattr(diagnosis, "plot_data", None)
    if isinstance(plot_data, dict) and plot_data.get("periodogram") is not None:
        curve = plot_data["periodogram"]
    for ax, domain in zip(axes, domains):
        unit = "deg" if domain == "angle" else "s"
        if curve is not None and domain == "angle":
            per, power = curve
            ax.plot(per, power, color="0.5", lw=0.8, label="mean normalised power", gid="periodogram")
        mine = [q for q in peaks if q.get("domain") == domain]
        for q in mine:
            period = q.get(f"period_{unit}") or (1.0 / q["frequency"] if q.get("frequency") else None)
            ratio = q.get("power_ratio")
            if period is None or ratio is None:
                continue
            explained = q.get("explained_by")
            colour = "tab:green" if explained else "tab:red"
            ax.vlines(period, 0 if curve is None else 1.0, ratio, color=colour, lw=1.5)
            ax.plot([period], [ratio], "o", color=colour, gid="peak", label=None)
            ax.annotate(f"{period:.3g} {unit}\n{explained or 'unexplained'}", (period, ratio), fontsize=7,
                        textcoords="offset points", xytext=(3, 3))
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(f"period [{unit}]")
        ax.set_ylabel("power / background")
        title = f"residual spectrum over {domain}: {len(mine)} peak{'s' if len(mine) != 1 else ''}"
        ax.set_title(title, fontsize=9)
        if not mine and curve is None:
            ax.text(0.5, 0.5, spectrum.get("note", "no significant peak"), transform=ax.transAxes, ha="center", fontsize=8)
            ax.set_xlim(1, 1000)
            ax.set_ylim(1, 10)
        if ax.get_legend_handles_labels()[0]:
            _legend(ax, fontsize=7)
    return fig


# ---------------------------------------------------------------------------------------------
# Detection quality


def _recall_panels(node: Any, path: str) -> list[tuple[str, dict[str, list[float | None]]]]:
    """Every mapping of name -> list of recalls inside ``recall_vs_magnitude`` (any nesting)."""
    if not isinstance(node, Mapping):
        return []
    series = {str(k): v for k, v in node.items() if isinstance(v, list) and k != "edges"}
    out = [(path, series)] if series else []
    for k, v in node.items():
        if isinstance(v, Mapping):
            out += _recall_panels(v, f"{path} / {k}" if path else str(k))
    return out


def plot_detection_quality(source: Mapping[str, Any] | PathLike = "benches/results/detection_quality.json") -> Figure:
    """Recall against fault magnitude per strategy (detector or peer, at its operating point),
    from the detection-quality benchmark (``benches/detection_quality.py`` writes
    ``benches/results/detection_quality.json``). Every ``name -> [recall per band]`` mapping
    under ``recall_vs_magnitude`` gets drawn, one panel per mapping (e.g. the curves every
    method saw, and ours on all curves), against the band centres of ``edges``."""
    doc: dict[str, Any] = dict(source) if isinstance(source, Mapping) else _read_json(source)
    rvm = doc.get("recall_vs_magnitude")
    if not isinstance(rvm, Mapping):
        raise SchemaError("the benchmark record has no 'recall_vs_magnitude' mapping", "recall_vs_magnitude")
    edges = np.asarray(rvm.get("edges") or [], dtype=float)
    panels = _recall_panels(rvm, "")
    if not panels:
        raise SchemaError("'recall_vs_magnitude' holds no recall series", "recall_vs_magnitude")
    fig = _new_figure(6.0 * len(panels), 4.2)
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    for ax, (title, series) in zip(axes, panels):
        for name, values in series.items():
            y = np.array([np.nan if v is None else float(v) for v in values])
            if len(edges) == len(y) + 1:
                x = 100 * (edges[:-1] + edges[1:]) / 2
            else:
                x = np.arange(len(y), dtype=float)
            ax.plot(x, 100 * y, "o-", ms=3, lw=1, label=name, gid=f"recall:{name}")
        ax.set_xlabel("fault magnitude [%]" if len(edges) else "magnitude band")
        ax.set_ylabel("recall [%]")
        ax.set_ylim(-2, 102)
        ax.set_title(title.replace("_", " ") or "recall", fontsize=9)
        _legend(ax, fontsize=6)
    return fig
