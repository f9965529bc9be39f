"""Identification on data the project did not generate (issue 12, items 1 and 4): a reduced
confusion matrix on the independent generator (tests/independent_generator), fixed seeds.

Before the identification step, a first-order low-pass under a hold-down (HDT) program could be
named ``speed_dependent_friction`` and speed-linear friction under HDT was named
``pressure_dependent_friction``: under HDT the speed falls as the clamp force and the torque rate
rise, so the three regressors are nearly collinear in the elastic window. The full matrix is
``benches/diagnose_confusion.py``.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pyarrow as pa
import pytest

import independent_generator as ig
import tightscan
from tightscan.diagnose import Diagnosis

N = 150


def _hidden(curves: pa.Table) -> pa.Table:
    """Nothing in the columns says how the data was made."""
    return curves.drop_columns([c for c in ("strategy", "thread", "operator") if c in curves.column_names])


def _claims(d: Diagnosis) -> list[list[str]]:
    """Level-1 claims in order, each as the list of effects it names (more than one: a tie)."""
    return [getattr(e, "names", None) or [e.name] for e in d.effects if e.level == "within_tightening"]


def _run(strategy: str, effect: Any, seed: int = 1, n: int = N) -> tuple[Diagnosis, pa.Table]:
    curves, truth = ig.generate(ig.GeneratorConfig(n=n, seed=seed, strategy=strategy, clamp_force=True, effects=(effect,) if effect else ()))  # type: ignore[arg-type]
    return tightscan.diagnose(_hidden(curves)), truth


# effect first expected (alone or in a tie), what must never be named alone, generator settings
CASES = {
    "lowpass1-HDT": ("channel_delay", "speed_dependent_friction", "HDT", ig.TorqueDynamics(form="lowpass1", tau_s=(0.003, 0.006))),
    "delay-HDT": ("channel_delay", "speed_dependent_friction", "HDT", ig.TorqueDynamics(form="delay", delay_s=(0.002, 0.004))),
    "speed-linear-HDT": ("speed_dependent_friction", "pressure_dependent_friction", "HDT", ig.SpeedFriction(form="linear", coeff=(0.08, 0.15))),
    "speed-linear-HDT-small": ("speed_dependent_friction", "pressure_dependent_friction", "HDT", ig.SpeedFriction(form="linear", coeff=(0.02, 0.05))),
    "speed-stribeck-HDT": ("speed_dependent_friction", "pressure_dependent_friction", "HDT", ig.SpeedFriction(form="stribeck", coeff=(0.08, 0.15))),
    "inertia-HDT": ("inertia", "pressure_dependent_friction", "HDT", ig.Inertia(inertia_kgm2=(5e-5, 1e-4))),
    "pressure-mix": ("pressure_dependent_friction", "speed_dependent_friction", "mix", ig.PressureFriction(form="linear", kappa=(0.15, 0.3))),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_true_effect_first_and_proxy_never_alone(case: str) -> None:
    expected, proxy, strategy, effect = CASES[case]
    d, _ = _run(strategy, effect)
    claims = _claims(d)
    assert claims, "nothing named"
    # the true effect first, alone or inside an honestly reported tie
    assert expected in claims[0], claims
    # the confounded proxy is never named alone, first or later
    assert [proxy] not in claims, claims
    # every claim passed the identification step: its evidence holds the joint fits
    for e in d.effects:
        if e.level == "within_tightening":
            assert isinstance(e.evidence["identification"], list)


def test_channel_lag_parameter_after_identification() -> None:
    """The low-pass is named with its time constant (within 15 % of the drawn mean)."""
    d, truth = _run("HDT", CASES["lowpass1-HDT"][3])
    first = next(e for e in d.effects if e.level == "within_tightening")
    assert first.names == ["channel_delay"]
    tau_true = 1000 * float(np.mean(truth.column("tau_s").to_numpy()))
    assert first.parameters["tau_ms"]["value"] == pytest.approx(tau_true, rel=0.15)


def test_collinearity_is_reported_and_shows_the_hdt_confounding() -> None:
    d, _ = _run("HDT", CASES["speed-linear-HDT"][3])
    coll = d.details["collinearity"]
    assert coll["condition_number"] > 1
    assert all(v >= 1 - 1e-9 for v in coll["vif"].values())
    # under HDT the speed law and the pressure law bend the elastic window alike
    assert abs(coll["correlation"]["speed_dependent_friction:linear"]["pressure_dependent_friction"]) > 0.8
    assert coll["vif"]["pressure_dependent_friction"] > 3
    # and the named effect carries the joint fit with that competitor, which it won
    first = next(e for e in d.effects if e.level == "within_tightening")
    vs = [x for x in first.evidence["identification"] if x["competitor"] == "pressure_dependent_friction"]
    assert vs and vs[0]["verdict"] == "encompasses"
    assert vs[0]["term_gain_with_competitor_in"]["significant"]
    assert not vs[0]["competitor_gain_with_term_in"]["significant"]
    doc = d.to_dict()
    assert {"collinearity", "ties", "form_misfit"} <= set(doc)
    json.dumps(doc, allow_nan=False)


def test_stribeck_friction_in_csdt_is_named_alone_not_tied_with_a_lag() -> None:
    """Stribeck friction in a CSDT program (fixed seed). The speed law and the channel lag fit
    the restart after the pause nearly alike. With the engine's elastic window starting
    two samples before its start level (so the break detector's start test sees a jump across
    it), the speed law keeps its gain with the lag in at seeds 1-4 and the true effect is
    named alone (in the log form at this seed); with the window as it was, the loop reported
    the tie "speed friction or channel lag" at seed 1. The tie was that close; the genuine tie
    of the reduced matrix is ``test_speed_and_pressure_friction_under_one_proportional_hdt_program_tie``."""
    d, _ = _run("CSDT", ig.SpeedFriction(form="stribeck", coeff=(0.08, 0.15)))
    claims = _claims(d)
    assert claims and claims[0] == ["speed_dependent_friction"], claims
    assert all("channel_delay" not in c for c in claims), claims
    assert not d.details["ties"]


def test_speed_and_pressure_friction_under_one_proportional_hdt_program_tie() -> None:
    """A genuine tie: every tightening runs the same hold-down program, whose speed command falls
    in proportion to the torque still to go from the start of the elastic window (knee 1, 400
    rpm, floor 5 rpm), so speed and clamp force carry the same information (projected
    correlation of the two laws -0.97), and the speed friction is faint (coefficient 0.002-0.004
    per 100 rpm). Either law fits alone (each well past alpha); with the other in, neither keeps
    a gain of 1 % (the speed law's own part, what the drive's lag and speed floor add, stays
    under it). The data cannot say which: the loop must name both together and neither alone.
    A loop that names the law that fits first (or drops the weaker of two collinear
    regressors) names one alone and fails. Robust: the tie held at 100 tightenings for seeds
    1-10 (seed 10: with time drift as a third member) and at 80 and 120 for seeds 1-5."""
    program = ig.ProcessConfig(hdt_rundown_rpm=400.0, hdt_knee=1.0, hdt_min_rpm=5.0)
    cfg = ig.GeneratorConfig(n=100, seed=3, strategy="HDT", clamp_force=True, effects=(ig.SpeedFriction(form="linear", coeff=(0.002, 0.004)),), process=program)
    curves, _ = ig.generate(cfg)
    d = tightscan.diagnose(_hidden(curves))
    claims = _claims(d)
    pair = {"speed_dependent_friction", "pressure_dependent_friction"}
    assert claims and pair <= set(claims[0]), claims
    assert all(c != [name] for c in claims for name in pair), claims
    assert any(pair <= set(t["names"]) for t in d.details["ties"]), d.details["ties"]
    # the evidence: the two fitted jointly, neither keeping its gain with the other in
    first = next(e for e in d.effects if e.level == "within_tightening")
    vs = [x for x in first.evidence["identification"] if {x["term"], x["competitor"]} == pair]
    assert vs and vs[0]["verdict"] == "tie"
    assert not vs[0]["term_gain_with_competitor_in"]["significant"] and not vs[0]["competitor_gain_with_term_in"]["significant"]
    assert abs(vs[0]["correlation"]) > 0.9


@pytest.mark.parametrize("strategy,seed", [("CST", 11), ("CSDT", 12), ("HDT", 13), ("mix", 14), ("HDT", 15), ("mix", 16)])
def test_clean_sets_claim_nothing(strategy: str, seed: int) -> None:
    d, _ = _run(strategy, None, seed=seed, n=120)
    assert _claims(d) == []


@pytest.mark.parametrize(
    "effect",
    [
        ig.TorqueDynamics(form="lowpass2", natural_freq_hz=(60.0, 120.0), damping=0.7),
        ig.TorqueDynamics(form="delay", delay_s=(0.002, 0.004)),
    ],
    ids=["lowpass2", "delay"],
)
def test_nothing_claimed_after_the_lag_for_the_misfit_of_its_form(effect: Any) -> None:
    """A second-order filter or a pure delay fitted as a first-order lag leaves structure that a
    speed law takes up (before item 4: speed friction, then time drift, named after the lag).
    With the lag's law extended by one degree of freedom that structure is gone: nothing more
    is claimed, and the report says which candidate only took up the misfit of which effect."""
    d, truth = _run("HDT", effect)
    assert _claims(d) == [["channel_delay"]]
    misfit = d.details["form_misfit"]
    assert misfit and misfit[0]["effect"] == "channel_delay"
    assert not misfit[0]["candidate_gain_with_extension_in"]["significant"]
    # issue 12, item 3: the reported tau is the channel's mean lag (2 zeta / omega_n of the
    # second-order filter, the delay itself) within 15 %; the first-order fit beside it is
    # biased low under HDT (0.75-0.8), which is why it is not the one reported
    if effect.form == "delay":
        mean_lag = float(np.mean(truth.column("delay_s").to_numpy()))
    else:
        mean_lag = float(np.mean(2 * truth.column("damping").to_numpy() / (2 * np.pi * truth.column("natural_freq_hz").to_numpy())))
    params = d.effects[0].parameters
    assert params["tau_ms"]["value"] == pytest.approx(1000 * mean_lag, rel=0.15)
    assert params["first_order_tau_ms"]["value"] < params["tau_ms"]["value"]
    assert 0 < params["tau_ms"]["se_folds"] < 0.1 * params["tau_ms"]["value"]


def _noise_floor(d: Diagnosis, truth: pa.Table) -> float:
    """The generator's own noise sd over the samples the loop models (the bench's
    ``truth_floor``): what an RMSE after can reach."""
    pdata = d.plot_data
    row = {v: i for i, v in enumerate(truth.column("tightening_id").to_pylist())}
    r = np.array([row[i] for i in pdata["ids"]])
    col = {c: truth.column(c).to_numpy(zero_copy_only=False).astype(float)[r] for c in ("noise_sd_nm", "noise_sd_rel", "noise_sd_target_rel", "target_torque")}
    gid = pdata["gid"]
    sd = col["noise_sd_nm"][gid] + col["noise_sd_target_rel"][gid] * np.nan_to_num(col["target_torque"])[gid] + col["noise_sd_rel"][gid] * np.abs(np.asarray(pdata["y"]))
    return float(np.sqrt(np.mean(sd * sd)))


def test_a_second_order_lag_relaxes_from_the_state_measured_before_the_window() -> None:
    """Issue 12: a second-order filter under a hold-down program (the bench's lowpass2 HDT large
    set, seed 2) was held in the lag's first-order linearised form, -tau dT/dt, the channel's
    steady state on a ramp. At the window's start the channel is not there yet, and the RMSE
    after was 1.23 of the noise sd, the excess in each window's first 8-12 samples. The
    relaxation from the state measured before the window (two pooled columns, scaled by how
    far the recorded torque there is from the linearised model) brings it to 1.06 and the mean
    lag to 0.99 of the truth (1.05 before)."""
    effect = ig.TorqueDynamics(form="lowpass2", natural_freq_hz=(60.0, 120.0), damping=0.7)
    d, truth = _run("HDT", effect, seed=2, n=300)
    assert _claims(d) == [["channel_delay"]]
    assert d.rmse_after / _noise_floor(d, truth) < 1.1
    lag = d.effects[0]
    assert lag.evidence["lag_anchor_transients"]["kept"]
    mean_lag = float(np.mean(2 * truth.column("damping").to_numpy() / (2 * np.pi * truth.column("natural_freq_hz").to_numpy())))
    assert lag.parameters["tau_ms"]["value"] == pytest.approx(1000 * mean_lag, rel=0.04)
    json.dumps(d.to_dict(), allow_nan=False)


def test_a_second_order_lag_in_extended_form_relaxes_per_tightening_from_its_anchor() -> None:
    """Issue 12: the same filter at seed 1 takes the lag's extended low-pass-path form, whose
    transient from the window's start is one pooled decay times the peak torque. A second-order
    channel also holds a rate at the anchor, different in every tightening, so its excess stayed
    in each window's first dozen samples (standardised residual 5.1 in the first): RMSE after
    1.105 of the noise sd. With the relaxation from the anchor (e^-u, u e^-u) refined per
    tightening, out of sample: 1.047."""
    effect = ig.TorqueDynamics(form="lowpass2", natural_freq_hz=(60.0, 120.0), damping=0.7)
    d, truth = _run("HDT", effect, seed=1, n=300)
    assert _claims(d) == [["channel_delay"]]
    assert d.effects[0].parameters["form"].startswith("higher order than first")
    relax = d.details["per_tightening_constants"]["anchor_relaxation_per_tightening"]
    assert relax["rmse_with"] < relax["rmse_without"]
    assert d.rmse_after / _noise_floor(d, truth) < 1.07


def test_stribeck_friction_sees_the_speed_between_samples_at_the_stop() -> None:
    """Issue 12: a Stribeck law under CSDT over-predicted the last sample before each pause by
    two noise sds, also with each tightening's true law: there the recorded speed falls by a
    third of itself per sample, and the friction of a torque sample is that of the sliding
    just before it, not of the speed sampled with it. The speed channel's timing against the
    torque, within a sample, is chosen by the out-of-sample RMSE (about a sixth of a sample
    earlier here, the generator's last internal step): RMSE after 1.131 -> 1.066 of the noise
    sd on this reduced set (the bench's CSDT small cells 1.110-1.124 -> 1.052-1.056)."""
    d, truth = _run("CSDT", ig.SpeedFriction(form="stribeck", coeff=(0.02, 0.05)), seed=2, n=120)
    assert _claims(d) == [["speed_dependent_friction"]]
    first = d.effects[0]
    assert first.parameters["form"] == "stribeck"
    timing = first.evidence["speed_law_form"]["speed_channel_timing"]
    assert any(t["kept"] and 0.05 < t["shift_samples"] < 0.35 and t["rmse_refined"] < t["rmse_refined_as_sampled"] for t in timing.values())
    assert d.rmse_after / _noise_floor(d, truth) < 1.09
    json.dumps(d.to_dict(), allow_nan=False)


def test_a_delay_held_in_linearised_form_claims_nothing_for_its_start_misfit() -> None:
    """Issue 12, item 4: a pure delay under a hold-down program (the bench's delay HDT large set,
    seed 2). After the lag (round 1, still in its linearised form, which has no extension) a
    logarithmic speed law gained 1.7 % at p 3.5e-6 and was named, tied with time drift,
    inertia and pressure friction: it took up the lag's misfit at each window's start. The
    misfit test now gives such a lag the relaxation from the measured state at its anchors as
    its extension, the speed law does not keep its gain with it in, and nothing is claimed
    after the lag (the delay 1.03 of the truth; it was 1.14)."""
    d, truth = _run("HDT", ig.TorqueDynamics(form="delay", delay_s=(0.002, 0.004)), seed=2, n=300)
    assert _claims(d) == [["channel_delay"]]
    misfit = d.details["form_misfit"]
    assert misfit and misfit[0]["effect"] == "channel_delay"
    assert d.effects[0].parameters["tau_ms"]["value"] == pytest.approx(1000 * float(np.mean(truth.column("delay_s").to_numpy())), rel=0.1)


def _speed_elasticity(p: dict[str, Any], t: pa.Table) -> float:
    """The true d ln(T - T_p) / d ln v at the loop's reference speed (the quantity both of its
    speed laws estimate; the bench's truth, benches/diagnose_confusion.py)."""
    v = float(p["reference_speed_rpm"])
    col = {c: t.column(c).to_numpy(zero_copy_only=False).astype(float) for c in ("speed_coeff", "pitch_mm", "d2_mm", "dkm_mm", "mu_th", "mu_b")}
    fr0 = 0.58 * col["d2_mm"] * col["mu_th"] + 0.5 * col["dkm_mm"] * col["mu_b"]
    c = col["speed_coeff"]
    if t.column("speed_friction_form")[0].as_py() == "log":
        v0 = t.column("speed_v0_rpm").to_numpy(zero_copy_only=False).astype(float)
        m, vdm = 1 + c * np.log1p(v / v0), c * v / (v + v0)
    else:
        vr = t.column("speed_v_ref_rpm").to_numpy(zero_copy_only=False).astype(float)
        m, vdm = 1 + c * v / vr, c * v / vr
    return float(np.mean(fr0 * vdm / (0.16 * col["pitch_mm"] + fr0 * m)))


@pytest.mark.parametrize(
    "strategy,effect,identifiable",
    [
        ("mix", ig.SpeedFriction(form="log", coeff=(0.08, 0.15)), True),
        ("CSDT", ig.SpeedFriction(form="linear", coeff=(0.08, 0.15)), True),
        ("CSDT", ig.Inertia(inertia_kgm2=(2e-4, 4e-4)), True),
        ("HDT", ig.Inertia(inertia_kgm2=(2e-4, 4e-4)), False),
    ],
    ids=["speed-log-mix", "speed-linear-CSDT", "inertia-CSDT", "inertia-HDT"],
)
def test_parameter_recovery_within_15_percent_or_not_identifiable(strategy: str, effect: Any, identifiable: bool) -> None:
    """Issue 12, item 3 (reduced; the table is the bench's): the speed coefficient (as the
    elasticity at the reported reference speed) and the inertia within 15 % of the truth, each
    with a standard error of the out-of-sample protocol (delete-a-fold jackknife); under a
    hold-down program the inertia is named but reported as not identifiable, with the range
    of its estimates, because its value depends on how the acceleration is estimated."""
    d, truth = _run(strategy, effect)
    first = next(e for e in d.effects if e.level == "within_tightening")
    assert first.names == ["inertia" if isinstance(effect, ig.Inertia) else "speed_dependent_friction"]
    p = first.parameters
    if isinstance(effect, ig.Inertia):
        key, true = "J_kg_m2", float(np.mean(truth.column("inertia_kgm2").to_numpy()))
    else:
        key = "a_eff" if "a_eff" in p else "b_eff"
        true = _speed_elasticity(p, truth)
    assert p[key]["se_folds"] > 0
    assert p["identifiable"] is identifiable
    if identifiable:
        assert p[key]["value"] == pytest.approx(true, rel=0.15)
        assert abs(p[key]["value"] - true) < 6 * p[key]["se_folds"] + 0.05 * true
    else:
        assert "not identifiable" in p["note_identifiability"]
        lo, hi = p[key]["range_over_speed_estimates"]
        assert hi / lo > 1.15
    json.dumps(d.to_dict(), allow_nan=False)


def test_stribeck_friction_no_single_law_fits_is_named_in_its_own_form() -> None:
    """Issue 12, item 1: small Stribeck friction under CSDT (the bench's set, seed 2) that the
    logarithmic law fits 8 % better pooled but in no consistent share of the tightenings (p 0.5)
    and the linear law not at all: nothing was named although the declared model's RMSE is three
    times the noise. The speed law's other forms are tried then, at alpha over the round's
    candidates and every shape tried, and the Stribeck form is named, alone, nothing after it."""
    d, _ = _run("CSDT", ig.SpeedFriction(form="stribeck", coeff=(0.02, 0.05)), seed=2, n=300)
    claims = _claims(d)
    assert claims == [["speed_dependent_friction"]]
    first = next(e for e in d.effects if e.level == "within_tightening")
    assert first.parameters["form"] == "stribeck"
    entered = first.evidence["entered_in_another_form"]
    assert entered["gain"]["p_value"] < entered["bonferroni_alpha"] < 0.01 / entered["shapes_tried"]
    assert d.rmse_after < 0.45 * d.rmse_before


def test_small_inertia_under_a_hold_down_program_is_reported_not_identifiable() -> None:
    """Issue 12, item 3: a small inertia under a hold-down program (the bench's HDT small set,
    seed 2) comes out at 0.84 of the truth while the smoothed and the raw speed channel agree to
    5 %; what gives it away is its dependence on the channels' relative timing: with the
    acceleration half a sample later J falls to 0.83 of the estimate. It must be reported as not
    identifiable, with that range, rather than as a value within 15 %."""
    d, truth = _run("HDT", ig.Inertia(inertia_kgm2=(5e-5, 1e-4)), seed=2, n=300)
    first = next(e for e in d.effects if e.level == "within_tightening")
    assert first.names == ["inertia"]
    p = first.parameters
    true = float(np.mean(truth.column("inertia_kgm2").to_numpy()))
    assert abs(p["J_kg_m2"]["value"] / true - 1.0) > 0.15  # the estimate is off: hence the flag
    lo_s, hi_s = p["J_kg_m2"]["range_over_speed_estimates"]
    assert hi_s / lo_s < 1.15  # the speed-channel check alone does not see it
    assert p["identifiable"] is False
    assert "half a sample" in p["note_identifiability"]
    lo, hi = p["J_kg_m2"]["range_over_acceleration_alignment"]
    assert hi / lo > 1.15
    json.dumps(d.to_dict(), allow_nan=False)


@pytest.mark.parametrize(
    "effects,names",
    [
        ((ig.TorqueDynamics(form="lowpass1", tau_s=(0.003, 0.006)), ig.SpeedFriction(form="linear", coeff=(0.08, 0.15))), {"channel_delay", "speed_dependent_friction"}),
        ((ig.TorqueRipple(orders=(1,), amplitude_fraction=(0.02, 0.03)), ig.PressureFriction(form="linear", kappa=(0.15, 0.3))), {"runout", "pressure_dependent_friction"}),
    ],
    ids=["lowpass+speed", "ripple+pressure"],
)
def test_two_effects_at_once_are_both_named_and_nothing_else(effects: Any, names: set[str]) -> None:
    """Issue 12, item 3: two undeclared effects in one set are both named, alone, in either
    order, and no third is claimed. A channel lag and friction rising with speed cancel where
    both act, so neither gains alone (before: nothing named, RMSE 5.8x the noise sd); they
    are found as a pair."""
    curves, _ = ig.generate(ig.GeneratorConfig(n=N, seed=3, strategy="mix", clamp_force=True, effects=effects))
    d = tightscan.diagnose(_hidden(curves))
    claims = _claims(d)
    assert len(claims) == 2 and {c[0] for c in claims} == names and all(len(c) == 1 for c in claims), claims
