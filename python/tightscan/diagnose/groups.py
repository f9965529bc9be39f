"""Level 2, grouping factors: does a categorical column (operator, station, tool, spindle, screw
batch ...) shift a per-tightening parameter?

Per factor x parameter, within the specification cells (the cell is a fixed effect, so that a
thread size or a target torque is never read as an operator effect):

- one-way ANOVA: the F-test of ``y ~ cell + factor`` against ``y ~ cell`` (statsmodels OLS,
  ``compare_f_test``; with one cell this is :func:`scipy.stats.f_oneway`), with partial eta^2
  and omega^2;
- Kruskal-Wallis (:func:`scipy.stats.kruskal`) on the values aligned by their cell's median,
  with epsilon^2 = H / (n - 1);
- repeated tightenings of one unit (the ``group_by`` columns of the folds: a thread re-used, a
  part): when the factor is constant within each such cluster, the tests take the cluster means
  as their units, so that 25 re-uses of one thread do not count as 25 replicates of its
  position or operator;
- a variance component: random intercept per level (statsmodels ``MixedLM``, REML, the cells as
  fixed effects): group and residual variance, ICC. Convergence problems are reported
  ("not estimated" with the reason), never raised.

Multiple testing: Holm (``statsmodels.stats.multitest.multipletests``) over all factors x
parameters, separately for the F-test and for Kruskal-Wallis; a factor is claimed for a
parameter when *both* reject at ``alpha`` after adjustment (so the family-wise error rate is at
most ``alpha`` for either test's assumptions) and its partial omega^2 is at least
``min_effect``. With two or more factors, two-way ANOVAs with interaction (Type II,
``anova_lm``) of each pair are reported in the details.
"""

from __future__ import annotations

import math
import re
import warnings
from typing import Any, Sequence

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.compute as pc

from ..exceptions import SchemaError
from .prepare import _CHANNELS, _NOT_COVARIATES, F64, I64
from .result import Effect

#: most levels a column may have to be taken as a grouping factor ("auto")
MAX_LEVELS = 50
#: fewest tightenings a level needs to enter a test (smaller levels are left out, reported)
MIN_LEVEL_N = 3
#: smallest partial omega^2 of a claimed factor (Cohen's "small" effect is 0.01)
MIN_EFFECT = 0.01
#: integer columns with at most this many levels are categorical even without a telling name
_INT_LEVELS = 12
_GROUP_NAME = re.compile(r"operator|worker|user|station|tool|spindle|batch|lot|shift|line|machine|nest|fixture|location|position|cavity|supplier|head|cell|channel")
_COUNT_NAME = re.compile(r"usage|reuse|re_use|count|cycles?|order|seq|date|time|index|number|duration|age")
_ID_NAME = re.compile(r"(^|_)id$|^id_code$|serial_number$|^file_name$|^run_id$")

Labels = npt.NDArray[Any]


def factor_columns(
    table: pa.Table, rows: I64, grouping_factors: Sequence[str] | str | None, spec: Sequence[str], group_cols: Sequence[str] = ()
) -> tuple[dict[str, Labels], dict[str, str]]:
    """The grouping factors of a table: name -> labels per tightening (``None`` where missing),
    and name -> why a column was not taken."""
    factors: dict[str, Labels] = {}
    skipped: dict[str, str] = {}
    idx = pa.array(rows)
    n = len(rows)
    if grouping_factors is None:
        return factors, skipped
    auto = grouping_factors == "auto"
    if auto:
        names = [f.name for f in table.schema if f.name not in _CHANNELS and f.name not in spec and not _NOT_COVARIATES.match(f.name)]
    else:
        names = [grouping_factors] if isinstance(grouping_factors, str) else list(grouping_factors)
        for c in names:
            if c not in table.column_names:
                raise SchemaError(f"grouping_factors: the table has no column {c!r}", c)
    seen: list[tuple[str, I64]] = []
    for name in names:
        t = table.schema.field(name).type
        if pa.types.is_list(t) or pa.types.is_large_list(t) or pa.types.is_struct(t) or pa.types.is_map(t):
            if not auto:
                skipped[name] = "not a scalar column"
            continue
        if auto:
            if _ID_NAME.search(name.lower()):
                skipped[name] = "an identifier"
                continue
            if pa.types.is_floating(t) or pa.types.is_timestamp(t) or pa.types.is_date(t) or pa.types.is_duration(t):
                continue  # continuous: a covariate of level 2, not a grouping factor
            if pa.types.is_integer(t):
                low = name.lower()
                if _COUNT_NAME.search(low) and not _GROUP_NAME.search(low):
                    skipped[name] = "a count or order (integer): a covariate of level 2"
                    continue
        col = table.column(name).take(idx)
        if pa.types.is_dictionary(t):
            col = col.cast(t.value_type)
        raw = col.to_pylist()
        labels = np.array([None if v is None or (isinstance(v, float) and not math.isfinite(v)) else str(v) for v in raw], dtype=object)
        present = labels[labels != None]  # noqa: E711 - elementwise on an object array
        if not len(present):
            skipped[name] = "no values (all null)"
            continue
        levels, counts = np.unique(present.astype(str), return_counts=True)
        if len(levels) < 2:
            skipped[name] = f"one level ({str(levels[0])!r})"
            continue
        if auto and pa.types.is_integer(t) and len(levels) > _INT_LEVELS and not _GROUP_NAME.search(name.lower()):
            skipped[name] = f"integer with {len(levels)} levels: a covariate of level 2"
            continue
        if auto and len(levels) > min(MAX_LEVELS, max(2, n // MIN_LEVEL_N)):
            skipped[name] = f"{len(levels)} levels: too many for a grouping factor"
            continue
        if int(np.sum(counts >= MIN_LEVEL_N)) < 2:
            skipped[name] = f"fewer than two levels with at least {MIN_LEVEL_N} tightenings"
            continue
        codes = _codes(labels)
        same = next((other for other, oc in seen if _same_partition(codes, oc)), None)
        if same is not None:
            skipped[name] = f"the same grouping as {same}"
            continue
        seen.append((name, codes))
        factors[name] = labels
    return factors, skipped


def _codes(labels: Labels) -> I64:
    out = np.full(len(labels), -1, dtype=np.int64)
    ok = labels != None  # noqa: E711
    if ok.any():
        _, inv = np.unique(labels[ok].astype(str), return_inverse=True)
        out[ok] = inv
    return out


def _same_partition(a: I64, b: I64) -> bool:
    if len(a) != len(b) or not np.array_equal(a < 0, b < 0):
        return False
    ok = a >= 0
    pairs = np.unique(np.c_[a[ok], b[ok]], axis=0)
    return len(pairs) == len(np.unique(a[ok])) == len(np.unique(b[ok]))


def _dummies(codes: I64, drop_first: bool) -> F64:
    k = int(codes.max()) + 1 if len(codes) else 0
    m = np.zeros((len(codes), k))
    m[np.arange(len(codes)), codes] = 1.0
    return m[:, 1:] if drop_first else m


def _one_pair(y: F64, labels: Labels, cell: Labels, variance_components: bool, clusters: Labels | None = None) -> dict[str, Any]:
    """Tests and effect sizes of one factor on one parameter (finite values, labelled rows).

    ``clusters``: repeated tightenings of one unit (a thread re-used, a part): when the factor
    is constant within each cluster, the tests take the cluster means as their units (the
    tightenings of one cluster are not independent replicates of the factor)."""
    out: dict[str, Any] = {}
    ok = np.isfinite(y) & (labels != None)  # noqa: E711
    if ok.sum() < 2 * MIN_LEVEL_N:
        return {"skipped": f"only {int(ok.sum())} tightenings with a value and a level"}
    y, labels, cell = y[ok], labels[ok].astype(str), cell[ok].astype(str)
    clu = clusters[ok].astype(str) if clusters is not None else None
    # gross outliers of the parameter (8 MADs from their cell's median) are left out, reported
    cell_codes = _codes(cell)
    med = np.array([np.median(y[cell_codes == c]) for c in range(int(cell_codes.max()) + 1)])
    dev = y - med[cell_codes]
    mad = float(np.median(np.abs(dev))) * 1.4826
    inl = np.abs(dev) <= 8 * max(mad, 1e-12 * max(1.0, float(np.max(np.abs(y)))))
    out["outliers_left_out"] = int((~inl).sum())
    y, labels, cell = y[inl], labels[inl], cell[inl]
    clu = clu[inl] if clu is not None else None
    levels, counts = np.unique(labels, return_counts=True)
    small = [str(lev) for lev, c in zip(levels, counts) if c < MIN_LEVEL_N]
    if small:
        keep = ~np.isin(labels, small)
        y, labels, cell = y[keep], labels[keep], cell[keep]
        clu = clu[keep] if clu is not None else None
        out["levels_left_out"] = {"levels": small, "reason": f"fewer than {MIN_LEVEL_N} tightenings"}
    levels = np.unique(labels)
    if len(levels) < 2:
        out["skipped"] = "fewer than two levels with enough tightenings"
        return out
    n = len(y)
    fcodes = _codes(labels)
    ccodes = _codes(cell)
    n_cells = int(ccodes.max()) + 1
    x0 = _dummies(ccodes, drop_first=False)  # cell means (one column: the intercept)
    if np.linalg.matrix_rank(np.c_[x0, _dummies(fcodes, drop_first=True)]) == np.linalg.matrix_rank(x0):
        out["skipped"] = "confounded with the specification cell: no level varies within a cell"
        return out
    # the unit of the tests: the tightening, or the cluster mean where the factor is constant
    # within clusters (a tightening's cell: its cluster's most frequent one)
    unit = "tightening"
    uy, uf, uc = y, fcodes, ccodes
    if clu is not None:
        kc = _codes(clu.astype(object))
        n_clu = int(kc.max()) + 1
        per = np.zeros((n_clu, len(levels)))
        np.add.at(per, (kc, fcodes), 1.0)
        if n_clu < n and np.all((per > 0).sum(axis=1) == 1):
            cnt = np.bincount(kc, minlength=n_clu).astype(np.float64)
            uy = np.bincount(kc, weights=y, minlength=n_clu) / cnt
            uf = np.argmax(per, axis=1).astype(np.int64)
            cc = np.zeros((n_clu, n_cells))
            np.add.at(cc, (kc, ccodes), 1.0)
            uc = np.unique(np.argmax(cc, axis=1), return_inverse=True)[1].astype(np.int64)  # cells left, renumbered
            unit = "cluster mean"
            out["clusters"] = n_clu
        else:
            out["clusters_note"] = "the factor varies within clusters: tightenings are the units"
    t = _tests(uy, uf, uc, len(levels))
    if "skipped" in t:
        out["skipped"] = t["skipped"]
        return out
    cell_mean = np.array([np.mean(y[ccodes == c]) for c in range(n_cells)])
    within = y - cell_mean[ccodes] + float(np.mean(y))
    per_level: dict[str, Any] = {}
    for k, lev in enumerate(levels):
        v = y[fcodes == k]
        w = within[fcodes == k]
        per_level[str(lev)] = {
            "n": int(len(v)),
            "mean": float(np.mean(v)),
            "se": float(np.std(v, ddof=1) / math.sqrt(len(v))) if len(v) > 1 else None,
            "mean_within_cells": float(np.mean(w)),
            "se_within_cells": float(np.std(w, ddof=1) / math.sqrt(len(w))) if len(w) > 1 else None,
        }
        if unit == "cluster mean":
            per_level[str(lev)]["clusters"] = int(np.sum(uf == k))
    wm = [float(v["mean_within_cells"]) for v in per_level.values()]
    # in-sample residual sd of the tightenings with and without the level means
    full_sd = math.sqrt(float(np.sum((within - np.array(wm)[fcodes]) ** 2)) / max(n - n_cells - len(levels) + 1, 1))
    out.update(
        {
            "tightenings": n,
            "test_unit": unit,
            "units": int(len(uy)),
            "levels": len(levels),
            "cells": n_cells,
            "anova": t["anova"],
            "kruskal_wallis": t["kruskal_wallis"],
            "effect_size": t["effect_size"],
            "per_level": per_level,
            "spread_within_cells": float(max(wm) - min(wm)),
            "residual_sd": full_sd,
            "sd_within_cells": math.sqrt(float(np.sum((within - np.mean(y)) ** 2)) / max(n - n_cells, 1)),
        }
    )
    out["variance_components"] = _variance_components(uy, _dummies(uc, drop_first=False), levels[uf]) if variance_components else {"estimated": False, "reason": "not asked for"}
    return out


def _tests(y: F64, fcodes: I64, ccodes: I64, n_levels: int) -> dict[str, Any]:
    """F-test of the factor within the cells, Kruskal-Wallis on cell-aligned values, effect
    sizes, on the given units."""
    import scipy.stats as st
    import statsmodels.api as sm

    n = len(y)
    n_cells = int(ccodes.max()) + 1
    if len(np.unique(fcodes)) < 2:
        return {"skipped": "fewer than two levels with enough units"}
    x0 = _dummies(ccodes, drop_first=False)
    x1 = np.c_[x0, _dummies(fcodes, drop_first=True)]
    r0 = int(np.linalg.matrix_rank(x0))
    r1 = int(np.linalg.matrix_rank(x1))
    df1, df2 = r1 - r0, n - r1
    if df1 < 1:
        return {"skipped": "confounded with the specification cell: no level varies within a cell"}
    if df2 < 2:
        return {"skipped": "too few units for the levels and cells"}
    with np.errstate(all="ignore"), warnings.catch_warnings():
        # a perfect fit (F inf or nan) and a rank-deficient design (a level confined to some
        # cells) are handled here: the degrees of freedom come from the ranks
        warnings.simplefilter("ignore")
        full = sm.OLS(y, x1).fit()
        reduced = sm.OLS(y, x0).fit()
        f_stat, p_f, _df = full.compare_f_test(reduced)
    ss_f = float(reduced.ssr - full.ssr)
    ss_res = float(full.ssr)
    ms_res = ss_res / df2
    f_stat = float(f_stat) if np.isfinite(f_stat) else 0.0
    p_f = float(p_f) if np.isfinite(p_f) else 1.0
    eta2 = ss_f / (ss_f + ss_res) if ss_f + ss_res > 0 else 0.0
    omega2 = max(0.0, (ss_f - df1 * ms_res) / (ss_f + (n - df1) * ms_res)) if ss_f + ss_res > 0 else 0.0
    # Kruskal-Wallis on cell-aligned values (each cell's median removed)
    cmed = np.array([np.median(y[ccodes == c]) if np.any(ccodes == c) else 0.0 for c in range(n_cells)])
    aligned = y - cmed[ccodes] if n_cells > 1 else y
    groups = [aligned[fcodes == k] for k in range(n_levels) if np.any(fcodes == k)]
    try:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all values tied: nan, handled below
            h, p_kw = st.kruskal(*groups)
        h, p_kw = float(h), float(p_kw)
        if not np.isfinite(p_kw):
            h, p_kw = 0.0, 1.0
    except ValueError:  # all values equal
        h, p_kw = 0.0, 1.0
    return {
        "anova": {"test": "F-test of y ~ cell + factor against y ~ cell" if n_cells > 1 else "one-way ANOVA", "f_statistic": f_stat, "df": [df1, df2], "p_value": p_f},
        "kruskal_wallis": {"test": "Kruskal-Wallis on cell-aligned values" if n_cells > 1 else "Kruskal-Wallis", "h_statistic": h, "df": len(groups) - 1, "p_value": p_kw},
        "effect_size": {"eta_squared_partial": eta2, "omega_squared_partial": omega2, "epsilon_squared": h / (n - 1) if n > 1 else 0.0},
    }


def _variance_components(y: F64, x0: F64, labels: Labels) -> dict[str, Any]:
    """Random intercept per level (REML), cells as fixed effects; never raises."""
    import statsmodels.api as sm

    n_levels = len(np.unique(labels))
    if n_levels < 3:
        return {"estimated": False, "reason": f"{n_levels} levels: a variance between levels needs at least 3"}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            res = sm.MixedLM(y, x0, groups=labels).fit(reml=True)
        except (ValueError, np.linalg.LinAlgError, ArithmeticError) as e:
            return {"estimated": False, "reason": f"MixedLM failed: {type(e).__name__}: {e}"}
    notes = sorted({f"{w.category.__name__}: {w.message}" for w in caught})
    try:
        var_g = float(np.asarray(res.cov_re)[0, 0])
        var_e = float(res.scale)
    except (IndexError, TypeError, ValueError) as e:
        return {"estimated": False, "reason": f"MixedLM gave no variance components: {e}", "warnings": notes}
    converged = bool(getattr(res, "converged", True))
    if not (np.isfinite(var_g) and np.isfinite(var_e)) or var_e <= 0:
        return {"estimated": False, "reason": "MixedLM gave no finite variance components", "warnings": notes}
    if not converged:
        return {"estimated": False, "reason": "MixedLM did not converge", "warnings": notes}
    var_g = max(var_g, 0.0)
    out: dict[str, Any] = {
        "estimated": True,
        "method": "MixedLM, random intercept per level, REML, cells as fixed effects",
        "group_variance": var_g,
        "residual_variance": var_e,
        "icc": var_g / (var_g + var_e),
        "group_sd": math.sqrt(var_g),
    }
    if notes:
        out["warnings"] = notes
    if var_g <= 1e-8 * var_e:
        out["note"] = "the group variance is on the boundary (0)"
    return out


def _two_way(y: F64, a: Labels, b: Labels, cell: Labels) -> dict[str, Any]:
    """Two-way ANOVA with interaction, Type II (statsmodels ols + anova_lm), cells as a fixed
    effect when there are several."""
    import pandas as pd
    import statsmodels.formula.api as smf
    from statsmodels.stats.anova import anova_lm

    ok = np.isfinite(y) & (a != None) & (b != None)  # noqa: E711
    y, a, b, cell = y[ok], a[ok].astype(str), b[ok].astype(str), cell[ok].astype(str)
    if len(y) < 8:
        return {"skipped": "too few tightenings with both factors"}
    if float(np.std(y)) <= 1e-12 * max(1.0, float(np.max(np.abs(y)))):
        return {"skipped": "the parameter does not vary"}
    la, lb = np.unique(a), np.unique(b)
    if len(la) < 2 or len(lb) < 2:
        return {"skipped": "a factor has one level here"}
    pairs = {(x, z) for x, z in zip(a.tolist(), b.tolist())}
    if len(pairs) < len(la) * len(lb):
        return {"skipped": f"the factors are not fully crossed ({len(pairs)} of {len(la) * len(lb)} level pairs present)"}
    df = pd.DataFrame({"y": y, "a": a, "b": b, "cell": cell})
    formula = "y ~ C(a) * C(b)" + (" + C(cell)" if len(np.unique(cell)) > 1 else "")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            fit = smf.ols(formula, data=df).fit()
            tab = anova_lm(fit, typ=2)
        except (ValueError, np.linalg.LinAlgError, ArithmeticError) as e:
            return {"skipped": f"anova_lm failed: {type(e).__name__}: {e}"}
    rows: dict[str, Any] = {}
    names = {"C(a)": "a", "C(b)": "b", "C(a):C(b)": "interaction", "C(cell)": "cell", "Residual": "residual"}
    for idx, r in tab.iterrows():
        key = names.get(str(idx), str(idx))
        rows[key] = {
            "sum_sq": float(r["sum_sq"]),
            "df": float(r["df"]),
            "f_statistic": float(r["F"]) if np.isfinite(r["F"]) else None,
            "p_value": float(r["PR(>F)"]) if np.isfinite(r["PR(>F)"]) else None,
        }
    out: dict[str, Any] = {"formula": formula, "type": 2, "tightenings": int(len(y)), "table": rows}
    notes = sorted({f"{w.category.__name__}: {w.message}" for w in caught})
    if notes:
        out["warnings"] = notes
    return out


def grouping_factor_analysis(
    params: dict[str, tuple[F64, str, str]],
    factors: dict[str, Labels],
    cell: Labels | None = None,
    *,
    clusters: Labels | None = None,
    alpha: float = 0.01,
    correction: str = "holm",
    min_effect: float = MIN_EFFECT,
    variance_components: bool = True,
    two_way: bool = True,
    max_pairs: int = 6,
) -> tuple[list[Effect], dict[str, Any]]:
    """Test every factor against every parameter; claim those that pass (see the module).

    ``params``: name -> (values per tightening, unit, description). ``factors``: name -> labels
    per tightening (``None`` where missing). ``cell``: specification cell per tightening (or
    None). ``clusters``: repeated-measure units per tightening (e.g. the thread a tightening
    re-uses), or None: a factor constant within clusters is tested on cluster means. Returns the claimed :class:`Effect` objects (``<parameter>_by_<factor>``) and the
    full table (JSON-ready)."""
    from statsmodels.stats.multitest import multipletests

    n = len(next(iter(params.values()))[0]) if params else 0
    cells = np.array(["all"] * n, dtype=object) if cell is None else np.asarray(cell, dtype=object)
    tests: list[dict[str, Any]] = []
    skipped: list[dict[str, Any]] = []
    for fname, labels in factors.items():
        for pname, (values, unit, _desc) in params.items():
            r = _one_pair(np.asarray(values, dtype=np.float64), np.asarray(labels, dtype=object), cells, variance_components, None if clusters is None else np.asarray(clusters, dtype=object))
            r = {"factor": fname, "parameter": pname, "unit": unit} | r
            (skipped if "skipped" in r else tests).append(r)
    details: dict[str, Any] = {
        "alpha": alpha,
        "correction": correction,
        "min_effect_omega_squared": min_effect,
        "claim_rule": "F-test and Kruskal-Wallis both significant after the correction, and partial omega^2 >= min_effect",
        "factors": list(factors),
        "parameters": list(params),
        "family_size": len(tests),
        "tests": tests,
        "skipped_tests": skipped,
    }
    effects: list[Effect] = []
    if tests:
        p_f = np.array([t["anova"]["p_value"] for t in tests])
        p_k = np.array([t["kruskal_wallis"]["p_value"] for t in tests])
        rej_f, adj_f, _, _ = multipletests(p_f, alpha=alpha, method=correction)
        rej_k, adj_k, _, _ = multipletests(p_k, alpha=alpha, method=correction)
        for t, rf, af, rk, ak in zip(tests, rej_f, adj_f, rej_k, adj_k):
            t["anova"]["p_value_adjusted"] = float(af)
            t["kruskal_wallis"]["p_value_adjusted"] = float(ak)
            t["significant"] = bool(rf and rk and t["effect_size"]["omega_squared_partial"] >= min_effect)
            if not t["significant"]:
                continue
            desc = params[t["parameter"]][2]
            effects.append(
                Effect(
                    name=f"{t['parameter']}_by_{t['factor']}",
                    description=f"difference between the levels of {t['factor']} (grouping factor): {desc} differs between them, within the specification cells",
                    level="between_tightenings",
                    significant=True,
                    parameters={
                        "covariate": t["factor"],
                        "factor": t["factor"],
                        "parameter": t["parameter"],
                        "unit": t["unit"],
                        "levels": t["per_level"],
                        "effect_range": {"change": t["spread_within_cells"]},
                        "effect_size": t["effect_size"],
                        "variance_components": t["variance_components"],
                    },
                    rmse_after=t["residual_sd"],
                    rmse_unit=t["unit"],
                    evidence={
                        "test": f"{t['anova']['test']}; {t['kruskal_wallis']['test']}",
                        "p_value": t["anova"]["p_value"],
                        "p_value_adjusted": t["anova"]["p_value_adjusted"],
                        "f_statistic": t["anova"]["f_statistic"],
                        "df": t["anova"]["df"],
                        "kruskal_p_value": t["kruskal_wallis"]["p_value"],
                        "kruskal_p_value_adjusted": t["kruskal_wallis"]["p_value_adjusted"],
                        "kruskal_h": t["kruskal_wallis"]["h_statistic"],
                        "correction": correction,
                        "alpha": alpha,
                        "family_size": len(tests),
                        "n_per_level": {k: v["n"] for k, v in t["per_level"].items()},
                        "tightenings": t["tightenings"],
                        "test_unit": t["test_unit"],
                        "units": t["units"],
                        "cells": t["cells"],
                        "rmse_before": t["sd_within_cells"],
                        "rmse_gain": (t["sd_within_cells"] - t["residual_sd"]) / t["sd_within_cells"] if t["sd_within_cells"] > 0 else 0.0,
                        "in_sample": True,
                    },
                )
            )
    # two-way ANOVAs with interaction of each pair of factors
    tw: list[dict[str, Any]] = []
    names = list(factors)
    if two_way and len(names) >= 2:
        pairs = [(names[i], names[j]) for i in range(len(names)) for j in range(i + 1, len(names))][:max_pairs]
        for fa, fb in pairs:
            for pname, (values, unit, _d) in params.items():
                r = _two_way(np.asarray(values, dtype=np.float64), np.asarray(factors[fa], dtype=object), np.asarray(factors[fb], dtype=object), cells)
                tw.append({"factors": [fa, fb], "parameter": pname, "unit": unit} | r)
        ps = [(i, t["table"]["interaction"]["p_value"]) for i, t in enumerate(tw) if "table" in t and t["table"].get("interaction", {}).get("p_value") is not None]
        if ps:
            rej, adj, _, _ = multipletests(np.array([p for _, p in ps]), alpha=alpha, method=correction)
            for (i, _p), rr, aa in zip(ps, rej, adj):
                tw[i]["interaction_p_value_adjusted"] = float(aa)
                tw[i]["interaction_significant"] = bool(rr)
    details["two_way"] = tw
    return effects, details
