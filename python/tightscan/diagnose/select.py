"""Step 5, select: which candidates the data supports (partial residuals, correlations, hints),
and level 2: per-tightening parameters against tightening-level covariates."""

from __future__ import annotations

import math
import re
from typing import Any, Sequence

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.compute as pc

from ..exceptions import SchemaError
from .threads import thread_geometry
from .result import Effect
from .prepare import _CHANNELS, _Groups, _NOT_COVARIATES, _Samples, _SPEC_DEFAULT, F64, I64
from .fit import _Engine, _Fit, _one_sided_tests, _Term


def _partial_residual(eng: _Engine, s: _Samples, term: _Term, fit: _Fit, idx: list[int], pcols_before: list[F64], resid_before: F64) -> tuple[F64, F64, F64]:
    """Binned partial-residual plot of an added effect: its fitted contribution (each tightening's
    declared part projected out) against the residual before it was added."""
    if term.per_tightening:
        contrib = np.zeros(len(s.y))
        for col, i in zip(term.columns, idx):
            contrib += col * fit.pcoef[s.gid, i]
    else:
        contrib = np.zeros(len(s.y))
        for col, i in zip(term.columns, idx):
            contrib += col * fit.beta[i]
    _, fitted = eng.g.fit(pcols_before, [contrib])
    x = contrib - fitted[:, 0]
    edges = np.unique(np.percentile(x, np.linspace(0, 100, 41)))
    if len(edges) < 3:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    k = np.clip(np.digitize(x, edges) - 1, 0, len(edges) - 2)
    cnt = np.bincount(k, minlength=len(edges) - 1).astype(np.float64)
    mx = np.bincount(k, weights=x, minlength=len(edges) - 1) / np.maximum(cnt, 1)
    my = np.bincount(k, weights=resid_before, minlength=len(edges) - 1) / np.maximum(cnt, 1)
    ok = cnt > 0
    return mx[ok], my[ok], cnt[ok]


def _hints(model: dict[str, _Term], fit: _Fit, idx: dict[str, list[int]]) -> dict[str, float]:
    """Current estimates that shape the regressors of nonlinear terms (Gauss-Newton refresh)."""
    out: dict[str, float] = {}
    if "channel_delay" in model and "channel_delay" in idx and len(fit.beta) > idx["channel_delay"][0]:
        tau = float(fit.beta[idx["channel_delay"][0]])
        if 0 < tau < 1.0:
            out["tau_s"] = tau
    return out


def _grouped_median(v: F64, gid: I64, n: int) -> F64:
    order = np.lexsort((v, gid))
    vs, gs = v[order], gid[order]
    ok = np.isfinite(vs)
    vs, gs = vs[ok], gs[ok]
    counts = np.bincount(gs, minlength=n)
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    out = np.full(n, np.nan)
    has = counts > 0
    lo = starts + (counts - 1) // 2
    hi = starts + counts // 2
    out[has] = 0.5 * (vs[lo[has]] + vs[hi[has]])
    return out


def _quantiles(v: F64) -> dict[str, float]:
    v = v[np.isfinite(v)]
    if not len(v):
        return {}
    q = np.percentile(v, [5, 25, 50, 75, 95])
    return {"p05": float(q[0]), "p25": float(q[1]), "median": float(q[2]), "p75": float(q[3]), "p95": float(q[4]), "mean": float(np.mean(v))}


def _model_string(s: _Samples, effects: list[Effect]) -> str:
    x = "F" if s.has_clamp else "theta"
    base = f"elastic: T = a_j + b_j {x}; rundown: T = c_j"
    if effects:
        base += "; + " + " + ".join(e.name for e in effects)
    return base


def _partial_corr(eng: _Engine, fit: _Fit, term: _Term, pkey: str, pcols: Sequence[F64]) -> float:
    """Correlation of the current in-sample residual with the term's first regressor, both with
    each tightening's declared (nuisance) part projected out."""
    zr, _ = eng._proj(pkey + "|corr", pcols, term.name, term.columns[0])
    r = fit.resid
    den = float(np.sqrt(np.sum(zr * zr) * np.sum(r * r)))
    return float(np.sum(zr * r) / den) if den > 0 else 0.0


# ---------------------------------------------------------------------------------------------
# Level 2


def _covariate_columns(table: pa.Table, rows: I64, covariates: Sequence[str] | str | None, spec: list[str], group_cols: list[str]) -> dict[str, tuple[str, npt.NDArray[Any]]]:
    """name -> (kind 'numeric'|'categorical', values per tightening)."""
    out: dict[str, tuple[str, npt.NDArray[Any]]] = {}
    idx = pa.array(rows)
    n = len(rows)
    if covariates == "auto":
        names = []
        for f in table.schema:
            if f.name in _CHANNELS or f.name in spec or f.name in group_cols or _NOT_COVARIATES.match(f.name):
                continue
            if pa.types.is_list(f.type) or pa.types.is_large_list(f.type) or pa.types.is_struct(f.type):
                continue
            names.append(f.name)
    elif covariates is None:
        names = []
    else:
        names = [covariates] if isinstance(covariates, str) else list(covariates)
        for c in names:
            if c not in table.column_names:
                raise SchemaError(f"covariates: the table has no column {c!r}", c)
    seen: list[npt.NDArray[Any]] = []
    for name in names:
        col = table.column(name).take(idx)
        t = col.type
        if pa.types.is_timestamp(t) or pa.types.is_date(t):
            v = np.asarray(pc.cast(pc.cast(col, pa.timestamp("s")) if pa.types.is_date(t) else col, pa.int64()).to_numpy(zero_copy_only=False), dtype=np.float64)
            v = v - np.nanmin(v) if np.any(np.isfinite(v)) else v
            kind = "numeric"
        elif pa.types.is_integer(t) or pa.types.is_floating(t) or pa.types.is_boolean(t):
            v = np.asarray(pc.cast(col, pa.float64()).to_numpy(zero_copy_only=False), dtype=np.float64)
            kind = "numeric"
        elif pa.types.is_string(t) or pa.types.is_large_string(t) or pa.types.is_dictionary(t):
            v = np.array([str(x) for x in col.to_pylist()], dtype=object)
            kind = "categorical"
        else:
            continue
        if kind == "numeric":
            fin = v[np.isfinite(v)]
            if len(np.unique(fin)) < 2:
                continue
            if len(np.unique(fin)) > 0.9 * n and covariates == "auto" and not re.search(r"date|time|order|seq", name):
                # an identifier-like number with all values distinct: only as an order
                pass
        else:
            levels = set(v.tolist())
            if len(levels) < 2 or len(levels) > max(2, min(50, n // 20)):
                continue
        if any(len(s_) == len(v) and np.array_equal(s_, v) for s_ in seen if s_.dtype == v.dtype):
            continue
        seen.append(v)
        out[name] = (kind, v)
    out["sequence_order"] = ("numeric", np.arange(n, dtype=np.float64))
    return out


def _effect_fit(kind: str, form: str, xtr: npt.NDArray[Any], rtr: F64, xte: npt.NDArray[Any]) -> tuple[F64, dict[str, Any]]:
    """Fit a covariate effect on training residuals; predict for test rows."""
    if form == "linear":
        ok = np.isfinite(xtr)
        if ok.sum() < 3:
            return np.zeros(len(xte)), {}
        xm = float(np.mean(xtr[ok]))
        sxx = float(np.sum((xtr[ok] - xm) ** 2))
        slope = float(np.sum((xtr[ok] - xm) * rtr[ok]) / sxx) if sxx > 0 else 0.0
        icpt = float(np.mean(rtr[ok])) - slope * xm
        pred = np.where(np.isfinite(xte), icpt + slope * np.nan_to_num(xte), 0.0)
        return pred, {"slope": slope, "intercept": icpt}
    # level means (categorical, or binned numeric)
    if kind == "numeric":
        edges = _bin_edges(xtr)
        ktr = np.digitize(np.nan_to_num(xtr, nan=np.inf), edges).astype(str)
        kte = np.digitize(np.nan_to_num(xte, nan=np.inf), edges).astype(str)
    else:
        ktr, kte = xtr.astype(str), xte.astype(str)
    means: dict[str, float] = {}
    counts: dict[str, int] = {}
    order = np.argsort(ktr, kind="stable")
    ks, rs = ktr[order], rtr[order]
    uniq, first = np.unique(ks, return_index=True)
    sums = np.add.reduceat(rs, first) if len(rs) else np.zeros(0)
    cnt = np.diff(np.r_[first, len(rs)])
    for u, s_, c in zip(uniq, sums, cnt):
        # shrink a little towards 0 so that rare levels do not win by noise
        means[str(u)] = float(s_ / (c + 2.0))
        counts[str(u)] = int(c)
    pred = np.array([means.get(str(k), 0.0) for k in kte])
    return pred, {"means": means, "counts": counts}


def _bin_edges(x: F64) -> F64:
    fin = x[np.isfinite(x)]
    u = np.unique(fin)
    if len(u) <= 30:
        return (u[:-1] + u[1:]) / 2 if len(u) > 1 else np.zeros(0)
    return np.unique(np.percentile(fin, np.linspace(0, 100, 11)[1:-1]))


#: a numeric specification column with more distinct values than this (and than a tenth of the
#: tightenings) is continuous: its cells are its quartiles
SPEC_MAX_LEVELS = 12


def _spec_labels(col: pa.ChunkedArray | pa.Array) -> list[Any]:
    """A specification column's labels for the cells: its values, or for a numeric column that
    varies almost per tightening (a target torque drawn per tightening, a measured stiffness)
    its quartile class -- else every tightening is a cell of its own and no factor or covariate
    can be compared within cells."""
    values: list[Any] = list(col.to_pylist())
    if not (pa.types.is_floating(col.type) or pa.types.is_integer(col.type) or pa.types.is_decimal(col.type)):
        return values
    x = np.array([np.nan if v is None else float(v) for v in values], dtype=np.float64)
    fin = x[np.isfinite(x)]
    if len(np.unique(fin)) <= max(SPEC_MAX_LEVELS, len(x) // 10):
        return values
    edges = np.quantile(fin, [0.25, 0.5, 0.75])
    return [None if not np.isfinite(v) else f"quartile {int(np.searchsorted(edges, v, side='right')) + 1}" for v in x]


def _level2_inputs(table: pa.Table, s: _Samples, fit: _Fit, x_scale_t: F64, spec_columns: Sequence[str] | str | None) -> tuple[dict[str, tuple[F64, str, str]], list[str], npt.NDArray[Any]]:
    """The per-tightening parameters of level 2 (name -> values, unit, description), the
    specification columns and each tightening's specification cell."""
    g = _Groups(s.gid, s.n_tight)
    rd = (s.seg == 1).astype(np.float64)
    rate = fit.pcoef[:, 1] / np.where(x_scale_t > 0, x_scale_t, 1.0)
    # the fitted rundown level (declared level plus whatever the added effects put there)
    fitted = s.y - fit.resid
    prevailing = np.where(g.sum(rd) > 0, g.sum(fitted * rd) / np.maximum(g.sum(rd), 1), np.nan)
    final_angle = s.phases["peak_angle"] - s.phases["snug_angle"]
    params: dict[str, tuple[F64, str, str]] = {
        "torque_rate": (rate, "Nm/kN" if s.has_clamp else "Nm/deg", "torque rate b_j of the elastic line"),
        "prevailing_torque": (prevailing, "Nm", "prevailing (rundown) torque c_j"),
        "tightening_angle": (final_angle, "deg", "angle from snug to the peak torque"),
    }
    if spec_columns == "auto":
        spec = [c for c in _SPEC_DEFAULT if c in table.column_names]
    elif spec_columns is None:
        spec = []
    else:
        spec = [spec_columns] if isinstance(spec_columns, str) else list(spec_columns)
    idx = pa.array(s.rows)
    geometry = ("pitch_mm", "d2_mm", "dkm_mm")
    geo: tuple[F64, F64, F64] | None = None
    if all(c in table.column_names for c in geometry):
        pitch, d2, dkm = (np.asarray(pc.cast(table.column(c).take(idx), pa.float64()).to_numpy(zero_copy_only=False), dtype=np.float64) for c in geometry)
        geo = (pitch, d2, dkm)
    elif "thread" in table.column_names:
        # the geometry from the designation (ISO metric table), as detect_batch reads it
        rows = [thread_geometry(v) for v in table.column("thread").take(idx).to_pylist()]
        if any(r is not None for r in rows):
            arr = np.array([r if r is not None else (np.nan, np.nan, np.nan) for r in rows], dtype=np.float64)
            geo = (arr[:, 0], arr[:, 1], arr[:, 2])
    if s.has_clamp and geo is not None:
        # with clamp force and the thread's geometry: b_j = 0.16 P + mu_tot (0.58 d2 + Dkm / 2)
        # [Nm/kN = mm], so each tightening's total friction coefficient follows from its slope
        pitch, d2, dkm = geo
        lever = 0.58 * d2 + 0.5 * dkm
        mu = np.where(lever > 0, (rate - 0.16 * pitch) / np.where(lever > 0, lever, 1.0), np.nan)
        params["mu_tot"] = (mu, "1", "total friction coefficient from the torque-clamp force slope and the thread geometry")
    if spec:
        keys = list(zip(*[_spec_labels(table.column(c).take(idx)) for c in spec]))
        cell = np.array([str(k) for k in keys], dtype=object)
    else:
        cell = np.array(["all"] * s.n_tight, dtype=object)
    return params, spec, cell


def _level2(
    table: pa.Table,
    s: _Samples,
    fit: _Fit,
    fold_t: I64,
    n_folds: int,
    alpha: float,
    min_gain: float,
    covariates: Sequence[str] | str | None,
    spec_columns: Sequence[str] | str | None,
    group_cols: list[str],
    x_scale_t: F64,
) -> tuple[list[Effect], dict[str, Any], dict[str, Any]]:
    params, spec, cell = _level2_inputs(table, s, fit, x_scale_t, spec_columns)
    xvar = x_scale_t**2
    covs = _covariate_columns(table, s.rows, covariates, spec, group_cols)
    effects: list[Effect] = []
    details: dict[str, Any] = {"specification_columns": spec, "covariates": {k: v[0] for k, v in covs.items()}, "parameters": {}}
    plots: dict[str, Any] = {}
    forms = [(name, kind, form) for name, (kind, _) in covs.items() for form in (("linear", "levels") if kind == "numeric" else ("levels",))]
    m = max(1, len(forms) * len(params))
    for pname, (pval, unit, pdesc) in params.items():
        ok = np.isfinite(pval)
        if ok.sum() < 30:
            continue
        # robust: drop gross outliers of the parameter (5 MADs), reported
        med = float(np.median(pval[ok]))
        mad = float(np.median(np.abs(pval[ok] - med))) * 1.4826
        inl = ok & (np.abs(pval - med) <= 8 * max(mad, 1e-12))
        use = np.flatnonzero(inl)
        y = pval[use]
        folds = fold_t[use]
        added: list[tuple[str, str, str]] = []
        base_pred = _l2_predict(y, folds, n_folds, cell[use], covs, use, added)
        err_base = y - base_pred
        rmse0 = float(np.sqrt(np.mean(err_base**2)))
        prow: dict[str, Any] = {"unit": unit, "tightenings": int(len(use)), "outliers_left_out": int(ok.sum() - len(use)), "rmse_declared": rmse0, "rounds": []}
        current = err_base
        for _round in range(4):
            tried: list[dict[str, Any]] = []
            best: tuple[float, tuple[str, str, str], F64, dict[str, float]] | None = None
            for name, kind, form in forms:
                if any(a[0] == name for a in added):
                    continue
                pred = _l2_predict(y, folds, n_folds, cell[use], covs, use, added + [(name, kind, form)])
                err = y - pred
                d = current**2 - err**2
                tests = _one_sided_tests(d / max(float(np.mean(current**2)), 1e-300))
                rm = float(np.sqrt(np.mean(err**2)))
                gain = (float(np.sqrt(np.mean(current**2))) - rm) / max(float(np.sqrt(np.mean(current**2))), 1e-300)
                sig = tests["p_value"] < alpha / m and gain >= min_gain
                tried.append({"covariate": name, "form": form, "rmse": rm, "rmse_gain": gain, "p_value": tests["p_value"], "significant": sig})
                if sig and (best is None or gain > best[0]):
                    best = (gain, (name, kind, form), err, tests)
            prow["rounds"].append(sorted(tried, key=lambda r: -float(r["rmse_gain"]))[:8])
            if best is None:
                break
            gain, spec_, err, tests = best
            before = float(np.sqrt(np.mean(current**2)))
            previous = current
            added.append(spec_)
            current = err
            name, kind, form = spec_
            summary = _l2_summary(y, cell[use], covs, use, added, spec_)
            consequence: dict[str, Any] = {}
            if pname == "prevailing_torque":
                consequence = {"curve_rmse_nm_before": before, "curve_rmse_nm_after": float(np.sqrt(np.mean(err**2))), "where": "rundown torque level, if c_j were predicted from the covariates"}
            elif pname == "torque_rate":
                w = xvar[use]
                consequence = {
                    "curve_rmse_nm_before": float(np.sqrt(np.mean(previous**2 * w))),
                    "curve_rmse_nm_after": float(np.sqrt(np.mean(err**2 * w))),
                    "where": "elastic window, if b_j were predicted from the covariates",
                }
            eff_name = f"{pname}_vs_{name}"
            effects.append(
                Effect(
                    name=eff_name,
                    description=_l2_description(pname, pdesc, name, kind),
                    level="between_tightenings",
                    significant=True,
                    parameters=summary,
                    rmse_after=float(np.sqrt(np.mean(err**2))),
                    rmse_unit=unit,
                    evidence={
                        "rmse_before": before,
                        "rmse_gain": gain,
                        "p_value": tests["p_value"],
                        "sign_p_value": tests["sign_p_value"],
                        "t_statistic": tests["t_statistic"],
                        "fraction_of_tightenings_improved": tests["fraction_improved"],
                        "bonferroni_alpha": alpha / m,
                        "form": form,
                        "folds": n_folds,
                        "tightenings": int(len(use)),
                    }
                    | ({"curve_level": consequence} if consequence else {}),
                )
            )
            plots[eff_name] = (covs[name][1][use], y, kind)
        details["parameters"][pname] = prow
    return effects, details, plots


def _l2_predict(y: F64, folds: I64, n_folds: int, cell: npt.NDArray[Any], covs: dict[str, tuple[str, npt.NDArray[Any]]], use: I64, added: list[tuple[str, str, str]]) -> F64:
    pred = np.zeros(len(y))
    for f in range(n_folds):
        te = folds == f
        tr = ~te
        if not te.any() or not tr.any():
            continue
        # baseline: specification cell means (grand mean for unseen cells)
        base_tr, base_te = _cell_means(y[tr], cell[tr], cell[te])
        r = y[tr] - base_tr
        p_te = base_te.copy()
        for name, kind, form in added:
            x = covs[name][1][use]
            ptr, _ = _effect_fit(kind, form, x[tr], r, x[tr])
            pte, _ = _effect_fit(kind, form, x[tr], r, x[te])
            r = r - ptr
            p_te += pte
        pred[te] = p_te
    return pred


def _cell_means(y: F64, cell_tr: npt.NDArray[Any], cell_te: npt.NDArray[Any]) -> tuple[F64, F64]:
    grand = float(np.mean(y))
    means: dict[str, float] = {}
    for c in np.unique(cell_tr):
        means[str(c)] = float(np.mean(y[cell_tr == c]))
    return np.array([means[str(c)] for c in cell_tr]), np.array([means.get(str(c), grand) for c in cell_te])


def _l2_summary(y: F64, cell: npt.NDArray[Any], covs: dict[str, tuple[str, npt.NDArray[Any]]], use: I64, added: list[tuple[str, str, str]], spec_: tuple[str, str, str]) -> dict[str, Any]:
    """The effect fitted on all tightenings: slope or level means with standard errors."""
    base, _ = _cell_means(y, cell, cell)
    r = y - base
    for name, kind, form in added:
        x = covs[name][1][use]
        if (name, kind, form) == spec_:
            break
        p, _ = _effect_fit(kind, form, x, r, x)
        r = r - p
    name, kind, form = spec_
    x = covs[name][1][use]
    out: dict[str, Any] = {"covariate": name, "form": form}
    if form == "linear":
        ok = np.isfinite(x)
        xm = float(np.mean(x[ok]))
        sxx = float(np.sum((x[ok] - xm) ** 2))
        slope = float(np.sum((x[ok] - xm) * r[ok]) / sxx)
        res = r[ok] - slope * (x[ok] - xm) - float(np.mean(r[ok]))
        se = float(np.sqrt(np.sum(res**2) / max(ok.sum() - 2, 1) / sxx))
        out["slope"] = {"value": slope, "se": se, "unit": "per unit of " + name}
        lo, hi = float(np.min(x[ok])), float(np.max(x[ok]))
        out["effect_range"] = {"from": lo, "to": hi, "change": slope * (hi - lo)}
    else:
        if kind == "numeric":
            edges = _bin_edges(x)
            k = np.digitize(np.nan_to_num(x, nan=np.inf), edges)
            labels = {}
            fin = np.isfinite(x)
            for b in np.unique(k):
                sel = (k == b) & fin
                labels[int(b)] = f"{float(np.min(x[sel])):g}..{float(np.max(x[sel])):g}" if sel.any() else "missing"
            keys = np.array([labels[int(b)] for b in k], dtype=object)
            order_keys = [labels[int(b)] for b in np.unique(k)]
        else:
            keys = x.astype(str)
            order_keys = [str(u) for u in np.unique(keys)]
        levels = {}
        for lab in order_keys:
            sel = keys == lab
            vals = y[sel]
            levels[lab] = {"mean": float(np.mean(vals)), "se": float(np.std(vals, ddof=1) / math.sqrt(len(vals))) if len(vals) > 1 else None, "n": int(len(vals))}
        out["levels"] = levels
        means = [float(v["mean"]) for v in levels.values() if v["mean"] is not None]
        out["effect_range"] = {"change": float(max(means) - min(means)), "first": means[0], "last": means[-1]}
    return out


def _l2_description(pname: str, pdesc: str, cov: str, kind: str) -> str:
    low = cov.lower()
    if re.search(r"usage|reuse|re_use|count|cycles|use_", low):
        what = "wear with re-use"
    elif re.search(r"order|date|time|seq", low):
        what = "drift over the sequence of tightenings (tool or material drift, temperature)"
    elif kind == "categorical":
        what = f"difference between groups ({cov})"
    else:
        what = f"dependence on {cov}"
    return f"{what}: {pdesc} changes with {cov}"
