"""One self-contained HTML report of a scan, to send to a colleague.

:func:`write_report` reads the results of :func:`tightscan.scan_parquet` (or any results table),
and writes one HTML file that opens offline: every figure is embedded as a PNG data URI, the
style sheet is inline, nothing is fetched. It holds the summary (tightenings, status counts,
changes by group and by detector, the detectors' levels and limits in use, the version, the
scan's metadata), the tightenings with the strongest evidence of a change with their curves
(given the curves), a control chart per group, the diagnose findings and the benchmark's recall
when given. ``tightscan report`` is the same from the command line. Needs matplotlib and
Jinja2 (``pip install 'tightscan[report]'``).
"""

from __future__ import annotations

import base64
import datetime as _dt
import io
import json
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Sequence, Union

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.dataset as ds
import pyarrow.parquet as pq

from . import _core
from ._metadata import RESULTS_METADATA_KEY, results_metadata
from ._scan import MANIFEST_DIR, read_results
from .exceptions import DataFileError, SchemaError

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from .diagnose.result import Diagnosis

__all__ = ["write_report", "render_report", "worst_tightenings", "DETECTORS"]

PathLike = Union[str, "os.PathLike[str]"]

#: Detectors whose ``<name>_alarm`` columns the summary counts.
DETECTORS = ("break", "cusum", "l1", "kde", "shewhart")
#: Pass-through columns that usually name a group of tightenings (station, tool ...).
_GROUP_HINTS = ("station", "tool", "spindle", "line", "position", "workpiece_location", "strategy", "thread", "program")
_ORDER_HINTS = ("timestamp", "time_stamp", "date", "datetime", "cycle", "tightening_id")


def _figure_uri(fig: Figure, dpi: int = 80) -> str:
    """The figure as a PNG data URI (PNG: a curve of thousands of samples is smaller as pixels
    than as SVG paths, and every browser shows it)."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi)
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def _as_table(data: Any, what: str) -> pa.Table:
    from ._tables import as_arrow

    return as_arrow(data, what)


def _fmt(v: Any, digits: int = 4) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return "-" if not math.isfinite(v) else f"{v:.{digits}g}"
    return str(v)


def _score(results: pa.Table) -> np.ndarray:
    """How strong the evidence of a change is: the largest statistic / limit over the detectors
    (break sup-LR over its critical value, CUSUM maximum over h, the L1 ratio), 0 when none ran."""
    n = results.num_rows
    best = np.zeros(n)

    def col(name: str) -> np.ndarray:
        if name not in results.column_names:
            return np.full(n, np.nan)
        return np.asarray(pc.cast(results.column(name), pa.float64()).to_numpy(zero_copy_only=False), dtype=float)

    with np.errstate(invalid="ignore", divide="ignore"):
        for ratio in (col("break_statistic") / col("break_critical_value"), col("cusum_max_statistic") / col("cusum_threshold"), col("l1_max_ratio")):
            best = np.fmax(best, np.where(np.isfinite(ratio), ratio, 0.0))
    return best


def worst_tightenings(results: pa.Table, n: int = 6) -> pa.Table:
    """The ``n`` tightenings with the strongest evidence of a change: detected changes first,
    then by the largest statistic / limit of any detector (``evidence`` column added)."""
    score = _score(results)
    changed = np.asarray(pc.fill_null(results.column("change_detected"), False).to_numpy(zero_copy_only=False), dtype=bool) if "change_detected" in results.column_names else np.zeros(results.num_rows, dtype=bool)
    order = np.lexsort((-score, ~changed))[: max(n, 0)]
    picked = results.take(pa.array(order, type=pa.int64()))
    return picked.append_column("evidence", pa.array(score[order], type=pa.float64()))


def _status_counts(results: pa.Table) -> list[tuple[str, int]]:
    codes = pc.replace_substring_regex(pc.cast(results.column("status"), pa.string()), r":.*$", "")
    counts = pc.value_counts(codes).to_pylist()
    return sorted(((str(c["values"]), int(c["counts"])) for c in counts), key=lambda x: (-x[1], x[0]))


def _detector_counts(results: pa.Table) -> list[dict[str, Any]]:
    """Per detector: alarms over all tightenings, and how many detected changes it is among the
    detectors that fired for."""
    fired: dict[str, int] = {}
    if "detectors_fired" in results.column_names and "change_detected" in results.column_names:
        changes = results.filter(pc.fill_null(results.column("change_detected"), False))
        parts = pc.list_flatten(pc.split_pattern(pc.fill_null(pc.cast(changes.column("detectors_fired"), pa.string()), ""), ","))
        for c in pc.value_counts(parts).to_pylist():
            if c["values"]:
                fired[str(c["values"])] = int(c["counts"])
    rows = []
    for det in DETECTORS:
        alarm = f"{det}_alarm"
        if alarm not in results.column_names:
            continue
        column = results.column(alarm)
        ran = len(column) - column.null_count
        if ran == 0 and det not in fired:
            continue
        rows.append({"detector": det, "ran": ran, "alarms": int(pc.sum(pc.fill_null(column, False)).as_py() or 0), "in_changes": fired.get(det, 0)})
    return rows


def _levels(results: pa.Table) -> list[tuple[str, str]]:
    """The detectors' levels and limits as the results record them (one value, or the range)."""
    out = []
    for name, label in (
        ("l1_alpha", "L1 monitoring: false-alarm probability per tightening (alpha)"),
        ("l1_gamma", "L1 monitoring: boundary exponent gamma"),
        ("cusum_threshold", "CUSUM threshold h [sigma]"),
        ("break_critical_value", "break scan: critical value of the sup-LR (depends on the window's samples)"),
    ):
        if name not in results.column_names:
            continue
        column = results.column(name)
        if column.null_count == len(column):
            continue
        lo, hi = pc.min(column).as_py(), pc.max(column).as_py()
        out.append((label, _fmt(lo) if lo == hi else f"{_fmt(lo)} to {_fmt(hi)}"))
    return out


#: The decision settings shown as this version's defaults (the results do not record theirs).
_DEFAULT_KEYS = ("alpha", "rule", "detectors", "break_alpha", "l1_alpha", "l1_gamma", "kappa", "arl0")


def _defaults() -> list[tuple[str, str]]:
    config = _core.default_config()
    out = []
    for key in _DEFAULT_KEYS:
        if key in config:
            value = config[key]
            if value is None:  # set by the decision rule's share of alpha (DecisionConfig)
                text = "from alpha and the rule"
            else:
                text = ", ".join(map(str, value)) if isinstance(value, (list, tuple)) else _fmt(value)
            out.append((key, text))
    return out


def _metadata(path: PathLike | None) -> tuple[list[tuple[str, str]], list[dict[str, Any]]]:
    """What the results file says about how it was made: its Parquet key-value metadata (without
    Arrow's and pandas' own schema keys) and, for a scan's directory, the manifests in
    ``_tightscan/``."""
    if path is None:
        return [], []
    p = Path(path)
    meta: list[tuple[str, str]] = []
    manifests: list[dict[str, Any]] = []
    files = [p] if p.is_file() else sorted(q for q in p.rglob("*.parquet") if MANIFEST_DIR not in q.parts)[:1]
    for f in files:
        try:
            kv = pq.read_schema(f).metadata or {}
        except (pa.ArrowInvalid, OSError):
            continue
        for k, v in kv.items():
            key = k.decode(errors="replace")
            if key in ("ARROW:schema", "pandas", RESULTS_METADATA_KEY.decode()):  # the record has its own tables
                continue
            text = v.decode(errors="replace")
            try:
                text = json.dumps(json.loads(text), indent=1, sort_keys=True)
            except ValueError:
                pass
            meta.append((key, text))
    if p.is_dir():
        for m in sorted((p / MANIFEST_DIR).glob("*.json"))[:50]:
            try:
                manifests.append(json.loads(m.read_text()))
            except (OSError, ValueError):
                continue
    return meta, manifests


def _recorded(table: pa.Table, source: PathLike | None) -> dict[str, Any] | None:
    """How the results were made, as they record it (:func:`tightscan.results_metadata`), laid
    out for the report; None for results that record nothing."""
    record = results_metadata(table) or (results_metadata(source) if source is not None else None)
    if record is None:
        return None

    def text(value: Any, rounded: bool = False) -> str:
        if isinstance(value, (list, tuple)):
            return ", ".join(json.dumps(v) if isinstance(v, dict) else str(v) for v in value)
        if value is None:
            return "unset"
        return _fmt(value) if rounded and isinstance(value, float) else str(value)

    config = record.get("config") or {}
    return {
        "version": str(record.get("version", "?")),
        "alpha": text(record.get("alpha")),
        "rule": text(record.get("rule")),
        "detectors": text(record.get("detectors")),
        "shares": [(k, text(v, rounded=True)) for k, v in (record.get("shares") or {}).items()],
        "derived": [(k, text(v, rounded=True)) for k, v in (record.get("derived") or {}).items()],
        "config": [(k, text(config[k])) for k in sorted(config)],
    }


def _guess_groups(results: pa.Table) -> list[str]:
    engine = {c[0] for c in _core.result_columns()} | {"tightening_id"}
    candidates = [c for c in results.column_names if c not in engine]
    ordered = [c for c in _GROUP_HINTS if c in candidates] + [c for c in candidates if c not in _GROUP_HINTS]
    for name in ordered:
        t = results.column(name).type
        if not (pa.types.is_string(t) or pa.types.is_large_string(t) or pa.types.is_dictionary(t) or pa.types.is_integer(t)):
            continue
        distinct = len(pc.unique(results.column(name)))
        if 2 <= distinct <= 24 and (not pa.types.is_integer(t) or name in _GROUP_HINTS):
            return [name]
    return []


def _guess_order(results: pa.Table) -> str | None:
    for name in _ORDER_HINTS:
        if name in results.column_names:
            return name
    return None


def _read_curves(curves: Any, ids: list[Any]) -> pa.Table | None:
    """Only the tightenings the report draws: a Parquet source is read with a filter on the ids."""
    if curves is None or not ids:
        return None
    if isinstance(curves, (str, os.PathLike)):
        try:
            dataset = ds.dataset(os.fspath(curves), format="parquet")
            return dataset.to_table(filter=pc.field("tightening_id").isin(ids))
        except (pa.ArrowInvalid, OSError) as e:
            raise DataFileError(f"cannot read curves {os.fspath(curves)}: {e}", os.fspath(curves)) from e
    table = _as_table(curves, "curves")
    if "tightening_id" not in table.column_names:
        raise SchemaError("the curves have no 'tightening_id' column", "tightening_id")
    return table.filter(pc.is_in(table.column("tightening_id"), pa.array(ids, type=table.column("tightening_id").type)))


def _diagnose_context(diagnosis: Diagnosis | Mapping[str, Any] | PathLike | None) -> dict[str, Any] | None:
    if diagnosis is None:
        return None
    from .plot import _diagnosis_document, plot_diagnosis_evidence, plot_diagnosis_residual, plot_spectrum

    doc = _diagnosis_document(diagnosis)
    figures: list[dict[str, str]] = []
    if getattr(diagnosis, "plot_data", None):
        d: Any = diagnosis
        for which in ("before", "after"):
            figures.append({"title": f"residual {which} the effects found", "uri": _figure_uri(plot_diagnosis_residual(d, which))})
        figures.append({"title": "evidence: residual against each effect's signal", "uri": _figure_uri(plot_diagnosis_evidence(d))})
    if doc.get("spectrum"):
        figures.append({"title": "residual spectrum with its peaks", "uri": _figure_uri(plot_spectrum(diagnosis))})
    effects = [
        {
            "name": e.get("name"),
            "level": str(e.get("level", "")).replace("_", " "),
            "significant": e.get("significant"),
            "rmse_after": _fmt(e.get("rmse_after")),
            "unit": e.get("rmse_unit", "Nm"),
            "description": e.get("description", ""),
        }
        for e in doc.get("effects", [])
    ]
    peaks = [
        {
            "domain": q.get("domain"),
            "period": _fmt(q.get("period_deg", q.get("period_s"))) + (" deg" if q.get("domain") == "angle" else " s"),
            "power_ratio": _fmt(q.get("power_ratio"), 3),
            "p_value": _fmt(q.get("p_value"), 2),
            "explained_by": q.get("explained_by") or "unexplained",
        }
        for q in (doc.get("spectrum") or {}).get("peaks", [])
    ]
    return {
        "model": doc.get("model"),
        "rmse_before": _fmt(doc.get("rmse_before")),
        "rmse_after": _fmt(doc.get("rmse_after")),
        "unexplained_structure": doc.get("unexplained_structure"),
        "tightenings": doc.get("tightenings"),
        "effects": effects,
        "peaks": peaks,
        "figures": figures,
    }


def render_report(
    results: Any,
    *,
    curves: Any = None,
    diagnosis: Diagnosis | Mapping[str, Any] | PathLike | None = None,
    detection_quality: Mapping[str, Any] | PathLike | None = None,
    by: Sequence[str] | str | None = None,
    order_by: str | None = None,
    feature: str | None = None,
    worst: int = 6,
    title: str | None = None,
) -> str:
    """The report's HTML as a string; :func:`write_report` writes it (arguments there)."""
    try:
        import jinja2
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("the report needs Jinja2: pip install 'tightscan[report]'") from e
    from .plot import friction_feature, plot_detection_quality, plot_detectors, plot_sequence, plot_tightening

    source: PathLike | None = results if isinstance(results, (str, os.PathLike)) else None
    table = read_results(results) if source is not None else _as_table(results, "results")
    for name in ("tightening_id", "status"):
        if name not in table.column_names:
            raise SchemaError(f"the results have no {name!r} column: are these tightscan results?", name)
    n = table.num_rows
    changed = table.column("change_detected") if "change_detected" in table.column_names else pa.chunked_array([pa.array([None] * n, pa.bool_())])
    n_changes = int(pc.sum(pc.fill_null(changed, False)).as_py() or 0)
    n_decided = n - changed.null_count

    for name in ([by] if isinstance(by, str) else list(by or [])) + [c for c in (order_by, feature) if c is not None]:
        if name not in table.column_names:
            raise SchemaError(f"column {name!r} is not in the results (pass it through at the scan: --passthrough)", name)
    by_list = [by] if isinstance(by, str) else list(by) if by is not None else _guess_groups(table)
    order_col = order_by if order_by is not None else _guess_order(table)
    groups: list[dict[str, Any]] = []
    if by_list:
        agg = table.select([*by_list, "change_detected"]).group_by(by_list).aggregate([("change_detected", "sum"), ([], "count_all")])
        for r in sorted(agg.to_pylist(), key=lambda r: [str(r[c]) for c in by_list]):
            k, c = int(r["count_all"]), int(r["change_detected_sum"] or 0)
            groups.append({"group": ", ".join(f"{b}={r[b]}" for b in by_list), "tightenings": k, "changes": c, "rate": f"{100 * c / k:.1f} %" if k else "-"})

    # the worst tightenings, with their curves when given
    top = worst_tightenings(table, worst)
    top_rows = top.to_pylist()
    ids = [r["tightening_id"] for r in top_rows]
    curve_table = _read_curves(curves, ids)
    worst_rows = []
    for r in top_rows:
        entry: dict[str, Any] = {
            "id": r["tightening_id"],
            "group": ", ".join(str(r.get(b)) for b in by_list),
            "status": str(r.get("status") or ""),
            "change": {True: "yes", False: "no", None: "not decided"}[r.get("change_detected")],
            "detectors": r.get("detectors_fired") or "-",
            "change_angle": _fmt(r.get("change_angle")),
            "evidence": _fmt(r.get("evidence"), 3),
            "figures": [],
            "missing_curve": False,
        }
        if curve_table is not None:
            in_curves = pc.any(pc.equal(curve_table.column("tightening_id"), pa.scalar(r["tightening_id"], curve_table.column("tightening_id").type))).as_py()
            if in_curves:
                entry["figures"] = [
                    {"title": "curve", "uri": _figure_uri(plot_tightening(curve_table, table, r["tightening_id"]))},
                    {"title": "detectors", "uri": _figure_uri(plot_detectors(curve_table, table, r["tightening_id"]), dpi=70)},
                ]
            else:
                entry["missing_curve"] = True
        worst_rows.append(entry)

    # control charts
    sequence: list[dict[str, str]] = []
    sequence_note = ""
    try:
        feat = feature or friction_feature(table.column_names, table)
        ok = table.filter(pc.fill_null(pc.equal(table.column("status"), "ok"), False))
        if ok.num_rows >= 2:
            sequence.append({"title": f"{feat} per group, in {order_col or 'table'} order", "uri": _figure_uri(plot_sequence(ok, by_list, order_col, feat), dpi=70)})
        else:
            sequence_note = "fewer than two tightenings with status ok: no control chart"
    except SchemaError as e:
        sequence_note = str(e)

    dq_figure = None
    if detection_quality is not None:
        dq_figure = _figure_uri(plot_detection_quality(detection_quality))

    meta, manifests = _metadata(source)
    env = jinja2.Environment(
        loader=jinja2.PackageLoader("tightscan", "templates"),
        autoescape=jinja2.select_autoescape(["html", "j2"], default=True),
        undefined=jinja2.StrictUndefined,
    )
    template = env.get_template("report.html.j2")
    return template.render(
        title=title or f"tightscan report: {os.fspath(source) if source is not None else 'results'}",
        generated=_dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        version=_core.__version__,
        source=os.fspath(source) if source is not None else None,
        tightenings=n,
        decided=n_decided,
        changes=n_changes,
        change_rate=f"{100 * n_changes / n_decided:.1f} %" if n_decided else "-",
        status_counts=_status_counts(table),
        by=by_list,
        groups=groups,
        detectors=_detector_counts(table),
        levels=_levels(table),
        defaults=_defaults(),
        recorded=_recorded(table, source),
        metadata=meta,
        manifests=[
            {"input": m.get("input"), "outputs": ", ".join(m.get("outputs") or []), "scan_key": str(m.get("scan_key", ""))[:16], "stats": m.get("stats", {})}
            for m in manifests
        ],
        worst=worst_rows,
        curves_given=curves is not None,
        sequence=sequence,
        sequence_note=sequence_note,
        diagnose=_diagnose_context(diagnosis),
        detection_quality=dq_figure,
    )


def write_report(
    results: Any,
    output: PathLike,
    *,
    curves: Any = None,
    diagnosis: Diagnosis | Mapping[str, Any] | PathLike | None = None,
    detection_quality: Mapping[str, Any] | PathLike | None = None,
    by: Sequence[str] | str | None = None,
    order_by: str | None = None,
    feature: str | None = None,
    worst: int = 6,
    title: str | None = None,
) -> Path:
    """Writes the self-contained HTML report of ``results`` to ``output``; returns its path.

    ``results``: the results Parquet file or directory :func:`scan_parquet` wrote (its
    metadata and manifests are summarised too), or a results table. ``curves``: the
    tightenings (Parquet path or table, either layout) to draw the ``worst`` tightenings from;
    only those ids are read. ``diagnosis``: a :class:`~tightscan.diagnose.Diagnosis` (all its
    figures), its dict, or the path of ``tightscan diagnose --json``'s file (findings and
    spectrum). ``detection_quality``: ``benches/results/detection_quality.json`` or its dict,
    for the recall-against-magnitude figure. ``by``: the group columns of the control charts
    and of the changes-by-group table (default: a pass-through column such as ``station`` or
    ``strategy`` with 2 to 24 values); ``order_by``: their order (default: ``timestamp``,
    ``date``, ``cycle`` or ``tightening_id``, the first present); ``feature``: what they chart
    (default: ``mu_tot``, else ``torque_rate``).

    >>> import tempfile, pathlib, tightscan
    >>> from tightscan.report import write_report
    >>> curves, _ = tightscan.simulate(30, seed=2)
    >>> results = tightscan.detect_batch(curves, passthrough=["strategy"])
    >>> out = write_report(results, pathlib.Path(tempfile.mkdtemp()) / "r.html", curves=curves, worst=1)
    >>> "data:image/png;base64," in out.read_text()
    True
    """
    html = render_report(
        results, curves=curves, diagnosis=diagnosis, detection_quality=detection_quality,
        by=by, order_by=order_by, feature=feature, worst=worst, title=title,
    )
    path = Path(output)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(html, encoding="utf-8")
    return path
