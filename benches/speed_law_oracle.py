"""What RMSE after a speed law can reach (issue 12): ``diagnose`` on the independent generator's
speed-friction sets, with the loop's speed-law form step replaced by terms built from the
generator's truth, against the loop as it is.

Modes (``--modes``):

- ``loop``: ``tightscan.diagnose`` as it is;
- ``oracle``: one speed-law term built from each tightening's TRUE constants (the generator's
  coefficient, Stribeck rise and Stribeck speed, friction coefficients and thread geometry),
  on the loop's own speed estimate, with one global coefficient (about 1): the RMSE no estimate
  of the law can beat by much;
- ``true-shape``: the Stribeck law with the population's true exponent (2) and mean Stribeck
  speed, its coefficients and per-tightening constants estimated as the loop does (what the
  choice of shape costs).

Columns: RMSE before, after with pooled constants, after (per-tightening constants where they
pass the loop's test), each over the generator's own noise sd on the modelled samples.

Run: PYTHONPATH=python:tests .venv/bin/python benches/speed_law_oracle.py --forms stribeck --strategies CSDT,HDT,mix --seeds 1,2
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import diagnose_confusion as dc  # noqa: E402
import tightscan  # noqa: E402
import tightscan.diagnose  # noqa: E402,F401
from tightscan.diagnose.candidates import _fitted_declared, _fold_se, _lowpass_filter_many  # noqa: E402
from tightscan.diagnose.fit import _Term  # noqa: E402

_DIAGNOSE = sys.modules["tightscan.diagnose"]
_LOOP_FORMS = _DIAGNOSE.speed_law_forms  # type: ignore[attr-defined]
_STATE: dict[str, Any] = {"mode": "loop", "truth": None}


def _col(t: pa.Table, name: str) -> np.ndarray:
    return np.array([np.nan if v is None else float(v) for v in t.column(name).to_pylist()])


def _truth_forms(s: Any, eng: Any, fit: Any, declared: list[Any], key: str, tag: int, tau_lp: float, **shapes: Any) -> list[_Term]:
    """In place of ``stribeck.speed_law_forms``: the term the mode asks for."""
    mode, truth = _STATE["mode"], _STATE["truth"]
    if mode == "loop" or s.omega is None:
        return list(_LOOP_FORMS(s, eng, fit, declared, key, tag, tau_lp, **shapes))
    row = {v: i for i, v in enumerate(truth.column("tightening_id").to_pylist())}
    r = np.array([row[i] for i in s.ids])
    g = s.gid
    coeff, vref, v0 = (_col(truth, c)[r][g] for c in ("speed_coeff", "speed_v_ref_rpm", "speed_v0_rpm"))
    form = truth.column("speed_friction_form").to_pylist()[0]
    el = s.seg == 0
    rd = (s.seg == 1).astype(np.float64)
    th = _fitted_declared(s, fit, declared)
    tp = np.where(eng.g.sum(rd) > 0, fit.pcoef[:, 2], s.prevailing)
    tp = np.where(np.isfinite(tp), tp, 0.0)
    om = np.maximum(np.abs(s.omega), 6.0)
    ref = float(np.median(om[el]))
    fr = (th - tp[g]) * el
    if mode == "true-shape":
        vs = 6.0 * float(np.nanmean(_col(truth, "stribeck_speed_rpm")))

        def static_at(v_rpm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            v = 6.0 * np.maximum(v_rpm, 1e-3)
            xs, xr = (om / v) ** 2, (ref / v) ** 2
            return np.nan_to_num(fr * (np.exp(-xs) - np.exp(-xr))), np.nan_to_num(fr * 2 * (xs * np.exp(-xs) - xr * np.exp(-xr)))

        cols = [static_at(np.full(len(g), vs / 6.0))[0], np.nan_to_num(fr * (om / ref - 1.0))]
        if tau_lp > 0:
            cols = _lowpass_filter_many(s, cols, tau_lp)

        def params2(f2: Any, idx: list[int]) -> dict[str, Any]:
            return {"s_eff": {"value": float(f2.beta[idx[0]])}, "k_eff": {"value": float(f2.beta[idx[1]])}, "stribeck_speed_rpm": {"value": vs / 6.0}}

        info = {"law": "stribeck", "speed_source": s.speed_source, "stribeck_speed_rpm": vs / 6.0, "stribeck_exponent": 2.0}
        return [_Term("speed_dependent_friction", "true shape", False, ["s_eff", "k_eff"], cols, params2, info, key, tag, [], static_at)]
    rise, vs_t = (_col(truth, c)[r][g] for c in ("stribeck_rise", "stribeck_speed_rpm"))
    pitch, d2, dkm, mth, mb = (_col(truth, c)[r][g] for c in ("pitch_mm", "d2_mm", "dkm_mm", "mu_th", "mu_b"))
    lead, fr0 = 0.16 * pitch, 0.58 * d2 * mth + 0.5 * dkm * mb

    def m(v: np.ndarray) -> np.ndarray:
        rpm = v / 6.0
        if form == "log":
            return 1 + coeff * np.log1p(rpm / v0)
        if form == "linear":
            return 1 + coeff * rpm / vref
        return 1 + rise * np.exp(-((rpm / vs_t) ** 2)) + coeff * rpm / vref

    m_ref = m(np.full_like(om, ref))
    col = [np.nan_to_num(fr * fr0 * (m(om) - m_ref) / (lead + fr0 * m_ref))]
    if tau_lp > 0:
        col = _lowpass_filter_many(s, col, tau_lp)

    def params(f2: Any, idx: list[int]) -> dict[str, Any]:
        return {"a_eff": {"value": float(f2.beta[idx[0]]), "se": float(f2.se[idx[0]]), "se_folds": _fold_se(f2, idx[0])}}

    return [_Term("speed_dependent_friction", "oracle: the generator's law per tightening", False, ["oracle"], col, params, {"law": "oracle", "speed_source": s.speed_source}, key, tag, [])]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--forms", default="stribeck", help="linear, log, stribeck")
    ap.add_argument("--strategies", default="CSDT,HDT,mix")
    ap.add_argument("--magnitudes", default="small,large")
    ap.add_argument("--seeds", default="1")
    ap.add_argument("--n", type=int, default=300)
    ap.add_argument("--modes", default="loop,oracle", help="loop, oracle, true-shape (Stribeck only)")
    a = ap.parse_args(argv)
    _DIAGNOSE.speed_law_forms = _truth_forms  # type: ignore[attr-defined]
    print("| form | strategy | magnitude | seed | mode | before | after, pooled constants | after | form fitted |")
    print("|---|---|---|---|---|---|---|---|---|")
    for form in a.forms.split(","):
        for st in a.strategies.split(","):
            for mag in a.magnitudes.split(","):
                cell = next(c for c in dc.independent_cells((st,), (mag,)) if c.effect == "speed" and c.form == form)
                for seed in (int(x) for x in a.seeds.split(",")):
                    curves, truth = cell.make(a.n, seed)
                    for mode in a.modes.split(","):
                        if mode == "true-shape" and form != "stribeck":
                            continue
                        _STATE["mode"], _STATE["truth"] = mode, truth
                        t0 = time.perf_counter()
                        d = tightscan.diagnose(dc._hidden(curves), alpha=0.01)
                        floor = dc.truth_floor(d, truth)
                        pooled = d.details["per_tightening_constants"].get("rmse_pooled_constants", math.nan)
                        named = [e for e in d.effects if e.level == "within_tightening"]
                        fitted = str(named[0].parameters.get("form", "-")) if named else "nothing named"
                        print(f"| {form} | {st} | {mag} | {seed} | {mode} | {d.rmse_before / floor:.3f} | {pooled / floor:.3f} | {d.rmse_after / floor:.3f} | {fitted} |", flush=True)
                        print(f"  {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
