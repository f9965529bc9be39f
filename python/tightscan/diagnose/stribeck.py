"""Other forms of ``speed_dependent_friction`` (issue 12), tried once the loop has named a
logarithmic or linear speed law.

The Stribeck form: friction that falls from its static level as the speed rises past a
Stribeck speed, then rises again with the viscous part,

    mu(v) = mu_c + (mu_s - mu_c) exp(-(v / v_s)^delta) + k_v v,

a minimum between the two (the classical Stribeck curve: Armstrong-Helouvry, Dupont & Canudas de
Wit 1994). Neither the logarithmic nor the linear law has a minimum, so on such friction both
leave a residual several times the noise. Relative to the friction at the reference speed (the
median speed of the elastic windows) the torque above the prevailing level is

    T - T_p = (T0 - T_p) (1 + s_eff (E(v) - E(v_ref)) + k_eff (v / v_ref - 1)),  E(v) = exp(-(v / v_s)^delta),

linear in (s_eff, k_eff) given (v_s, delta): two global columns. The logarithmic law with an
offset speed, ln(1 + v / v0), of which ln(v / v_ref) is the limit v0 -> 0: one column.

The shapes (v_s, delta; v0) are chosen on a grid by the loop's out-of-sample RMSE, and the best
replaces the named law only when it passes the loop's gain test against that law at ``alpha``
over the law families and speed sources (Bonferroni), so a logarithmic or linear law is kept
where the extra shape does not predict better.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from .candidates import _fitted_declared, _fold_se, _lowpass_filter_many
from .fit import _Engine, _Fit, _Term
from .prepare import F64
from .result import EFFECT_NAMES

#: Stribeck speeds tried [rpm] and exponents (1: exponential, 2: Gaussian decay, the two usual)
STRIBECK_SPEEDS_RPM = (2.0, 4.0, 7.0, 12.0, 20.0, 35.0, 60.0, 100.0, 170.0)
STRIBECK_EXPONENTS = (1.0, 2.0)
#: offset speeds of the logarithmic law ln(1 + v / v0) tried [rpm]
LOG_OFFSET_SPEEDS_RPM = (3.0, 6.0, 12.0, 25.0, 50.0, 100.0, 200.0)


def speed_law_forms(
    s: Any,
    eng: _Engine,
    fit: _Fit,
    declared: list[F64],
    key: str,
    tag: int,
    tau_lp: float,
    stribeck_shapes: Sequence[tuple[float, float]] | None = None,
    log_offsets: Sequence[float] = LOG_OFFSET_SPEEDS_RPM,
) -> list[_Term]:
    """One candidate term per (v_s, delta) of the Stribeck grid whose decay varies inside the
    elastic windows, and one per offset speed v0 of the logarithmic law, built from the fitted
    declared torque as the other speed laws are (never from the measured torque of the
    sample), tagged ``tag``, ``tag + 1`` ... ``tau_lp`` > 0: the columns pass the channel's
    low-pass. ``stribeck_shapes`` (v_s [rpm], delta) and ``log_offsets`` (v0 [rpm]) in place of
    the grids: the terms at shapes between grid points."""
    if s.omega is None:
        return []
    g = eng.g
    gid = s.gid
    el = s.seg == 0
    elf = el.astype(np.float64)
    rdf = (s.seg == 1).astype(np.float64)
    th = _fitted_declared(s, fit, declared)
    tp = np.where(g.sum(rdf) > 0, fit.pcoef[:, 2], s.prevailing)
    tp = np.where(np.isfinite(tp), tp, 0.0)
    om = np.maximum(np.abs(s.omega), 6.0)  # 1 rpm floor, as the other speed laws
    ref = float(np.median(om[el])) if np.any(el) else float("nan")
    if not math.isfinite(ref) or ref <= 0:
        return []
    fr = (th - tp[gid]) * elf
    viscous = fr * (om / ref - 1.0)
    out: list[_Term] = []
    description = EFFECT_NAMES["speed_dependent_friction"] + "; Stribeck form: static friction falling to a minimum, then viscous"
    shapes = list(stribeck_shapes) if stribeck_shapes is not None else [(v, dl) for v in STRIBECK_SPEEDS_RPM for dl in STRIBECK_EXPONENTS]
    for v_s_rpm, delta in shapes:
        v_s = 6.0 * v_s_rpm
        decay = np.exp(-((om / v_s) ** delta))
        e_ref = math.exp(-((ref / v_s) ** delta))
        if float(np.std(decay[el])) < 0.01:
            continue  # the decay is flat over the speeds seen: no Stribeck shape to fit
        cols = [np.nan_to_num(fr * (decay - e_ref)), np.nan_to_num(viscous)]
        # the law's derivative by ln v_s (per unit s_eff): the direction in which a
        # tightening's own Stribeck speed moves the law (a screw or lubricant of its own)
        e_ref_slope = delta * (ref / v_s) ** delta * e_ref
        shape = [np.nan_to_num(fr * (delta * (om / v_s) ** delta * decay - e_ref_slope))]
        if tau_lp > 0:
            cols = _lowpass_filter_many(s, cols, tau_lp)
            shape = _lowpass_filter_many(s, shape, tau_lp)
        # d ln m / d ln v at v_ref, the elasticity both other laws estimate (a_eff, b_eff)
        slope_ref = -delta * (ref / v_s) ** delta * e_ref

        def params(f2: _Fit, idx: list[int], v_s_rpm: float = v_s_rpm, delta: float = delta, slope_ref: float = slope_ref) -> dict[str, Any]:
            i, j = idx[0], idx[1]
            b = f2.beta
            cov = f2.cov if f2.cov is not None and f2.cov.shape[0] > max(i, j) else None
            grad = np.array([slope_ref, 1.0])
            el_val = float(slope_ref * b[i] + b[j])
            el_se = float(math.sqrt(max(float(grad @ cov[np.ix_([i, j], [i, j])] @ grad), 0.0))) if cov is not None else float("nan")
            bf = f2.beta_folds
            el_folds = slope_ref * bf[:, i] + bf[:, j] if bf.ndim == 2 and bf.shape[1] > max(i, j) else np.zeros(0)
            k = len(el_folds)
            el_se_folds = float(math.sqrt((k - 1) / k * float(np.sum((el_folds - el_folds.mean()) ** 2)))) if k >= 2 else float("nan")
            return {
                "s_eff": {"value": float(b[i]), "se": float(f2.se[i]), "se_folds": _fold_se(f2, i)},
                "k_eff": {"value": float(b[j]), "se": float(f2.se[j]), "se_folds": _fold_se(f2, j)},
                "elasticity_at_reference": {"value": el_val, "se": el_se, "se_folds": el_se_folds},
                "stribeck_speed_rpm": {"value": v_s_rpm, "grid": list(STRIBECK_SPEEDS_RPM)},
                "stribeck_exponent": {"value": delta, "grid": list(STRIBECK_EXPONENTS)},
                "reference_speed_rpm": ref / 6.0,
                "law": "T - T_prevailing = (T0 - T_prevailing) (1 + s_eff (exp(-(v / v_s)^delta) - exp(-(v_ref / v_s)^delta)) + k_eff (v / v_ref - 1))",
                "note": (
                    "Stribeck form: s_eff = (mu_s - mu_c) / mu(v_ref) and k_eff = k_v v_ref / mu(v_ref), each times the friction share "
                    "of the torque per clamp force; elasticity_at_reference = d ln(T - T_p) / d ln v at v_ref (what a_eff and b_eff "
                    "of the other laws estimate); v_s and delta chosen by the out-of-sample RMSE on the grid, v_s then between its neighbours on the grid (Brent)"
                ),
            }

        def static_at(v_rpm: F64, delta: float = delta) -> tuple[F64, F64]:
            # the static column and its derivative by ln v_s, each sample at its tightening's
            # own Stribeck speed ``v_rpm`` (per sample)
            vs = 6.0 * np.maximum(v_rpm, 1e-3)
            xs, xr = (om / vs) ** delta, (ref / vs) ** delta
            es, er = np.exp(-xs), np.exp(-xr)
            col = np.nan_to_num(fr * (es - er))
            slope = np.nan_to_num(fr * delta * (xs * es - xr * er))
            return (col, slope) if tau_lp <= 0 else tuple(_lowpass_filter_many(s, [col, slope], tau_lp))  # type: ignore[return-value]

        info = {"law": "stribeck", "speed_source": s.speed_source, "stribeck_speed_rpm": v_s_rpm, "stribeck_exponent": delta}
        if tau_lp > 0:
            info["filtered_by_channel_low_pass_ms"] = 1000 * tau_lp
        # each grid point its own tag: the engine caches projections by column name
        out.append(_Term("speed_dependent_friction", description, False, ["s_eff", "k_eff"], cols, params, info, key, tag + len(out), shape, static_at))
    # the logarithmic law with an offset speed, ln(1 + v / v0): ln(v / v_ref) is its limit
    # v0 -> 0, and it flattens below v0 (a lubricant film that does not thin at standstill)
    description_log = EFFECT_NAMES["speed_dependent_friction"].replace("ln(v / v_ref)", "ln(1 + v / v0)")
    for v0_rpm in log_offsets:
        v0 = 6.0 * v0_rpm
        # normalised so that the coefficient is the elasticity at v_ref, as a_eff of ln(v / v_ref)
        col = fr * (np.log1p(om / v0) - math.log1p(ref / v0)) * (ref + v0) / ref
        if tau_lp > 0:
            col = _lowpass_filter_many(s, [col], tau_lp)[0]

        def params_log(f2: _Fit, idx: list[int], v0_rpm: float = v0_rpm) -> dict[str, Any]:
            i = idx[0]
            return {
                "a_eff": {"value": float(f2.beta[i]), "se": float(f2.se[i]), "se_folds": _fold_se(f2, i)},
                "offset_speed_rpm": {"value": v0_rpm, "grid": list(LOG_OFFSET_SPEEDS_RPM)},
                "reference_speed_rpm": ref / 6.0,
                "law": "T - T_prevailing = (T0 - T_prevailing) (1 + a_eff (v_ref + v0) / v_ref (ln(1 + v / v0) - ln(1 + v_ref / v0)))",
                "note": "a_eff = d ln(T - T_p) / d ln v at v_ref (the friction share of the torque per clamp force times the law's own elasticity there); v0 chosen by the out-of-sample RMSE on the grid",
            }

        info = {"law": "log_offset", "speed_source": s.speed_source, "offset_speed_rpm": v0_rpm}
        if tau_lp > 0:
            info["filtered_by_channel_low_pass_ms"] = 1000 * tau_lp
        out.append(_Term("speed_dependent_friction", description_log, False, ["a_eff"], [np.nan_to_num(col)], params_log, info, key, tag + len(out), []))
    return out
