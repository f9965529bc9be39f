"""Step 3, candidates: the effects the declared model may lack, each as regressors built from the
data (never from the measured torque of the sample itself), with its physical name."""

from __future__ import annotations

import math
from typing import Any, Callable, Sequence

import numpy as np
import numpy.typing as npt

from .result import EFFECT_NAMES
from .prepare import _Groups, _Samples, B8, F64, I64
from .fit import _Engine, _Fit, _Term
from .spectrum import _long_stretch, _periodogram, _poly_fit, _refine_period, _spans as _spans_of, _spectral_search


# ---------------------------------------------------------------------------------------------
# Candidates


def _fitted_declared(s: _Samples, fit: _Fit, declared: list[F64]) -> F64:
    th = np.zeros(len(s.y))
    for k, col in enumerate(declared):
        th += col * fit.pcoef[s.gid, k]
    return th


class _Grid:
    """Samples of one segment laid out as (row = tightening, column = sample), rows sorted by
    length (longest first) so that the rows still running at a column are a prefix."""

    def __init__(self, s: _Samples, segment: int) -> None:
        idx = np.flatnonzero(s.seg == segment)
        g = s.gid[idx]
        starts = np.flatnonzero(np.r_[True, g[1:] != g[:-1]]) if len(idx) else np.zeros(0, dtype=np.int64)
        lens = np.diff(np.r_[starts, len(idx)])
        order = np.argsort(-lens, kind="stable")
        row_of_run = np.empty(len(starts), dtype=np.int64)
        row_of_run[order] = np.arange(len(starts))
        self.idx = idx
        self.lens = lens[order]
        self.tg = g[starts][order]
        self.rank = np.arange(len(idx)) - np.repeat(starts, lens)
        self.row = np.repeat(row_of_run, lens)
        self.n_rows = len(starts)
        self.width = int(lens.max()) if len(lens) else 0
        # live[j]: number of rows longer than j (a prefix, rows being sorted by length)
        self.live = np.searchsorted(-self.lens, -np.arange(self.width), side="left").astype(np.int64)

    def grid(self, v: npt.NDArray[Any], fill: float = 0.0) -> npt.NDArray[Any]:
        shape = (self.n_rows, self.width) + v.shape[1:]
        out = np.full(shape, fill, dtype=np.float64)
        out[self.row, self.rank] = v[self.idx]
        return out

    def factors(self, t: F64, tau: float) -> tuple[F64, F64]:
        """Per (row, column) decay a = exp(-dt / tau) and ramp factor tau (1 - a) / dt, with dt
        from the previous column (a = 1, factor 0 where dt <= 0: the state holds)."""
        TT = self.grid(t)
        dt = np.zeros_like(TT)
        dt[:, 1:] = TT[:, 1:] - TT[:, :-1]
        return _decay(dt, tau)


def _decay(dt: F64, tau: float) -> tuple[F64, F64]:
    ok = dt > 0
    a = np.where(ok, np.exp(-np.where(ok, dt, 1.0) / tau), 1.0)
    f = np.where(ok, tau * (1 - a) / np.where(ok, dt, 1.0), 0.0)
    return a, f


def _lowpass_parts(s: _Samples, X: F64, x_pre: F64, tau: float) -> tuple[F64, F64, F64, F64]:
    """A first-order low-pass of the input path ``X`` over each elastic window, exact for inputs
    linear between samples (a transducer filter), in parts that are linear in the recorded
    state at the anchors: the sample just before the window and the end of each pause.

    Returns per sample (0 outside the elastic zone): the decay D since the last anchor, the
    anchor's input value x_r and measured torque y_r, and the lag R of ``X`` started settled at
    the anchor, so that ``LP[X] - X = D (y_r - x_r) + R`` when the state at the anchor is y_r.
    """
    n = len(X)
    D_out, xr_out, yr_out, R_out = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    if s.t is None or tau <= 0 or not np.any(s.seg == 0):
        return D_out, xr_out, yr_out, R_out
    gr = _Grid(s, 0)
    XX, TT = gr.grid(X), gr.grid(s.t)
    a, f = gr.factors(s.t, tau)
    tg = gr.tg
    RY, RT = gr.grid(s.restart_y, np.nan), gr.grid(s.restart_t, np.nan)
    has_pre = np.isfinite(s.pre_t[tg]) & np.isfinite(s.pre_y[tg])
    # the first column: from the sample before the window (an anchor), else settled
    x_prev0 = np.where(has_pre, x_pre[tg], XX[:, 0])
    a[:, 0], f[:, 0] = _decay(TT[:, 0] - np.where(has_pre, s.pre_t[tg], TT[:, 0]), tau)
    dX = np.zeros_like(XX)
    dX[:, 0] = XX[:, 0] - x_prev0
    dX[:, 1:] = XX[:, 1:] - XX[:, :-1]
    restart = np.isfinite(RY)
    rr, rc = np.nonzero(restart)
    # after a pause the state restarts from the recorded torque at its end
    a[rr, rc], f[rr, rc] = _decay(TT[rr, rc] - RT[rr, rc], tau)
    restart_cols = set(int(j) for j in np.unique(rc))
    decay = np.where(has_pre, 1.0, 0.0)
    x_r = x_prev0.copy()
    y_r = np.where(has_pre, s.pre_y[tg], 0.0)
    lag = np.zeros(gr.n_rows)
    outs = [np.zeros((gr.n_rows, gr.width)) for _ in range(4)]
    for j in range(gr.width):
        m = int(gr.live[j])
        if j in restart_cols:
            r = restart[:m, j]
            prev = XX[:m, j - 1] if j > 0 else x_prev0[:m]
            x_r[:m] = np.where(r, prev, x_r[:m])
            y_r[:m] = np.where(r, RY[:m, j], y_r[:m])
            decay[:m] = np.where(r, 1.0, decay[:m])
            lag[:m] = np.where(r, 0.0, lag[:m])
        decay[:m] *= a[:m, j]
        lag[:m] = a[:m, j] * lag[:m] - dX[:m, j] * f[:m, j]
        outs[0][:m, j] = decay[:m]
        outs[1][:m, j] = x_r[:m]
        outs[2][:m, j] = y_r[:m]
        outs[3][:m, j] = lag[:m]
    for dst, src in zip((D_out, xr_out, yr_out, R_out), outs):
        dst[gr.idx] = src[gr.row, gr.rank]
    return D_out, xr_out, yr_out, R_out


def _lowpass_filter_many(s: _Samples, cols: list[F64], tau: float) -> list[F64]:
    """``LP_tau`` of many regressors at once, per segment, each started settled (exact for
    inputs linear between samples): one pass over the samples for all columns."""
    if s.t is None or tau <= 0:
        return cols
    Z = np.column_stack(cols)
    out = Z.copy()
    for segment in (0, 1):
        if not np.any(s.seg == segment):
            continue
        gr = _Grid(s, segment)
        XX = gr.grid(Z)
        a, f = gr.factors(s.t, tau)
        dX = np.zeros_like(XX)
        dX[:, 1:] = XX[:, 1:] - XX[:, :-1]
        dev = np.zeros((gr.n_rows, Z.shape[1]))
        D = np.zeros_like(XX)
        for j in range(1, gr.width):
            m = int(gr.live[j])
            dev[:m] = a[:m, j, None] * dev[:m] - dX[:m, j] * f[:m, j, None]
            D[:m, j] = dev[:m]
        out[gr.idx] = Z[gr.idx] + D[gr.row, gr.rank]
    return [out[:, i].copy() for i in range(out.shape[1])]


def _lowpass_regressor(s: _Samples, g: _Groups, slope_x: F64, tau: float, decay: list[F64] | None = None) -> F64:
    """``(LP_tau[T_hat] - T_hat) / tau`` (about -dT_hat/dt) for the declared line refitted
    exactly under a low-pass of ``tau``: with the parts of :func:`_lowpass_parts`,
    y = a + b x + D (y_r - a - b x_r) + b R is linear in (a, b) given tau."""
    el = (s.seg == 0).astype(np.float64)
    rd = 1.0 - el
    first = np.flatnonzero(np.r_[True, (s.gid[1:] != s.gid[:-1]) | (s.seg[1:] != s.seg[:-1])] & (s.seg == 0))
    x_first = np.full(s.n_tight, np.nan)
    th_first = np.full(s.n_tight, np.nan)
    x_first[s.gid[first]] = s.x[first]
    th_first[s.gid[first]] = s.theta[first]
    x_pre = np.nan_to_num(np.where(np.isfinite(s.pre_theta), x_first + slope_x * (s.pre_theta - th_first), x_first))
    D, x_r, y_r, R = _lowpass_parts(s, s.x, x_pre, tau)
    mean_x = (g.sum(s.x * el) / np.maximum(g.sum(el), 1))[s.gid]
    col_a = (1.0 - D) * el
    col_b = ((s.x - mean_x) - D * (x_r - mean_x) + R) * el
    target = s.y - D * y_r
    coef, _ = g.fit([col_a, col_b, rd], [target])
    a_t, b_t = coef[s.gid, 0, 0], coef[s.gid, 1, 0]
    dev = D * (y_r - a_t - b_t * (x_r - mean_x)) + b_t * R
    out: F64 = dev / tau
    if decay is not None:
        decay.append(D * el)
    return out


def _anchor_transients(s: _Samples, fitted: F64, lag_col: F64, tau: float) -> list[F64]:
    """The relaxation of a channel lag from its state at each anchor (the sample just before the
    elastic window, the end of a pause), for a lag held in its first-order linearised form
    ``y = T_hat + tau (-dT_hat/dt)``: two columns, ``m e^-u`` and ``m u e^-u`` with
    ``u = (t - t_anchor) / tau``.

    Why: the linearisation is the channel's steady state on a ramp. At the window's start the
    channel is not there yet (before the window the torque rose along the seating curve, at
    another rate), and how far it is off is measured: ``m``, the recorded torque at the anchor
    less the linearised model carried back to the anchor's time. A channel of order two holds
    its state in a value and a rate, and relaxes from it as a combination of ``e^-u`` and
    ``u e^-u`` (exact for two equal poles, close for damping near 0.7 with tau the mean lag;
    a first-order channel needs only the first): with one pooled coefficient each, the
    relaxation is predicted from the data before the window, not fitted per tightening (which
    the out-of-sample protocol cannot estimate from the few samples it spans). ``fitted`` is
    the fitted declared torque and ``lag_col`` the lag's column times its coefficient's unit
    (``-dT_hat/dt``); the model at a sample is ``fitted + tau lag_col``."""
    n = len(s.y)
    el = s.seg == 0
    if s.t is None or tau <= 0 or not np.any(el):
        return []
    new_run = np.r_[True, (s.gid[1:] != s.gid[:-1]) | (s.seg[1:] != s.seg[:-1])]
    first = new_run & el
    restart = el & np.isfinite(s.restart_y) & ~first
    t_anchor = np.full(n, np.nan)
    y_anchor = np.full(n, np.nan)
    t_anchor[first] = s.pre_t[s.gid[first]]
    y_anchor[first] = s.pre_y[s.gid[first]]
    t_anchor[restart] = s.restart_t[restart]
    y_anchor[restart] = s.restart_y[restart]
    # the model carried back from the anchor's first sample to the anchor (at the rate -lag_col)
    is_anchor = first | restart
    m_at = np.where(is_anchor, y_anchor - (fitted + tau * lag_col + lag_col * (s.t - t_anchor)), np.nan)
    # each elastic sample takes the latest anchor of its own tightening and window
    last = np.maximum.accumulate(np.where(is_anchor, np.arange(n), -1))
    run_start = np.maximum.accumulate(np.where(new_run, np.arange(n), 0))
    ok = el & (last >= run_start)
    a = np.where(ok, last, 0)
    m = np.where(ok, m_at[a], np.nan)
    u = (s.t - t_anchor[a]) / tau
    ok &= np.isfinite(m) & np.isfinite(u) & (u >= 0)
    e = np.where(ok, np.exp(-np.where(ok, u, 0.0)), 0.0)
    m = np.where(ok, m, 0.0)
    return [m * e, m * np.where(ok, u, 0.0) * e]


def _candidates(
    s: _Samples, eng: _Engine, fit: _Fit, declared: list[F64], tag: int, model_periods: Sequence[tuple[str, float]], hints: dict[str, float]
) -> tuple[dict[str, _Term], dict[str, Any]]:
    """Every candidate term, its regressors built from the fit (fitted torque, slopes) and the
    channels other than the measured torque; keyed by a stable key."""
    g = eng.g
    gid = s.gid
    el = s.seg == 0
    rd = s.seg == 1
    elf, rdf = el.astype(np.float64), rd.astype(np.float64)
    th = _fitted_declared(s, fit, declared)
    # elastic slope dT/dx per tightening, and dT/dtheta per sample
    xc = (s.x - g.sum(s.x * elf)[gid] / np.maximum(g.sum(elf)[gid], 1)) * elf
    xs = np.sqrt(g.sum(xc * xc) / np.maximum(g.sum(elf), 1))
    b_t = fit.pcoef[:, 1] / np.where(xs > 0, xs, 1.0)
    if s.has_clamp:
        dth = np.r_[np.diff(s.x), 0.0]
        dang = np.r_[np.diff(s.theta), 0.0]
        ok = el & np.r_[(gid[1:] == gid[:-1]) & (s.seg[1:] == 0), False] & (np.abs(dang) > 0)
        num = g.sum(np.where(ok, dth * dang, 0.0))
        den = g.sum(np.where(ok, dang * dang, 0.0))
        k_t = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
        dT_dtheta = b_t[gid] * k_t[gid] * elf
    else:
        k_t = np.ones(s.n_tight)
        dT_dtheta = b_t[gid] * elf
    tp = np.where(g.sum(rdf) > 0, fit.pcoef[:, 2], s.prevailing)
    tp = np.where(np.isfinite(tp), tp, 0.0)
    cands: dict[str, _Term] = {}

    def glob(name: str, cols: list[F64], labels: list[str], params: Callable[[_Fit, list[int]], dict[str, Any]], info: dict[str, Any] | None = None, description: str | None = None, key: str | None = None, extension: list[F64] | None = None) -> None:
        cols = [np.where(np.isfinite(c), c, 0.0) for c in cols]
        if not any(np.any(c != 0) for c in cols):
            return
        info = dict(info or {})
        key = key or name
        ext = [np.where(np.isfinite(c), c, 0.0) for c in extension or []]
        cands[key] = _Term(name, description or EFFECT_NAMES[name], False, labels, cols, params, info, key, tag, ext)

    def pv(fit2: _Fit, idx: list[int], scale: float = 1.0) -> dict[str, float]:
        return {"value": float(fit2.beta[idx[0]] * scale), "se": float(fit2.se[idx[0]] * abs(scale)), "se_folds": _fold_se(fit2, idx[0]) * abs(scale)}

    if s.omega is not None:
        om = np.maximum(np.abs(s.omega), 6.0)  # 1 rpm floor
        ref = float(np.median(om[el]))
        lnv = np.log(om / ref)
        # speed-dependent friction: the friction torque above the prevailing level scales
        fr = (th - tp[gid]) * elf
        spread = float(np.std(lnv[el]))

        def p_speed(f2: _Fit, idx: list[int]) -> dict[str, Any]:
            return {
                "a_eff": pv(f2, idx),
                "reference_speed_rpm": ref / 6.0,
                "law": "T - T_prevailing = (T0 - T_prevailing) (1 + a_eff ln(v / v_ref))",
                "note": "a_eff = a * (friction share of the torque per clamp force, about 0.85-0.9 for ISO metric threads): the lead term 0.16 P does not depend on speed",
            }

        if spread > 0.01:
            glob("speed_dependent_friction", [fr * lnv], ["a_eff"], p_speed, {"speed_source": s.speed_source, "ln_speed_sd_in_window": spread, "law": "log"}, extension=[fr * (om / ref - 1.0)])

            # the same effect with friction linear in the speed (viscous): under a hold-down
            # program the speed falls in proportion to the remaining torque, so a linear law
            # bends the torque-force line exactly as pressure friction does except where the
            # speed stops following the force (the knee, the speed floor, a pause): only the
            # law that follows the speed there can win that comparison
            def p_speed_linear(f2: _Fit, idx: list[int]) -> dict[str, Any]:
                return {
                    "b_eff": pv(f2, idx),
                    "reference_speed_rpm": ref / 6.0,
                    "law": "T - T_prevailing = (T0 - T_prevailing) (1 + b_eff (v / v_ref - 1))",
                    "note": "b_eff = b * (friction share of the torque per clamp force): the lead term 0.16 P does not depend on speed",
                }

            glob(
                "speed_dependent_friction",
                [fr * (om / ref - 1.0)],
                ["b_eff"],
                p_speed_linear,
                {"speed_source": s.speed_source, "ln_speed_sd_in_window": spread, "law": "linear"},
                key="speed_dependent_friction:linear",
                extension=[fr * lnv],
            )
        lnr = lnv * rdf
        if float(np.std(lnv[rd])) > 0.01 if np.any(rd) else False:

            def p_sp(f2: _Fit, idx: list[int]) -> dict[str, Any]:
                return {"a_prevailing": pv(f2, idx), "reference_speed_rpm": ref / 6.0}

            glob("speed_dependent_prevailing_torque", [tp[gid] * lnr], ["a_prevailing"], p_sp)
        # channel delay: recorded T(t - tau) = T - tau dT/dt (first order); once tau is known
        # roughly, the fitted torque path through a first-order low-pass with that tau
        tau0 = hints.get("tau_s", 0.0)
        zd_ext: list[F64] = []
        if tau0 > 1e-5 and s.t is not None:
            decay: list[F64] = []
            zd = _lowpass_regressor(s, g, k_t if s.has_clamp else np.ones(s.n_tight), tau0, decay)
            form = f"low-pass path, refined at tau = {1000 * tau0:.3g} ms"
            # a second time constant: a second-order filter or a pure delay differs from the
            # first-order path in the curvature of the lag (the s^2 term), which this takes up
            dz = np.r_[np.diff(zd), 0.0]
            dt_ = np.r_[np.diff(s.t), 0.0]
            nxt = np.r_[(gid[1:] == gid[:-1]) & (s.seg[1:] == s.seg[:-1]), False] & el & (dt_ > 0)
            zd_dot = np.where(nxt, dz / np.where(dt_ > 0, dt_, 1.0), 0.0) * tau0
            # the window's last sample has no next one: its backward difference (a zero there
            # left the lag's curvature out of every window's end, where the tool stops)
            prv = np.r_[False, nxt[:-1]] & el & ~nxt
            zd_dot = np.where(prv, np.r_[0.0, zd_dot[:-1]], zd_dot)
            # ... and the transient from each anchor (the sample before the window, the end of a
            # pause), whose state a higher-order channel holds in more than the one recorded value
            restarted = np.cumsum(np.isfinite(s.restart_y) & el) - np.repeat(np.r_[0, np.cumsum(np.isfinite(s.restart_y) & el)][g.starts], np.diff(np.r_[g.starts, len(gid)])) > 0
            zd_ext = [
                _lowpass_regressor(s, g, k_t if s.has_clamp else np.ones(s.n_tight), 2.0 * tau0),
                zd_dot,
                decay[0] * s.scale[gid] * ~restarted,
                decay[0] * s.scale[gid] * restarted,
            ]
        else:
            zd = -dT_dtheta * s.omega
            form = "first order: -dT_hat/dt"

        def p_delay(f2: _Fit, idx: list[int]) -> dict[str, Any]:
            return {"tau_ms": pv(f2, idx, 1000.0)}

        lag = _lag_xcorr(s, fit.resid, th, el)
        glob("channel_delay", [zd], ["tau"], p_delay, {"cross_correlation_lag": lag, "regressor": form}, extension=zd_ext)
    if s.alpha is not None:

        def p_inertia(f2: _Fit, idx: list[int]) -> dict[str, Any]:
            return {"J_kg_m2": pv(f2, idx)}

        # its extension: the acceleration as the backward difference of the recorded speed, so
        # that a lag claimed after the inertia must keep its gain when the acceleration may be
        # estimated either way (under a hold-down program the two differ, and a lag, collinear
        # with the acceleration there, would otherwise take up the difference)
        glob(
            "inertia",
            [s.alpha],
            ["J"],
            p_inertia,
            {"acceleration_source": "speed channel (first difference)" if s.speed_source == "speed channel" else "angle/time (second derivative)"},
            extension=[s.alpha_raw] if s.alpha_raw is not None else None,
        )
    # curvature / pressure-dependent friction: b L w^2 in the elastic zone, w = (x - x_s) / L the
    # position in the window (x_s its start, L its span in x): kappa is the relative change of
    # the slope across half the window (slope at the end / at the start = 1 + 2 kappa)
    x_lo = np.full(s.n_tight, np.inf)
    x_hi = np.full(s.n_tight, -np.inf)
    np.minimum.at(x_lo, gid[el], s.x[el])
    np.maximum.at(x_hi, gid[el], s.x[el])
    span_x = np.where(x_hi > x_lo, x_hi - x_lo, np.nan)
    w = (s.x - x_lo[gid]) / span_x[gid]
    zq = np.nan_to_num(b_t[gid] * span_x[gid] * w * w) * elf
    name_q = "pressure_dependent_friction" if s.has_clamp else "elastic_curvature"
    b_base = b_t.copy()
    x0 = np.zeros(s.n_tight) if s.has_clamp else s.phases["snug_angle"]
    x_ref = s.xf_ref  # x - x0 at the end of the tightening

    def p_curv(f2: _Fit, idx: list[int]) -> dict[str, Any]:
        kappa = float(f2.beta[idx[0]])
        b_new = f2.pcoef[:, 1] / np.where(xs > 0, xs, 1.0)
        # quadratic in x_F = x - x0: Q x_F^2 + B x_F; pressure law: B = K0 (1 - c), Q = K0 c / x_ref
        q = kappa * b_base / span_x
        bb = b_new + 2 * q * (x0 - x_lo)
        den = bb + q * x_ref
        ok = np.isfinite(q) & np.isfinite(den) & (den > 0) & (x_ref > 0) & (x0 <= x_lo)
        cprime = np.where(ok, q * x_ref / np.where(ok, den, 1.0), np.nan)
        c_med = float(np.nanmedian(cprime)) if np.any(ok) else float("nan")
        out: dict[str, Any] = {
            "kappa": pv(f2, idx),
            "slope_change_across_window": {"value": 2 * kappa, "se": 2 * float(f2.se[idx[0]]), "se_folds": 2 * _fold_se(f2, idx[0]), "unit": "relative (end / start - 1)"},
            "pressure_coefficient": {
                "value": c_med,
                "se": abs(c_med) * float(f2.se[idx[0]]) / max(abs(kappa), 1e-300),
                "se_folds": abs(c_med) * _fold_se(f2, idx[0]) / max(abs(kappa), 1e-300),
                "tightenings": int(np.sum(ok)),
            },
            "law": "T - T_p = K0 F (1 + c_eff (F / F_end - 1)), F_end the clamp force at the end of the tightening",
        }
        if not s.has_clamp:
            out["note"] = (
                "without clamp force F is taken proportional to the angle past snug: the bend may be friction "
                "changing with pressure or a joint stiffness changing with load, which the data cannot separate"
            )
        else:
            out["note"] = "c_eff = c * (friction share of the torque per clamp force, about 0.85-0.9 for ISO metric threads)"
        return out

    glob(name_q, [zq], ["kappa"], p_curv, extension=[zq * np.nan_to_num(w)])
    # time within the tightening (additive drift, relative to the tightening's peak torque)
    if s.t is not None:

        def p_time(f2: _Fit, idx: list[int]) -> dict[str, Any]:
            return {"drift_per_s_relative": pv(f2, idx)}

        glob("time_drift", [s.scale[gid] * s.t], ["drift"], p_time, extension=[s.scale[gid] * s.t * s.t])
    # program steps: per step of the tool program (those seen in the elastic window of at least
    # 5 % of the tightenings), an offset, a change of the torque rate from the step's start and
    # a short transient after it (global coefficients, relative to the tightening's scale)
    if s.step is not None and s.step_theta is not None and s.step_t is not None:
        cols = []
        labels: list[str] = []
        for seg_id, seg_mask in ((0, el), (1, rd)):
            # a step's terms are identified only against another step in the same stretch: keep
            # the steps that share a stretch with another one in enough tightenings, and measure
            # offsets against the most common of them
            steps_here = np.unique(s.step[seg_mask])
            n_steps_t = np.zeros(s.n_tight)
            for v in steps_here:
                n_steps_t += np.bincount(gid[seg_mask & (s.step == v)], minlength=s.n_tight) > 0
            mixed = n_steps_t > 1
            shared = [v for v in steps_here if np.sum(mixed & (np.bincount(gid[seg_mask & (s.step == v)], minlength=s.n_tight) > 0)) >= max(10, 0.05 * s.n_tight)]
            if len(shared) < 2:
                continue
            counts = [int(np.sum(seg_mask & (s.step == v))) for v in shared]
            reference = shared[int(np.argmax(counts))]
            where = "elastic" if seg_id == 0 else "rundown"
            for v in shared:
                ind = (seg_mask & (s.step == v)).astype(np.float64)
                if v != reference:
                    cols.append(s.scale[gid] * ind)
                    labels.append(f"{where}, step {v}: offset from step {reference}")
                if seg_id == 0:
                    cols.append(dT_dtheta * s.step_theta * ind)
                    labels.append(f"{where}, step {v}: torque-rate change")
                    for tau_ms in (5.0, 25.0):
                        cols.append(s.scale[gid] * np.exp(-s.step_t / (tau_ms / 1000.0)) * ind)
                        labels.append(f"{where}, step {v}: transient {tau_ms:g} ms")
        if cols:
            step_labels = list(labels)

            def p_step(f2: _Fit, idx: list[int]) -> dict[str, Any]:
                out: dict[str, Any] = {}
                for lab, i in zip(step_labels, idx):
                    unit = "relative to the torque rate" if "rate" in lab else "fraction of the peak torque"
                    out[lab] = {"value": float(f2.beta[i]), "se": float(f2.se[i]), "se_folds": _fold_se(f2, i), "unit": unit}
                return out

            glob("program_step", cols, labels, p_step)
    # periodicities: once per revolution always, other periods from the spectral search of the
    # long rundown stretch against the angle and against time. Each tightening's modulation
    # (its own phase: a sine and a cosine per tightening) is estimated on that stretch and
    # predicted into the samples of the model, which it has not seen; one global coefficient
    # (kappa, about 1) scales the prediction, so the term goes through the same K-fold gain test
    # across tightenings as every other. Two forms: additive (an eccentric socket or spindle, a
    # drag of its own in Nm) and multiplicative (the transducer's sensitivity, T (1 + r sin)).
    if "long" not in eng.memo:
        eng.memo["long"] = _long_stretch(s)
    if "spectrum" not in eng.memo:
        eng.memo["spectrum"] = _spectral_search(eng.memo["long"], s.n_tight)
    lg = eng.memo["long"]
    search = eng.memo["spectrum"]
    pinfo = _periodogram(lg, s.n_tight, search=search)
    wanted: list[tuple[str, float]] = [("angle", 360.0)]
    speed_med = None
    if lg is not None and lg.t is not None:
        dth, dtt = np.diff(lg.theta), np.diff(lg.t)
        okv = (np.diff(lg.gid) == 0) & (dtt > 0)
        speed_med = float(np.median(dth[okv] / dtt[okv])) if okv.any() else None
    angle_window = search.get("axes", {}).get("angle", {}).get("window_deg")
    def refined(axis: str, period: float) -> float:
        key = ("refined", axis, period)
        if key not in eng.memo:
            window = search.get("axes", {}).get(axis, {}).get("window_deg" if axis == "angle" else "window_s")
            eng.memo[key] = _refine_period(lg, axis, period, window, s.n_tight) if lg is not None and window else period
        return float(eng.memo[key])

    for pk in search.get("peaks", []):
        if pk["domain"] == "angle" and abs(pk["period_deg"] - 360.0) > 36.0 and sum(a == "angle" for a, _ in wanted) < 3:
            wanted.append(("angle", refined("angle", pk["period_deg"])))
    for pk in search.get("peaks", []):
        if pk["domain"] != "time" or sum(a == "time" for a, _ in wanted) >= 2:
            continue
        # the image of a periodicity over the angle at the median speed is not a new candidate
        if speed_med and angle_window:
            f_ang = 1.0 / (pk["period_s"] * speed_med)
            if any(a == "angle" and abs(f_ang - 1.0 / q) < 2.0 / angle_window for a, q in wanted):
                continue
        wanted.append(("time", refined("time", pk["period_s"])))
    for axis, period in list(model_periods):
        if all(not (a == axis and abs(period - q) <= 1e-9 * period) for a, q in wanted):
            wanted.append((axis, period))
    ref_t = lg.ref if lg is not None and lg.ref is not None else s.scale
    for axis, period in wanted:
        if lg is None:
            break
        u_long = lg.theta if axis == "angle" else lg.t
        u_model = s.theta if axis == "angle" else s.t
        if u_long is None or u_model is None:
            continue
        span_u = lg.span if axis == "angle" else _spans_of(lg.gid, u_long, s.n_tight)
        usable = (span_u >= period) & (lg.count >= 30)
        if usable.sum() < max(10, 0.05 * s.n_tight):
            continue
        unit = "deg" if axis == "angle" else "s"
        base = "runout" if (axis == "angle" and period == 360.0) else "periodic_disturbance"
        peak_info = next((q for q in search.get("peaks", []) if q["domain"] == axis and abs(refined(axis, q[f"period_{unit}"]) - period) <= 1e-9 * period), None)
        # (a modulation of the transducer's gain follows its rotation: on the time axis only the
        # additive form)
        for form in ("additive", "multiplicative") if axis == "angle" else ("additive",):
            memo_key = ("period", axis, period, form)
            sel = usable[lg.gid]
            if memo_key not in eng.memo:
                ph_l = 2 * math.pi * u_long[sel] / period
                lev = lg.level[lg.gid[sel]] if form == "multiplicative" else 1.0
                eng.memo[memo_key] = _poly_fit(lg.gid[sel], lg.theta[sel], s.long_y[sel], s.n_tight, [lev * np.sin(ph_l), lev * np.cos(ph_l)])
            wave_key = ("wave", axis, period, form)
            if wave_key not in eng.memo:
                # the prediction into the model's samples and the pooled amplitude depend on the
                # long stretch only: built once
                _, coef, var = eng.memo[memo_key]
                c1 = np.nan_to_num(coef[:, 3])
                c2 = np.nan_to_num(coef[:, 4])
                v1, v2 = var[:, 3], var[:, 4]
                ph = 2 * math.pi * u_model / period
                ok_ = usable & np.isfinite(v1 + v2) & (v1 + v2 > 0)
                amp_ = np.sqrt(c1**2 + c2**2)
                eng.memo[wave_key] = (
                    c1[gid] * np.sin(ph) + c2[gid] * np.cos(ph),
                    ok_,
                    amp_,
                    _pooled_amplitude(amp_[ok_], (v1 + v2)[ok_], None if form == "multiplicative" else ref_t[ok_], eng.fold_t[ok_]),
                    float(np.median(amp_[ok_] / np.sqrt((v1[ok_] + v2[ok_]) / 2))) if ok_.any() else float("nan"),
                )
            wave, ok, amp, pooled, snr = eng.memo[wave_key]
            z = th * wave if form == "multiplicative" else wave
            if form == "multiplicative":
                r2 = pooled["r2_weighted"]
                r_hat = math.sqrt(max(r2, 0.0))
                r2_se = pooled["r2_weighted_se"]
                amplitude = {"value": r_hat, "se": r2_se / (2 * r_hat) if r_hat > 0 else float("nan"), "se_folds": pooled["r_se_folds"], "unit": "relative to the torque"}
                law = f"T (1 + r sin(2 pi {'theta' if axis == 'angle' else 't'} / period + phi_j)), phase phi_j per tightening"
            else:
                amplitude = {"value": pooled["relative"], "se": pooled["relative_se"], "se_folds": pooled["relative_se_folds"], "unit": "fraction of the target torque (of the peak torque where the table has no target)"}
                law = f"T + A_j sin(2 pi {'theta' if axis == 'angle' else 't'} / period + phi_j), amplitude A_j and phase phi_j per tightening"

            def p_per(
                f2: _Fit,
                idx: list[int],
                period: float = period,
                unit: str = unit,
                amplitude: dict[str, Any] = amplitude,
                pooled: dict[str, float] = pooled,
                n_ok: int = int(ok.sum()),
                med_amp: float = float(np.median(amp[ok])) if ok.any() else float("nan"),
                law: str = law,
                form: str = form,
            ) -> dict[str, Any]:
                out = {
                    f"period_{unit}": period,
                    "amplitude": amplitude,
                    "kappa": {"value": float(f2.beta[idx[0]]), "se": float(f2.se[idx[0]]), "se_folds": _fold_se(f2, idx[0])},
                    "amplitude_median_per_tightening": med_amp,
                    "tightenings_with_a_long_rundown": n_ok,
                    "form": form,
                    "pooled_amplitude_z": pooled["z"],
                    "law": law,
                    "note": "amplitude pooled over the tightenings (mean of the squared per-tightening amplitude less its "
                    "estimation variance); A_j and phi_j from the rundown before the declared stretch; kappa (about 1 when the "
                    "modulation found there is the one in the rest of the curve) scales its prediction into the model's samples",
                }
                if form == "additive":
                    out["amplitude_nm"] = {"value": pooled["nm"], "se": pooled["nm_se"], "se_folds": pooled["nm_se_folds"]}
                return out

            info = {f"period_{unit}": period, "axis": axis, "form": form, "median_amplitude_snr_in_rundown": snr, "pooled_amplitude_z": pooled["z"]}
            if axis == "angle":
                info["period_deg"] = period
            if peak_info is not None:
                info["spectral_peak"] = {k: peak_info[k] for k in ("power_ratio", "p_value", "amplitude_nm")}
            if base == "runout":
                desc = EFFECT_NAMES[base] + ("" if form == "multiplicative" else " (additive: a drag of its own)")
            else:
                desc = f"periodic {'modulation of' if form == 'multiplicative' else 'disturbance on'} the torque with a period of {period:.4g} {unit}" + (" in time" if axis == "time" else "")
            key = base if (base == "runout" and form == "multiplicative") else f"{base}:{axis}:{period:.6g}:{form}" if base != "runout" else f"{base}:{form}"
            glob(base, [z], ["kappa"], p_per, info, desc, key=key)
    tau_lp = hints.get("tau_s", 0.0)
    if tau_lp > 0:
        # the recorded torque is the transducer's low-pass of everything: so are the regressors
        todo = [t for t in cands.values() if not t.per_tightening and t.name != "channel_delay"]
        flat = [c for t in todo for c in t.columns]
        if flat:
            filtered = _lowpass_filter_many(s, flat, tau_lp)
            i = 0
            for t in todo:
                t.columns = filtered[i : i + len(t.columns)]
                i += len(t.columns)
                t.info["filtered_by_channel_low_pass_ms"] = 1000 * tau_lp
    return cands, pinfo


def _fold_se(fit: _Fit, i: int) -> float:
    """Standard error of a global coefficient from the out-of-sample protocol itself: the
    delete-a-fold jackknife over the K estimates each fitted without one fold of tightenings
    (the same estimates that predict the held-out fold), sqrt((K - 1) / K * sum (b_k - mean)^2).
    It needs no model of the noise and sees what the sandwich does not: a coefficient that
    moves with which tightenings are in the fit."""
    bf = fit.beta_folds[:, i] if fit.beta_folds.ndim == 2 and fit.beta_folds.shape[1] > i else np.zeros(0)
    k = len(bf)
    if k < 2 or not np.all(np.isfinite(bf)):
        return float("nan")
    return float(math.sqrt((k - 1) / k * float(np.sum((bf - bf.mean()) ** 2))))


def _pooled_amplitude(amp: F64, var: F64, ref: F64 | None, folds: I64 | None = None) -> dict[str, float]:
    """Pooled amplitude evidence of a per-tightening sine and cosine pair: with a_j^2 = c1^2 + c2^2
    and v_j = var(c1) + var(c2), E[a_j^2] = A_j^2 + v_j, so mean(a_j^2 - v_j) estimates the mean
    square amplitude (its root: the amplitude); under no modulation a_j^2 / (v_j / 2) is chi2_2,
    and z compares its mean over the tightenings with 2. ``folds`` (the fold of each tightening):
    the ``*_se_folds`` entries are the delete-a-fold jackknife of the pooled amplitudes, the
    standard error of the out-of-sample protocol."""
    n = len(amp)
    nan = float("nan")
    if n == 0:
        return {"z": nan, "nm": nan, "nm_se": nan, "relative": nan, "relative_se": nan, "r2_weighted": nan, "r2_weighted_se": nan, "nm_se_folds": nan, "relative_se_folds": nan, "r_se_folds": nan}
    a2 = amp * amp
    q = a2 / np.maximum(var / 2, 1e-300)
    z = float((np.mean(q) - 2.0) / (2.0 / math.sqrt(n)))

    def root_mean(x2: F64, v: F64) -> tuple[float, float]:
        m = float(np.mean(x2 - v))
        se = float(np.std(x2, ddof=1) / math.sqrt(n)) if n > 1 else nan
        r = math.sqrt(max(m, 0.0))
        return r, (se / (2 * r) if r > 0 else nan)

    def r2_weighted(x2: F64, v: F64) -> float:
        w = 1.0 / v**2
        return float(np.sum(w * (x2 - v)) / np.sum(w))

    def jackknife(stat: Callable[[npt.NDArray[np.bool_]], float]) -> float:
        if folds is None:
            return nan
        levels = np.unique(folds)
        if len(levels) < 2:
            return nan
        est = np.array([stat(folds != f) for f in levels])
        if not np.all(np.isfinite(est)):
            return nan
        k = len(est)
        return float(math.sqrt((k - 1) / k * float(np.sum((est - est.mean()) ** 2))))

    nm, nm_se = root_mean(a2, var)
    rel, rel_se = root_mean(a2 / ref**2, var / ref**2) if ref is not None else (nan, nan)
    w = 1.0 / var**2
    r2w = r2_weighted(a2, var)
    r2w_se = float(np.sqrt(np.sum(w**2 * (2 * var**2 + 2 * a2 * var))) / np.sum(w))
    return {
        "z": z,
        "nm": nm,
        "nm_se": nm_se,
        "relative": rel,
        "relative_se": rel_se,
        "r2_weighted": r2w,
        "r2_weighted_se": r2w_se,
        "nm_se_folds": jackknife(lambda m: math.sqrt(max(float(np.mean(a2[m] - var[m])), 0.0))),
        "relative_se_folds": jackknife(lambda m: math.sqrt(max(float(np.mean((a2[m] - var[m]) / ref[m] ** 2)), 0.0))) if ref is not None else nan,
        "r_se_folds": jackknife(lambda m: math.sqrt(max(r2_weighted(a2[m], var[m]), 0.0))),
    }


def _lag_xcorr(s: _Samples, resid: F64, th: F64, el: B8, max_lag: int = 12) -> dict[str, Any]:
    """Lag (samples) at which the fitted torque, shifted, best explains the residual in the
    elastic zone: the residual of a delayed channel looks like T_hat(t - L) - T_hat(t)."""
    n = len(resid)
    best = (0.0, 0)
    out = []
    for lag in range(1, max_lag + 1):
        i = np.arange(lag, n)
        ok = el[i] & el[i - lag] & (s.gid[i] == s.gid[i - lag])
        d = th[i - lag] - th[i]
        r = resid[i]
        dd, rr = d[ok], r[ok]
        den = float(np.sqrt(np.sum(dd * dd) * np.sum(rr * rr)))
        c = float(np.sum(dd * rr) / den) if den > 0 else 0.0
        out.append(c)
        if c > best[0]:
            best = (c, lag)
    dt = None
    if s.t is not None:
        dts = np.diff(s.t)[(np.diff(s.gid) == 0)]
        dt = float(np.median(dts[dts > 0])) if np.any(dts > 0) else None
    return {
        "best_lag_samples": best[1],
        "best_lag_ms": best[1] * dt * 1000 if dt else None,
        "correlation": best[0],
        "by_lag": out,
    }
