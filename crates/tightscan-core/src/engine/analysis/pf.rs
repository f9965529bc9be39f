//! The particle-filter step: the fault test of [`crate::detectors::pf`] over the window's
//! whitened samples, the same samples the break scan tests, judged by the null table
//! ([`crate::detectors::pf::pf_null_p_value`]).

use crate::detectors::noise::whiten;
use crate::detectors::pf::{onset_posterior, pf_fault_test_whitened, pf_predictive_p_value, ChangeDirection, OnsetQuantiles, PfConfig, WhitenedLine};
use crate::engine::input::Sample;
use crate::engine::rows::{PfOnset, PfRow};
use crate::engine::Detector;

use super::breaks::{change_start_angle, encoder_step_torque, ARTEFACT_P_FRACTION};
use super::Scratch;

impl Detector {
    /// The filter over the whitened window (noise colour taken out by the window's noise
    /// model, heavy tails made Gaussian), seeded by the configuration's seed plus the row, so
    /// the result does not depend on how rows are spread over threads. `None` when the window
    /// is too short for the filter's training.
    pub(super) fn pf_row<A: Sample>(&self, angle: &[A], row: usize, s: &mut Scratch) -> Option<PfRow> {
        let (lag, n) = (s.lag, s.n_window);
        if n <= lag || n > s.wx.len() || n > s.wy.len() {
            return None;
        }
        let cfg = &self.config.pf;
        let filter = PfConfig { particles: cfg.particles, seed: cfg.seed.wrapping_add(row as u64), keep_track: cfg.friction_track, ..PfConfig::default() };
        // The shared samples are weighed by the same growth (`window_growth`) with the angle's
        // quantisation error in the weights; the filter's are weighed again without it
        // (`weigh_by_growth`), except where that growth is the noise model's own slope (its
        // intercept above the floor), where the filter has always read the shared samples and
        // its calibration was measured so (the CUSUM before it may have weighed them without).
        let growth = s.growth;
        if growth != s.noise.sd_slope {
            // Already so where the shared weights had no quantisation term, or the CUSUM
            // weighed the window again without it.
            if s.quantised_weights {
                s.weigh_by_growth(growth);
            }
        } else {
            s.restore_shared_weights();
        }
        // The whitened constant: the weights of noise growing with the torque (all 1 without),
        // whitened like the angle and the torque were.
        s.weighted.clear();
        if s.weights.is_empty() {
            s.weighted.resize(s.xs.len(), 1.0);
        } else {
            s.weighted.extend_from_slice(&s.weights);
        }
        let mut intercept = Vec::with_capacity(s.weighted.len());
        whiten(&s.weighted, &s.noise.coefficients, &mut intercept);
        if n > intercept.len() || n > s.xs.len() {
            return None;
        }
        // The test: a continuous kink at the change, whose null distribution is the table's.
        // Where the tool restarts after a stop left out of the window (a CSDT pause): the
        // whitened samples whose filter reaches across the stop are skipped, and the level is
        // let free there (the relaxation at standstill). Without, the pause made a fifth of
        // clean CSDT curves under AR(1) 0.9 alarm (alarms placed at the pause, a sample wide).
        let restarts: Vec<std::ops::Range<usize>> =
            (lag + 1..n).filter(|&k| matches!((s.index.get(k - 1), s.index.get(k)), (Some(&a), Some(&b)) if b > a + 1)).map(|k| k - lag..(k + lag).min(n) - lag).collect();
        let mut angle_fit = Vec::new();
        let mut wx_fit = Vec::new();
        // The angle without the encoder's beat ([`beat_free_angle`]), in the test, the onset's
        // direction and the pivot alike.
        beat_free_angle(&s.x[..n], &s.index[..n], &s.xs[..n], s.encoder_resolution, &mut angle_fit);
        let weighted_fit: Vec<f64> = angle_fit.iter().zip(&s.weighted).map(|(x, w)| x * w).collect();
        whiten(&weighted_fit, &s.noise.coefficients, &mut wx_fit);
        if n > wx_fit.len() {
            return None;
        }
        let line = WhitenedLine { intercept: Some(&intercept[lag..n]), x: &wx_fit[lag..n], pivot_x: &angle_fit[lag..n], y: &s.wy[lag..n], restarts: &restarts };
        let res = pf_fault_test_whitened(&line, self.pf_alpha, &filter)?;
        // The null table's p-value (Ville's bound, res.p_value, holds too, but at 10-100 times
        // the simulated tail it leaves most of alpha unused), averaged over the whitening's
        // uncertainty: the AR fit's error leaves colour the table does not have.
        let p_value = pf_predictive_p_value(res.statistic, n - lag, s.noise.gain_log_se);
        let significant = p_value <= self.pf_alpha;
        // Where: a friction change steps the torque and turns its line about the snug (where the
        // clamp force starts); the kink model put simulated changes 2-4 samples early. The
        // change's sample is placed by its exact posterior given a change (`onset_posterior`:
        // the marginal likelihood of every candidate sample, the data after the change
        // included), not by the filter's surviving paths, which share their jump times after
        // resampling. Run only where the p-value is significant, so clean curves cost one
        // filter.
        let exact = if significant {
            let direction = ChangeDirection { weight: &s.weighted[..n], weighted_x: &weighted_fit, pivot: s.snug_x, phi: &s.noise.coefficients };
            onset_posterior(&line, &direction, &filter)
        } else {
            None
        };
        // The encoder check of the break scan (`min_jump_steps`): a significant kink is
        // credited only where the torque it moves by the window's end exceeds 1.5 encoder steps
        // of torque, or where its p-value is a hundredth of alpha, or where one encoder step of
        // torque is below the noise's sd (there the quantisation cannot make a kink the noise
        // does not dwarf, and the check would only drop the noise's own alarms).
        let knot = exact.map(|q| (q.median.ceil() as usize).max(1) + lag).or(res.onset.map(|(mid, ..)| mid + lag));
        let alarm = significant
            && (p_value <= ARTEFACT_P_FRACTION * self.pf_alpha
                || knot.is_none_or(|k| beyond_quantisation(&s.x[..n], &s.y[..n], k, s.encoder_resolution, self.config.breaks.min_jump_steps)));
        // A kink not credited is placed as any other row without an alarm (by the particles).
        let exact = exact.filter(|_| alarm);
        // Angles on the interpolated angle (the encoder's quantisation averaged out, as the
        // break scan's change angle): the recorded angle of a 0.1 deg encoder at 2 kHz is a
        // staircase, and an interval between two recorded angles missed the built-in
        // simulator's onsets in 41-54 % of CST alarms (the onset lay past its recorded end).
        // Where that angle is the recorded one or an average of recorded ones, it lags the
        // shaft by half an encoder step ([`floor_lag`]): uncorrected, the change angles of the
        // built-in simulator's CSDT alarms lay a median 0.04-0.05 deg early and their interval
        // ended short of the onset in 42-60 % (benches/README.md, pf section).
        let lag_of_floor = floor_lag(&s.x[..n], &s.xs[..n], s.angle_averaged);
        let interpolated = |j: usize| -> Option<f64> {
            let i = *s.index.get(j)?;
            Some(angle.get(i)?.to_f64() - s.x.get(j)? + s.xs.get(j)? + lag_of_floor)
        };
        // On an alarm, the posterior's continuous positions (`OnsetQuantiles`: each sample's
        // mass spread over the advance since the sample before, where the data cannot place the
        // change) on the angle, linear between the two samples' angles, so that the spread is
        // even in the angle. Whole samples gave a posterior on one sample its whole advance as
        // the 90 % interval: the independent generator's onsets were covered in 0.94-0.99 of
        // alarms, 0.87-0.91 spread (benches/README.md, pf section).
        let at = |t: f64| -> Option<f64> {
            let t = t + lag as f64;
            let k = (t.ceil() as usize).max(1);
            let (a, b) = (interpolated(k - 1)?, interpolated(k)?);
            Some(a + (t - (k - 1) as f64).clamp(0.0, 1.0) * (b - a))
        };
        let continuous = |q: OnsetQuantiles| -> Option<PfOnset> {
            let index = *s.index.get((q.median.ceil() as usize).max(1) + lag)?;
            let angle = at(q.median)?;
            Some(PfOnset { index, angle, lo_angle: at(q.lo)?.min(angle), hi_angle: at(q.hi)?.max(angle) })
        };
        let onset = match exact {
            Some(q) => continuous(q),
            // The filter's particles (no alarm, or no exact posterior), in whole samples.
            None => res.onset.and_then(|(mid, lo, hi)| {
                let (mid, lo, hi) = (mid + lag, lo + lag, hi + lag);
                let index = *s.index.get(mid)?;
                // A jump "at sample k" happened after sample k - 1 and by sample k: the interval
                // runs from the sample before its earliest jump to its latest jump, and the change
                // angle is halfway between the median's sample and the one before it.
                let before = |j: usize| interpolated(j.saturating_sub(1));
                let at_mid = interpolated(mid)?;
                let angle = change_start_angle(angle, s, mid) + lag_of_floor;
                Some(PfOnset { index, angle, lo_angle: before(lo).unwrap_or(at_mid).min(angle), hi_angle: interpolated(hi)?.max(angle) })
            }),
        };
        Some(PfRow {
            alarm,
            statistic: res.statistic,
            p_value,
            fault_probability: res.fault_probability,
            onset,
            friction: res.rate_track,
        })
    }
}

/// Whether a kink at sample `knot` of the recorded window (`x` the recorded angle, `y` the
/// torque) could not be the encoder's quantisation: the least-squares line with a change of
/// slope at the knot moves the torque by the window's end by more than `steps` encoder steps of
/// torque ([`encoder_step_torque`]), or one step of torque is below the
/// fit's residual sd. Where the quantisation dominates the noise it alone makes kinks: clean
/// independent-generator curves (2 kHz, 0.5 deg, white noise, 600 a cell, pf_alpha 0.05)
/// alarmed at 20.5 % (CST) and 15.3 % (HDT), their kinks a median 0.34 and 0.18 steps; faulty
/// ones (3-15 %) a median 3.8 and 2.9 steps.
fn beyond_quantisation(x: &[f64], y: &[f64], knot: usize, resolution: f64, steps: f64) -> bool {
    let n = x.len().min(y.len());
    let (Some(&first), Some(&last), Some(&at)) = (x.first(), x.get(n.wrapping_sub(1)), x.get(knot)) else { return true };
    if !(resolution > 0.0) || n < 8 || last <= first {
        return true;
    }
    let rows = x[..n].iter().zip(&y[..n]).map(|(&a, &t)| ([1.0, a - first, (a - at).max(0.0)], t));
    let Some((beta, _, rss)) = crate::detectors::least_squares_3(rows) else { return true };
    let step = encoder_step_torque(&x[..n], &y[..n], resolution);
    let sd = (rss / (n - 3) as f64).sqrt();
    step <= sd || (beta[2] * (last - at)).abs() > steps * step
}

/// How far the shaft lies past the interpolated angle `xs` on average. A floor-quantising
/// encoder records the shaft anywhere in the step above its count, half a step behind on
/// average; where `xs` is the recorded angle `x` itself or the engine's centred moving average
/// of it (`averaged`: dense rises, `smooth_angle` in engine/analysis/mod.rs), the average keeps
/// that lag: half the encoder's step. Where `xs` was interpolated between the count's rises
/// (exact at each rise) or the angle is not quantised, 0. The detectors do not care (a constant
/// angle offset moves no line's rate); an angle reported against the shaft's does.
fn floor_lag(x: &[f64], xs: &[f64], averaged: bool) -> f64 {
    let n = x.len().min(xs.len());
    // The encoder's step: the smallest rise, or a half, third or quarter of it where the rises
    // are whole multiples of that (a tool turning 2.4 steps a sample rises by two and three).
    let smallest = x[..n].windows(2).map(|w| w[1] - w[0]).filter(|&d| d > 1e-9).fold(f64::INFINITY, f64::min);
    let Some(grid) = (1..=4).map(|k| smallest / k as f64).find(|&r| {
        r.is_finite()
            && x[..n].windows(2).all(|w| {
                let q = (w[1] - w[0]) / r;
                (q - q.round()).abs() < 0.01
            })
    }) else {
        return 0.0;
    };
    if averaged || x[..n] == xs[..n] {
        0.5 * grid
    } else {
        0.0
    }
}

/// Runs of consecutive samples shorter than this keep the interpolated angle.
const BEAT_RUN: usize = 40;
/// Share of a run's samples whose count rises by its most common number of encoder steps, from
/// which the run is a beat ([`beat_free_angle`]).
const BEAT_SHARE: f64 = 0.9;

/// How far, in encoder steps, the line in time may stray from the interpolated angle anywhere in
/// a beat run ([`beat_free_angle`]).
const BEAT_LINE_STEPS: f64 = 2.0;

/// The angle the filter regresses on: the interpolated angle `xs`, except in runs of
/// consecutive samples (`index`) where the recorded angle `x` rises by the same whole number of
/// encoder steps (one or more) from nearly every sample to the next, where it is the
/// least-squares line in time through `xs`. `step`: the encoder's grid in `x`
/// ([`encoder_resolution`](crate::physics::torque_rate::encoder_resolution); nothing is changed
/// where it is 0).
///
/// Why: where the tool turns by close to a whole number of encoder steps a sample, the count
/// rises by that number sample after sample and the encoder's floor error drifts through a
/// step over tens to hundreds of samples, then wraps: the interpolated angle (a moving average
/// over about two steps' worth of samples there) keeps that error, and the torque on it holds
/// a slow sawtooth of the torque rate times a step, with a level shift at each wrap, which the
/// filter reads as a turn of the line. On the built-in simulator's clean CSDT curves (white
/// noise, 2 kHz, 0.1 deg) the curves with a stretch within 0.02 steps of a whole number a
/// sample alarmed at 25 % (139 of 1,800), the others at 5.5 %. Where the line stays within
/// [`BEAT_LINE_STEPS`] of the interpolated angle all through the run (checked; a speed that
/// changes inside the run fails it), it is the better angle: the floor error alone spans a step,
/// and the encoder tells no more than that there. (Within one step the rule kept 7 of the 44
/// beat curves of seed 6005 alarming instead of 3: the interpolated angle strays a little past a
/// step about the wraps.)
fn beat_free_angle(x: &[f64], index: &[usize], xs: &[f64], step: f64, out: &mut Vec<f64>) {
    out.clear();
    out.extend_from_slice(xs);
    let n = x.len().min(index.len()).min(xs.len());
    if !(step > 0.0) {
        return;
    }
    let mut start = 0;
    while start < n {
        let mut end = start + 1;
        while end < n && index[end] == index[end - 1] + 1 {
            end += 1;
        }
        if end - start >= BEAT_RUN {
            let rises: Vec<i64> = (start + 1..end).map(|k| ((x[k] - x[k - 1]) / step).round() as i64).collect();
            let mut counts = std::collections::BTreeMap::new();
            for &r in &rises {
                *counts.entry(r).or_insert(0usize) += 1;
            }
            let (mode, count) = counts.iter().max_by_key(|(_, &c)| c).map_or((0, 0), |(&m, &c)| (m, c));
            let regular = mode >= 1 && count as f64 >= BEAT_SHARE * rises.len() as f64 && rises.iter().all(|r| (r - mode).abs() <= 1);
            if regular {
                let m = (end - start) as f64;
                let t_mean = (start..end).map(|k| index[k] as f64).sum::<f64>() / m;
                let x_mean = xs[start..end].iter().sum::<f64>() / m;
                let (mut stt, mut stx) = (0.0, 0.0);
                for k in start..end {
                    let dt = index[k] as f64 - t_mean;
                    stt += dt * dt;
                    stx += dt * (xs[k] - x_mean);
                }
                let speed = stx / stt;
                let on_line = |k: usize| x_mean + speed * (index[k] as f64 - t_mean);
                // A speed that changes inside the run can keep most rises equal and still
                // carry the angle steps away from one line; only a line within a step of the
                // interpolated angle everywhere replaces it.
                if stt > 0.0 && (start..end).all(|k| (xs[k] - on_line(k)).abs() <= BEAT_LINE_STEPS * step) {
                    for (k, v) in out.iter_mut().enumerate().take(end).skip(start) {
                        *v = on_line(k);
                    }
                }
            }
        }
        start = end;
    }
}

#[cfg(test)]
mod tests {
    use super::super::{window_growth, MAX_WINDOW_SD_RATIO};
    use super::{beat_free_angle, beyond_quantisation, floor_lag};
    use crate::physics::torque_rate::encoder_resolution;

    /// The recorded angle of a floor-quantising encoder (0.1 deg) and its three-sample average
    /// lag the shaft by half a step on average; an angle interpolated between the rises, or not
    /// quantised, does not.
    #[test]
    fn the_floor_lag_is_half_a_step_where_counts_are_averaged() {
        let n = 400;
        // 1.37 steps a sample: rises of one and two steps, the floor error a sawtooth (the
        // engine's average then spans three samples).
        let truth: Vec<f64> = (0..n).map(|t| 0.1 * (0.41 + 1.37 * t as f64)).collect();
        let x: Vec<f64> = truth.iter().map(|a| (a / 0.1 + 1e-9).floor() * 0.1).collect();
        let lag = |v: &[f64]| truth.iter().zip(v).map(|(a, b)| a - b).sum::<f64>() / n as f64;
        assert!((lag(&x) - 0.05).abs() < 0.005, "recorded lag {}", lag(&x));
        assert!((floor_lag(&x, &x, false) - 0.05).abs() < 1e-12);
        let averaged: Vec<f64> = (0..n).map(|i| {
            let h = 1.min(i).min(n - 1 - i);
            x[i - h..=i + h].iter().sum::<f64>() / (2 * h + 1) as f64
        }).collect();
        assert!((lag(&averaged) - 0.05).abs() < 0.005);
        // The engine's own smoothing takes that average here, and says so.
        let index: Vec<usize> = (0..n).collect();
        let mut smoothed = Vec::new();
        let (resolution, is_average) = super::super::smooth_angle(&[], &x, &index, n, 0.0, &mut smoothed);
        assert!((resolution - 0.1).abs() < 1e-12 && is_average);
        assert!(smoothed.iter().zip(&averaged).all(|(a, b)| (a - b).abs() < 1e-9));
        assert!((floor_lag(&x, &smoothed, is_average) - 0.05).abs() < 1e-12);
        // Any other interpolation: no lag assumed; unquantised angles: none.
        let shifted: Vec<f64> = averaged.iter().map(|v| v + 0.03).collect();
        assert_eq!(floor_lag(&x, &shifted, false), 0.0);
        let smooth: Vec<f64> = (0..100).map(|t| 0.013 * t as f64 + 0.004 * (t as f64 / 3.0).sin()).collect();
        assert_eq!(floor_lag(&smooth, &smooth, false), 0.0);
        // Rises of two and three steps: the grid is half the smallest rise.
        let coarse: Vec<f64> = (0..n).map(|t| ((0.41 + 2.37 * t as f64) + 1e-9).floor() * 0.1).collect();
        assert!((floor_lag(&coarse, &coarse, false) - 0.05).abs() < 1e-12);
        assert_eq!(floor_lag(&[], &[], false), 0.0);
    }

    /// The filter's growth is the fitted sd line's own where the window's sd range is
    /// plausible: a transducer of 0.01 Nm + 0.4 % of the reading over a window from 20 to 80 Nm
    /// (sd 0.09 -> 0.33 Nm) keeps `s1 / s0` = 0.4 per Nm, where the shared floor (a tenth of a
    /// loud block's sd, e.g. 0.4 Nm) would have made it 0.1. A purely proportional noise (`s0`
    /// fitted a little below 0) is weighed as proportional over the window (sd ratio 4, not
    /// an unbounded weight); a window starting near zero torque is bounded at
    /// [`MAX_WINDOW_SD_RATIO`]. No growth, no weights.
    #[test]
    fn the_filter_weighs_by_the_fitted_sd_line_within_the_windows_range() {
        let xs: Vec<f64> = (0..=600).map(|k| 0.1 * k as f64).collect();
        // Torque from t0 = 20 Nm rising 1 Nm a degree: 20 -> 80 Nm.
        let y = xs.clone();
        let sd_ratio = |growth: f64, quiet: f64, loud: f64| (1.0 + growth * loud) / (1.0 + growth * quiet);
        let g = window_growth((0.01, 0.004), &xs, &y, 20.0);
        assert!((g - 0.4).abs() < 1e-9, "growth {g}");
        let floored = 0.004 / (0.1_f64 * 0.4).max(0.01);
        // The sd across the window: 3.7 times at its end, 3.0 with the floored slope.
        assert!(sd_ratio(floored, 20.0, 80.0) < 0.85 * sd_ratio(g, 20.0, 80.0));
        let proportional = window_growth((-0.001, 0.004), &xs, &y, 20.0);
        assert!((sd_ratio(proportional, 20.0, 80.0) - 4.0).abs() < 0.02, "proportional: {}", sd_ratio(proportional, 20.0, 80.0));
        let from_zero = window_growth((0.0, 0.004), &xs, &y, 0.5);
        assert!((sd_ratio(from_zero, 0.5, 60.5) - MAX_WINDOW_SD_RATIO).abs() < 1e-6, "from 0.5 Nm: {}", sd_ratio(from_zero, 0.5, 60.5));
        assert_eq!(window_growth((0.0, 0.0), &xs, &y, 20.0), 0.0);
        assert_eq!(window_growth((0.01, 0.004), &xs[..1], &y[..1], 20.0), 0.0);
    }

    /// The floor-quantised angle of a shaft at `speed` steps a sample from `phase`, steps 0.1 deg.
    fn recorded(n: usize, speed: f64, phase: f64) -> (Vec<f64>, Vec<f64>) {
        let truth: Vec<f64> = (0..n).map(|t| 0.1 * (phase + speed * t as f64)).collect();
        let x = truth.iter().map(|a| (a / 0.1 + 1e-9).floor() * 0.1).collect();
        (truth, x)
    }

    /// A beat (1.02 steps a sample: the count rises by one step sample after sample and wraps
    /// every 50) leaves the recorded angle a sawtooth of a step about the shaft's; the line in
    /// time is within a twentieth of a step of it, offset aside. A speed of 1.37 steps a sample
    /// (rises of one and two mixed) is not a beat and keeps the interpolated angle, and runs are
    /// cut where samples were left out.
    #[test]
    fn a_beat_is_replaced_by_the_line_in_time() {
        let n = 300;
        let (truth, x) = recorded(n, 1.02, 0.3);
        let index: Vec<usize> = (0..n).collect();
        let mut out = Vec::new();
        beat_free_angle(&x, &index, &x, encoder_resolution(&x), &mut out);
        let error = |v: &[f64]| -> (f64, f64) {
            let d: Vec<f64> = v.iter().zip(&truth).map(|(a, b)| a - b).collect();
            let mean = d.iter().sum::<f64>() / d.len() as f64;
            let spread = d.iter().map(|e| (e - mean).abs()).fold(0.0, f64::max);
            (mean, spread)
        };
        let (_, before) = error(&x);
        let (_, after) = error(&out);
        assert!(before > 0.04, "the recorded angle's error spreads {before} deg");
        assert!(after < 0.005, "the line's error spreads {after} deg");

        // The speed rising from 1.0 to 1.15 steps a sample halfway: more than nine rises in ten
        // are one step, but the angle leaves any one line by several; the interpolated angle stays.
        let ramp: Vec<f64> = (0..n).map(|t| 0.1 * ((0.3 + t as f64 + 0.15 * (t as f64 - 150.0).max(0.0)) + 1e-9).floor()).collect();
        beat_free_angle(&ramp, &index, &ramp, encoder_resolution(&ramp), &mut out);
        assert_eq!(out, ramp);

        let (_, mixed) = recorded(n, 1.37, 0.3);
        beat_free_angle(&mixed, &index, &mixed, encoder_resolution(&mixed), &mut out);
        assert_eq!(out, mixed);

        // A stop left out after sample 150: each run gets its own line.
        let gapped: Vec<usize> = (0..n).map(|k| if k < 150 { k } else { k + 40 }).collect();
        let (truth, x) = recorded(n + 40, 1.02, 0.7);
        let x: Vec<f64> = gapped.iter().map(|&k| x[k]).collect();
        beat_free_angle(&x, &gapped, &x, encoder_resolution(&x), &mut out);
        for (k, &i) in gapped.iter().enumerate() {
            assert!((out[k] - truth[i]).abs() < 0.06, "sample {k}: {} against {}", out[k], truth[i]);
        }

        // No grid, too short, empty: the interpolated angle back, no panic.
        let smooth: Vec<f64> = (0..100).map(|t| 0.013 * t as f64 + 0.004 * (t as f64 / 3.0).sin()).collect();
        beat_free_angle(&smooth, &index[..100], &smooth, encoder_resolution(&smooth), &mut out);
        assert_eq!(out, smooth);
        beat_free_angle(&x[..10], &index[..10], &x[..10], encoder_resolution(&x[..10]), &mut out);
        assert_eq!(out, x[..10].to_vec());
        beat_free_angle(&[], &[], &[], encoder_resolution(&[]), &mut out);
        assert!(out.is_empty());
    }

    /// A kink the encoder's quantisation makes is not credited; a friction change's kink, or
    /// any kink where the noise dwarfs an encoder step, is. The shaft turns 0.23 deg a sample
    /// against a 0.5 deg floor encoder over a line of 2 Nm/deg (one step 1 Nm of torque).
    #[test]
    fn a_kink_within_the_encoder_s_steps_is_not_credited() {
        let n = 300;
        let shaft: Vec<f64> = (0..n).map(|t| 0.23 * t as f64).collect();
        let recorded: Vec<f64> = shaft.iter().map(|a| (a / 0.5).floor() * 0.5).collect();
        let clean: Vec<f64> = shaft.iter().map(|a| 2.0 * a).collect();
        // Noise-free: against the recorded angle the torque is the line plus the floor's
        // sawtooth (up to one step); no knot moves it by 1.5 steps.
        for knot in [30, 150, 270] {
            assert!(!beyond_quantisation(&recorded, &clean, knot, 0.5, 1.5), "knot {knot}");
            assert!(beyond_quantisation(&shaft, &clean, knot, 0.0, 1.5), "no encoder, knot {knot}");
        }
        // A rate 10 % higher after sample 150: 3.5 steps of torque by the end.
        let changed: Vec<f64> = shaft.iter().map(|&a| 2.0 * a + 0.2 * (a - shaft[150]).max(0.0)).collect();
        assert!(beyond_quantisation(&recorded, &changed, 150, 0.5, 1.5));
        // Noise of sd 3 Nm (three steps): the check stands down.
        let noisy: Vec<f64> = clean.iter().enumerate().map(|(t, y)| y + 3.0 * ((t * 7919 % 1000) as f64 / 1000.0 - 0.5) * 12f64.sqrt()).collect();
        assert!(beyond_quantisation(&recorded, &noisy, 150, 0.5, 1.5));
    }
}
