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


def _factor_fit(eng: _Engine, pcols: Sequence[F64], base: F64, us: Sequence[F64], w: F64 | None) -> tuple[F64, F64, list[F64]]:
    """Per tightening: the factor deviations d_j (one per component ``us``) in
    ``base ~ P_j c_j + sum_k d_jk u_k`` fitted on the samples weighted ``w`` (a half, or all),
    their covariance, and the residuals of each ``u_k`` on the tightening's own columns (fitted
    on those samples, evaluated on all). Shapes (G, K), (G, K, K)."""
    g = eng.g
    k = len(us)
    _, fitted = g.fit(list(pcols), [base, *us], w=w)
    ry = base - fitted[:, 0]
    ru = [u - fitted[:, 1 + i] for i, u in enumerate(us)]
    ww = np.ones_like(base) if w is None else w
    A = np.empty((g.n, k, k))
    b = np.empty((g.n, k))
    for a in range(k):
        b[:, a] = g.sum(ww * ry * ru[a])
        for c in range(a, k):
            A[:, a, c] = A[:, c, a] = g.sum(ww * ru[a] * ru[c])
    scale = np.trace(A, axis1=1, axis2=2) / k
    live = scale > 1e-300
    A[:, np.arange(k), np.arange(k)] += (1e-9 * scale + 1e-300)[:, None]
    Ainv = np.linalg.inv(A)
    d = np.where(live[:, None], np.einsum("gij,gj->gi", Ainv, b), 0.0)
    rss = np.maximum(g.sum(ww * ry * ry) - np.sum(d * b, axis=1), 0.0)
    s2 = rss / np.maximum(g.sum(ww) - len(pcols) - k, 1.0)
    V = np.where(live[:, None, None], Ainv * s2[:, None, None], np.inf)
    return d, V, ru


def _shrink(d: F64, V: F64, tau2: F64) -> F64:
    """Posterior mean of the per-tightening deviations under a normal prior of variances
    ``tau2`` (per tightening, per component): T (T + V_j)^-1 d_j."""
    k = d.shape[1]
    T = np.zeros_like(V)
    T[:, np.arange(k), np.arange(k)] = tau2
    ok = np.all(np.isfinite(V.reshape(len(V), -1)), axis=1)
    M = np.where(ok[:, None, None], T + np.where(ok[:, None, None], V, 0.0), np.eye(k))
    x = np.linalg.solve(M, np.where(ok[:, None], d, 0.0)[:, :, None])[:, :, 0]
    out: F64 = np.where(ok[:, None], np.einsum("gij,gj->gi", T, x), 0.0)
    return out


def refine_per_tightening(
    eng: _Engine,
    pcols: Sequence[F64],
    zcols: Sequence[F64],
    fit: _Fit,
    terms: dict[str, list[list[int]]],
    alpha: float,
    directions: dict[str, list[F64]] | None = None,
) -> dict[str, Any] | None:
    """Refine, per tightening, the constant of each global term in ``terms`` (key -> its
    components, each a list of indices of its columns in ``zcols`` that share one factor: one
    component for a law with one constant, two for a Stribeck law whose static and viscous
    parts may vary apart), with the model's other coefficients held at their pooled values.
    Returns the refined out-of-sample residual and its RMSE, the per-tightening factors
    (in-sample, shrunk) of each term's first component, the between-tightening sd of each
    factor, and the gain test of the refinement against ``fit``; None when there is nothing to
    refine.

    ``directions``: for a term whose contribution is not linear in its constants (a channel
    lag: the low-pass path of the torque, not tau times a fixed column; a Stribeck law's
    Stribeck speed), the derivatives of its contribution with respect to the relative change
    of each constant, in place of its components (a Gauss-Newton step per tightening)."""
    s, g = eng.s, eng.g
    if not terms or len(fit.beta) == 0:
        return None
    fold = eng.fold
    zb_oos = np.zeros(len(s.y))
    zb_in = np.zeros(len(s.y))
    for i in range(len(zcols)):
        zb_oos += zcols[i] * fit.beta_folds[fold, i]
        zb_in += zcols[i] * fit.beta[i]
    e = fit.e_oos.copy()
    out_terms: dict[str, Any] = {}
    base_oos = s.y - zb_oos
    base_in = s.y - zb_in
    lo, hi = FACTOR_BOUNDS[0] - 1.0, FACTOR_BOUNDS[1] - 1.0
    # one term after the other, each on the residual the ones before it left (in practice one
    # named effect; with two the second is refined with the first's factors in)
    for key, comps in terms.items():
        us_oos: list[F64] = []
        us_in: list[F64] = []
        if directions is not None and key in directions:
            us_oos, us_in = list(directions[key]), list(directions[key])
        else:
            for idx in comps:
                us_oos.append(sum((zcols[i] * fit.beta_folds[fold, i] for i in idx), np.zeros(len(s.y))))
                us_in.append(sum((zcols[i] * fit.beta[i] for i in idx), np.zeros(len(s.y))))
        keep = [i for i, u in enumerate(us_in) if np.any(u != 0)]
        if not keep:
            continue
        us_oos, us_in = [us_oos[i] for i in keep], [us_in[i] for i in keep]
        k = len(us_in)
        # all samples: the per-tightening estimates and the between-tightening variances
        d_full, V_full, ru_full = _factor_fit(eng, pcols, base_in, us_in, None)
        tau2 = np.array([_dersimonian_laird(d_full[:, c], V_full[:, c, c]) for c in range(k)])
        # the variances of each fold from the tightenings outside it
        tau2_fold = np.array([[_dersimonian_laird(d_full[eng.fold_t != f, c], V_full[eng.fold_t != f, c, c]) for c in range(k)] for f in range(eng.n_folds)])
        t2 = tau2_fold[eng.fold_t]
        # each half predicts the other
        e_new = e.copy()
        for w_fit, other in ((eng.h0, eng.h1 > 0), (eng.h1, eng.h0 > 0)):
            d_h, V_h, ru_h = _factor_fit(eng, pcols, base_oos, us_oos, w_fit)
            shrunk = np.clip(_shrink(d_h, V_h, t2), lo, hi)
            pred = sum((shrunk[s.gid, c] * ru_h[c] for c in range(k)), np.zeros(len(s.y)))
            e_new = np.where(other, e_new - pred, e_new)
        d_shrunk = np.clip(_shrink(d_full, V_full, np.broadcast_to(tau2, d_full.shape)), lo, hi)
        e = e_new
        base_in = base_in - sum((d_shrunk[s.gid, c] * us_in[c] for c in range(k)), np.zeros(len(s.y)))
        out_terms[key] = {
            "between_tightening_sd_relative": math.sqrt(float(tau2[0])),
            "between_tightening_sd_relative_by_component": [math.sqrt(float(v)) for v in tau2],
            "tau2_by_fold": tau2_fold,
            "factor": 1.0 + d_shrunk[:, 0],
            "factor_raw": 1.0 + d_full[:, 0],
            "factors": [1.0 + d_shrunk[:, c] for c in range(k)],
            "factors_raw": [1.0 + d_full[:, c] for c in range(k)],
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


def spread_summary(pooled: dict[str, Any] | None, factor: F64, factor_raw: F64, sd_rel: float, used: bool) -> dict[str, Any]:
    """The between-tightening spread of an effect's constant for the JSON: the pooled value, the
    sd of the constant between tightenings (the random-effects estimate, not the spread of the
    noisy per-tightening fits), and quantiles of the shrunk per-tightening values."""
    value = float(pooled["value"]) if isinstance(pooled, dict) and pooled.get("value") is not None else float("nan")
    per_t = value * factor
    q = np.percentile(per_t, [5, 25, 50, 75, 95]) if len(per_t) else np.full(5, np.nan)
    return {
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
