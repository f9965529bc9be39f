"""Per-tightening refinement of a named effect's constant (issue 12): a pooled coefficient per
effect, and how much it varies between tightenings.

Real tools do not share one constant: a transducer filter, a tool's inertia or a lubricant
batch differ between tools, spindles and screws. Once the loop has named an effect with its
pooled coefficient (the reported value and its standard error stay the pooled ones), each
tightening ``j`` gets a factor ``1 + d_j`` on that effect's fitted contribution ``u`` (the
term's regressors times their pooled coefficients): ``y = P_j c_j + (1 + d_j) u + e``, a 1-D
fit per tightening around the pooled value, the tightening's own declared columns ``P_j``
fitted with it.

The raw ``d_j`` are noisy where a tightening carries little of the effect, so they are shrunk
towards 0 (the pooled value) by empirical Bayes: ``d_j* = tau^2 / (tau^2 + v_j) d_j``, with
``v_j`` the estimation variance of ``d_j`` and ``tau^2`` the between-tightening variance of the
factor, estimated by DerSimonian and Laird's method of moments (1986) -- a random-effects model
of the constant. Where the constant is the same in every tightening ``tau^2`` is about 0 and
nothing moves.

Honesty of the RMSE after: the refined model goes through the loop's own out-of-sample
protocol. The pooled coefficients are those fitted without the tightening's fold; ``tau^2`` is
estimated without that fold; ``d_j`` is estimated on one of the alternate blocks of samples
within the tightening and predicts the other, as for every per-tightening parameter. The
refinement enters ``rmse_after`` only when its out-of-sample improvement passes the loop's
one-sided test at ``alpha``. It runs after the loop has named its effects, so it cannot change
what is named or claimed.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Sequence

import numpy as np

from .fit import _Engine, _Fit, _one_sided_tests
from .prepare import F64

#: the effects whose constant may differ between tightenings (a physical constant of the tool,
#: the channel or the lubrication); periodic terms already have per-tightening phases
REFINABLE = ("channel_delay", "inertia", "speed_dependent_friction", "speed_dependent_prevailing_torque", "pressure_dependent_friction", "elastic_curvature")

#: the per-tightening factor 1 + d_j is kept in [0, 3]: a constant does not change sign between
#: tightenings of one table, nor grow without bound
FACTOR_BOUNDS = (0.0, 3.0)


def _dersimonian_laird(d: F64, v: F64) -> float:
    """Between-unit variance of ``d`` whose own estimation variances are ``v`` (method of
    moments of DerSimonian & Laird 1986), 0 when the spread is no more than ``v`` explains."""
    ok = np.isfinite(d) & np.isfinite(v) & (v > 0)
    d, v = d[ok], v[ok]
    k = len(d)
    if k < 3:
        return 0.0
    w = 1.0 / v
    dbar = float(np.sum(w * d) / np.sum(w))
    q = float(np.sum(w * (d - dbar) ** 2))
    den = float(np.sum(w) - np.sum(w * w) / np.sum(w))
    return max(0.0, (q - (k - 1)) / den) if den > 0 else 0.0


def _factor_fit(eng: _Engine, pcols: Sequence[F64], base: F64, u: F64, w: F64 | None) -> tuple[F64, F64, F64, F64]:
    """Per tightening: the factor deviation d_j of ``u`` in ``base ~ P_j c_j + d_j u`` fitted on
    the samples weighted ``w`` (a half, or all), its variance, and the residuals of ``base`` and
    ``u`` on the tightening's own columns (fitted on those samples, evaluated on all)."""
    g = eng.g
    _, fitted = g.fit(list(pcols), [base, u], w=w)
    ry = base - fitted[:, 0]
    ru = u - fitted[:, 1]
    ww = np.ones_like(base) if w is None else w
    num = g.sum(ww * ry * ru)
    den = g.sum(ww * ru * ru)
    live = den > 1e-300
    d = np.where(live, num / np.where(live, den, 1.0), 0.0)
    n_used = g.sum(ww)
    rss = np.maximum(g.sum(ww * ry * ry) - d * num, 0.0)
    s2 = rss / np.maximum(n_used - len(pcols) - 1.0, 1.0)
    v = np.where(live, s2 / np.where(live, den, 1.0), np.inf)
    return d, v, ry, ru


def refine_per_tightening(
    eng: _Engine,
    pcols: Sequence[F64],
    zcols: Sequence[F64],
    fit: _Fit,
    terms: dict[str, list[int]],
    alpha: float,
    directions: dict[str, F64] | None = None,
) -> dict[str, Any] | None:
    """Refine, per tightening, the constant of each global term in ``terms`` (key -> indices of
    its columns in ``zcols``), jointly with the model's other coefficients held at their
    pooled values. Returns the refined out-of-sample residual and its RMSE, the per-tightening
    factors (in-sample, shrunk) of each term, the between-tightening sd of each factor, and the
    gain test of the refinement against ``fit``; None when there is nothing to refine.

    ``directions``: for a term whose contribution is not linear in its constant (a channel
    lag: the low-pass path of the torque, not tau times a fixed column), the derivative of its
    contribution with respect to the relative change of the constant, in place of the
    contribution itself (a Gauss-Newton step per tightening)."""
    s, g = eng.s, eng.g
    if not terms or len(fit.beta) == 0:
        return None
    fold = eng.fold
    k_all = len(zcols)
    # the model's prediction with each tightening's out-of-fold coefficients, and in-sample
    zb_oos = np.zeros(len(s.y))
    zb_in = np.zeros(len(s.y))
    for i in range(k_all):
        zb_oos += zcols[i] * fit.beta_folds[fold, i]
        zb_in += zcols[i] * fit.beta[i]
    e = fit.e_oos.copy()
    d_in_all: dict[str, F64] = {}
    out_terms: dict[str, Any] = {}
    base_oos = s.y - zb_oos
    base_in = s.y - zb_in
    # one term after the other, each on the residual the ones before it left (in practice one
    # named effect; with two the second is refined with the first's factors in)
    for key, idx in terms.items():
        u_oos = np.zeros(len(s.y))
        u_in = np.zeros(len(s.y))
        for i in idx:
            u_oos += zcols[i] * fit.beta_folds[fold, i]
            u_in += zcols[i] * fit.beta[i]
        if directions is not None and key in directions:
            u_in = directions[key]
            u_oos = u_in
        if not np.any(u_in != 0):
            continue
        # all samples: the per-tightening estimates and the between-tightening variance
        d_full, v_full, _, _ = _factor_fit(eng, pcols, base_in, u_in, None)
        tau2 = _dersimonian_laird(d_full, v_full)
        # tau^2 of each fold from the tightenings outside it
        tau2_fold = np.array([_dersimonian_laird(d_full[eng.fold_t != f], v_full[eng.fold_t != f]) for f in range(eng.n_folds)])
        t2 = tau2_fold[eng.fold_t]
        lo, hi = FACTOR_BOUNDS[0] - 1.0, FACTOR_BOUNDS[1] - 1.0
        # each half predicts the other
        e_new = e.copy()
        for w_fit, other in ((eng.h0, eng.h1 > 0), (eng.h1, eng.h0 > 0)):
            d_h, v_h, _, ru_h = _factor_fit(eng, pcols, base_oos, u_oos, w_fit)
            shrunk = np.clip(np.where(np.isfinite(v_h), t2 / (t2 + v_h), 0.0) * d_h, lo, hi)
            shrunk = np.where(t2 > 0, shrunk, 0.0)
            e_new = np.where(other, e_new - shrunk[s.gid] * ru_h, e_new)
        d_shrunk = np.clip(np.where(np.isfinite(v_full), tau2 / (tau2 + v_full), 0.0) * d_full, lo, hi) if tau2 > 0 else np.zeros_like(d_full)
        e = e_new
        base_in = base_in - d_shrunk[s.gid] * u_in
        d_in_all[key] = d_shrunk
        out_terms[key] = {
            "between_tightening_sd_relative": math.sqrt(tau2),
            "tau2_by_fold": tau2_fold,
            "factor": 1.0 + d_shrunk,
            "factor_raw": 1.0 + d_full,
        }
    if not out_terms:
        return None
    mse_t = g.mean(e * e)
    refined = dataclasses.replace(fit, e_oos=e, mse_t=mse_t, rmse=float(np.sqrt(np.mean(e * e))))
    u = np.clip((fit.mse_t - mse_t) / np.maximum(fit.mse_t, 1e-300), -1.0, 1.0)
    tests = _one_sided_tests(u)
    gain = (fit.rmse - refined.rmse) / fit.rmse if fit.rmse > 0 else 0.0
    return {
        "fit": refined,
        "terms": out_terms,
        "rmse_pooled_constants": fit.rmse,
        "rmse_per_tightening_constants": refined.rmse,
        "rmse_gain": gain,
        "p_value": tests["p_value"],
        "significant": bool(tests["p_value"] < alpha and gain > 0),
    }


def spread_summary(pooled: dict[str, Any] | None, factor: F64, factor_raw: F64, sd_rel: float, used: bool, parameter: str) -> dict[str, Any]:
    """The between-tightening spread of an effect's constant for the JSON: the pooled value, the
    sd of the constant between tightenings (the random-effects estimate, not the spread of the
    noisy per-tightening fits), and quantiles of the shrunk per-tightening values."""
    value = float(pooled["value"]) if isinstance(pooled, dict) and pooled.get("value") is not None else float("nan")
    per_t = value * factor
    q = np.percentile(per_t, [5, 25, 50, 75, 95]) if len(per_t) else np.full(5, np.nan)
    return {
        "parameter": parameter,
        "pooled": value,
        "sd_between_tightenings": abs(value) * sd_rel,
        "sd_relative": sd_rel,
        "per_tightening_quantiles": {"p05": float(q[0]), "p25": float(q[1]), "median": float(q[2]), "p75": float(q[3]), "p95": float(q[4])},
        "raw_factor_sd": float(np.std(factor_raw[np.isfinite(factor_raw)])) if np.any(np.isfinite(factor_raw)) else float("nan"),
        "used_in_rmse_after": used,
        "method": (
            "random effects: a factor 1 + d_j per tightening on the effect's pooled contribution, fitted with the "
            "tightening's own columns and shrunk towards the pooled value by tau^2 / (tau^2 + var d_j) (tau^2 by "
            "DerSimonian-Laird); sd_between_tightenings = |pooled| tau; the quantiles are of the shrunk values"
        ),
    }
