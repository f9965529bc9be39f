"""False alarms under coloured torque noise (issue: detection that holds on data we did not
generate). A transducer's anti-aliasing filter makes the noise autocorrelated; the detectors
test the window pre-whitened with an AR model of its noise, fitted to local residuals
(crates/tightscan-core/src/detectors/noise.rs).

The curves are the built-in simulator's, noise-free, with AR(1) noise of the simulator's
default marginal sd (0.2 % of the target torque) added here, so the noise is not the
simulator's own. The rule splits alpha by the union bound (no calibration to any simulator), so
on these curves, where the break scan and the CUSUM overlap, it runs below alpha."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

import tightscan

N_CURVES = 1500


def _with_ar1_noise(phi: float, seed: int) -> pa.Table:
    curves, _ = tightscan.simulate(N_CURVES, seed=seed, fault_fraction=0.0, torque_noise=0.0)
    return _add_ar1_noise(curves, phi, seed)


def _add_ar1_noise(curves: pa.Table, phi: float, seed: int) -> pa.Table:
    """The curves' torque plus AR(1) noise of marginal sd 0.2 % of the target (white at phi 0)."""
    rng = np.random.default_rng(seed)
    noisy = []
    for torque, target in zip(curves["torque"].to_pylist(), curves["target_torque"].to_pylist()):
        t = np.asarray(torque, dtype=float)
        sd = 0.002 * target
        innovations = rng.normal(size=t.size) * sd * np.sqrt(1.0 - phi**2)
        e = np.empty(t.size)
        e[0] = rng.normal() * sd
        for i in range(1, t.size):
            e[i] = phi * e[i - 1] + innovations[i]
        noisy.append(t + e)
    return curves.set_column(curves.column_names.index("torque"), "torque", pa.array(noisy, pa.list_(pa.float64())))


def _false_alarm_rate(results: pa.Table, n: int = N_CURVES) -> float:
    decided = [v for v in results["change_detected"].to_pylist() if v is not None]
    assert len(decided) >= 0.98 * n
    return float(np.mean(decided))


@pytest.mark.slow
def test_size_under_moderately_coloured_noise_is_nominal() -> None:
    # AR(1) with phi = 0.5; before pre-whitening the default rule alarmed on 33 % of these.
    # Binomial sd at 1 % over 1,500 curves is 0.26 points: a nominal rule falls below 0.5 % here
    # with probability 3 %, so the lower edge is 0.4 % (2.3 sd); the cell goal [0.5, 1.5] x
    # alpha is for 4,000 curves. Measured 0.40 % here with the rule calibrated to this
    # simulator, 0.27 % with the plain union bound: conservative, below the cell goal (the
    # tests' averaging over the AR fit's uncertainty makes them so where phi is well
    # determined, and the two detectors overlap). The lower edge only guards a dead rule.
    results = tightscan.detect_batch(_with_ar1_noise(0.5, seed=71))
    assert 0.001 <= _false_alarm_rate(results) <= 0.015
    lag1 = np.nanmedian(np.array(results["noise_lag1"].to_pylist(), dtype=float))
    assert 0.4 <= lag1 <= 0.6


@pytest.mark.slow
def test_size_under_strongly_coloured_noise_is_nominal() -> None:
    # AR(1) with phi = 0.85 (a first-order low-pass of about 50 Hz on a 2 kHz channel). Before
    # pre-whitening the rule alarmed on 86 % of these; 5 % with the AR model fitted to the
    # window and three windows before it (median phi 0.80); 3.4 % with the rundown in the fit,
    # the moments solved exactly and local quadratics (median 0.87); 1.0 % once the break scan
    # and the CUSUM average over the AR fit's uncertainty (NoiseModel::gain_log_se, a grouped
    # jackknife); 0.53 % with the plain union bound instead of the calibration to this simulator;
    # 0.20 % once the CUSUM's blocks regress on the angle averaged in time (its alarms here had
    # been on the encoder staircase's leftover: see
    # test_the_cusum_blocks_under_strong_colour_are_not_flattened_by_the_encoder). Conservative,
    # below the cell goal; the lower edge only guards a dead rule.
    results = tightscan.detect_batch(_with_ar1_noise(0.85, seed=72))
    assert 0.001 <= _false_alarm_rate(results) <= 0.015
    lag1 = np.nanmedian(np.array(results["noise_lag1"].to_pylist(), dtype=float))
    assert 0.82 <= lag1 <= 0.9


@pytest.mark.slow
def test_size_under_noise_growing_with_the_torque_is_bounded() -> None:
    # The independent generator's own transducer noise: 0.01 Nm + 0.4 % of the reading, so the
    # sd at the target is about three times that at the window's start. Tests that assume one
    # variance alarm on the loud end (Chow's end test first): 20 % of these clean CST curves
    # before the detectors weighted the samples by the noise growth they measure
    # (NoiseModel::sd_slope; since the twenty-fourth session the fitted sd line bounded over the
    # window, `window_growth`), 2.1 % after (1.2 % with the same noise made constant in each
    # curve), 1.5 % with the noise model's rundown history, 1.2 % with the plain union bound
    # instead of the calibration to the built-in simulator. The goal is 1.5 x alpha.
    import independent_generator as ig

    curves, _ = ig.generate(ig.GeneratorConfig(n=N_CURVES, seed=73, strategy="CST", encoder_step_deg=0.1))
    results = tightscan.detect_batch(curves)
    assert _false_alarm_rate(results) <= 0.018


@pytest.mark.slow
def test_size_under_heavy_tailed_noise_is_bounded() -> None:
    # Student-t noise with 4 degrees of freedom (a transducer's spikes), on the independent
    # generator's CST curves. The break scan and Chow's end test are F tests whose size holds
    # for Gaussian noise: 8.7 % false alarms before heavy-tailed windows were made Gaussian by
    # normal scores under a fitted t (Scratch::gaussianise_heavy_tails), 5.1 % after (n = 1,000;
    # 5.7 % at this seed and size; 4.0-4.1 % with the noise model's rundown history; 1.2 % once
    # the rule dropped its calibration to the built-in simulator). The goal is 1.5 x alpha.
    import independent_generator as ig

    noise = ig.NoiseConfig(colour="t4")
    curves, _ = ig.generate(
        ig.GeneratorConfig(n=N_CURVES, seed=74, strategy="CST", encoder_step_deg=0.1, noise=noise)
    )
    results = tightscan.detect_batch(curves)
    assert _false_alarm_rate(results) <= 0.018


@pytest.mark.slow
def test_size_under_the_independent_generators_coloured_noise_is_bounded() -> None:
    # The independent generator's transducer noise (0.01 Nm + 0.4 % of the reading) made AR(1)
    # with phi 0.85, CST: 8.3 % false alarms with the AR model fitted to the window and three
    # windows before it (median phi 0.78: too few samples, and a fixed-point bias correction
    # that stopped short), 3.8 % with the rundown's samples, local quadratics over 64-sample
    # blocks and the moment equations solved exactly (median 0.85), 1.4 % once the tests
    # average over the AR fit's uncertainty, 1.0 % with the plain union bound, 0.33 % once the
    # CUSUM's blocks regress on the angle averaged in time (its alarms here had been on the
    # encoder staircase's leftover). The goal is [0.5, 1.5] x alpha: conservative now, and the
    # lower edge only guards a dead rule.
    import independent_generator as ig

    noise = ig.NoiseConfig(colour="ar1", phi=0.85)
    curves, _ = ig.generate(
        ig.GeneratorConfig(n=N_CURVES, seed=75, strategy="CST", encoder_step_deg=0.1, noise=noise)
    )
    results = tightscan.detect_batch(curves)
    assert 0.001 <= _false_alarm_rate(results) <= 0.02
    lag1 = np.nanmedian(np.array(results["noise_lag1"].to_pylist(), dtype=float))
    assert 0.82 <= lag1 <= 0.88


@pytest.mark.slow
def test_size_and_power_at_phi_0_9_on_the_independent_generator() -> None:
    # phi 0.9 (a 35 Hz filter on a 2 kHz channel), CST: 11.8 % false alarms with the plug-in
    # AR fit, 2.1 % with the tests averaged over its uncertainty, 1.5 % with the plain union
    # bound instead of the calibration to the built-in simulator (the goal: 1.5 %). Power is what the averaging costs: abrupt friction changes of
    # 15-45 % were found in 0.875 of the curves at phi 0.85 before it (at 3.3 % false alarms),
    # 0.82 after (n = 200, benches/transfer_check.py), 0.80 with the union bound; where phi is this close to 1 the whitened
    # change is small against the noise left.
    # The averaging treats the statistic as growing with the leftover long-run variance to the
    # measured power kappa (WHITENING_SENSITIVITY), not 1: at these seeds the clean curves alarm
    # at 1.20 % (exponent 1: 0.87 %; kappa also in short windows fitted near the unit root:
    # 4.16 %, which the exception for them exists to stop) and the faulty ones are found in
    # 0.935 (exponent 1: 0.89). With the GLS break scan (its own kappa, floored at 0.5 in short
    # windows fitted near the unit root): clean 1.60 % (floor 1: 1.40 %), faulty 0.97. With the
    # longer blocks under strong colour (STRONG_COLOUR) and the floor at 1: clean 1.67 %,
    # faulty 0.99.
    import independent_generator as ig

    noise = ig.NoiseConfig(colour="ar1", phi=0.9)
    clean, _ = ig.generate(ig.GeneratorConfig(n=N_CURVES, seed=76, strategy="CST", encoder_step_deg=0.1, noise=noise))
    # The AR order the fit needs at phi 0.9 is higher, and with it the fewest samples a window
    # needs: 2 % of these curves get too_short (1,469 of 1,500 decided).
    decided = [v for v in tightscan.detect_batch(clean)["change_detected"].to_pylist() if v is not None]
    assert len(decided) >= 0.95 * N_CURVES
    assert float(np.mean(decided)) <= 0.022
    fault = ig.FaultConfig(kind="abrupt", magnitude=(0.15, 0.45), fraction_faulty=1.0)
    noise85 = ig.NoiseConfig(colour="ar1", phi=0.85)
    faulty, _ = ig.generate(
        ig.GeneratorConfig(n=200, seed=91, strategy="CST", encoder_step_deg=0.1, noise=noise85, fault=fault)
    )
    found = [bool(v) for v in tightscan.detect_batch(faulty)["change_detected"].to_pylist()]
    assert float(np.mean(found)) >= 0.91


def test_small_steps_under_strong_colour_are_found_by_the_gls_scan() -> None:
    # Abrupt friction changes of 3-15 % on the independent generator's CST curves under AR(1)
    # 0.85: the torque step whitens to its full height at the change's first sample and 0.15 of
    # it after, so a scan fitting two lines to the whitened window leaves most of the evidence
    # in its residuals. With the step whitened as the line (the GLS break regression,
    # detectors/gls_breakpoint.rs) 366 of these 400 curves were found (0.915); with two lines
    # 325 (0.8125). With the noise model refitted on longer blocks under strong colour
    # (STRONG_COLOUR in engine/analysis/mod.rs), 386 (0.965): the floor sits under that by
    # about three binomial sd and above the 64-sample noise model's 0.915.
    import independent_generator as ig

    fault = ig.FaultConfig(kind="abrupt", magnitude=(0.03, 0.15), fraction_faulty=1.0)
    noise = ig.NoiseConfig(colour="ar1", phi=0.85)
    faulty, _ = ig.generate(
        ig.GeneratorConfig(n=400, seed=93, strategy="CST", encoder_step_deg=0.1, noise=noise, fault=fault)
    )
    found = [bool(v) for v in tightscan.detect_batch(faulty)["change_detected"].to_pylist()]
    assert float(np.mean(found)) >= 0.94


def test_the_noise_model_pins_strong_colour_with_longer_blocks() -> None:
    # Where the 64-sample blocks' fit says lag-1 0.7 or more, the noise model is refitted on
    # blocks twice as long (engine/analysis/mod.rs, STRONG_COLOUR): a 64-sample quadratic takes
    # out much of strongly coloured noise's slow part, and the bias correction that puts it back
    # spreads the estimate. What the tests' whitening depends on is the log gain ln(1 - phi);
    # its rms error on these 400 clean curves under AR(1) 0.85 is 0.202 with the longer blocks
    # and was 0.289 with the 64-sample fit alone (0.355 against 0.431 at phi 0.9). The bound
    # sits five of its sampling sd (about 0.007) from either.
    import independent_generator as ig

    noise = ig.NoiseConfig(colour="ar1", phi=0.85)
    clean, _ = ig.generate(ig.GeneratorConfig(n=400, seed=81, strategy="CST", encoder_step_deg=0.1, noise=noise))
    lag1 = np.array([v for v in tightscan.detect_batch(clean)["noise_lag1"].to_pylist() if v is not None])
    assert len(lag1) >= 390
    log_gain_error = np.log(1.0 - np.clip(lag1, 0.0, 0.999)) - np.log(1.0 - 0.85)
    assert float(np.sqrt(np.mean(log_gain_error**2))) <= 0.24


@pytest.mark.slow
def test_size_on_a_slow_channel_under_coloured_noise_is_bounded() -> None:
    """500 Hz, AR(1) 0.85 (the independent generator; 0.1 deg encoder, and 0.5 deg for CST): a
    few hundred samples of rundown hold three or four noise blocks, too few for the jackknife of
    the whitening's uncertainty, so it comes from a parametric bootstrap; the rundown's blocks
    begin after the tool's start-up and end before the seating; the end test averages over that
    uncertainty, and a stop sample within an encoder step and a half of the line is no change.

    Before the bootstrap and the seating cut the rule alarmed on 10.9 % of these clean curves.
    Before the start-up cut, the block holding the start-up step (5-7 times the median block's
    variance, lag-1 correlation 0) made phi come out below 0.5 in 6.9 % of these curves, and
    the rule alarmed on 3.05 % of 1,116 decided (CST 0.5 deg 5.5 %: most of its alarms the end
    test's, on stop samples 0.1-2.3 encoder steps from the line). Measured after: 0.71 % of
    1,126 decided, no phi below 0.5 (binomial sd at 1 %: 0.3 points)."""
    import independent_generator as ig

    alarms, decided, lag1 = 0, 0, []
    for strategy, encoder, seed in (("CST", 0.1, 2101), ("HDT", 0.1, 2102), ("CST", 0.5, 2103)):
        config = ig.GeneratorConfig(
            n=600, seed=seed, strategy=strategy, sample_rate_hz=500.0, encoder_step_deg=encoder,
            noise=ig.NoiseConfig(colour="ar1", phi=0.85),
        )
        curves, _ = ig.generate(config)
        results = tightscan.detect_batch(curves)
        flags = [v for v in results["change_detected"].to_pylist() if v is not None]
        lag1 += [v for v in results["noise_lag1"].to_pylist() if v is not None]
        alarms += sum(flags)
        decided += len(flags)
    # A third of the slow channel's curves have too short an elastic window (too_short).
    assert decided >= 1000
    assert sum(v < 0.5 for v in lag1) / len(lag1) <= 0.01
    assert alarms / decided <= 0.015


def test_the_cusum_blocks_under_strong_colour_are_not_flattened_by_the_encoder() -> None:
    """CST, 2 kHz, AR(1) 0.9, 0.1 deg encoder (independent generator). Near the unit root the
    whitened angle regressor is mostly the angle's change from sample to sample, and the
    encoder staircase's leftover after interpolation is such a change: errors in the regressor,
    which only flatten a block's whitened slope. The CUSUM then read their spread between
    blocks as a falling torque rate (2,000 clean curves: 18 CUSUM alarms, all `decrease`; none
    with a 0.01 deg encoder). The CUSUM's blocks now regress on the angle averaged over nine
    samples in time. The training blocks' dispersion (root mean square of their standardised
    slopes, about 1 when the blocks' noise is what the model says) shows it: median 1.27 on
    these 542 decided curves before, 0.905 after (0.91 with a fine encoder)."""
    import statistics

    import independent_generator as ig

    config = ig.GeneratorConfig(
        n=600, seed=2111, strategy="CST", sample_rate_hz=2000.0, encoder_step_deg=0.1,
        noise=ig.NoiseConfig(colour="ar1", phi=0.9),
    )
    curves, _ = ig.generate(config)
    results = tightscan.detect_batch(curves)
    dispersion = [v for v in results["cusum_dispersion"].to_pylist() if v is not None]
    alarms = sum(bool(v) for v in results["cusum_alarm"].to_pylist())
    assert len(dispersion) >= 500
    assert statistics.median(dispersion) <= 1.05
    # The CUSUM's share of the rule's alpha is a quarter of 1 %: 1.4 alarms expected in these
    # curves, and at most 4 (0.74 %) is a 1 % test of it (Poisson: P(>= 5) = 1.2 %). The bound
    # was 0.5 %, which a CUSUM at its nominal share fails on 16 % of seeds; since the weights
    # carry the angle's quantisation error there are 3 alarms here (2 before; median
    # dispersion 0.89 -> 0.83). The dispersion is what tells the old fault (1.27) apart.
    assert alarms <= 4


def test_the_cusum_s_last_block_is_not_steepened_by_the_tool_braking_past_the_window() -> None:
    """CST, 2 kHz, white noise, 0.1 deg encoder (independent generator). The CUSUM's blocks
    regress on the angle averaged in time, and past the tested window the tool brakes up to the
    peak (3-6 samples). An average that reached into those samples pulled the last samples'
    angle back, which steepened the last block's slope: its standardised rate had mean +0.39
    over 600 clean curves (the other blocks' 0.02-0.08), and half the CUSUM's false alarms
    (`increase`, at the window's end) came from it, which the exact thresholds per block count
    made plain (0.38 % of 4,000 clean curves against a share of 0.25 %). Averaged within the
    window only, the last block's mean is -0.02 (600 curves) and the CUSUM fires on 0.22 %."""
    from tightscan.traces import detector_traces

    import independent_generator as ig

    config = ig.GeneratorConfig(n=200, seed=21, strategy="CST", sample_rate_hz=2000.0, encoder_step_deg=0.1)
    curves, _ = ig.generate(config)
    last = []
    for tightening_id in curves["tightening_id"].to_pylist():
        trace = detector_traces(curves, tightening_id)
        if trace.cusum is not None and len(trace.cusum.z) >= 2:
            last.append(trace.cusum.z[-1])
    assert len(last) >= 170
    # the mean of 170+ standard normal z's has standard error 0.08: +0.39 fails by 2.5 of them
    assert abs(float(np.mean(last))) <= 0.2, np.mean(last)


def test_the_cusum_s_blocks_keep_one_scale_where_the_noise_is_a_percentage_of_the_reading() -> None:
    """CST, 2 kHz, 0.01 deg encoder (independent generator), white noise of 0.002 Nm + 0.5 % of
    the reading: a transducer whose noise is almost all a percentage of the torque. The window
    is weighed by the noise's growth, and the weights came from the noise model's slope, whose
    intercept is floored at a tenth of the loudest block's sd: far too flat here (the noise
    grows 3-4 times over the window), so the window's loud end kept more noise than its quiet
    start, and the CUSUM's standardised block rates grew along it. Mean z^2 of the last two
    fifths of the monitored blocks over the first two, on these 1,000 curves: 1.164 before,
    1.040 with the window weighed by the fitted sd line over the window (`window_growth`,
    engine/analysis/mod.rs). Each mean holds 4,708 z's: the ratio's standard error is about
    0.03. On 2,000 such curves (seed 4242) the rule's false alarms went 1.65 -> 1.30 %, its
    CUSUM's 0.40 -> 0.20 % against a share of 0.25 %."""
    from tightscan.traces import detector_traces

    import independent_generator as ig

    config = ig.GeneratorConfig(
        n=1000, seed=4242, strategy="CST", sample_rate_hz=2000.0, encoder_step_deg=0.01,
        noise=ig.NoiseConfig(sd_nm=0.002, sd_rel=0.005),
    )
    curves, _ = ig.generate(config)
    early: list[float] = []
    late: list[float] = []
    for tightening_id in curves["tightening_id"].to_pylist():
        trace = detector_traces(curves, tightening_id)
        if trace.cusum is None or len(trace.cusum.z) < 5:
            continue
        z = np.asarray(trace.cusum.z)
        k = 2 * len(z) // 5
        early.extend(z[:k] ** 2)
        late.extend(z[len(z) - k :] ** 2)
    assert len(early) >= 3000
    ratio = float(np.mean(late) / np.mean(early))
    assert ratio <= 1.09, f"late / early mean z^2: {ratio:.3f}"


def test_the_cusum_s_weights_do_not_carry_an_encoder_step_its_averaged_angle_lacks() -> None:
    """CST, 2 kHz, AR(1) 0.85 noise of 0.01 Nm + 0.4 % of the reading (independent generator):
    the same 800 curves read through a 0.01 deg encoder and re-quantised to 0.1 deg, so the
    torque is the same and only the recorded angle differs. The window's weights carry the
    angle's quantisation error as the whole encoder step (for the break scan's start test, on
    the interpolated angle); the CUSUM regresses on the angle averaged over nine samples, whose
    leftover is a small part of the step, and with the step in its weights the window's quiet
    start was weighed as if it held that error: the monitored blocks' z's came out wider
    through the coarse encoder, mean z^2 1.069 times the fine encoder's (10,524 z's; without
    the CUSUM's widening 1.075, and 1.17 with twice the step). The CUSUM now weighs the window
    without it: 0.983."""
    import pyarrow as pa
    from tightscan.traces import detector_traces

    import independent_generator as ig

    config = ig.GeneratorConfig(
        n=800, seed=1000, strategy="CST", sample_rate_hz=2000.0, encoder_step_deg=0.01,
        noise=ig.NoiseConfig(colour="ar1", phi=0.85),
    )
    fine, _ = ig.generate(config)
    coarse_angle = [(np.floor(np.asarray(a) / 0.1 + 1e-9) * 0.1).tolist() for a in fine["angle"].to_pylist()]
    coarse = fine.set_column(fine.column_names.index("angle"), "angle", pa.array(coarse_angle, pa.list_(pa.float64())))
    z_fine: list[float] = []
    z_coarse: list[float] = []
    for tightening_id in fine["tightening_id"].to_pylist():
        for curves, z in ((fine, z_fine), (coarse, z_coarse)):
            trace = detector_traces(curves, tightening_id)
            if trace.cusum is not None:
                z.extend(trace.cusum.z)
    assert min(len(z_fine), len(z_coarse)) >= 9000
    ratio = float(np.mean(np.square(z_coarse)) / np.mean(np.square(z_fine)))
    assert ratio <= 1.03, f"mean z^2 through the 0.1 deg encoder over the 0.01 deg one: {ratio:.3f}"


def test_the_cusum_leaves_out_the_block_whitened_across_the_pause() -> None:
    """CSDT, 2 kHz, 0.5 deg encoder, AR(1) 0.9 (built-in simulator's curves, noise added here).
    The pause's samples are left out of the window, and the first samples after it were
    whitened with samples from before it, whose noise the pause has made independent of theirs:
    an innovation with (1 + phi^2) / (1 - phi^2) = 9.5 times the variance, at the start of the
    first block after the pause. Its standardised rate had mean square 5.45 over these 599
    curves (largest 11.7; the other blocks' 0.99), and the CUSUM alarmed on 1.50 % of 2,000
    such clean curves against its share of 0.25 %, 27 of 30 alarms with their largest z
    there. That block is now left out as the blocks touching the pause are: 1.02, and 0.40 %."""
    import sys
    from pathlib import Path

    from tightscan.traces import detector_traces

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benches"))
    import size_grid

    curves = size_grid.builtin_cell(600, 4711, "CSDT", 2000.0, 0.5, "ar1", 0.9)
    after: list[float] = []
    for tightening_id, angle in zip(curves["tightening_id"].to_pylist(), curves["angle"].to_pylist()):
        trace = detector_traces(curves, tightening_id)
        if trace.cusum is None or len(trace.cusum.z) < 3:
            continue
        a = np.asarray(angle)
        # the pause: the longest run of one recorded angle
        bounds = np.r_[0, np.flatnonzero(np.diff(a) != 0) + 1, len(a)]
        pause = a[bounds[int(np.argmax(np.diff(bounds)))]]
        past = np.flatnonzero(np.asarray(trace.cusum.angle) > pause)
        if len(past) and past[0] > 0:
            after.append(trace.cusum.z[past[0]])
    assert len(after) >= 500
    mean_square = float(np.mean(np.square(after)))
    assert mean_square <= 1.5, f"first block after the pause: mean z^2 {mean_square:.2f}"


def _coarse_encoder_curves(n: int, seed: int, resolution: float, phi: float) -> pa.Table:
    """Built-in CST curves at 2 kHz read through an encoder of `resolution` deg, with AR(1)
    noise of the default marginal sd (white where phi is 0) added here."""
    curves, _ = tightscan.simulate(
        n, seed=seed, fault_fraction=0.0, strategies=["CST"], torque_noise=0.0, sample_rate_hz=2000.0, angle_resolution_deg=resolution
    )
    return _add_ar1_noise(curves, phi, seed)


@pytest.mark.slow
def test_the_cusum_takes_the_share_the_break_scan_s_encoder_check_leaves() -> None:
    # A 0.5 deg encoder under AR(1) 0.85: the scan credits a break only beyond 1.5 encoder
    # steps, many times its jump's noise, and spends almost none of its 0.5625 % (the scan's
    # share of break_alpha under strong colour, 0.75 of it beside the end and start tests and
    # the episode scan's halved share; 0.675 % while the episode scan was off there). The CUSUM
    # takes that part
    # (cusum_alpha) and alarms at it: before the handover the rule ran at 0.30 % of such curves
    # (its CUSUM at its share of 0.25 %; size grid, 2,000 curves, seed 1027). 8,000 curves: a
    # CUSUM that ignored cusum_alpha would alarm about 20 times (its share), 4.5 sd below what
    # cusum_alpha adds up to here (about 52).
    n = 8000
    results = tightscan.detect_batch(_coarse_encoder_curves(n, 1027, 0.5, 0.85))
    alpha = np.array([v for v in results["cusum_alpha"].to_pylist() if v is not None])
    assert alpha.size >= 0.95 * n
    assert np.all(alpha >= 0.0025 - 1e-12) and np.all(alpha <= 0.0025 + 0.0075 * 0.75 + 1e-12), (alpha.min(), alpha.max())
    assert np.median(alpha) > 0.005, np.quantile(alpha, [0.1, 0.5, 0.9])
    alarms = int(np.sum([bool(v) for v in results["cusum_alarm"].to_pylist() if v is not None]))
    expected = float(alpha.sum())
    assert abs(alarms - expected) < 3.5 * np.sqrt(expected), (alarms, expected)
    own_share = 0.0025 * alpha.size
    assert alarms > own_share + 3.5 * np.sqrt(own_share), (alarms, expected, own_share)
    assert 0.005 <= _false_alarm_rate(results, n) <= 0.015


def test_the_cusum_takes_the_scan_s_share_by_the_check_alone() -> None:
    # A 0.01 deg encoder: the check's jump is within the jump's noise, the scan spends its
    # share and the CUSUM keeps its own. A 0.5 deg encoder against white noise: the
    # quantisation is about the noise's own size, the check leaves the scan's share unspent, and
    # the CUSUM takes it (before its scale took each block's angle error it was held to its own
    # share there, where its block rates strayed: 1.6-4.4 times its share).
    for resolution, phi, kept in ((0.01, 0.0, True), (0.5, 0.0, False)):
        results = tightscan.detect_batch(_coarse_encoder_curves(300, 1200, resolution, phi))
        alpha = np.array([v for v in results["cusum_alpha"].to_pylist() if v is not None])
        assert alpha.size >= 280
        own_share = float(np.mean(np.isclose(alpha, 0.0025, rtol=1e-9)))
        assert (own_share >= 0.9) if kept else (np.median(alpha) > 0.006), (resolution, own_share, np.quantile(alpha, [0.5, 0.9, 1.0]))


def test_the_cusum_holds_its_alpha_where_a_coarse_encoder_s_error_changes_along_the_window() -> None:
    # An HDT tool at 2 kHz through a 0.5 deg encoder turns several encoder steps a sample early
    # in the window (an angle error independent from sample to sample, which the CUSUM's
    # averaged angle hides from its residuals but not from its block slopes) and few near the
    # target (an error the interpolation between the count's rises all but removes). A scale
    # pooled over the window left the early blocks' z's too wide: the CUSUM alone at alpha 2 %
    # alarmed on 125 of these 3,861 decided clean curves where its alpha adds up to 77 (5.4 sd
    # over); with each block's scale taking the angle error its own samples carry, 72.
    curves, _ = tightscan.simulate(
        4000, seed=1115, fault_fraction=0.0, strategies=["HDT"], torque_noise=0.0, sample_rate_hz=2000.0, angle_resolution_deg=0.5
    )
    rng = np.random.default_rng(1115)
    noisy = [
        np.asarray(t, dtype=float) + 0.002 * target * rng.normal(size=len(t))
        for t, target in zip(curves["torque"].to_pylist(), curves["target_torque"].to_pylist())
    ]
    curves = curves.set_column(curves.column_names.index("torque"), "torque", pa.array(noisy, pa.list_(pa.float64())))
    results = tightscan.detect_batch(curves, config={"detectors": ["cusum"], "alpha": 0.02})
    alpha = np.array([v for v in results["cusum_alpha"].to_pylist() if v is not None])
    assert alpha.size >= 3600
    alarms = int(np.sum([bool(v) for v in results["cusum_alarm"].to_pylist() if v is not None]))
    expected = float(alpha.sum())
    assert expected - 3.5 * np.sqrt(expected) < alarms < expected + 2.5 * np.sqrt(expected), (alarms, alpha.size, expected)
