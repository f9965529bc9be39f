"""The independent tightening-curve generator (tests/independent_generator) checked against
its own physics, and used black-box on tightscan's public functions."""

from __future__ import annotations

import collections
import dataclasses
import math
from typing import Any, Literal

import numpy as np
import pyarrow as pa
import pytest
from numpy.typing import NDArray

import independent_generator as ig
import tightscan
from independent_generator.config import (
    FaultConfig,
    GeneratorConfig,
    Inertia,
    NoiseConfig,
    SpeedFriction,
    TorqueDynamics,
    TorqueRipple,
)
from independent_generator.effects import TorqueChannel

Arr = NDArray[np.float64]
QUIET = NoiseConfig(sd_nm=0.002, sd_rel=0.0)


def channels(curves: pa.Table, i: int) -> dict[str, Arr]:
    out = {}
    for name in ("angle", "torque", "time", "speed", "clamp_force"):
        if name in curves.column_names:
            out[name] = np.asarray(curves.column(name)[i].values.to_numpy(zero_copy_only=False), dtype=float)
    return out


def truth_row(truth: pa.Table, i: int) -> dict[str, Any]:
    return {name: truth.column(name)[i].as_py() for name in truth.column_names}


def elastic(curves: pa.Table, truth: pa.Table, i: int, lo: float = 0.1, hi: float = 0.9,
            start: float | None = None, end: float | None = None) -> tuple[Arr, Arr, Arr]:
    """Angle, torque and clamp force (or empty) of the fraction [lo, hi] of the true elastic
    window (or of [start, end]), before the tool releases."""
    c, t = channels(curves, i), truth_row(truth, i)
    ws = t["window_start_angle"] if start is None else start
    we = t["window_end_angle"] if end is None else end
    a0, a1 = ws + lo * (we - ws), ws + hi * (we - ws)
    sel = (c["angle"] >= a0) & (c["angle"] <= a1) & (c["time"] < (t["release_time"] or math.inf))
    force = c["clamp_force"][sel] if "clamp_force" in c else np.zeros(0)
    return c["angle"][sel], c["torque"][sel], force


def slope(x: Arr, y: Arr) -> float:
    return float(np.polyfit(x, y, 1)[0])


def friction_term(t: dict[str, Any], mu_th_factor: float = 1.0, mu_b_factor: float = 1.0) -> float:
    return float(ig.torque_factor(t["pitch_mm"], t["d2_mm"], t["dkm_mm"], t["mu_th"] * mu_th_factor,
                                  t["mu_b"] * mu_b_factor))


@pytest.fixture(scope="module")
def clean_mix() -> tuple[pa.Table, pa.Table]:
    return ig.generate(GeneratorConfig(n=100, seed=7))


@pytest.fixture(scope="module")
def rig_set() -> tuple[pa.Table, pa.Table]:
    return ig.generate(ig.rig(n=10, seed=5))


# --- reproducibility ---------------------------------------------------------------------


def _busy(n: int) -> GeneratorConfig:
    return GeneratorConfig(
        n=n, seed=13, effects=(TorqueDynamics("lowpass2"), TorqueRipple("drag", orders=(1, 2)),
                               SpeedFriction("stribeck"), Inertia("transducer")),
        fault=FaultConfig(kind="mix", signed=True), noise=NoiseConfig(colour="ar1", phi=0.5), operators=3,
        clamp_force=True, with_yield_fraction=0.3)


def test_reproducible_by_seed_and_independent_of_n() -> None:
    a = ig.generate(_busy(3))
    b = ig.generate(_busy(3))
    assert a[0].equals(b[0]) and a[1].equals(b[1])
    big_c, big_t = ig.generate(_busy(9))  # tightening i is the same whatever n
    assert a[0].equals(big_c.slice(0, 3)) and a[1].equals(big_t.slice(0, 3))
    other = ig.generate(dataclasses.replace(_busy(3), seed=14))
    assert not a[0].column("torque").equals(other[0].column("torque"))


def test_switching_an_effect_keeps_the_other_draws() -> None:
    _, plain = ig.generate(GeneratorConfig(n=5, seed=3))
    _, rippled = ig.generate(GeneratorConfig(n=5, seed=3, effects=(TorqueRipple(),)))
    for name in ("strategy", "thread", "target_torque", "mu_th", "mu_b", "joint_stiffness", "snug_angle"):
        assert plain.column(name).equals(rippled.column(name)), name


# --- recording ---------------------------------------------------------------------------


@pytest.mark.parametrize(("rate", "step", "strategy"), [(500.0, 0.5, "CSDT"), (2000.0, 0.05, "CST"),
                                                       (10000.0, 0.01, "HDT")])
def test_angle_quantisation_and_sample_spacing(rate: float, step: float,
                                               strategy: Literal["CST", "CSDT", "HDT"]) -> None:
    curves, truth = ig.generate(GeneratorConfig(n=2, seed=2, sample_rate_hz=rate, encoder_step_deg=step,
                                                strategy=strategy))
    assert curves.schema.field("angle").type == pa.list_(pa.float64())
    assert curves.schema.field("tightening_id").type == pa.int64()
    for i in range(2):
        c = channels(curves, i)
        counts = c["angle"] / step
        assert np.max(np.abs(counts - np.rint(counts))) < 1e-6  # floor-quantised to the step
        steps = np.diff(c["angle"])
        assert np.all(steps >= -1e-9)  # no compliance: the encoder never turns back
        assert np.min(steps[steps > 0]) >= step * (1 - 1e-6)
        assert np.allclose(np.diff(c["time"]), 1.0 / rate, rtol=0, atol=1e-9)
        assert len(c["time"]) == truth_row(truth, i)["n_samples"] == len(c["torque"]) == len(c["speed"])


def test_curves_follow_the_data_contract_columns(rig_set: tuple[pa.Table, pa.Table]) -> None:
    curves, truth = rig_set
    assert curves.column_names == ["tightening_id", "angle", "torque", "time", "speed", "clamp_force", "strategy",
                                   "thread", "target_torque", "joint_stiffness"]
    assert truth.num_rows == 10 and truth.column("tightening_id").to_pylist() == list(range(10))
    assert np.allclose(np.asarray(curves.column("joint_stiffness")), np.asarray(truth.column("joint_stiffness")))


# --- noise -------------------------------------------------------------------------------


def _lag1(x: Arr) -> float:
    x = x - x.mean()
    return float(np.dot(x[1:], x[:-1]) / np.dot(x, x))


@pytest.mark.parametrize("phi", [0.0, 0.5, 0.9])
def test_public_ar1_noise_has_the_asked_lag1_and_unit_sd(phi: float) -> None:
    z = ig.unit_noise(np.random.default_rng(5), 20000, "ar1" if phi else "white", phi)
    assert abs(_lag1(z) - phi) < 0.03
    # the sd of an AR(1) mean over n samples is ~ sqrt((1+phi)/(1-phi)/n); tolerance on sd alike
    assert abs(z.std() - 1.0) < (0.03 if phi < 0.9 else 0.08)


def test_t4_noise_is_heavy_tailed_with_unit_sd() -> None:
    z = ig.unit_noise(np.random.default_rng(6), 40000, "t4")
    assert abs(z.std() - 1.0) < 0.05
    kurtosis = float(np.mean(z**4) / np.mean(z**2) ** 2)
    assert kurtosis > 4.5  # normal: 3
    assert abs(_lag1(z)) < 0.03


@pytest.mark.parametrize("noise", [NoiseConfig(sd_nm=0.05, sd_rel=0.0, colour="ar1", phi=0.6),
                                   NoiseConfig(sd_nm=0.01, sd_target_rel=0.002, sd_rel=0.05, colour="ar1", phi=0.3)])
def test_noise_in_the_curves_has_the_asked_sd_and_lag1(noise: NoiseConfig) -> None:
    """Rundown at constant speed: the prevailing torque is smooth, so a local quadratic leaves
    the noise; scaled by the asked sd (sd_nm + sd_target_rel target + sd_rel |torque|) it has
    unit sd and the asked lag-1 autocorrelation."""
    curves, truth = ig.generate(GeneratorConfig(n=12, seed=8, strategy="CST", noise=noise))
    residuals = []
    for i in range(12):
        c, t = channels(curves, i), truth_row(truth, i)
        sel = (c["angle"] > 400.0) & (c["angle"] < t["switch_angle"] - 5.0)
        x, y = c["angle"][sel], c["torque"][sel]
        for lo in range(0, len(x) - 200, 200):
            xs, ys = x[lo:lo + 200], y[lo:lo + 200]
            fit = np.polyval(np.polyfit(xs, ys, 2), xs)
            sd = ig.torque_noise_sd(fit, noise.sd_nm, noise.sd_rel, t["target_torque"], noise.sd_target_rel)
            residuals.append((ys - fit) / sd)
    r = np.concatenate(residuals)
    assert len(r) > 3000
    assert abs(_lag1(r) - noise.phi) < 0.05
    assert abs(r.std() - 1.0) < 0.08


# --- physics -----------------------------------------------------------------------------


@pytest.mark.parametrize("strategy", ["CST", "CSDT", "HDT"])
def test_elastic_slope_is_k_times_the_friction_term(strategy: Literal["CST", "CSDT", "HDT"]) -> None:
    curves, truth = ig.generate(GeneratorConfig(n=15, seed=21, strategy=strategy))
    ratios = []
    for i in range(15):
        t = truth_row(truth, i)
        a, tq, _ = elastic(curves, truth, i)
        assert len(a) >= 20
        expected = t["joint_stiffness"] * friction_term(t)
        assert expected == pytest.approx(t["torque_rate"])
        ratios.append(slope(a, tq) / expected)
    r = np.asarray(ratios)
    assert np.median(np.abs(r - 1)) < 0.01
    assert np.all(np.abs(r - 1) < 0.04)


def test_clamp_force_slope_gives_the_friction_term(rig_set: tuple[pa.Table, pa.Table]) -> None:
    """Rig data: dT/dF over the window = 0.16 P + 0.58 d2 mu_th + Dkm/2 mu_b, F = k (theta - snug)."""
    curves, truth = rig_set
    for i in range(10):
        t = truth_row(truth, i)
        a, tq, f = elastic(curves, truth, i)
        assert slope(f, tq) == pytest.approx(friction_term(t), rel=0.02)
        assert slope(a, f) == pytest.approx(t["joint_stiffness"], rel=0.02)
        # the elastic line meets F = 0 at the snug angle
        p = np.polyfit(a, f, 1)
        assert -p[1] / p[0] == pytest.approx(t["snug_angle"], abs=0.3)


def test_snug_angle_by_the_tangent_method(clean_mix: tuple[pa.Table, pa.Table]) -> None:
    curves, truth = clean_mix
    errors = []
    for i in range(30):
        t = truth_row(truth, i)
        a, tq, _ = elastic(curves, truth, i)
        p = np.polyfit(a, tq, 1)
        errors.append((t["prevailing_torque"] - p[1]) / p[0] - t["snug_angle"])
    # quantisation floors the angle: the line sits up to one step to the left, on average half
    assert np.median(np.abs(errors)) < 0.15
    assert np.max(np.abs(errors)) < 0.6


def test_abrupt_fault_raises_the_slope_by_the_friction_share() -> None:
    m = 0.3
    fault = FaultConfig(kind="abrupt", magnitude=m, onset_fraction=(0.4, 0.5))
    curves, truth = ig.generate(GeneratorConfig(n=10, seed=31, strategy="CST", fault=fault, noise=QUIET))
    for i in range(10):
        t = truth_row(truth, i)
        assert t["faulty"] and t["fault_kind"] == "abrupt" and t["onset_reached"]
        onset, ws, we = t["onset_angle"], t["window_start_angle"], t["window_end_angle"]
        assert ws < onset < we
        a0, t0, _ = elastic(curves, truth, i, 0.1, 0.9, start=ws, end=onset)
        a1, t1, _ = elastic(curves, truth, i, 0.1, 0.9, start=onset, end=we)
        expected = friction_term(t, 1 + m, 1 + m) / friction_term(t)
        assert 1.2 < expected < 1.3  # the lead term 0.16 P does not scale with mu
        assert slope(a1, t1) / slope(a0, t0) == pytest.approx(expected, rel=0.03)
        # and the torque steps up at the onset by F(onset) times the change of the friction term
        c = channels(curves, i)
        before = np.polyval(np.polyfit(a0, t0, 1), onset)
        after = np.polyval(np.polyfit(a1, t1, 1), onset)
        force = t["joint_stiffness"] * (onset - t["snug_angle"])
        assert after - before == pytest.approx(force * (friction_term(t, 1 + m, 1 + m) - friction_term(t)), rel=0.05)
        assert c["torque"].max() >= t["target_torque"]


def test_incipient_and_intermittent_faults() -> None:
    inc = FaultConfig(kind="incipient", magnitude=0.4, onset_fraction=0.3)
    curves, truth = ig.generate(GeneratorConfig(n=6, seed=32, strategy="CST", fault=inc, noise=QUIET))
    for i in range(6):
        t = truth_row(truth, i)
        a, tq, _ = elastic(curves, truth, i, 0.05, 0.95, start=t["onset_angle"])
        assert np.polyfit(a, tq, 2)[0] > 0  # a drift of friction: the curve bends upwards
    inter = FaultConfig(kind="intermittent", magnitude=0.4, onset_fraction=0.2, episodes=(2, 2),
                        episode_fraction=0.15)
    curves, truth = ig.generate(GeneratorConfig(n=6, seed=33, strategy="CST", fault=inter, noise=QUIET))
    checked = 0
    for i in range(6):
        t = truth_row(truth, i)
        starts, ends = t["episode_start_angles"], t["episode_end_angles"]
        assert len(starts) == len(ends) == 2 and starts[0] == pytest.approx(t["onset_angle"], abs=1e-6)
        a, tq, _ = elastic(curves, truth, i, 0.1, 0.9, end=starts[0])
        line = np.polyfit(a, tq, 1)
        c = channels(curves, i)
        inside = (c["angle"] > starts[0] + 0.5) & (c["angle"] < ends[0] - 0.5) & (c["torque"] < t["target_torque"])
        if inside.sum() >= 3:
            assert np.all(c["torque"][inside] > np.polyval(line, c["angle"][inside]))
            checked += 1
    assert checked >= 4


def test_yield_lowers_the_gradient() -> None:
    curves, truth = ig.generate(GeneratorConfig(n=6, seed=34, strategy="CST", with_yield_fraction=1.0, noise=QUIET))
    for i in range(6):
        t = truth_row(truth, i)
        assert t["yields"] and t["yield_angle"] == pytest.approx(t["window_end_angle"])
        a0, t0, _ = elastic(curves, truth, i)
        c = channels(curves, i)
        # past the transition (3 of its angles) the gradient is at most r + e^-3 (r <= 0.25)
        sel = (c["angle"] > t["yield_angle"] + 3 * t["yield_transition_deg"]) & (c["angle"] < t["stop_angle"])
        sel &= c["time"] < t["stop_time"]
        assert sel.sum() >= 10
        assert slope(c["angle"][sel], c["torque"][sel]) < 0.4 * slope(a0, t0)
        assert t["stop_reason"] == "target"


# --- strategies and controller -----------------------------------------------------------


def test_tool_stops_at_the_measured_target_with_a_small_overshoot(clean_mix: tuple[pa.Table, pa.Table]) -> None:
    curves, truth = clean_mix
    assert set(truth.column("stop_reason").to_pylist()) == {"target"}
    assert set(truth.column("strategy").to_pylist()) == {"CST", "CSDT", "HDT"}
    over = np.asarray(truth.column("overshoot_nm")) / np.asarray(truth.column("target_torque"))
    # the controller stops on the noisy measured torque: a hard joint at 200 rpm overshoots most
    assert np.all(over > -0.02) and np.all(over < 0.15) and abs(np.median(over)) < 0.02
    for i in range(10):
        c, t = channels(curves, i), truth_row(truth, i)
        assert c["torque"].max() >= t["target_torque"]
        assert c["speed"][-1] == 0.0 and abs(c["torque"][-1]) < 0.2  # released


def test_csdt_pauses_at_the_pause_torque() -> None:
    curves, truth = ig.generate(GeneratorConfig(n=5, seed=41, strategy="CSDT", noise=QUIET))
    for i in range(5):
        c, t = channels(curves, i), truth_row(truth, i)
        start = t["pause_start_time"]
        assert start is not None and t["pause_torque"] < t["target_torque"]
        stopped = (c["time"] > start + 0.01) & (c["time"] < start + t["pause_s"] - 0.001)
        assert np.all(c["speed"][stopped] == 0.0) and stopped.sum() > 10
        held = c["torque"][stopped]
        assert np.ptp(c["angle"][stopped]) == 0.0
        assert t["pause_torque"] <= held.mean() < t["pause_torque"] + 0.1 * t["target_torque"]


def test_hdt_slows_down_as_the_torque_nears_the_target() -> None:
    curves, truth = ig.generate(GeneratorConfig(n=6, seed=42, strategy="HDT", noise=QUIET))
    for i in range(6):
        c, t = channels(curves, i), truth_row(truth, i)
        rising = c["time"] < t["stop_time"]
        tq, sp = c["torque"][rising], c["speed"][rising]
        half = sp[np.argmax(tq >= 0.5 * t["target_torque"])]
        late = sp[np.argmax(tq >= 0.95 * t["target_torque"])]
        assert late < 0.5 * half
        assert sp.max() == pytest.approx(t["rundown_speed_rpm"], rel=0.01)


# --- effects -----------------------------------------------------------------------------


def test_torque_channel_step_responses() -> None:
    dt = 1e-4
    n = 2000
    ch = TorqueChannel(np.array([1, 2, 3]), np.array([0.01, 0, 0]), np.array([0, 50.0, 0]), np.array([0, 0.3, 0]),
                       np.array([0, 0, 0.0035]), dt)
    out = np.empty((n, 3))
    for j in range(n):
        ch.step(np.ones(3))
        out[j] = ch.output
    assert out[int(round(0.01 / dt)) - 1, 0] == pytest.approx(1 - math.exp(-1), rel=1e-6)
    overshoot = out[:, 1].max() - 1.0
    assert overshoot == pytest.approx(math.exp(-math.pi * 0.3 / math.sqrt(1 - 0.09)), rel=0.02)
    assert out[-1, 1] == pytest.approx(1.0, abs=1e-3)
    assert np.argmax(out[:, 2] > 0.5) == 35


def _tail(curve: dict[str, Arr], t: dict[str, Any]) -> float:
    """Time from the start of the release until the torque stays below 10 % of the target."""
    after = curve["time"] >= t["release_time"]
    high = np.nonzero(after & (curve["torque"] > 0.1 * t["target_torque"]))[0]
    return float(curve["time"][high[-1]] - t["release_time"]) if len(high) else 0.0


def test_lowpass_leaves_a_decaying_tail_after_the_stop() -> None:
    tau = 0.008
    cfg = GeneratorConfig(n=4, seed=51, strategy="CST", noise=QUIET)
    plain_c, plain_t = ig.generate(cfg)
    lp_c, lp_t = ig.generate(GeneratorConfig(n=4, seed=51, strategy="CST", noise=QUIET,
                                             effects=(TorqueDynamics("lowpass1", tau_s=tau),)))
    for i in range(4):
        c, t = channels(lp_c, i), truth_row(lp_t, i)
        assert t["tau_s"] == tau and t["effects"] == "torque_dynamics:lowpass1"
        extra = _tail(c, t) - _tail(channels(plain_c, i), truth_row(plain_t, i))
        assert 1.5 * tau < extra < 3.5 * tau  # ln(10) tau = 2.3 tau
        after = c["time"] >= t["release_time"] + t["release_s"]
        decay = c["torque"][after]
        assert np.all(np.diff(decay[decay > 0.05 * t["target_torque"]]) < 0)  # monotone decay
        assert c["time"][-1] - t["release_time"] > 5 * tau  # recorded long enough to see it


@pytest.mark.parametrize("order", [1, 2])
def test_ripple_has_the_asked_period_amplitude_and_phase(order: int) -> None:
    amp = 0.2
    ripple = TorqueRipple("drag", orders=(order,), amplitude_nm=amp)
    curves, truth = ig.generate(GeneratorConfig(n=4, seed=61, strategy="CST", effects=(ripple,), noise=QUIET))
    for i in range(4):
        c, t = channels(curves, i), truth_row(truth, i)
        assert t["ripple_order"] == str(order) and t["ripple_amplitude_nm"] == amp
        sel = (c["angle"] > 100.0) & (c["angle"] < t["window_start_angle"] - 10.0)
        x, y = c["angle"][sel], c["torque"][sel]
        phi = np.deg2rad(x)
        # smooth prevailing torque (quadratic in angle) + harmonics of the revolution
        basis = [np.ones_like(x), x / 1000.0, (x / 1000.0) ** 2]
        for h in (1, 2, 3):
            basis += [np.sin(h * phi), np.cos(h * phi)]
        coef = np.linalg.lstsq(np.column_stack(basis), y, rcond=None)[0]
        amps = {h: math.hypot(coef[1 + 2 * h], coef[2 + 2 * h]) for h in (1, 2, 3)}
        assert amps[order] == pytest.approx(amp, rel=0.1)  # floor quantisation of the angle
        assert all(amps[h] < 0.1 * amp for h in amps if h != order)
        phase = math.atan2(coef[2 + 2 * order], coef[1 + 2 * order])  # A sin(h phi + p) = A cos p sin + A sin p cos
        assert abs((phase - t["ripple_phase"] + math.pi) % (2 * math.pi) - math.pi) < 0.1


def test_transducer_inertia_adds_j_alpha() -> None:
    j = 3e-4
    cfg = dict(n=3, seed=71, strategy="CST", noise=QUIET)
    plain_c, _ = ig.generate(GeneratorConfig(**cfg))  # type: ignore[arg-type]
    in_c, in_t = ig.generate(GeneratorConfig(**cfg, effects=(Inertia("transducer", inertia_kgm2=j),)))  # type: ignore[arg-type]
    for i in range(3):
        p, c, t = channels(plain_c, i), channels(in_c, i), truth_row(in_t, i)
        # up to the slow-down before head contact both tools move alike; the difference is J alpha
        end = int(np.argmax(c["angle"] > t["switch_angle"] + 15.0))
        start = int(np.argmax(c["angle"] > 200.0))
        assert np.array_equal(p["angle"][:end], c["angle"][:end]) and end - start > 100
        diff = c["torque"][start:end] - p["torque"][start:end]
        alpha = np.gradient(c["speed"][start:end] * 6.0, c["time"][start:end]) * math.pi / 180.0
        assert diff.min() < -0.3  # the slow-down is visible
        assert float(np.dot(diff, alpha) / np.dot(alpha, alpha)) == pytest.approx(j, rel=0.1)


def test_linear_speed_friction_scales_the_elastic_slope() -> None:
    cfg = dict(n=6, seed=81, strategy="CST", noise=QUIET)
    _, plain_t = ig.generate(GeneratorConfig(**cfg))  # type: ignore[arg-type]
    curves, truth = ig.generate(GeneratorConfig(**cfg, effects=(SpeedFriction("linear", coeff=0.1),)))  # type: ignore[arg-type]
    for i in range(6):
        t = truth_row(truth, i)
        assert t["mu_th"] == truth_row(plain_t, i)["mu_th"]
        factor = 1 + 0.1 * t["final_speed_rpm"] / 100.0
        a, tq, _ = elastic(curves, truth, i, 0.3, 0.9)
        expected = t["joint_stiffness"] * friction_term(t, factor, factor)
        assert slope(a, tq) == pytest.approx(expected, rel=0.02)


def test_operators_shift_the_angle_and_share_parameters() -> None:
    curves, truth = ig.generate(GeneratorConfig(n=20, seed=91, operators=3, strategy="CST"))
    ops = truth.column("operator").to_pylist()
    assert curves.column("operator").to_pylist() == ops and set(ops) == {"op0", "op1", "op2"}
    by_op: dict[str, set[tuple[float, float, float]]] = collections.defaultdict(set)
    for i in range(20):
        t = truth_row(truth, i)
        by_op[t["operator"]].add((t["operator_speed_factor"], t["operator_angle_offset_deg"],
                                  t["arm_compliance_deg_per_nm"]))
        assert t["socket_play_deg"] >= 0
        # the encoder counts the socket play: head contact comes that much later
        assert t["contact_angle"] >= t["socket_play_deg"]
        # the housing turns back by compliance x torque: the measured slope is softer
        a, tq, _ = elastic(curves, truth, i)
        bolt_rate = t["torque_rate"]
        assert slope(a, tq) == pytest.approx(1.0 / (1.0 / bolt_rate + t["arm_compliance_deg_per_nm"]), rel=0.03)
    assert all(len(v) == 1 for v in by_op.values())
    assert len({next(iter(v)) for v in by_op.values()}) == 3


def test_presets_and_validation() -> None:
    curves, truth = ig.generate(ig.production(n=3, seed=2, hand_held=True))
    assert curves.column_names[-1] == "operator" and truth.column("effects")[0].as_py().count(",") == 4
    with pytest.raises(ValueError, match="sample_rate_hz"):
        GeneratorConfig(sample_rate_hz=100.0)
    with pytest.raises(ValueError, match="phi"):
        NoiseConfig(colour="ar1", phi=1.0)
    with pytest.raises(ValueError, match="once"):
        GeneratorConfig(effects=(TorqueRipple(), TorqueRipple()))


# --- tightscan, black box ----------------------------------------------------------------


def test_detect_batch_runs_and_mostly_says_ok(clean_mix: tuple[pa.Table, pa.Table]) -> None:
    curves, _ = clean_mix
    results = tightscan.detect_batch(curves)
    assert isinstance(results, pa.Table) and results.num_rows == curves.num_rows
    statuses = collections.Counter(s.split(":")[0] for s in results.column("status").to_pylist())
    assert statuses["ok"] >= 0.9 * curves.num_rows, statuses


def test_diagnose_runs_on_rig_data(rig_set: tuple[pa.Table, pa.Table]) -> None:
    curves, _ = rig_set
    diagnosis = tightscan.diagnose(curves, folds=3)
    assert isinstance(diagnosis.to_dict(), dict)
