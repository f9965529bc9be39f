"""Close the loop on measured data: fit the declared tightening model, look for structure in its
residuals, trace it to the effect the model lacks, add that effect, and report the error before
and after, out of sample.

Two levels (docs/diagnose-s01.md explains the method and what it found on real data):

- **Within a tightening** (level 1). Per tightening ``j`` the declared model is the elastic line
  ``T = a_j + b_j x`` over the elastic window of :func:`tightscan.detect_batch` (``x`` is the
  clamp force when the table has it, else the angle) and the prevailing torque ``T = c_j`` over
  a rundown stretch before snug. ``a_j, b_j, c_j`` are the tightening's own (nuisance)
  parameters. A candidate effect adds regressors built from the data -- never from the measured
  torque of the sample itself, only from the fitted torque and from the other channels -- with
  *global* coefficients (physical constants shared by all tightenings: a delay, an inertia, a
  friction law), or, where physics makes it so, per-tightening coefficients (the phase of a
  run-out).
- **Between tightenings** (level 2). The per-tightening parameters (torque rate, prevailing
  torque, tightening angle) against tightening-level covariates found in the table (re-use
  count, position, order in the sequence, date ...), out of sample; and against grouping
  factors (operator, station, tool, spindle, screw batch: categorical columns) with one-way
  ANOVA and Kruskal-Wallis within the specification cells, effect sizes, a MixedLM variance
  component and Holm's correction across factors x parameters (:mod:`.groups`).

Every comparison is out of sample: K-fold across tightenings (grouped so that one thread or part
never sits on both sides) for global coefficients, and alternate blocks of samples within a
tightening for per-tightening parameters, the declared model going through exactly the same
protocol. A candidate is added when its gain is significant (one-sided test on per-tightening
improvements, Bonferroni over the candidates of the round, ``alpha``) *and* practically relevant
(``min_gain`` of the RMSE); the loop repeats until nothing significant remains.

>>> import tightscan
>>> curves, _ = tightscan.simulate(150, seed=5, fault_fraction=0.0, strategies=["CSDT", "HDT"],
...                                torque_lowpass_ms=5.0)
>>> result = tightscan.diagnose(curves.drop_columns(["strategy", "thread"]))
>>> [e.name for e in result.effects], round(result.effects[0].parameters["tau_ms"]["value"])
(['channel_delay'], 5)
>>> result.rmse_after < 0.8 * result.rmse_before, result.unexplained_structure
(True, False)
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
import types
from typing import Any, Sequence

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from scipy.optimize import minimize_scalar

from .._progress import Progress
from ..exceptions import InvalidParameterError
from .prepare import _as_table, _prepare, F64, speed_at_timing
from .fit import _Engine, _Fit, _folds, _one_sided_tests, _Term
from .candidates import _anchor_transients, _candidates, _fitted_declared
from .identify import _collinearity, _gain_test, _identify
from .spectrum import _long_stretch, _spectral_search, _whiteness
from .select import _grouped_median, _hints, _level2, _level2_inputs, _model_string, _partial_corr, _partial_residual, _quantiles
from .groups import factor_columns, grouping_factor_analysis
from .prepare import load_table
from .report import write_report
from .result import EFFECT_NAMES, Diagnosis, Effect
from .stribeck import STRIBECK_SPEEDS_RPM, speed_law_forms
from .refine import REFINABLE, StribeckLaw, refine_per_tightening, spread_summary

#: the parameter of each effect whose per-tightening spread is reported (the first present)
_PRIMARY_PARAMETER = ("tau_ms", "J_kg_m2", "a_eff", "b_eff", "elasticity_at_reference", "a_prevailing", "kappa")

__all__ = ["diagnose", "Diagnosis", "Effect", "write_report", "load_table", "EFFECT_NAMES"]



def _speed_form_grid(s: Any, eng: _Engine, fit: _Fit, declared: list[F64], key: str, tag: int, tau_hint: float) -> tuple[list[_Term], int, int]:
    """The speed law's other forms (``speed_law_forms``) on the smoothed speed and, where the
    table has it, on the speed channel as recorded (it keeps the corners of a pause and of a
    program step that the smoothing rounds off, where a Stribeck law is steepest): the terms,
    the number of speed sources, and the next free tag (tags key the engine's caches)."""
    grid = speed_law_forms(s, eng, fit, declared, key, tag + 1, tau_hint)
    tag += len(grid) + 1
    sources = 1
    if s.omega_raw is not None:
        raw_grid = speed_law_forms(dataclasses.replace(s, omega=s.omega_raw), eng, fit, declared, key, tag + 1, tau_hint)
        tag += len(raw_grid) + 1
        for cand in raw_grid:
            cand.info["speed_source"] = "speed channel as recorded"
        grid += raw_grid
        sources = 2
    return grid, sources, tag

def diagnose(
    data: Any,
    *,
    folds: int = 5,
    alpha: float = 0.01,
    min_gain: float = 0.01,
    max_effects: int = 6,
    group_by: Sequence[str] | str | None = "auto",
    covariates: Sequence[str] | str | None = "auto",
    spec_columns: Sequence[str] | str | None = "auto",
    rundown_deg: float | None = None,
    whiteness_tolerance: float = 0.05,
    min_samples: int = 10,
    parsimony: float = 0.8,
    periodic_span_deg: float | None = None,
    seed: int = 0,
    reach: float = 0.3,
    collinear: float = 0.5,
    grouping_factors: Sequence[str] | str | None = "auto",
    progress: bool | None = None,
) -> Diagnosis:
    """Diagnose what the declared tightening model misses, out of sample.

    ``data``: a tightening table in the contract layout (pyarrow, polars, anything with the
    Arrow stream interface), or a path: a Rexroth export directory (``runs/*.json`` with an
    optional ``labels.csv`` beside, or ``*.json``), a Parquet file or a directory of them.

    Returns a :class:`Diagnosis`; ``to_dict()`` gives the JSON document (``model``,
    ``rmse_before``, ``rmse_after`` [Nm, level-1 curve residual, out of sample], ``effects``
    in the order added, ``unexplained_structure``, and details).

    ``folds``: K of the K-fold split across tightenings, grouped by ``group_by`` (``"auto"``:
    ``workpiece_id`` + ``workpiece_location`` when present, ...; ``None``: every tightening its
    own group). ``alpha``: family-wise level per round (Bonferroni over its candidates).
    ``min_gain``: smallest relative RMSE reduction an effect must bring. ``max_effects``: level-1
    effects at most. ``covariates``: level-2 covariates (``"auto"``: every scalar metadata
    column that is not an identifier, outcome or specification, plus the order of the tightening).
    ``spec_columns``: columns whose cells form the level-2 baseline (``"auto"``: thread, target
    torque, program ... when present). ``rundown_deg``: length of the rundown stretch (default:
    the elastic window's angle span). ``periodic_span_deg``: how much rundown before that
    stretch is searched for periodicities (run-out; ``None``: all of it, many revolutions long). ``whiteness_tolerance``: largest share of
    the final residual variance a pooled AR(10) may predict before ``unexplained_structure``
    is set. ``parsimony``: a term with per-tightening coefficients is added before a global one
    only if the global one's gain is below this fraction of its gain. ``min_samples``: fewest
    samples of a tightening's elastic window (and rundown stretch) to use it. ``seed``: of the
    fold assignment.

    Identification (``details["collinearity"]``, ``details["ties"]``, each effect's
    ``evidence["identification"]``): before a selected term is named, it is fitted jointly with
    every close competitor -- a significant candidate whose gain was at least ``reach`` times its
    gain, or one whose regressor correlates with it by ``collinear`` or more once each
    tightening's own columns are projected out -- and both are compared out of sample with the
    other left out. It is named alone only if it keeps a significant gain with the competitor in
    and the competitor loses its gain with it in; a competitor that does the reverse is named
    instead; where neither keeps a gain, the effect is a tie (``Effect.names``) and no member
    is named alone.

    Two effects that cancel one at a time (a channel lag and friction rising with speed):
    when no single candidate passes, the global candidates of distinct effects with the four
    largest pooled gains are fitted in pairs at ``alpha / (candidates + pairs)``; a pair whose
    members each keep their gain with the other in enters (``evidence["entered_as_pair"]``),
    the better one first, the other having to pass alone the round after.

    Parameters: each global parameter carries ``se`` (sandwich over tightenings) and
    ``se_folds`` (delete-a-fold jackknife of the K out-of-sample fits). A channel lag's
    ``tau_ms`` is its mean lag (fitted with the lag's second-moment term: the time constant of
    a first-order low-pass, the delay of a pure delay, 2 zeta / omega_n of a second-order
    filter), ``first_order_tau_ms`` beside it. A speed law and an inertia are estimated with
    the smoothed speed channel and with the channel as recorded (backward difference for the
    acceleration); the model keeps the better out of sample, and ``identifiable: false`` with
    ``range_over_speed_estimates`` says when the two differ by more than 15 % (a program that
    feeds the torque back into the speed). An inertia is also estimated with the acceleration
    half a sample earlier and half a sample later (``range_over_acceleration_alignment``): the
    relative timing of the torque and speed channels is not known to better than a sample, so
    a J that moves by more than 15 % with it is reported as not identifiable as well.

    Per-tightening constants (``details["per_tightening_constants"]``, each effect's
    ``parameters_spread``): a filter, an inertia or a lubricant differs between tools, spindles
    and screws, so after the loop each named effect's constant is refined per tightening -- a
    factor on its pooled contribution (for a lag, along the derivative of its low-pass path in
    tau; for a Stribeck law, its static and viscous parts and its Stribeck speed apart), shrunk
    towards the pooled value by random effects (DerSimonian-Laird). ``parameters`` keep the
    pooled values; ``parameters_spread`` gives the between-tightening sd and quantiles, and the
    per-tightening table a column per constant. ``rmse_after`` uses the per-tightening
    constants only when they predict better out of sample (pooled coefficients and the
    between-tightening variance from the other folds, each tightening's factor from one block of
    its samples predicting the other) by the one-sided test at ``alpha``. During the loop a
    candidate must also keep its gain when the constants of the effects already in are refined
    so (their spread is not a further effect).

    Speed-law forms (``evidence["speed_law_form"]``, ``parameters["form"]``): once
    ``speed_dependent_friction`` is named (logarithmic or linear), the Stribeck form
    ``mu_c + (mu_s - mu_c) exp(-(v / v_s)^delta) + k_v v`` (``s_eff``, ``k_eff``,
    ``elasticity_at_reference``, each with ``se`` and ``se_folds``) and the logarithmic law with
    an offset speed ``ln(1 + v / v0)`` are fitted at each shape of a grid; the best replaces the
    named law when it passes the gain test against it at ``alpha`` over the grid.

    Grouping factors (``details["grouping_factors"]``): ``grouping_factors`` names the
    categorical columns to test (``"auto"``: string, dictionary and boolean columns, and integer
    columns with few levels or a telling name such as ``spindle``, with 2 to 50 levels, that are
    not identifiers, outcomes, channels, counts or specification; ``None``: none). For each
    factor x parameter (torque rate, prevailing torque, tightening angle; ``mu_tot`` with clamp
    force and the thread geometry: ``pitch_mm``, ``d2_mm``, ``dkm_mm`` columns, or an ISO
    designation in a ``thread`` column): the F-test of the factor within
    the specification cells (the cell a fixed effect, so a thread size is not read as an
    operator effect; a numeric specification that varies almost per tightening, such as a
    target torque drawn per tightening, enters by its quartiles), Kruskal-Wallis on cell-aligned values, partial eta^2 and omega^2,
    epsilon^2, per-level means with standard errors, and a random-intercept variance component
    (statsmodels MixedLM: ICC; "not estimated" with the reason when it fails). A factor is
    claimed, as the level-2 effect ``<parameter>_by_<factor>``, when both tests are significant
    at ``alpha`` after Holm's correction over all factors x parameters and its partial omega^2
    is at least 0.01. Two factors or more: two-way ANOVAs with interaction (Type II) of each
    pair, in the details. These are in-sample tests of a difference between levels; the
    covariate search above asks the out-of-sample question (does the column predict the
    parameter) and may name the same column as ``<parameter>_vs_<column>``.

    ``progress``: a bar of the stages on stderr (``None``: on an interactive terminal).
    """
    # The progress bar counts the stages: preparing the samples, each round of the residual loop
    # (max_effects + 1 at most; the rest is skipped when the loop stops early), the final
    # level-1 checks and level 2. Closed however the diagnosis ends, so an error is not
    # printed under a live bar.
    bar = Progress("diagnosing", max_effects + 4, progress, unit="steps")
    try:
        return _diagnose(
            data,
            folds=folds,
            alpha=alpha,
            min_gain=min_gain,
            max_effects=max_effects,
            group_by=group_by,
            covariates=covariates,
            spec_columns=spec_columns,
            rundown_deg=rundown_deg,
            whiteness_tolerance=whiteness_tolerance,
            min_samples=min_samples,
            parsimony=parsimony,
            periodic_span_deg=periodic_span_deg,
            seed=seed,
            reach=reach,
            collinear=collinear,
            grouping_factors=grouping_factors,
            bar=bar,
        )
    finally:
        bar.close()


def _diagnose(
    data: Any,
    *,
    folds: int = 5,
    alpha: float = 0.01,
    min_gain: float = 0.01,
    max_effects: int = 6,
    group_by: Sequence[str] | str | None = "auto",
    covariates: Sequence[str] | str | None = "auto",
    spec_columns: Sequence[str] | str | None = "auto",
    rundown_deg: float | None = None,
    whiteness_tolerance: float = 0.05,
    min_samples: int = 10,
    parsimony: float = 0.8,
    periodic_span_deg: float | None = None,
    seed: int = 0,
    reach: float = 0.3,
    collinear: float = 0.5,
    grouping_factors: Sequence[str] | str | None = "auto",
    bar: Progress,
) -> Diagnosis:
    started = time.perf_counter()
    if folds < 2:
        raise InvalidParameterError("folds must be at least 2", "folds")
    if not 0 < alpha < 1:
        raise InvalidParameterError("alpha must be in (0, 1)", "alpha")
    table = _as_table(data)
    s = _prepare(table, rundown_deg, min_samples, periodic_span_deg)
    bar.advance()
    fold_t, group_cols = _folds(table, s.rows, folds, group_by, seed)
    eng = _Engine(s, fold_t, folds)
    g = eng.g
    # the spectral search of the long rundown stretch (angle and time): its peaks are candidates
    eng.memo["long"] = _long_stretch(s)
    eng.memo["spectrum"] = _spectral_search(eng.memo["long"], s.n_tight, alpha, min_gain)
    el = (s.seg == 0).astype(np.float64)
    rd = (s.seg == 1).astype(np.float64)
    # declared per-tightening columns: elastic intercept and slope, rundown level
    xc = (s.x - g.sum(s.x * el)[s.gid] / np.maximum(g.sum(el)[s.gid], 1)) * el
    xs = np.sqrt(g.sum(xc * xc) / np.maximum(g.sum(el), 1))[s.gid]
    xn = xc / np.where(xs > 0, xs, 1.0)
    declared: list[F64] = [el, xn, rd]
    declared_labels = ["a (elastic intercept)", "b (elastic slope)", "c (prevailing torque)"]
    x_scale_t = np.sqrt(g.sum(xc * xc) / np.maximum(g.sum(el), 1))

    def assemble(model: dict[str, _Term]) -> tuple[list[F64], str, list[str], list[F64], dict[str, list[int]]]:
        pc: list[F64] = list(declared)
        pk = "declared"
        zn: list[str] = []
        zc: list[F64] = []
        idx: dict[str, list[int]] = {}
        for key, t in model.items():
            if t.per_tightening:
                idx[key] = list(range(len(pc), len(pc) + len(t.columns)))
                pc = pc + t.columns
                pk += f"|{key}@{t.tag}"
            else:
                idx[key] = list(range(len(zc), len(zc) + len(t.columns)))
                zn = zn + [f"{key}:{lab}@{t.tag}" for lab in t.labels]
                zc = zc + t.columns
        return pc, pk, zn, zc, idx

    def evaluate_with(model: dict[str, _Term], extra: _Term | Sequence[_Term] | None) -> tuple[_Fit, dict[str, list[int]]]:
        both = dict(model)
        for t in [] if extra is None else [extra] if isinstance(extra, _Term) else extra:
            both[t.key] = t
        pc, pk, zn, zc, idx = assemble(both)
        return eng.evaluate(pk, pc, zn, zc), idx

    build = 0  # a counter that tags each rebuild of the candidates (the engine caches by it)

    def _refine_model(model_: dict[str, _Term], fit_: _Fit, idx_: dict[str, list[int]], keys: set[str] | None = None) -> dict[str, Any] | None:
        """The named effects' constants refined per tightening (``refine.py``) in the model
        ``model_`` fitted as ``fit_``: one factor per law, a Stribeck law's static and viscous
        parts each their own; a lag along the derivative of its low-pass path in tau."""
        nonlocal build
        comps = {
            key: ([[i] for i in idx_[key]] if t.info.get("law") == "stribeck" else [idx_[key]])
            for key, t in model_.items()
            if not t.per_tightening and t.name in REFINABLE and key in idx_ and (keys is None or key in keys)
        }
        if not comps:
            return None
        pc_, _pk_, _zn_, zc_, _ = assemble(model_)
        directions: dict[str, list[F64]] = {}
        relaxations: dict[str, list[F64]] = {}
        laws: dict[str, StribeckLaw] = {}
        for key in comps:
            held = model_[key]
            if held.info.get("law") == "stribeck" and held.static_at is not None and len(idx_[key]) == 2:
                # static part, viscous part and Stribeck speed per tightening, jointly
                laws[key] = StribeckLaw(held.static_at, held.columns[1], float(held.info["stribeck_speed_rpm"]))
                continue
            if held.info.get("law") == "stribeck" and held.extension and len(idx_[key]) == 2:
                # static part, viscous part, and the Stribeck speed (its derivative, times s_eff)
                b_static, b_viscous = (float(fit_.beta[i]) for i in idx_[key])
                directions[key] = [held.columns[0] * b_static, held.columns[1] * b_viscous, held.extension[0] * b_static]
                continue
            if held.name != "channel_delay":
                continue
            # the lag's contribution is the low-pass path of the torque at tau, nonlinear in
            # tau: its derivative by the relative change of tau, a central difference
            tau_now = float(fit_.beta[idx_[key][0]])
            if not 0 < tau_now < 1.0:
                continue
            paths = []
            for step in (1.1, 1 / 1.1):
                build += 1
                lag_at = _candidates(s, eng, fit_, declared, build, _model_periods(model_), {"tau_s": tau_now * step})[0].get(key)
                if lag_at is not None:
                    paths.append(tau_now * step * lag_at.columns[0])
            if len(paths) == 2:
                directions[key] = [(paths[0] - paths[1]) / (1.1 - 1 / 1.1)]
                if held.info.get("anchor_transients") and len(idx_[key]) == 3:
                    # the relaxation from the anchors has a factor of its own: how far the
                    # channel's state is off there is measured with the noise of a few samples
                    directions[key].append(sum((held.columns[i] * float(fit_.beta[idx_[key][i]]) for i in (1, 2)), np.zeros(len(s.y))))
                elif held.info.get("form", "").startswith("mean lag"):
                    relaxations[key] = _relaxation_directions(held)
        refined = refine_per_tightening(eng, pc_, zc_, fit_, comps, alpha, directions, laws)
        if relaxations:
            # the lag's extended form holds the transient from each anchor in pooled columns
            # (the first-order decay e^-u from the anchor, u = (t - t_anchor) / tau, times the
            # peak torque): the relaxation of the value recorded there. A channel of order two
            # also holds a rate at the anchor, and relaxes from it as u e^-u (a decaying sine
            # for damping below 1, the same near u = 0): its amplitude differs in every
            # tightening (the history of the torque rate just before the window, which the few
            # samples recorded there do not measure: its correlation with the rate over the six
            # samples before the window is under 0.5) and takes either sign. So the relaxation
            # from each anchor (e^-u and u e^-u, the window's start and each pause apart) has
            # amplitudes of its own per tightening, shrunk towards the population and
            # cross-validated on short blocks like every refinement, and is kept only where it
            # predicts better out of sample than the refinement without it: a second-order
            # filter under a hold-down program (lowpass2, HDT, 300 tightenings) left its
            # excess in each window's first dozen samples, standardised residual 5.1 in the
            # first, 1.03 in the middle of the windows
            with_relax = {k: v + relaxations.get(k, []) for k, v in directions.items()}
            alt = refine_per_tightening(eng, pc_, zc_, fit_, comps, alpha, with_relax, laws)
            if alt is not None and alt["significant"] and (refined is None or not refined["significant"] or alt["fit"].rmse < refined["fit"].rmse):
                alt["anchor_relaxation_per_tightening"] = {"rmse_without": None if refined is None else refined["fit"].rmse, "rmse_with": alt["fit"].rmse, "kept": True}
                return alt
            if refined is not None:
                refined["anchor_relaxation_per_tightening"] = {"rmse_without": refined["fit"].rmse, "rmse_with": None if alt is None else alt["fit"].rmse, "kept": False}
        return refined

    def _relaxation_directions(held: _Term) -> list[F64]:
        """The relaxation from each anchor of a lag in its extended form, per unit amplitude of
        a tenth of the peak torque: e^-u and u e^-u from the window's start and from the end of
        each pause (where the form has those columns), with u from the form's own first-order
        decay (its columns are that decay times the peak torque, 0 outside the elastic zone).
        Additive amplitudes, not factors on a pooled value: the refinement's factor bounds
        (1 + d in [0, 3]) then allow -0.1 to 0.2 of the peak torque, beyond any transient."""
        out: list[F64] = []
        scale = s.scale[s.gid]
        for label in ("transient from the window's start", "transient after a pause"):
            col = sum((c for c, lab in zip(held.columns, held.labels) if lab == label), np.zeros(len(s.y)))
            if not np.any(col != 0):
                continue
            decay = col / np.where(scale > 0, scale, 1.0)
            u = np.where(decay > 0, -np.log(np.where(decay > 0, decay, 1.0)), 0.0)
            out += [0.1 * col, 0.1 * col * u]
        return out

    def _lag_anchor_columns(held: _Term, fit_: _Fit, idx_: list[int]) -> list[F64]:
        """The relaxation from the anchors' measured state (``_anchor_transients``) of a lag
        held in its first-order linearised form (one column, no extension), at its fitted tau;
        [] for any other term."""
        if held.name != "channel_delay" or held.extension or len(held.columns) != 1:
            return []
        tau_now = float(fit_.beta[idx_[0]])
        if not 0 < tau_now < 1.0:
            return []
        cols = _anchor_transients(s, _fitted_declared(s, fit_, declared), held.columns[0], tau_now)
        return cols if any(np.any(c != 0) for c in cols) else []

    model: dict[str, _Term] = {}
    base, _ = evaluate_with(model, None)
    # weights: 1 / sigma_j^2 of the declared fit (robust to smooth structure: first differences)
    d = np.r_[0.0, np.diff(base.resid)]
    same = np.r_[False, (s.gid[1:] == s.gid[:-1]) & (s.seg[1:] == s.seg[:-1])]
    absd = np.where(same, np.abs(d), np.nan)
    sig_t = _grouped_median(absd, s.gid, s.n_tight) * 1.4826 / math.sqrt(2.0)
    sig_t = np.where(np.isfinite(sig_t) & (sig_t > 0), sig_t, np.nanmedian(sig_t[sig_t > 0]) if np.any(sig_t > 0) else 1.0)
    eng.weights_t = 1.0 / (sig_t * sig_t)
    eng._cache.clear()
    eng._pairs.clear()
    def _speed_form_search(model_: dict[str, _Term], current_: _Fit, cands_: list[_Term], m_: int) -> dict[str, Any] | None:
        """The best of the speed law's other forms (``speed_law_forms``, both speed sources) as
        a round's candidate, when it passes the gain test at alpha / (candidates + shapes)."""
        nonlocal build
        tau_hint = _hints(model_, current_, {}).get("tau_s", 0.0)
        grid, _, build = _speed_form_grid(s, eng, current_, declared, "speed_dependent_friction", build, tau_hint)
        best: tuple[_Fit, _Term, list[int]] | None = None
        for cand in grid:
            fit_c, idx_c = evaluate_with(model_, cand)
            if best is None or fit_c.rmse < best[0].rmse:
                best = (fit_c, cand, idx_c[cand.key])
        if best is None:
            return None
        alpha_f = alpha / (m_ + len(grid))
        test = _gain_test(current_, best[0], alpha_f, min_gain)
        if not test["significant"]:
            return None
        u = np.clip((current_.mse_t - best[0].mse_t) / np.maximum(current_.mse_t, 1e-300), -1.0, 1.0)
        tests = _one_sided_tests(u)
        gain = max(test["rmse_gain"], test["median_tightening_rmse_gain"])
        entry = (gain, best[1], best[0], tests | {"bonferroni_alpha": alpha_f, "candidates_in_round": m_ + len(grid), "median_gain": test["median_tightening_rmse_gain"]})
        shape = {k: v for k, v in best[1].info.items() if k in ("law", "stribeck_speed_rpm", "stribeck_exponent", "offset_speed_rpm", "speed_source")}
        return {"form": shape, "gain": test, "shapes_tried": len(grid), "bonferroni_alpha": alpha_f, "_entry": entry, "_idx": best[2]}

    base, _ = evaluate_with(model, None)
    rmse_before = base.rmse
    mse_before_t = base.mse_t.copy()
    e_before = base.e_oos.copy()
    current = base
    current_idx: dict[str, list[int]] = {}
    effects: list[Effect] = []
    rounds: list[dict[str, Any]] = []
    leftover_significant = False
    periodogram_info: dict[str, Any] = {}
    collinearity: dict[str, Any] = {}
    ties: list[dict[str, Any]] = []
    tied_out: set[str] = set()  # effects reported in a tie: not offered again
    misfits: list[dict[str, Any]] = []
    misfit_out: set[str] = set()  # candidates that only took up the form misfit of an effect in
    partial: dict[str, Any] = {}
    for round_no in range(max_effects + 1):
        bar.advance()
        build += 1
        periods = _model_periods(model)
        terms, pinfo = _candidates(s, eng, current, declared, build, periods, _hints(model, current, current_idx))
        if round_no == 0:
            periodogram_info = pinfo
        pc, pk, zn, zc, _ = assemble(model)
        eng.keep_only(pk, zn)
        # a further form of an effect already in the model is not a new effect (periodic
        # disturbances at other periods are)
        in_model = {t.name for t in model.values() if t.name != "periodic_disturbance"}
        cands_all = [
            t
            for key, t in terms.items()
            if key not in model and t.name not in tied_out | misfit_out and t.name not in in_model and _period_of(t) not in periods
        ]
        tried: list[dict[str, Any]] = []
        significant_terms: list[tuple[float, _Term, _Fit, dict[str, Any]]] = []
        m = max(len(cands_all), 1)
        # how collinear the candidates are in this round's data, each tightening's own columns
        # (and the per-tightening columns of the model) projected out as the fit does
        coll = _collinearity(eng, pk, pc, cands_all)
        if round_no == 0:
            collinearity = coll
        alone: dict[str, _Fit] = {}
        tests_by_key: dict[str, tuple[float, dict[str, Any]]] = {}
        alone_idx: dict[str, list[int]] = {}
        for term in cands_all:
            fit, fit_idx = evaluate_with(model, term)
            alone[term.key] = fit
            alone_idx[term.key] = fit_idx[term.key]
            # relative improvement per tightening, in [-1, 1]: it cannot exceed 1, and a
            # tightening that got more than twice as bad counts as -1 (no single curve decides)
            u = np.clip((current.mse_t - fit.mse_t) / np.maximum(current.mse_t, 1e-300), -1.0, 1.0)
            tests = _one_sided_tests(u)
            gain = (current.rmse - fit.rmse) / current.rmse
            # practical relevance: pooled, or in the typical tightening (a minority of curves
            # with a large misfit of another cause, e.g. friction faults, must not hide it)
            median_gain = float(np.median(1.0 - np.sqrt(fit.mse_t / np.maximum(current.mse_t, 1e-300))))
            significant = tests["p_value"] < alpha / m and max(gain, median_gain) >= min_gain
            tried.append(
                {
                    "name": term.name,
                    "key": term.key,
                    "per_tightening": term.per_tightening,
                    "rmse": fit.rmse,
                    "rmse_gain": gain,
                    "median_tightening_rmse_gain": median_gain,
                    "p_value": tests["p_value"],
                    "sign_p_value": tests["sign_p_value"],
                    "t_statistic": tests["t_statistic"],
                    "fraction_improved": tests["fraction_improved"],
                    "significant": significant,
                }
            )
            tests_by_key[term.key] = (max(gain, median_gain), tests | {"bonferroni_alpha": alpha / m, "candidates_in_round": m, "median_gain": median_gain})
            if significant:
                significant_terms.append((max(gain, median_gain), term, fit, tests_by_key[term.key][1]))
        rounds.append(
            {
                "round": round_no + 1,
                "rmse": current.rmse,
                "candidates": sorted(tried, key=lambda r: -r["rmse_gain"]),
                "collinearity": {k: coll[k] for k in ("condition_number", "vif")},
            }
        )
        if effects:
            by_name = {r["name"]: r["rmse_gain"] for r in tried}
            for alt in effects[-1].evidence.get("alternatives", []):
                alt["rmse_gain_after_it"] = by_name.get(alt["name"])
        pair_evidence: dict[str, Any] | None = None
        form_evidence: dict[str, Any] | None = None
        if not significant_terms:
            # Two effects that cancel where both act (a channel lag lowers the torque where it
            # rises fast, friction rising with speed raises it there) show no gain one at a time:
            # each alone fits the sum with the wrong shape. The global candidates with the
            # largest pooled gains are then fitted in pairs; a pair is taken when it gains
            # jointly and each member keeps its gain with the other in, at alpha over the
            # singles and pairs of the round. The member that fits better alone enters now,
            # the other has to pass the round after on its own.
            pair_evidence = _pair_search(cands_all, tried, alone, current, lambda a, b: evaluate_with(model, [a, b])[0], alpha, m, min_gain)
            if pair_evidence is not None:
                first = next(t for t in cands_all if t.key == pair_evidence["enters_first"])
                significant_terms = [(pair_evidence["joint_gain"]["rmse_gain"], first, alone[first.key], tests_by_key[first.key][1])]
            elif any(t.name == "speed_dependent_friction" for t in cands_all):
                # No pair either. A speed law whose form the logarithmic and linear candidates
                # miss (a Stribeck curve: static friction falling to a minimum, then viscous) can
                # fit the table far better pooled yet gain in no consistent share of the
                # tightenings: the wrong shape helps some and hurts others. Its other forms are
                # then tried as candidates of the same effect, at alpha over the round's
                # candidates and every shape tried (Bonferroni: the shape is chosen on the same
                # data). After the pair search, so that two effects that cancel (a lag and a
                # speed law, which a Stribeck shape can mimic together) are found as such
                form_evidence = _speed_form_search(model, current, cands_all, m)
                if form_evidence is not None:
                    entry = form_evidence.pop("_entry")
                    # the form replaces the law of the same key in this round's fits
                    alone[entry[1].key], alone_idx[entry[1].key] = entry[2], form_evidence.pop("_idx")
                    significant_terms = [entry]
            if not significant_terms:
                break
        if round_no == max_effects:
            leftover_significant = True
            break
        significant_terms.sort(key=lambda r: -r[0])
        best = significant_terms[0]
        parsimony_note = None
        if best[1].per_tightening:
            # Occam: per-tightening coefficients (2 per tightening) must beat the best global
            # term clearly; else the global one goes first and the other must prove itself after
            glob_terms = [r for r in significant_terms if not r[1].per_tightening]
            if glob_terms and glob_terms[0][0] >= parsimony * best[0]:
                parsimony_note = f"preferred to {best[1].name} (gain {best[0]:.4f}, per-tightening coefficients) by the parsimony rule"
                best = glob_terms[0]
        gain, term, fit, tests = best
        # identification: the close competitors of the selected term -- those whose own gain was
        # within reach of its gain, or whose regressor is strongly collinear with it -- each
        # fitted jointly with it and compared out of sample with either one left out
        # (other forms of the same effect are not competitors: the better-fitting form is in)
        close = [r[1] for r in significant_terms if r[1].name != term.name and r[0] >= reach * gain]
        close += [
            t
            for t in cands_all
            if t.name != term.name and t not in close and abs(coll["correlation"].get(term.key, {}).get(t.key, 0.0) or 0.0) >= collinear
        ]

        # a channel lag enters as its first-order form (-dT/dt) until its time constant is
        # known; a few Gauss-Newton steps on the low-pass path first, so that the comparison is
        # with the lag as it will be fitted, not with its linearisation (which a speed law in a
        # mixed table can out-fit)
        for lag_term in [t for t in [term, *close] if t.name == "channel_delay"]:
            refined = lag_term
            for _ in range(3):
                hint = _hints({refined.key: refined}, alone[refined.key], {refined.key: alone_idx[refined.key]})
                if "tau_s" not in hint:
                    break
                build += 1
                fresh_all, _i = _candidates(s, eng, current, declared, build, _model_periods(model), hint)
                fresh_lag = fresh_all.get(refined.key)
                if fresh_lag is None:
                    break
                fit_lag, idx_lag = evaluate_with(model, fresh_lag)
                if not fit_lag.rmse < alone[refined.key].rmse:
                    break
                refined = fresh_lag
                alone[refined.key], alone_idx[refined.key] = fit_lag, idx_lag[refined.key]
            if refined is not lag_term:
                if term is lag_term:
                    term = refined
                close = [refined if t is lag_term else t for t in close]

        def joint_fit(a: _Term, b: _Term) -> _Fit:
            return evaluate_with(model, [a, b])[0]

        chosen, tied, identification = _identify(term, close, alone, joint_fit, alpha / m, min_gain, coll["correlation"], coll["vif"])
        if chosen is not term:
            gain, tests = tests_by_key[chosen.key]
        term, fit = chosen, alone[chosen.key]
        # nothing spurious (item 4): once an effect is in, a further term must keep its gain
        # when that effect's own law is given one more degree of freedom; structure that the
        # extension takes up is the misfit of a form (a second-order filter fitted as a
        # first-order one), which a confounded proxy would otherwise be named for
        misfit = None
        for ekey, held in model.items():
            extension = held.extension or _lag_anchor_columns(held, current, current_idx[ekey])
            if not extension:
                continue
            ext = _Term(held.name, held.description, False, [f"{held.name}: extension {i}" for i in range(len(extension))], extension, _no_parameters, {}, f"{ekey}:extension", held.tag)
            fit_ext = evaluate_with(model, ext)[0]
            keep = _gain_test(fit_ext, evaluate_with(model, [ext, term])[0], alpha / m, min_gain)
            if not keep["significant"]:
                misfit = {
                    "candidate": term.name,
                    "effect": held.name,
                    "extension_gain": _gain_test(current, fit_ext, alpha / m, min_gain),
                    "candidate_gain_with_extension_in": keep,
                    "round": round_no + 1,
                }
                break
        if misfit is None and not term.per_tightening:
            # ... and when the constants of the effects in the model may differ between
            # tightenings (a filter, an inertia, a lubricant per tool or screw): structure that
            # per-tightening constants take up is their spread, not a further effect (under a
            # hold-down program a speed law follows a lag's per-tightening error closely)
            held_refined = _refine_model(model, current, current_idx)
            if held_refined is not None:
                with_term, with_idx = evaluate_with(model, term)
                term_refined = _refine_model(dict(model) | {term.key: term}, with_term, with_idx, keys=set(held_refined["terms"]))
                if term_refined is not None:
                    keep = _gain_test(held_refined["fit"], term_refined["fit"], alpha / m, min_gain)
                    if not keep["significant"]:
                        misfit = {
                            "candidate": term.name,
                            "effect": ", ".join(model[k].name for k in held_refined["terms"]),
                            "kind": "per-tightening constants of the effects in the model",
                            "extension_gain": _gain_test(current, held_refined["fit"], alpha / m, min_gain),
                            "candidate_gain_with_extension_in": keep,
                            "round": round_no + 1,
                        }
        if misfit is not None:
            misfits.append(misfit)
            misfit_out.add(term.name)
            continue
        tied_out |= {t.name for t in tied}
        pc_prev, pk_prev = pc, pk
        corr_before = _partial_corr(eng, current, term, pk_prev, pc_prev)
        model[term.key] = term
        rmse_prev = current.rmse
        # rebuild the model's regressors from the updated fit (a Gauss-Newton step for the
        # terms built on the fitted torque or on a current estimate), until it settles
        for _ in range(6):
            build += 1
            idx_now = assemble(model)[4]
            hints_before = _hints(model, fit, idx_now)
            fresh, _info = _candidates(s, eng, fit, declared, build, _model_periods(model), hints_before)
            trial = {key: fresh.get(key, t) for key, t in model.items()}
            rmse_old = fit.rmse
            fit_try, idx_try = evaluate_with(trial, None)
            if not fit_try.rmse <= rmse_old * (1 + 1e-3):
                current_idx = assemble(model)[4]
                break  # the rebuilt regressors do not fit better: keep the previous ones
            model, fit, current_idx = trial, fit_try, idx_try
            hints_after = _hints(model, fit, current_idx)
            moved = any(abs(hints_after.get(k, 0.0) - v) > 0.005 * abs(v) for k, v in hints_before.items())
            if abs(rmse_old - fit.rmse) < 1e-4 * fit.rmse and not moved:
                break
        evidence = {
            "rmse_before": rmse_prev,
            "rmse_gain": (rmse_prev - fit.rmse) / rmse_prev,
            "median_tightening_rmse_gain": tests["median_gain"],
            "p_value": tests["p_value"],
            "sign_p_value": tests["sign_p_value"],
            "t_statistic": tests["t_statistic"],
            "fraction_of_tightenings_improved": tests["fraction_improved"],
            "bonferroni_alpha": tests["bonferroni_alpha"],
            "candidates_in_round": tests["candidates_in_round"],
            "correlation_with_residual": corr_before,
            "per_tightening_coefficients": term.per_tightening,
            "folds": folds,
            "tightenings": s.n_tight,
            "round": round_no + 1,
        } | {k: v for k, v in term.info.items()}
        if parsimony_note:
            evidence["parsimony"] = parsimony_note
        if pair_evidence is not None:
            evidence["entered_as_pair"] = pair_evidence
        if form_evidence is not None:
            evidence["entered_in_another_form"] = form_evidence
        evidence["identification"] = identification
        if chosen is not best[1]:
            evidence["identification_note"] = f"{best[1].name} fitted best alone, but {chosen.name} encompasses it"
        # other candidates that explained much of the same residual: what the data cannot tell
        # apart from the winner (their gain after it was added is filled in next round)
        evidence["alternatives"] = [
            {"name": r[1].name, "rmse_gain": r[0]} for r in significant_terms if r[1] is not term and r[0] >= 0.3 * gain
        ]
        partial[term.name] = _partial_residual(eng, s, model[term.key], fit, current_idx[term.key], pc_prev, current.resid)
        names = [term.name] + [t.name for t in tied]
        if tied:
            # the data cannot tell them apart: named together, never one of them alone. The
            # model carries the best-fitting member (its parameters are reported as such)
            tie_evidence = [e for e in identification if e["verdict"] == "tie"]
            ties.append({"names": names, "fitted_as": term.name, "evidence": tie_evidence})
            evidence["tie"] = {"names": names, "fitted_as": term.name}
        effects.append(
            Effect(
                name=" or ".join(names),
                description=term.description if not tied else "the data cannot tell these effects apart: " + "; ".join(f"{t.name}: {t.description}" for t in [term, *tied]),
                level="within_tightening",
                significant=True,
                parameters={},
                rmse_after=fit.rmse,
                evidence=evidence,
                names=names,
            )
        )
        current = fit
    bar.advance(max_effects - round_no)  # the rounds the loop did not need
    # the form of a channel lag: a second-order filter or a pure delay fitted as a first-order
    # low-pass gives a time constant biased low where the torque rate changes fast (under a
    # hold-down program: 0.75-0.8 of the true mean lag, even where the data cannot tell the
    # forms apart by their fit). With the lag's second-moment term and the free transients from
    # the anchors in as well, its coefficient is the channel's mean lag (the first moment of its
    # impulse response: tau of a first-order low-pass, the delay of a pure delay, 2 zeta /
    # omega_n of a second-order filter) whatever the form: that is the reported tau_ms (the
    # first-order value beside it). The extended form enters the model (and rmse_after) only
    # when it passes the loop's out-of-sample gain test at alpha
    lag_forms: dict[str, Any] = {}
    lag_anchor: dict[str, Any] = {}
    # a lag held in its first-order linearised form (-dT/dt: the channel's steady state on a
    # ramp) is wrong where the channel is not in that state, at the window's start and after a
    # pause: a second-order filter under a hold-down program left 1.23 of the noise sd, the
    # excess in each window's first 8-12 samples, and with that misfit its tau 1.05 of the
    # mean lag. The relaxation from the state measured at each anchor (``_anchor_transients``,
    # two pooled columns) enters the lag's term when it passes the gain test at alpha (that
    # set: 1.06 of the noise sd, tau 0.99 of the truth)
    for key, held in list(model.items()):
        cols = _lag_anchor_columns(held, current, current_idx[key])
        if not cols:
            continue
        anchored = dataclasses.replace(
            held,
            labels=held.labels + ["relaxation from the anchor state", "relaxation from the anchor state (rate)"],
            columns=held.columns + cols,
            info=dict(held.info) | {"anchor_transients": "relaxation from the recorded torque before the window and after each pause (two pooled columns)"},
        )
        trial = dict(model)
        trial[key] = anchored
        fit_anc, idx_anc = evaluate_with(trial, None)
        test = _gain_test(current, fit_anc, alpha, 0.0)
        lag_anchor[key] = {
            "gain": test,
            "tau_ms_without": held.parameters(current, current_idx[key]).get("tau_ms"),
            "kept": test["significant"],
        }
        if test["significant"]:
            model, current, current_idx = trial, fit_anc, idx_anc
    for key, held in list(model.items()):
        if held.name != "channel_delay" or len(held.extension) < 4:
            continue
        extended = _Term(
            held.name,
            held.description,
            False,
            held.labels + ["second moment of the lag", "transient from the window's start", "transient after a pause"],
            held.columns + held.extension[1:4],
            held.parameters,
            dict(held.info) | {"form": "mean lag of a channel of higher order than the first (second moment and anchor transients fitted)"},
            held.key,
            held.tag,
            held.extension,
        )
        trial = dict(model)
        trial[key] = extended
        fit_ext, idx_ext = evaluate_with(trial, None)
        test = _gain_test(current, fit_ext, alpha, 0.0)
        lag_forms[key] = {"extension_gain": test, "first_order_tau_ms": model[key].parameters(current, current_idx[key]).get("tau_ms"), "mean_lag_ms": extended.parameters(fit_ext, idx_ext[key]).get("tau_ms"), "kept": test["significant"]}
        if test["significant"]:
            model, current, current_idx = trial, fit_ext, idx_ext
    # identifiability of the parameters of a speed law and of an inertia: estimated again with
    # the speed channel as recorded and its backward difference instead of the smoothed speed
    # and acceleration. Where a tool program feeds the measured torque back into the speed (a
    # hold-down law), most of the acceleration left once each tightening's own line is fitted is
    # the drive's answer to the torque noise of the samples before, faster than the sampling
    # can resolve: the coefficient then depends on how the acceleration is estimated (inertia
    # at 0.5 or 0.8 of its value), and no estimate from the sampled channel can be trusted to
    # 15 %. A parameter that moves by more than that is reported as not identifiable.
    estimator_check: dict[str, Any] = {}
    speed_keys = [k for k, t in model.items() if t.name in ("inertia", "speed_dependent_friction")]
    if speed_keys and s.omega_raw is not None:
        s_raw = dataclasses.replace(s, omega=s.omega_raw, alpha=s.alpha_raw if s.alpha_raw is not None else s.alpha)
        build += 1
        raw_terms, _ = _candidates(s_raw, eng, current, declared, build, _model_periods(model), _hints(model, current, current_idx))
        for key in speed_keys:
            alt = raw_terms.get(key)
            if alt is None or len(alt.columns) != len(model[key].columns):
                continue
            trial = dict(model)
            trial[key] = alt
            fit_raw, idx_raw = evaluate_with(trial, None)
            p_main = model[key].parameters(current, current_idx[key])
            p_raw = alt.parameters(fit_raw, idx_raw[key])
            pname = next((n for n in ("J_kg_m2", "a_eff", "b_eff") if n in p_main), None)
            if pname is None:
                continue
            v_main, v_raw = float(p_main[pname]["value"]), float(p_raw[pname]["value"])
            ratio = v_raw / v_main if v_main != 0 else math.nan
            # the model keeps the estimate that predicts better out of sample (the smoothed one
            # unless the recorded channel does: a clean speed channel, whose program steps and
            # braking corners the smoothing rounds off)
            use_raw = bool(fit_raw.rmse < current.rmse)
            estimator_check[key] = {
                "parameter": pname,
                "smoothed": p_main[pname],
                "raw_channel": p_raw[pname],
                "rmse_smoothed": current.rmse,
                "rmse_raw_channel": fit_raw.rmse,
                "model_uses": "raw channel" if use_raw else "smoothed",
                "ratio": ratio,
                "identifiable": bool(math.isfinite(ratio) and abs(ratio - 1.0) <= 0.15),
            }
            if use_raw:
                model, current, current_idx = trial, fit_raw, idx_raw
            if key == "inertia":
                # ... and with the acceleration taken half a sample earlier and half a sample
                # later (linear interpolation between neighbouring samples): the relative timing
                # of the torque and speed channels is known to within a sample at best, and an
                # acceleration the sampling resolves gives nearly the same J either way. Under a
                # hold-down program with a small J it does not (0.70 and 0.86 of the truth on
                # one independent-generator set, whose smoothed and raw estimates agree to 5 %)
                acc = s.alpha_raw if use_raw and s.alpha_raw is not None else s.alpha
                if acc is None:
                    continue
                acc0 = np.where(np.isfinite(acc), acc, 0.0)
                same_prev = np.r_[False, s.gid[1:] == s.gid[:-1]]
                same_next = np.r_[s.gid[:-1] == s.gid[1:], False]
                shifted = {
                    "half_sample_earlier": 0.5 * (acc0 + np.where(same_prev, np.r_[0.0, acc0[:-1]], acc0)),
                    "half_sample_later": 0.5 * (acc0 + np.where(same_next, np.r_[acc0[1:], 0.0], acc0)),
                }
                p_now = model[key].parameters(current, current_idx[key])[pname]
                v_now = float(p_now["value"])
                alignment: dict[str, Any] = {}
                for label, acc_shift in shifted.items():
                    build += 1
                    alt_s = _candidates(dataclasses.replace(s, alpha=acc_shift), eng, current, declared, build, _model_periods(model), _hints(model, current, current_idx))[0].get(key)
                    if alt_s is None or len(alt_s.columns) != len(model[key].columns):
                        continue
                    trial_s = dict(model)
                    trial_s[key] = alt_s
                    fit_s, idx_s = evaluate_with(trial_s, None)
                    v_s = float(alt_s.parameters(fit_s, idx_s[key])[pname]["value"])
                    alignment[label] = {"value": v_s, "ratio": v_s / v_now if v_now != 0 else math.nan, "rmse": fit_s.rmse}
                chk = estimator_check[key]
                chk["acceleration_alignment"] = alignment
                aligned_ok = all(math.isfinite(a["ratio"]) and abs(a["ratio"] - 1.0) <= 0.15 for a in alignment.values())
                chk["identifiable_over_alignment"] = aligned_ok
                chk["identifiable"] = bool(chk["identifiable"] and aligned_ok)
    # the form of a speed law: the Stribeck curve (a friction minimum between static friction
    # and the viscous rise, which neither the logarithmic nor the linear law has) or the
    # logarithmic law with an offset speed, ln(1 + v / v0), replaces the law the loop named
    # when, at its best shape parameters on the grid, it passes the loop's gain test against
    # that law at alpha over the grid (Bonferroni)
    speed_forms: dict[str, Any] = {}
    # the refinement of the Stribeck form chosen, kept so that it is not run twice
    refined_form: tuple[_Fit, dict[str, Any] | None] | None = None
    for key, held in list(model.items()):
        if held.name != "speed_dependent_friction":
            continue
        tau_hint = _hints(model, current, current_idx).get("tau_s", 0.0)
        grid, sources, build = _speed_form_grid(s, eng, current, declared, key, build, tau_hint)
        # the test of the best shape: Bonferroni over the law families and speed sources. The
        # shape within a family (v_s and delta, or v0) is a fitted parameter, chosen by the
        # same out-of-sample RMSE; its optimism, one shape among neighbouring ones that fit
        # nearly alike, is small against a gain test over hundreds of tightenings
        families = len({c.info.get("law") for c in grid}) * sources

        profile: list[dict[str, Any]] = []
        best_form: tuple[_Fit, dict[str, list[int]], dict[str, _Term], _Term] | None = None
        best_by_exponent: dict[float, tuple[_Fit, dict[str, list[int]], dict[str, _Term], _Term]] = {}
        for cand in grid:
            trial = {k: (cand if k == key else t) for k, t in model.items()}
            fit_c, idx_c = evaluate_with(trial, None)
            shape = {k: v for k, v in cand.info.items() if k in ("law", "stribeck_speed_rpm", "stribeck_exponent", "offset_speed_rpm", "speed_source")}
            profile.append(shape | {"rmse": fit_c.rmse})
            if best_form is None or fit_c.rmse < best_form[0].rmse:
                best_form = (fit_c, idx_c, trial, cand)
            if cand.info.get("law") == "stribeck" and cand.info.get("stribeck_exponent") is not None:
                ex = float(cand.info["stribeck_exponent"])
                if ex not in best_by_exponent or fit_c.rmse < best_by_exponent[ex][0].rmse:
                    best_by_exponent[ex] = (fit_c, idx_c, trial, cand)
        if best_form is None:
            continue
        # the Stribeck speed between the grid's neighbours of the best grid point (Brent on
        # ln v_s, the same out-of-sample RMSE): the decay seen in its tail changes fast with
        # v_s, and one shared Stribeck curve (one lubricant) should be met, not bracketed
        for ex, (fit_b, _idx_b, _trial_b, cand_b) in list(best_by_exponent.items()):
            v_best = float(cand_b.info["stribeck_speed_rpm"])
            if v_best not in STRIBECK_SPEEDS_RPM:
                continue
            i_grid = STRIBECK_SPEEDS_RPM.index(v_best)
            raw_source = cand_b.info.get("speed_source") == "speed channel as recorded" and s.omega_raw is not None
            s_src = dataclasses.replace(s, omega=s.omega_raw) if raw_source else s
            found: list[tuple[_Fit, dict[str, list[int]], dict[str, _Term], _Term]] = []

            def rmse_at(ln_v: float, ex: float = ex, s_src: Any = s_src, raw_source: bool = raw_source, found: list[Any] = found) -> float:
                nonlocal build
                build += 1
                terms = speed_law_forms(s_src, eng, current, declared, key, build, tau_hint, stribeck_shapes=[(math.exp(ln_v), ex)], log_offsets=())
                if not terms:
                    return math.inf
                if raw_source:
                    terms[0].info["speed_source"] = "speed channel as recorded"
                trial = {k: (terms[0] if k == key else t) for k, t in model.items()}
                fit_v, idx_v = evaluate_with(trial, None)
                if not found or fit_v.rmse < found[0][0].rmse:
                    found[:] = [(fit_v, idx_v, trial, terms[0])]
                return fit_v.rmse

            lo_v, hi_v = STRIBECK_SPEEDS_RPM[max(i_grid - 1, 0)], STRIBECK_SPEEDS_RPM[min(i_grid + 1, len(STRIBECK_SPEEDS_RPM) - 1)]
            minimize_scalar(rmse_at, bounds=(math.log(lo_v), math.log(hi_v)), method="bounded", options={"xatol": 0.02, "maxiter": 12})
            if found and found[0][0].rmse < fit_b.rmse:
                best_by_exponent[ex] = found[0]
                profile.append({k: v for k, v in found[0][3].info.items() if k in ("law", "stribeck_speed_rpm", "stribeck_exponent", "speed_source")} | {"rmse": found[0][0].rmse, "between_grid_points": True})
                if found[0][0].rmse < best_form[0].rmse:
                    best_form = found[0]
        test = _gain_test(current, best_form[0], alpha / max(families, 1), min_gain)
        speed_forms[key] = {
            "law_named": held.info.get("law"),
            "best_other_form": best_form[3].info.get("law"),
            "its_gain_over_the_law_named": test,
            "kept": test["significant"],
            "bonferroni_alpha": alpha / max(families, 1),
            "shapes_tried": len(grid),
            "grid": profile,
        }
        # a Stribeck law named in its own form (it entered the loop so) chooses its exponent the
        # same way: its round took the exponent of the best pooled fit
        named_stribeck = held.info.get("law") == "stribeck"
        by_refined = (test["significant"] or named_stribeck) and best_form[3].info.get("law") == "stribeck" and len(best_by_exponent) > 1
        if by_refined:
            # the speed the law sees, when it is the speed channel as recorded: shifted within a
            # sample against the torque (``speed_at_timing``). Where the tool stops for a pause,
            # the recorded speed falls by a third of itself from one sample to the next, where
            # the Stribeck law is steepest: the law at the speed sampled with the torque
            # over-predicted the last sample before each stop by two noise sds, also with each
            # tightening's true law (CSDT, 2 kHz). The shift is proposed by the pooled
            # out-of-sample RMSE (quarter samples either way, then Brent between the best one's
            # neighbours) and kept only where the law with its constants refined per tightening
            # predicts better with it than as sampled: with one Stribeck curve shared by
            # tightenings of their own Stribeck speeds the pooled fit can use the shift for
            # that spread instead (half a sample on a mixed set, pooled 2.05 -> 1.98 of the
            # noise sd, refined 1.063 -> 1.122)
            timing: dict[str, Any] = {}
            timed_forms: dict[float, tuple[_Fit, dict[str, list[int]], dict[str, _Term], _Term]] = {}
            for ex, (fit_b, _idx_b, _trial_b, cand_b) in list(best_by_exponent.items()):
                if cand_b.info.get("speed_source") != "speed channel as recorded" or s.omega_raw_prev is None:
                    continue
                v_b = float(cand_b.info["stribeck_speed_rpm"])
                tried_t: list[dict[str, float]] = [{"shift_samples": 0.0, "rmse": fit_b.rmse}]
                best_t: list[Any] = [0.0, fit_b.rmse, None]

                def rmse_shift(shift: float, ex: float = ex, v_b: float = v_b, tried_t: list[dict[str, float]] = tried_t, best_t: list[Any] = best_t) -> float:
                    nonlocal build
                    build += 1
                    terms = speed_law_forms(dataclasses.replace(s, omega=speed_at_timing(s, shift)), eng, current, declared, key, build, tau_hint, stribeck_shapes=[(v_b, ex)], log_offsets=())
                    if not terms:
                        return math.inf
                    terms[0].info["speed_source"] = "speed channel as recorded"
                    terms[0].info["speed_timing_samples"] = shift
                    trial = {k: (terms[0] if k == key else t) for k, t in model.items()}
                    fit_v, idx_v = evaluate_with(trial, None)
                    tried_t.append({"shift_samples": shift, "rmse": fit_v.rmse})
                    if fit_v.rmse < best_t[1]:
                        best_t[:] = [shift, fit_v.rmse, (fit_v, idx_v, trial, terms[0])]
                    return fit_v.rmse

                shifts = (-0.5, -0.25, 0.25, 0.5)
                for sh in shifts:
                    rmse_shift(sh)
                grid_t = (-0.5, -0.25, 0.0, 0.25, 0.5)
                i_t = grid_t.index(best_t[0])
                minimize_scalar(rmse_shift, bounds=(grid_t[max(i_t - 1, 0)], grid_t[min(i_t + 1, len(grid_t) - 1)]), method="bounded", options={"xatol": 0.01, "maxiter": 10})
                timing[f"{ex:g}"] = {"shift_samples": float(best_t[0]), "rmse_pooled": float(best_t[1]), "rmse_pooled_as_sampled": fit_b.rmse, "tried": tried_t}
                if best_t[2] is not None:
                    timed_forms[ex] = best_t[2]
            if timing:
                speed_forms[key]["speed_channel_timing"] = timing
            # the exponent by the out-of-sample RMSE with each tightening's constants refined:
            # with v_s drawn per tightening, the pooled fit prefers the exponent whose curve is
            # the population's average (a mixture of Gaussian decays has an exponential-like
            # tail), while each tightening follows the exponent of its own law
            refined_by_exponent: dict[str, float] = {}
            chosen_form = best_form
            chosen_rmse = math.inf
            for ex, cand_ex in sorted(best_by_exponent.items()):
                for cand_fit in [cand_ex] + ([timed_forms[ex]] if ex in timed_forms else []):
                    ref = _refine_model(cand_fit[2], cand_fit[0], cand_fit[1])
                    rmse_ex = ref["fit"].rmse if ref is not None and ref["significant"] else cand_fit[0].rmse
                    if ex in timed_forms:
                        timing[f"{ex:g}"]["rmse_refined" if cand_fit is timed_forms[ex] else "rmse_refined_as_sampled"] = rmse_ex
                    refined_by_exponent[f"{ex:g}"] = min(rmse_ex, refined_by_exponent.get(f"{ex:g}", math.inf))
                    if rmse_ex < chosen_rmse:
                        chosen_form, chosen_rmse = cand_fit, rmse_ex
                        refined_form = (cand_fit[0], ref)
            for ex_key, t_info in timing.items():
                t_info["kept"] = bool(chosen_form is timed_forms.get(float(ex_key)))
            best_form = chosen_form
            speed_forms[key]["exponent_by_refined_rmse"] = refined_by_exponent
        if test["significant"] or by_refined:
            current, current_idx, model = best_form[0], best_form[1], best_form[2]
    # the constant of each named effect per tightening (random effects around the pooled value,
    # out of sample): the reported parameter stays the pooled one, its spread is reported beside
    pooled_fit = current
    refinement = refined_form[1] if refined_form is not None and refined_form[0] is current else _refine_model(model, current, current_idx)
    if refinement is not None and refinement["significant"]:
        current = refinement["fit"]
    final = current
    # parameters of the added effects from the final model (the pooled coefficients)
    per_tightening_constants: dict[str, F64] = {}
    for eff, key in zip(effects, list(model)):
        eff.parameters = model[key].parameters(pooled_fit, current_idx[key])
        if key in lag_forms:
            lf = lag_forms[key]
            mean_lag = lf["mean_lag_ms"]
            if isinstance(mean_lag, dict) and math.isfinite(mean_lag.get("value", math.nan)):
                eff.parameters["tau_ms"] = mean_lag
            eff.parameters["first_order_tau_ms"] = lf["first_order_tau_ms"]
            eff.parameters["form"] = (
                "higher order than first (the extended form fits better out of sample); tau_ms is the mean lag"
                if lf["kept"]
                else "first order or not told apart from it; tau_ms is the mean lag of the extended form (consistent for any form), first_order_tau_ms the first-order fit"
            )
            eff.evidence["lag_form"] = lf
        if key in lag_anchor:
            eff.evidence["lag_anchor_transients"] = lag_anchor[key]
        if key in speed_forms:
            eff.evidence["speed_law_form"] = speed_forms[key]
            eff.parameters["form"] = str(model[key].info.get("law"))
        if key in estimator_check:
            chk = estimator_check[key]
            eff.evidence["estimator_check"] = chk
            eff.parameters["identifiable"] = chk["identifiable"]
            pv_main = eff.parameters.get(chk["parameter"])
            aligned = [float(a["value"]) for a in chk.get("acceleration_alignment", {}).values()]
            if isinstance(pv_main, dict):
                both = [float(chk["smoothed"]["value"]), float(chk["raw_channel"]["value"])]
                pv_main["range_over_speed_estimates"] = [min(both), max(both)]
                if aligned:
                    pv_main["range_over_acceleration_alignment"] = [min(aligned + [float(pv_main["value"])]), max(aligned + [float(pv_main["value"])])]
            if not chk["identifiable"]:
                why = []
                if abs(chk["ratio"] - 1.0) > 0.15 or not math.isfinite(chk["ratio"]):
                    why.append(f"{chk['parameter']} is {chk['ratio']:.2f} times as large with the speed channel as recorded and its backward difference as with the smoothed speed and acceleration")
                if not chk.get("identifiable_over_alignment", True):
                    ratios = ", ".join(f"{a['ratio']:.2f}" for a in chk["acceleration_alignment"].values())
                    why.append(f"{chk['parameter']} is {ratios} times as large with the acceleration half a sample earlier / later (the channels' relative timing is not known to better than a sample)")
                eff.parameters["note_identifiability"] = (
                    "not identifiable to 15 %: " + "; ".join(why) + " (a program that feeds the torque back into "
                    "the speed: the acceleration the transducer feels is faster than the sampling resolves); the effect is named, its size is not pinned"
                )
        if refinement is not None and key in refinement["terms"]:
            rt = refinement["terms"][key]
            # the parameter each factor scales: the law's constant, or a Stribeck law's static
            # and viscous coefficients and its Stribeck speed (whose component is the change of
            # ln v_s: the factor on v_s is exp of it)
            if model[key].info.get("law") == "stribeck":
                pnames: list[str] = ["s_eff", "k_eff", "stribeck_speed_rpm"]
            else:
                pnames = [n for n in _PRIMARY_PARAMETER if isinstance(eff.parameters.get(n), dict)][:1]
            for c, spread_name in enumerate(pnames[: len(rt["factors"])]):
                fac, fac_raw, sd_c = rt["factors"][c], rt["factors_raw"][c], rt["between_tightening_sd_relative_by_component"][c]
                if spread_name == "stribeck_speed_rpm":
                    fac, fac_raw = np.exp(fac - 1.0), np.exp(np.clip(fac_raw - 1.0, -50.0, 50.0))
                eff.parameters_spread[spread_name] = spread_summary(eff.parameters[spread_name], fac, fac_raw, sd_c, bool(refinement["significant"]))
                per_tightening_constants[f"{model[key].name}_{spread_name}"] = float(eff.parameters[spread_name]["value"]) * fac
    white = _whiteness(s, final.resid)
    # the spectral search again with the model's periodic terms taken out of the long stretch:
    # a significant peak left is a periodicity that no candidate explains
    spec_before = eng.memo["spectrum"]
    model_periods = _model_periods(model)
    spec_after = _spectral_search(eng.memo["long"], s.n_tight, alpha, min_gain, remove=model_periods, before=spec_before) if model_periods else spec_before
    spectrum = _spectrum_details(spec_before, spec_after, model, bool(model_periods))
    unexplained = bool(white["ar_r2"] > whiteness_tolerance or leftover_significant or spectrum["unexplained_peaks"])

    bar.advance()
    # level 2
    level2, l2_details, l2_plots = _level2(table, s, final, fold_t, folds, alpha, min_gain, covariates, spec_columns, group_cols, x_scale_t)
    # level 2, grouping factors: does a categorical column shift a per-tightening parameter?
    started_groups = time.perf_counter()
    l2_params, l2_spec, l2_cell = _level2_inputs(table, s, final, x_scale_t, spec_columns)
    factors, factor_skips = factor_columns(table, s.rows, grouping_factors, l2_spec, group_cols)
    clusters = None
    if group_cols:
        ridx = pa.array(s.rows)
        keys = list(zip(*[table.column(c).take(ridx).to_pylist() for c in group_cols]))
        clusters = np.array([str(k) for k in keys], dtype=object)
    group_effects, group_details = grouping_factor_analysis(l2_params, factors, l2_cell, clusters=clusters, alpha=alpha)
    group_details["clusters"] = group_cols
    group_details["seconds"] = time.perf_counter() - started_groups
    group_details["columns_not_taken"] = factor_skips
    group_details["specification_columns"] = l2_spec
    if "mu_tot" not in l2_params:
        group_details["mu_tot"] = "not available: needs clamp force and the thread geometry (pitch_mm, d2_mm, dkm_mm columns, or an ISO designation in a thread column)"
    found_vs = {e.name for e in level2}
    for e in group_effects:
        twin = f"{e.parameters['parameter']}_vs_{e.parameters['factor']}"
        if twin in found_vs:
            e.evidence["also_predicts_out_of_sample"] = twin
        labels = factors[e.parameters["factor"]]
        pv = l2_params[e.parameters["parameter"]][0]
        shown = np.isfinite(pv) & (labels != None)  # noqa: E711 - elementwise on an object array
        l2_plots[e.name] = (labels[shown].astype(str), pv[shown], "categorical")
    effects_all = effects + level2 + group_effects

    model_str = _model_string(s, effects)
    per_t = pa.table(
        {
            "tightening_id": pa.array(s.ids),
            "n_samples": pa.array(g.count.astype(np.int64)),
            "rmse_before": pa.array(np.sqrt(mse_before_t)),
            "rmse_after": pa.array(np.sqrt(final.mse_t)),
            "torque_rate": pa.array(final.pcoef[:, 1] / np.where(x_scale_t > 0, x_scale_t, 1.0)),
            "prevailing_torque": pa.array(np.where(g.sum(rd) > 0, g.sum((s.y - final.resid) * rd) / np.maximum(g.sum(rd), 1), np.nan)),
            "noise_sd": pa.array(sig_t),
        }
        # each named effect's constant per tightening (shrunk towards the pooled value)
        | {name: pa.array(v) for name, v in per_tightening_constants.items()}
    )
    rb, ra = np.sqrt(mse_before_t), np.sqrt(final.mse_t)
    details: dict[str, Any] = {
        "declared_model": {
            "elastic": "T = a_j + b_j * " + ("clamp_force (smoothed along the angle)" if s.has_clamp else "angle (dequantised)"),
            "rundown": "T = c_j",
            "per_tightening_parameters": declared_labels,
        },
        "tightenings": s.n_tight,
        "tightenings_in_table": table.num_rows,
        "samples": int(len(s.y)),
        "elastic_samples": int(el.sum()),
        "rundown_samples": int(rd.sum()),
        "speed_source": s.speed_source,
        "clamp_force": s.has_clamp,
        "folds": folds,
        "group_by": group_cols,
        "alpha": alpha,
        "min_gain": min_gain,
        "per_tightening_rmse": {
            "before": _quantiles(rb),
            "after": _quantiles(ra),
            "fraction_improved": float(np.mean(ra < rb)),
        },
        "noise_floor_estimate": float(np.sqrt(np.sum(g.count * sig_t**2) / np.sum(g.count))),
        "whiteness": white,
        "per_tightening_constants": _refinement_details(refinement, pooled_fit.rmse, final.rmse, model),
        "collinearity": collinearity,
        "ties": ties,
        "form_misfit": misfits,
        "periodogram": periodogram_info,
        "spectrum": spectrum,
        "rounds": rounds,
        "level2": l2_details,
        "grouping_factors": group_details,
        "seconds": time.perf_counter() - started,
    }
    plot = {
        "e_before": e_before,
        "e_after": final.e_oos,
        "gid": s.gid,
        "seg": s.seg,
        "pos": s.pos_in_window,
        "theta": s.theta,
        "y": s.y,
        "sigma_t": sig_t,
        "ids": s.ids,
        "rb": rb,
        "ra": ra,
        "terms": [(t.name, t.columns if not t.per_tightening else []) for t in model.values()],
        "level2": l2_plots,
        "partial": partial,
        "periodogram": periodogram_info.get("_curve"),
    }
    periodogram_info.pop("_curve", None)
    bar.advance()
    return Diagnosis(
        model=model_str,
        rmse_before=rmse_before,
        rmse_after=final.rmse,
        effects=effects_all,
        unexplained_structure=unexplained,
        details=details,
        per_tightening=per_t,
        plot_data=plot,
    )


def _pair_search(
    cands: Sequence[_Term],
    tried: list[dict[str, Any]],
    alone: dict[str, _Fit],
    current: _Fit,
    joint_fit: Any,
    alpha: float,
    m: int,
    min_gain: float,
    top: int = 4,
) -> dict[str, Any] | None:
    """The best pair of global candidates of different effects (among the ``top`` by pooled
    gain) that gains jointly and of which each member keeps a gain with the other in, tested at
    ``alpha / (m + pairs)``; None when no pair does."""
    gain_of = {r["key"]: r["rmse_gain"] for r in tried}
    pool = sorted((t for t in cands if not t.per_tightening), key=lambda t: -gain_of.get(t.key, -math.inf))
    chosen: list[_Term] = []
    for t in pool:
        if len(chosen) < top and all(t.name != c.name for c in chosen):
            chosen.append(t)
    pairs = [(a, b) for i, a in enumerate(chosen) for b in chosen[i + 1 :]]
    if not pairs:
        return None
    level = alpha / (m + len(pairs))
    best: dict[str, Any] | None = None
    for a, b in pairs:
        joint = joint_fit(a, b)
        together = _gain_test(current, joint, level, min_gain)
        if not together["significant"]:
            continue
        keep_a = _gain_test(alone[b.key], joint, level, min_gain)
        keep_b = _gain_test(alone[a.key], joint, level, min_gain)
        if not (keep_a["significant"] and keep_b["significant"]):
            continue
        if best is None or together["rmse_gain"] > best["joint_gain"]["rmse_gain"]:
            first, second = (a, b) if gain_of.get(a.key, 0.0) >= gain_of.get(b.key, 0.0) else (b, a)
            best = {
                "names": [first.name, second.name],
                "enters_first": first.key,
                "joint_gain": together,
                "gain_of_each_with_the_other_in": {a.name: keep_a, b.name: keep_b},
                "pairs_tried": len(pairs),
                "bonferroni_alpha": level,
            }
    return best


def _period_of(t: _Term) -> tuple[str, float] | None:
    axis = t.info.get("axis")
    if axis is None:
        return None
    return (str(axis), float(t.info["period_deg" if axis == "angle" else "period_s"]))


def _model_periods(model: dict[str, _Term]) -> list[tuple[str, float]]:
    """(axis, period) of the model's periodic terms."""
    return [p for p in (_period_of(t) for t in model.values()) if p is not None]


def _spectrum_details(before: dict[str, Any], after: dict[str, Any], model: dict[str, _Term], removed: bool) -> dict[str, Any]:
    """``details["spectrum"]``: the peaks of the spectral search before the loop, which effect
    explains each (a periodic term of the model at its period, or its image at the median speed
    on the other axis: the peak is gone once the model's periodic terms are taken out), the peaks
    left after that, and the log-spectral distances."""
    after_keys = {(q["domain"], round(q["frequency"], 12)) for q in after.get("peaks", [])}
    terms = [(t.name, _period_of(t)) for t in model.values() if _period_of(t) is not None]

    def clean(q: dict[str, Any]) -> dict[str, Any]:
        return {k: v for k, v in q.items() if not k.startswith("_")}

    peaks = []
    for q in before.get("peaks", []):
        left = removed and any(q["domain"] == d and abs(q["frequency"] - f) <= 2.0 / _window(after, d) for d, f in after_keys)
        explained = None
        if removed and not left:
            # the term at the peak's period on its axis, else the periodic terms whose removal
            # took it away (its image on the other axis, a leakage)
            same = [name for name, pp in terms if pp is not None and pp[0] == q["domain"] and abs(1.0 / pp[1] - q["frequency"]) <= 2.0 / _window(before, q["domain"])]
            explained = same[0] if same else ", ".join(sorted({name for name, _ in terms}))
        peaks.append(clean(q) | {"explained_by": explained})
    unexplained = [clean(q) for q in after.get("peaks", [])]
    out: dict[str, Any] = {
        "method": before.get("stretch"),
        "alpha": before.get("alpha"),
        "min_power_share": before.get("min_power_share"),
        "bins_searched": before.get("bins_searched"),
        "axes": before.get("axes", {}),
        "peaks": peaks,
        "unexplained_peaks": unexplained,
        "model_periods": [{"axis": a, "period": p} for a, p in _model_periods(model)],
        "axes_after": after.get("axes", {}) if removed else None,
        "log_spectral_distance_db": {k: v.get("log_spectral_distance_db") for k, v in after.get("axes", {}).items()} if removed else {k: 0.0 for k in before.get("axes", {})},
    }
    if "note" in before:
        out["note"] = before["note"]
    return out


def _window(search: dict[str, Any], domain: str) -> float:
    ax = search.get("axes", {}).get(domain, {})
    w = ax.get("window_deg" if domain == "angle" else "window_s")
    return float(w) if w else float("inf")


def _refinement_details(refinement: dict[str, Any] | None, rmse_pooled: float, rmse_after: float, model: dict[str, _Term]) -> dict[str, Any]:
    """``details["per_tightening_constants"]``: whether the named effects' constants were refined
    per tightening, the out-of-sample RMSE with pooled and with per-tightening constants, and
    the test that decided which one ``rmse_after`` is."""
    if refinement is None:
        return {"refined": [], "rmse_pooled_constants": rmse_pooled, "rmse_after": rmse_after, "note": "no named effect with a constant to refine"}
    out = {
        "refined": [model[k].name + (f" ({model[k].info['law']} law)" if model[k].info.get("law") else "") for k in refinement["terms"]],
        "rmse_pooled_constants": refinement["rmse_pooled_constants"],
        "rmse_per_tightening_constants": refinement["rmse_per_tightening_constants"],
        "rmse_gain": refinement["rmse_gain"],
        "p_value": refinement["p_value"],
        "used_in_rmse_after": refinement["significant"],
        "rmse_after": rmse_after,
        "block_samples": refinement["block_samples"],
        "protocol": (
            "out of sample: pooled coefficients fitted without the tightening's fold, the between-tightening variance "
            "without that fold, each tightening's factors on three of four groups of short blocks of its samples "
            "predicting the fourth (block length from the noise's correlation; a Stribeck law's three constants jointly, "
            "MAP under a normal population); the declared columns in the loop's own protocol; "
            "used in rmse_after when its per-tightening improvement passes the one-sided t test at alpha"
        ),
    }
    if "anchor_relaxation_per_tightening" in refinement:
        # a lag in its extended form: its relaxation from each anchor with amplitudes of its own
        # per tightening, kept where that predicts better out of sample
        out["anchor_relaxation_per_tightening"] = refinement["anchor_relaxation_per_tightening"]
    return out


def _no_parameters(fit: _Fit, idx: list[int]) -> dict[str, Any]:
    return {}


class _CallableModule(types.ModuleType):
    """``tightscan.diagnose`` is both this module and the function exported under its name; an
    import of the submodule (e.g. pytest collecting its doctests) rebinds the package attribute
    to the module, so the module forwards calls to the function."""

    def __call__(self, *args: Any, **kwargs: Any) -> Diagnosis:
        return diagnose(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule
