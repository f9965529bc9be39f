"""End-to-end size and power of the decision rule on the simulator. The detectors' own size
and power tests against theory, Monte Carlo and R are Rust tests next to their code
(crates/tightscan-core/src/{breakpoint,cusum,detect,monitor,critical_values,kde,shewhart,
sequence}.rs)."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

import tightscan


def _flag(results: pa.Table, name: str) -> np.ndarray:
    return np.array([bool(x) for x in results.column(name).to_pylist()])


@pytest.fixture(scope="module")
def clean() -> pa.Table:
    """In-control tightenings of all strategies, a seed the calibration never saw."""
    curves, _ = tightscan.simulate(6000, seed=31, fault_fraction=0.0)
    return curves


@pytest.mark.parametrize("alpha", [0.05, 0.01, 0.005])
def test_decision_rule_holds_its_false_alarm_rate(clean: pa.Table, alpha: float) -> None:
    """The union bound holds the rule at or below alpha (no calibration to this simulator, so it
    is conservative here where the two detectors overlap), also in the tail where encoder steps
    mimic small breaks; and it is not dead. Measured at this seed: 3.10 % at 0.05, 0.97 % at 0.01,
    0.53 % at 0.005 (2.53 / 0.68 / 0.43 % when this test was written). The calibration to this simulator that was dropped gave 4.8 % and 1.08 %
    here, and 1.4-2.1 % on the independent generator; with the encoder-step check at 1.0 step
    instead of 1.5 the bound broke in the tail (1.3 % at 0.01)."""
    results = tightscan.detect_batch(clean, config={"alpha": alpha})
    rate = _flag(results, "change_detected").mean()
    sd = np.sqrt(alpha * (1 - alpha) / clean.num_rows)
    assert 0.4 * alpha <= rate <= alpha + 2 * sd, rate


def test_rule_keeps_every_strategy_near_alpha(clean: pa.Table) -> None:
    results = tightscan.detect_batch(clean, passthrough=["strategy"])
    strategy = np.array(results.column("strategy").to_pylist())
    detected = _flag(results, "change_detected")
    for s in ("CST", "CSDT", "HDT"):
        assert detected[strategy == s].mean() < 0.02, s


def test_other_rules_are_conservative(clean: pa.Table) -> None:
    """The union bound (any) and a subset of it (2-of-n) stay at or below alpha."""
    for config in ({"detectors": ["break"], "alpha": 0.05}, {"rule": "2-of-n", "alpha": 0.05}):
        rate = _flag(tightscan.detect_batch(clean, config=config), "change_detected").mean()
        assert rate <= 0.05 + 0.01, (config, rate)


def test_a_late_large_rise_is_found_by_the_end_test() -> None:
    """A friction rise of 25-45 % late in the elastic zone sends the torque past the target at
    once: the change is in the last one to three samples. The end test (the break detector's
    `break_tail_fraction` of alpha) finds those; the scan alone, which needs ten samples after a
    break and never sees the trimmed end of the window, does not. Measured at this seed: 397
    such curves, all found; 0.8 % without the end test."""
    curves, truth = tightscan.simulate(
        3000, seed=34, fault_fraction=1.0, fault_kinds=["abrupt"], magnitude_range=(0.25, 0.45),
        onset_fraction_range=(0.75, 0.85),
    )
    magnitude = np.asarray(truth.column("magnitude").to_numpy(zero_copy_only=False), dtype=float)
    n = np.asarray(truth.column("n_samples").to_numpy(zero_copy_only=False), dtype=float)
    onset = np.array([np.nan if v is None else v for v in truth.column("onset_index").to_pylist()], dtype=float)
    late = (magnitude > 0) & (n - onset <= 3)
    assert late.sum() > 200
    with_end_test = tightscan.detect_batch(curves)
    found = _flag(with_end_test, "change_detected")[late]
    assert found.mean() > 0.98
    tail_p = np.array(with_end_test.column("break_tail_p_value").to_pylist(), dtype=float)[late]
    assert np.median(tail_p) < 1e-6
    without = _flag(tightscan.detect_batch(curves, config={"break_tail_fraction": 0.0}), "change_detected")[late]
    assert without.mean() < 0.2


def _clean_with_white_noise(n: int, seed: int, strategy: str, rate: float, encoder: float, t4: bool = False) -> list[bool]:
    """The decisions on `n` clean built-in curves, noise-free, with white noise of 0.2 % of the
    target added here (`t4`: Student t with 4 degrees of freedom, scaled to that sd)."""
    curves, _ = tightscan.simulate(
        n, seed=seed, fault_fraction=0.0, strategies=[strategy], torque_noise=0.0, sample_rate_hz=rate,
        angle_resolution_deg=encoder,
    )
    rng = np.random.default_rng(seed)
    draw = (lambda k: rng.standard_t(4, size=k) / np.sqrt(2.0)) if t4 else (lambda k: rng.normal(size=k))
    noisy = [
        np.asarray(t, dtype=float) + 0.002 * target * draw(len(t))
        for t, target in zip(curves["torque"].to_pylist(), curves["target_torque"].to_pylist())
    ]
    curves = curves.set_column(curves.column_names.index("torque"), "torque", pa.array(noisy, pa.list_(pa.float64())))
    return [bool(v) for v in tightscan.detect_batch(curves)["change_detected"].to_pylist() if v is not None]


def test_a_coarse_encoder_on_a_slowing_tool_is_not_a_change() -> None:
    """HDT at 2 kHz with a 0.5 deg encoder: the tool slows through one encoder step a sample in
    the elastic window, where the staircase's beat turns. Interpolated by straight lines between
    its knots, the turn came out up to a third of a step low for tens of samples, a jump under
    one encoder step that the scan found far beyond its critical value: 45 false alarms in these
    600 clean curves (7.5 %; 9.2 % at the next seed). With a quadratic through the knots about
    the turn, 7 (1.17 %); 4 since the encoder-step check credits such breaks at three times the
    critical value."""
    decided = _clean_with_white_noise(600, 5101, "HDT", 2000.0, 0.5)
    assert len(decided) >= 590
    assert sum(decided) / len(decided) <= 0.015


def test_a_slow_encoder_across_a_pause_is_not_a_change() -> None:
    """CSDT at 10 kHz with a 0.5 deg encoder (a step every 20-40 samples): the tool turns on for
    tens of samples after its last encoder step before the pause, and a line from that step to
    the first after the pause took those samples for standstill, the run before the pause up to a
    step behind the run after it: 103 false alarms in these 800 clean curves (12.9 %; 17.8 % of
    400 at the next seed). Each side interpolated from its own steps: 3 (0.38 %); 1 since the
    encoder-step check credits breaks within it at three times the critical value."""
    decided = _clean_with_white_noise(800, 5201, "CSDT", 10000.0, 0.5)
    assert len(decided) >= 790
    assert sum(decided) / len(decided) <= 0.015


def test_an_encoder_offset_under_a_step_is_not_a_change() -> None:
    """CST at 2 kHz with a 0.5 deg encoder: the noise (0.2 % of the target) is small against an
    encoder step, and what the interpolated staircase leaves (an offset of a fraction of a step
    between two stretches) makes breaks of 0.1-0.8 steps that the scan finds at 2-4 times its
    critical value. Credited at twice the critical value: 27 false alarms in these 1,200 clean
    curves (2.25 %). Now a break within the encoder-step check needs three times the critical
    value, or twice with the change of slope alone significant: 12 (1.00 %)."""
    decided = _clean_with_white_noise(1200, 5301, "CST", 2000.0, 0.5)
    assert len(decided) >= 1190
    assert sum(decided) / len(decided) <= 0.015


def test_a_tool_turning_just_under_a_whole_number_of_encoder_steps_is_not_a_change() -> None:
    """CST at 2 kHz with a 0.1 deg encoder, the final speed 98.9-99.5 rpm (independent generator,
    white noise): 2.97-2.99 encoder steps a sample, so the angle steps by 3 counts and now and
    then by 2, never by one. The encoder's grid was taken as the smallest step or nothing, and
    3 counts is no multiple of 2: no grid, so the angle's slow quantisation beat (a count every
    50-100 samples) stayed in the scan's regressor and its encoder-step check was off. 43 false
    alarms in these 600 clean curves (7.2 %; 8.7 % at the next seed). With the steps' common
    divisor as the grid (physics/torque_rate.rs, encoder_resolution): 3 (0.5 %)."""
    import independent_generator as ig

    config = ig.GeneratorConfig(
        n=600, seed=5401, strategy="CST", sample_rate_hz=2000.0, encoder_step_deg=0.1, process=ig.ProcessConfig(final_rpm=(98.9, 99.5))
    )
    curves, _ = ig.generate(config)
    decided = [bool(v) for v in tightscan.detect_batch(curves)["change_detected"].to_pylist() if v is not None]
    assert len(decided) >= 590
    assert sum(decided) / len(decided) <= 0.015


def test_a_fine_encoder_on_a_slow_channel_leaves_the_break_scan_its_power() -> None:
    """CST at 500 Hz with a 0.01 deg encoder (independent generator): the tool turns about 170
    counts a sample, and steps of 170 and 171 counts are within 1 % of each other, so the
    encoder's grid came out as a whole sample's advance (1.7 deg) instead of the count. The
    break scan's encoder-step check then asked every break for a jump of 1.5 samples' worth of
    torque rise, and only breaks far above the critical value passed: abrupt 3-6 % changes were
    found in 51 % of these curves (break scan alone). With the count found from how consecutive
    steps differ (physics/torque_rate.rs, finer_count): 83 %. The clean curves of the same
    setting had no false alarm at all before (the default rule, 1,200 curves: 0.00 %; 0.25 %
    after)."""
    import independent_generator as ig

    config = ig.GeneratorConfig(
        n=300, seed=5601, strategy="CST", sample_rate_hz=500.0, encoder_step_deg=0.01,
        fault=ig.FaultConfig(kind="abrupt", magnitude=(0.03, 0.06), onset_fraction=(0.3, 0.6)),
    )
    curves, _ = ig.generate(config)
    results = tightscan.detect_batch(curves, config={"detectors": ["break"]})
    ok = [s == "ok" for s in results["status"].to_pylist()]
    found = [bool(v) for v, k in zip(results["break_alarm"].to_pylist(), ok) if k]
    assert len(found) >= 180
    assert sum(found) / len(found) >= 0.75


def test_heavy_tails_of_a_slow_channel_s_short_windows_are_made_gaussian() -> None:
    """HDT at 500 Hz with a 0.1 deg encoder, t4 noise (built-in simulator): the elastic windows
    hold 21-37 samples, and the Student t fit that makes heavy tails Gaussian before the F tests
    needed 30 whitened samples in the window's front alone, so it never ran there. A t4 spike
    among a window's first samples then passed the start test as a change (p 1e-4 to 1e-20 on a
    straight noise-free line): 22 false alarms in these 876 decided curves (2.5 %). With the
    rundown's residuals counted towards the fit's sample size (the window's front needs 10 of
    its own for its scale): 14 (1.6 %). With the noise-growth fit no longer reading the window's
    bend in time as growing noise (test_a_slow_hdt_channel_s_bend_in_time_is_no_growing_noise):
    9 (1.0 %)."""
    decided = _clean_with_white_noise(1000, 5555, "HDT", 500.0, 0.1, t4=True)
    assert len(decided) >= 850
    assert sum(decided) / len(decided) <= 0.015


def test_a_slow_hdt_channel_s_bend_in_time_is_no_growing_noise() -> None:
    """HDT at 500 Hz (independent generator, 0.01 deg encoder, a constant 0.15 Nm of white
    noise): the elastic rise takes 20-40 samples, and in time it bends hard (the advance falls
    from 6 to 2 deg a sample within ten). The noise-growth fit read each 8-sample block's
    variance about its own line, so the bend passed for noise growing with the torque; the
    weights built on that growth inflated the window's first samples, and the start test
    claimed changes there. About a quadratic through 10 samples the bend stays out of the
    variances. Old: start test at p <= 0.0075 in 34 of 654 decided curves (5.2 %), rule
    15 false alarms (2.3 %); new: 12 (1.8 %) and 5 (0.8 %). The start test's p-values are
    still a little small there (0.75 % expected at 0.0075)."""
    import independent_generator as ig

    config = ig.GeneratorConfig(
        n=1000, seed=11, strategy="HDT", sample_rate_hz=500.0, encoder_step_deg=0.01, noise=ig.NoiseConfig(sd_nm=0.15, sd_rel=0.0)
    )
    curves, _ = ig.generate(config)
    results = tightscan.detect_batch(curves).to_pandas()
    decided = results[results["change_detected"].notna()]
    assert len(decided) >= 600
    assert (decided["break_head_p_value"] <= 0.0075).mean() <= 0.025
    assert decided["change_detected"].astype(bool).mean() <= 0.015


def test_a_coarse_encoder_s_error_is_weighed_with_the_growing_noise() -> None:
    """HDT at 2 kHz read through a 0.5 deg encoder (independent generator, its noise growing with
    the torque): at the window's start the tool turns about three counts a sample, so the
    angle's quantisation error (about 0.1 Nm of torque) is far above the torque noise there
    (0.03-0.07 Nm). The noise-growth fit sees the torque only; its weights gave those first
    samples the weight of their small torque noise alone, and the start test claimed them at
    p 1e-6 to 1e-13. With the angle's error in the weights: these 1,000 clean curves (the
    whole size grid's seed for the cell) 1.40 % false alarms with the noise-growth fit's lines
    in time, 3.20 % with its quadratics and weights of the torque noise alone, 0.70 % now."""
    import independent_generator as ig

    config = ig.GeneratorConfig(
        n=1000, seed=1115, strategy="HDT", sample_rate_hz=2000.0, encoder_step_deg=0.5, noise=ig.NoiseConfig(colour="white")
    )
    curves, _ = ig.generate(config)
    results = tightscan.detect_batch(curves).to_pandas()
    decided = results[results["change_detected"].notna()]
    assert len(decided) >= 950
    assert (decided["break_head_p_value"] <= 1e-5).mean() <= 0.005
    assert decided["change_detected"].astype(bool).mean() <= 0.015


def test_a_slow_channel_s_braked_last_sample_is_not_a_change() -> None:
    """CST at 500 Hz with a 0.1 deg encoder under AR(1) 0.85 (independent generator): the tool
    turns 7-24 encoder steps a sample and brakes within the peak's sample, whose torque then
    lies under the line by the torque rate times a fraction of a sample's advance (0.55 Nm, a
    whole 0.5 deg step, on a curve's true angle). Whitening makes that one sample very
    significant for the end test. Two things now keep it from claiming a change: a braked
    sample past the window is the centre of its encoder cell, not a step ahead of the shaft;
    and the end test credits a deviation only beyond one and a half times the stop's own scale
    (the larger of an encoder step and half a sample's advance). 16 false alarms in these 616
    decided curves before (2.6 %); 20 (3.2 %) with the encoder's grid found but neither
    change; 8 (1.3 %) with both."""
    import independent_generator as ig

    config = ig.GeneratorConfig(
        n=1000, seed=5501, strategy="CST", sample_rate_hz=500.0, encoder_step_deg=0.1, noise=ig.NoiseConfig(colour="ar1", phi=0.85)
    )
    curves, _ = ig.generate(config)
    decided = [bool(v) for v in tightscan.detect_batch(curves)["change_detected"].to_pylist() if v is not None]
    assert len(decided) >= 600
    assert sum(decided) / len(decided) <= 0.015


def test_a_pause_on_a_slow_channel_is_left_out() -> None:
    """CSDT at 500 Hz with a 0.5 deg encoder (independent generator, white noise): a count lasts
    a few samples, the pause 12-80. A stop was a run of unchanged angle ten times the window's
    mean run, and most pauses stayed in the window, where the torque's relaxation and wind-up
    made breaks: 38 false alarms in 974 decided (3.9 %). At six times the mean run (the pause
    left out, and 83 windows too short after it): 10 of 891 (1.1 %); 9 since the encoder-step
    check's change."""
    import independent_generator as ig

    config = ig.GeneratorConfig(
        n=1200, seed=2100, strategy="CSDT", sample_rate_hz=500.0, encoder_step_deg=0.5,
        noise=ig.NoiseConfig(colour="white", phi=0.0),
    )
    curves, _ = ig.generate(config)
    decided = [v for v in tightscan.detect_batch(curves)["change_detected"].to_pylist() if v is not None]
    assert len(decided) >= 850
    assert sum(decided) / len(decided) <= 0.015


def test_response_table_rule(clean: pa.Table) -> None:
    """A table of detector responses: rows match on the detectors they name; the table's
    alarms are exactly the rows' patterns applied to `detectors_fired`, and stay within alpha."""
    config = {
        "alpha": 0.05,
        "detectors": ["break", "cusum", "l1"],
        "rule": [{"break": True, "l1": False}, {"cusum": True, "l1": True}],
    }
    curves, _ = tightscan.simulate(2000, seed=36, fault_fraction=0.5)
    for table in (clean, curves):
        out = tightscan.detect_batch(table, config=config)
        fired = [set(f.split(",")) if f else set() for f in out.column("detectors_fired").to_pylist()]
        expected = np.array([("break" in f and "l1" not in f) or ("cusum" in f and "l1" in f) for f in fired])
        assert (_flag(out, "change_detected") == expected).all()
    rate = _flag(tightscan.detect_batch(clean, config=config), "change_detected").mean()
    assert rate <= 0.05 + 3 * np.sqrt(0.05 * 0.95 / clean.num_rows), rate
    # The dataclass form gives the same configuration.
    dc = tightscan.DetectConfig(
        decision=tightscan.DecisionConfig(alpha=0.05, detectors=("break", "cusum", "l1"), rule=tuple(config["rule"]))  # type: ignore[arg-type]
    )
    assert dc.to_dict()["rule"] == config["rule"]


@pytest.mark.parametrize(
    "rule",
    [[], [{"l1": False}], [{"kde": True}], [{"brake": True}], [{"break": "yes"}], "3-of-n", "most"],
)
def test_bad_rules_are_named(rule: object) -> None:
    with pytest.raises(tightscan.InvalidParameterError) as err:
        tightscan.detect_batch(tightscan.simulate(3, seed=1)[0], config={"rule": rule})
    assert err.value.parameter == "rule"


def test_power_onset_and_the_baseline() -> None:
    """Faults of 3-45 % anywhere in the elastic zone, all kinds, all strategies."""
    curves, truth = tightscan.simulate(3000, seed=32, fault_fraction=1.0, magnitude_range=(0.03, 0.45))
    results = tightscan.detect_batch(curves)
    detected = _flag(results, "change_detected")
    magnitude = np.abs(np.asarray(truth.column("magnitude").to_numpy(zero_copy_only=False), dtype=float))
    # Measured at this seed: 0.998 below 15 %, 0.9995 from 15 % (0.984 before the end test);
    # 0.988 / 0.994 after pre-whitening; 0.977 / 0.992 once the tests averaged over the AR
    # fit's uncertainty (faulty curves whose window gets an AR model pay for its error);
    # 0.972 / 0.990 once the noise model's window stretch is cut at a CSDT pause (which took
    # AR(1) 0.85-0.9 CSDT false alarms from 2.7-3.3 % to 1.8-2.0 %; 16 of the 22 misses from
    # 15 % on are intermittent faults); 0.977 / 0.990 with long windows' noise fitted on the
    # rundown. The goals of issue 4 are 0.88 and 0.99.
    assert detected[magnitude < 0.15].mean() > 0.965
    assert detected[magnitude >= 0.15].mean() > 0.985
    kind = np.array(truth.column("fault_kind").to_pylist())
    onset = np.asarray(truth.column("onset_angle").to_numpy(zero_copy_only=False), dtype=float)
    angle = np.asarray(results.column("change_angle").to_numpy(zero_copy_only=False), dtype=float)
    abrupt = detected & (kind == "abrupt")
    # The break scan places an abrupt change to a sample: median 0.05 deg measured.
    assert np.median(np.abs(angle - onset)[abrupt]) < 0.5
    # The classical 3-sigma chart on the same residuals alarms on about half of the clean curves.
    clean, _ = tightscan.simulate(1000, seed=33, fault_fraction=0.0)
    shewhart = _flag(tightscan.detect_batch(clean), "shewhart_alarm").mean()
    assert shewhart > 0.3


@pytest.mark.parametrize("strategy", ["CST", "CSDT", "HDT"])
def test_kernel_density_test_holds_its_rate_on_every_strategy(strategy: str) -> None:
    """kde=True at its default alpha (0.01 outside the rule) on clean curves of one strategy.
    Measured 0.2-0.6 %. When its residuals came from a line fitted through the CSDT pause, it
    alarmed on half of the clean CSDT curves."""
    curves, _ = tightscan.simulate(1000, seed=35, fault_fraction=0.0, strategies=[strategy])
    rate = _flag(tightscan.detect_batch(curves, config={"kde": True}), "kde_alarm").mean()
    assert rate < 0.025, rate
