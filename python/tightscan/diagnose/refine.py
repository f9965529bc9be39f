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
estimated without that fold; within the tightening, its samples are dealt in short blocks to
four groups, and ``d_j`` estimated on three groups predicts the fourth (blocks of one sample
for white noise, longer where the noise is correlated, ``_decorrelation_block``: short, because
an effect may act in a stretch shorter than the loop's own blocks, as a Stribeck law in a
speed dip); the declared columns keep the loop's own protocol, so no sample's value enters its
own prediction. The refinement enters ``rmse_after`` only when its out-of-sample improvement
passes the loop's one-sided test at ``alpha``. It runs after the loop has named its effects, so
it cannot change what is named; a further claim must keep its gain with the held effects
refined.

A Stribeck law (``stribeck.py``) has three constants whose effect is far from linear in one of
them (the Stribeck speed, where the speeds seen lie in the tail of its decay): they are fitted
per tightening jointly, maximum a posteriori under a normal population estimated by EM
(``_stribeck_map``), instead of one linear step from the pooled values.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable, Sequence

import numpy as np
import numpy.typing as npt

from .fit import _Engine, _Fit, _one_sided_tests
from .prepare import F64

#: the effects whose constant may differ between tightenings (a physical constant of the tool,
#: the channel or the lubrication); periodic terms already have per-tightening phases
REFINABLE = ("channel_delay", "inertia", "speed_dependent_friction", "speed_dependent_prevailing_torque", "pressure_dependent_friction", "elastic_curvature")

#: the per-tightening factor 1 + d_j is kept in [0, 3]: a constant does not change sign between
#: tightenings of one table, nor grow without bound
FACTOR_BOUNDS = (0.0, 3.0)

#: groups of sample blocks within each tightening for the out-of-sample fit of its constants
#: (each group predicted from the other three): short blocks, because an effect may act in a
#: short stretch only (a Stribeck law in a speed dip of some ten samples, which the loop's own
#: blocks, 1/16 of a window, often hold whole, leaving the other half nothing to learn the
#: tightening's constant from)
WITHIN_GROUPS = 4
#: the noise correlation between neighbouring blocks that is tolerated (block length from it)
BLOCK_CORRELATION = 0.2


def _decorrelation_block(eng: _Engine, resid: F64) -> int:
    """Samples per block such that the noise of neighbouring blocks is nearly independent
    (lag correlation below ``BLOCK_CORRELATION``): 1 for white noise. The noise's lag-1
    correlation phi comes from the first differences of the in-sample residual over the rundown
    samples (where a speed law of the elastic window is zero, and smooth misfit hardly enters
    a difference): for AR(1) noise their lag-1 correlation is -(1 - phi) / 2. Misfit the
    differences keep (an effect still pooled that acts in the rundown, as an inertia's
    transients) reads as correlation and only lengthens the blocks, the cautious side. Capped
    at the loop's own block length."""
    s = eng.s
    # a difference at i: samples i - 1 and i of one tightening's rundown; pairs of neighbours
    valid = np.r_[False, (s.gid[1:] == s.gid[:-1]) & (s.seg[1:] == 1) & (s.seg[:-1] == 1)]
    d = np.r_[0.0, np.diff(resid)]
    pair = valid[1:] & valid[:-1]
    if int(np.sum(pair)) < 20:
        return 1
    a, b = d[:-1][pair], d[1:][pair]
    den = math.sqrt(float(np.sum(a * a) * np.sum(b * b)))
    r1 = float(np.sum(a * b)) / den if den > 0 else -0.5
    phi = min(max(1.0 + 2.0 * r1, 0.0), 0.99)
    if phi <= BLOCK_CORRELATION:
        return 1
    return int(min(math.ceil(math.log(BLOCK_CORRELATION) / math.log(phi)), max(2, int(np.median(np.bincount(s.gid[s.seg == 0]))) // 16)))


def _sample_groups(eng: _Engine, block: int) -> npt.NDArray[np.int64]:
    """Each sample's group: blocks of ``block`` samples dealt in turn to ``WITHIN_GROUPS``
    groups within each (tightening, segment)."""
    s = eng.s
    key = s.gid * 2 + s.seg
    first_of = np.r_[True, key[1:] != key[:-1]]
    rank = np.arange(len(key)) - np.maximum.accumulate(np.where(first_of, np.arange(len(key)), 0))
    out: npt.NDArray[np.int64] = (rank // block) % WITHIN_GROUPS
    return out


def _in_loop_protocol(eng: _Engine, pcols: Sequence[F64], v: F64) -> F64:
    """``v`` less what the tightening's declared columns take of it, fitted on the half of the
    loop's blocks that does not hold the sample (the loop's out-of-sample protocol)."""
    g = eng.g
    _, p0 = g.fit(list(pcols), [v], w=eng.h0)
    _, p1 = g.fit(list(pcols), [v], w=eng.h1)
    out: F64 = v - np.where(eng.s.half, p1[:, 0], p0[:, 0])
    return out


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


@dataclasses.dataclass(frozen=True)
class StribeckLaw:
    """What the joint per-tightening fit of a Stribeck law needs: its static column and that
    column's derivative by ln v_s at a Stribeck speed per sample [rpm], its viscous column
    (unit coefficient), and the pooled Stribeck speed [rpm]."""

    static_at: Callable[[F64], tuple[F64, F64]]
    viscous: F64
    stribeck_speed_rpm: float


#: ln v_s of a tightening is kept within these Stribeck speeds [rpm] (the speeds a tightening
#: runs at; beyond them the law is flat over the data)
STRIBECK_SPEED_BOUNDS_RPM = (0.5, 1000.0)


def _stribeck_map(eng: _Engine, pcols: Sequence[F64], rest: F64, law: StribeckLaw, theta0: F64, w: F64 | None, rounds: int = 4, steps: int = 5) -> tuple[F64, F64, F64]:
    """Each tightening's Stribeck law -- static coefficient, viscous coefficient, ln v_s -- by
    maximum a posteriori under a normal population (random effects), fitted with the
    tightening's own declared columns on the samples weighted ``w``.

    ``rest``: the data less every other term of the model (the Stribeck law's own contribution
    in); ``theta0`` (G, 3): the pooled values, where each tightening starts. Gauss-Newton steps
    per tightening with the population's precision as the prior (a tightening whose speeds do
    not reach its Stribeck speed stays at the population's value, one whose data pin it down
    takes its own); between rounds the population mean and variances are re-estimated from the
    tightenings' estimates and their posterior variances (EM for a normal random effect). The
    decay is far from linear in v_s where the speeds seen lie in its tail, so one linear step
    from the pooled v_s (what the other laws get) is not enough. Returns the per-tightening
    estimates (G, 3), the population mean (3,) and variances (3,)."""
    g = eng.g
    gid = eng.s.gid
    ww = np.ones_like(rest) if w is None else w
    theta = theta0.copy()
    n_w = g.sum(ww)
    live = n_w > len(pcols) + 3
    if not np.any(live):
        return theta, np.mean(theta0, axis=0), np.zeros(3)
    mu = np.mean(theta[live], axis=0)
    # a broad start: half the pooled amplitude, a factor e^0.7 = 2 in v_s
    var = np.array([(0.5 * mu[0]) ** 2, (0.5 * mu[1]) ** 2, 0.7**2]) + 1e-30
    lo_l, hi_l = (math.log(v) for v in STRIBECK_SPEED_BOUNDS_RPM)
    s2 = np.ones(g.n)
    for rnd in range(rounds):
        for step in range(steps + (1 if rnd == 0 else 0)):
            S, dS = law.static_at(np.exp(theta[gid, 2]))
            m = theta[gid, 0] * S + theta[gid, 1] * law.viscous
            J = [S, law.viscous, theta[gid, 0] * dS]
            _, fitted = g.fit(list(pcols), [rest - m, *J], w=w)
            rr = rest - m - fitted[:, 0]
            rJ = [J[c] - fitted[:, 1 + c] for c in range(3)]
            if rnd == 0 and step == 0:
                # the noise of each tightening: its residual at the pooled law
                s2 = np.maximum(g.sum(ww * rr * rr) / np.maximum(n_w - len(pcols) - 3, 1.0), 1e-30)
                continue
            A = np.empty((g.n, 3, 3))
            b = np.empty((g.n, 3))
            for a in range(3):
                b[:, a] = g.sum(ww * rJ[a] * rr) / s2 - (theta[:, a] - mu[a]) / var[a]
                for c in range(a, 3):
                    A[:, a, c] = A[:, c, a] = g.sum(ww * rJ[a] * rJ[c]) / s2
                A[:, a, a] += 1.0 / var[a]
            delta = np.linalg.solve(A, b[:, :, None])[:, :, 0]
            delta[:, 2] = np.clip(delta[:, 2], -0.7, 0.7)
            theta = np.where(live[:, None], theta + delta, theta)
            theta[:, 2] = np.clip(theta[:, 2], lo_l, hi_l)
        post_var = np.diagonal(np.linalg.inv(A), axis1=1, axis2=2)
        s2 = np.maximum(g.sum(ww * rr * rr) / np.maximum(n_w - len(pcols) - 3, 1.0), 1e-30)
        mu = np.mean(theta[live], axis=0)
        var = np.maximum(np.mean((theta[live] - mu) ** 2 + post_var[live], axis=0), 1e-30)
    return theta, mu, var


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
    stribeck: dict[str, StribeckLaw] | None = None,
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
    of each constant, in place of its components (a Gauss-Newton step per tightening).

    ``stribeck``: a Stribeck law (components: static, viscous) whose three constants are fitted
    per tightening jointly, by ``_stribeck_map``, on one block of samples predicting the other,
    as every per-tightening constant."""
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
    block = _decorrelation_block(eng, fit.resid)
    group = _sample_groups(eng, block)
    # a Stribeck law first (its own joint fit of three constants per tightening), then the
    # factors of every other named effect in one joint fit per tightening: two effects whose
    # contributions overlap (a lag and a speed law, which cancel where both act) are refined
    # together, not the second on what the first left
    us_oos: list[F64] = []
    us_in: list[F64] = []
    owner: list[str] = []
    stribeck_shift = [np.zeros(len(s.y)) for _ in range(WITHIN_GROUPS)]
    for key, comps in terms.items():
        law = stribeck.get(key) if stribeck is not None else None
        if law is not None and len(comps) == 2:
            e, base_in, out_terms[key], shifts = _refine_stribeck(eng, pcols, zcols, fit, comps, law, e, base_oos, base_in, group)
            stribeck_shift = [a + b for a, b in zip(stribeck_shift, shifts)]
            continue
        if directions is not None and key in directions:
            key_oos, key_in = list(directions[key]), list(directions[key])
        else:
            key_oos = [sum((zcols[i] * fit.beta_folds[fold, i] for i in idx), np.zeros(len(s.y))) for idx in comps]
            key_in = [sum((zcols[i] * fit.beta[i] for i in idx), np.zeros(len(s.y))) for idx in comps]
        for u_oos, u_in in zip(key_oos, key_in):
            if np.any(u_in != 0):
                us_oos.append(u_oos)
                us_in.append(u_in)
                owner.append(key)
    if us_in:
        k = len(us_in)
        # all samples: the per-tightening estimates and the between-tightening variances
        d_full, V_full, _ = _factor_fit(eng, pcols, base_in, us_in, None)
        tau2 = np.array([_dersimonian_laird(d_full[:, c], V_full[:, c, c]) for c in range(k)])
        # the variances of each fold from the tightenings outside it
        tau2_fold = np.array([[_dersimonian_laird(d_full[eng.fold_t != f, c], V_full[eng.fold_t != f, c, c]) for c in range(k)] for f in range(eng.n_folds)])
        t2 = tau2_fold[eng.fold_t]
        # each group of sample blocks predicted from the others; what the declared columns take
        # of the effect, in the loop's own protocol (fitted on the other half of its blocks)
        ru_loop = [_in_loop_protocol(eng, pcols, u) for u in us_oos]
        e_new = e.copy()
        for kk in range(WITHIN_GROUPS):
            other = group == kk
            # the Stribeck law as refined without this group in (its per-tightening constants
            # from the same samples as these factors)
            d_h, V_h, _ = _factor_fit(eng, pcols, base_oos - stribeck_shift[kk], us_oos, (~other).astype(np.float64))
            shrunk = np.clip(_shrink(d_h, V_h, t2), lo, hi)
            pred = sum((shrunk[s.gid, c] * ru_loop[c] for c in range(k)), np.zeros(len(s.y)))
            e_new = np.where(other, e_new - pred, e_new)
        d_shrunk = np.clip(_shrink(d_full, V_full, np.broadcast_to(tau2, d_full.shape)), lo, hi)
        e = e_new
        base_in = base_in - sum((d_shrunk[s.gid, c] * us_in[c] for c in range(k)), np.zeros(len(s.y)))
        for key in dict.fromkeys(owner):
            cs = [c for c in range(k) if owner[c] == key]
            out_terms[key] = {
                "between_tightening_sd_relative": math.sqrt(float(tau2[cs[0]])),
                "between_tightening_sd_relative_by_component": [math.sqrt(float(tau2[c])) for c in cs],
                "tau2_by_fold": tau2_fold[:, cs],
                "factor": 1.0 + d_shrunk[:, cs[0]],
                "factor_raw": 1.0 + d_full[:, cs[0]],
                "factors": [1.0 + d_shrunk[:, c] for c in cs],
                "factors_raw": [1.0 + d_full[:, c] for c in cs],
                "refined_jointly_with": [o for o in dict.fromkeys(owner) if o != key],
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
        "block_samples": block,
    }


def _refine_stribeck(
    eng: _Engine, pcols: Sequence[F64], zcols: Sequence[F64], fit: _Fit, comps: list[list[int]], law: StribeckLaw, e: F64, base_oos: F64, base_in: F64, group: npt.NDArray[np.int64]
) -> tuple[F64, F64, dict[str, Any], list[F64]]:
    """A Stribeck law refined per tightening, all three constants jointly (``_stribeck_map``):
    the out-of-sample residual, the in-sample base with the refined law in, the term's factors
    for the report (static and viscous coefficient over the pooled ones, 1 + the change of
    ln v_s), and per group the change of the law's contribution estimated without that group
    (what the other effects' factors are then fitted beside).

    Out of sample: a tightening's constants are estimated on three of the ``group`` s of its
    samples and predict the fourth; the declared columns keep the loop's own protocol (fitted
    on the other half of the loop's blocks), so no sample's own value enters its prediction and
    the residual compares with the pooled one like for like."""
    s, g = eng.s, eng.g
    i_s, i_k = comps[0][0], comps[1][0]
    l0 = math.log(max(law.stribeck_speed_rpm, 1e-3))
    lo, hi = FACTOR_BOUNDS

    def pooled(b: F64) -> tuple[F64, F64]:
        u = zcols[i_s] * b[s.gid, 0] + zcols[i_k] * b[s.gid, 1]
        return u, np.column_stack([b[:, 0], b[:, 1], np.full(g.n, l0)])

    def contribution(theta: F64) -> F64:
        S, _ = law.static_at(np.exp(theta[s.gid, 2]))
        out: F64 = theta[s.gid, 0] * S + theta[s.gid, 1] * law.viscous
        return out

    def bounded(theta: F64, start: F64) -> F64:
        # a coefficient does not change sign between tightenings nor grow without bound
        out = theta.copy()
        for c in (0, 1):
            a, b = lo * start[:, c], hi * start[:, c]
            out[:, c] = np.clip(out[:, c], np.minimum(a, b), np.maximum(a, b))
        return out

    b_oos = fit.beta_folds[eng.fold_t][:, [i_s, i_k]]
    u_oos, theta0_oos = pooled(b_oos)
    e_new = e.copy()
    shifts: list[F64] = []
    for k in range(WITHIN_GROUPS):
        other = group == k
        w_fit = (~other).astype(np.float64)
        theta_h, _, _ = _stribeck_map(eng, pcols, base_oos + u_oos, law, theta0_oos, w_fit)
        shift = contribution(bounded(theta_h, theta0_oos)) - u_oos
        e_new = np.where(other, e_new - _in_loop_protocol(eng, pcols, shift), e_new)
        shifts.append(shift)
    b_in = np.broadcast_to(fit.beta[[i_s, i_k]], (g.n, 2))
    u_in, theta0_in = pooled(b_in)
    theta, mu, var = _stribeck_map(eng, pcols, base_in + u_in, law, theta0_in, None)
    theta = bounded(theta, theta0_in)
    base_in = base_in + u_in - contribution(theta)
    scale = np.array([fit.beta[i_s], fit.beta[i_k]])
    scale = np.where(scale != 0, scale, 1.0)
    factors = [theta[:, 0] / scale[0], theta[:, 1] / scale[1], 1.0 + theta[:, 2] - l0]
    sd = [math.sqrt(float(var[0])) / abs(float(scale[0])), math.sqrt(float(var[1])) / abs(float(scale[1])), math.sqrt(float(var[2]))]
    return e_new, base_in, {
        "between_tightening_sd_relative": sd[0],
        "between_tightening_sd_relative_by_component": sd,
        "factor": factors[0],
        "factor_raw": factors[0],
        "factors": factors,
        "factors_raw": factors,
        "population_mean": {"s_eff": float(mu[0]), "k_eff": float(mu[1]), "stribeck_speed_rpm": math.exp(float(mu[2]))},
        "method": "joint per-tightening fit of the static and viscous coefficients and ln v_s, maximum a posteriori under a normal population (EM)",
    }, shifts


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
