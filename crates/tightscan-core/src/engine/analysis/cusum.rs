//! The CUSUM step: the window cut into equal-angle blocks, each block's torque rate
//! standardised against the training blocks' pooled rate and the within-block noise, and the
//! two-sided CUSUM run over the monitored blocks (METHODS.md section 2).

use crate::detectors::cusum::TwoSidedCusum;
use crate::engine::input::Sample;
use crate::engine::rows::{CusumAlarmRow, CusumRow};
use crate::engine::status::TighteningStatus;
use crate::engine::traces::CusumTrace;
use crate::engine::Detector;
use crate::physics::torque_rate::{block_count, block_stats_whitened, ElasticWindow, PooledFit};

use super::{time_smoothed_angle, weigh, Scratch, TIME_SMOOTHING};
use crate::detectors::noise::whiten;

/// Chi-square quantile by Wilson and Hilferty (1931): k (1 - 2/(9k) + z sqrt(2/(9k)))^3.
fn chi_square_quantile(k: f64, z: f64) -> f64 {
    let c = 2.0 / (9.0 * k);
    k * (1.0 - c + z * c.sqrt()).powi(3)
}

/// Standard normal quantile at 0.999: the dispersion pre-test fires for white noise once in a
/// thousand tightenings, so it barely moves the size.
const Z_0999: f64 = 3.090_232_306;

/// Where the CUSUM's threshold comes from: the default, the exact probability of an alarm
/// within the blocks a tightening monitors at the CUSUM's share of alpha; or one threshold for
/// every block count, set by the user (`threshold`, or `arl0` through Siegmund's ARL).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum ThresholdSource {
    /// Alarm probability within the monitored blocks.
    FalseAlarm(f64),
    /// One threshold h.
    Fixed(f64),
}

/// Offsets of ln(scale) at which the false-alarm probability is tabled for the predictive
/// widening: -1 to 1.5 by 0.05. A scale of e^1.5 puts the threshold 4.5 times higher, where the
/// probability is below 1e-30; below e^-1 the widening's Gauss-Hermite nodes reach only for
/// a log-gain standard error above 0.35, and the table's end is used there (a smaller widening).
const SCALE_GRID_START: f64 = -1.0;
const SCALE_GRID_STEP: f64 = 0.05;
const SCALE_GRID_POINTS: usize = 51;

/// The CUSUM's threshold for one monitored block count, and ln of its false-alarm probability
/// over that count with h and kappa scaled by e^u, u on the scale grid.
#[derive(Debug)]
struct StepsCalibration {
    threshold: f64,
    ln_false_alarm: Vec<f64>,
}

/// Thresholds and false-alarm tables by monitored block count, each computed the first time a
/// tightening with that many blocks is analysed (a few milliseconds) and shared by every thread
/// and every later call with the same settings.
#[derive(Debug)]
pub(crate) struct CusumCalibration {
    kappa: f64,
    source: ThresholdSource,
    by_steps: Vec<std::sync::OnceLock<Option<StepsCalibration>>>,
}

impl CusumCalibration {
    /// The calibration for `source` and `kappa`, from the process-wide cache.
    pub(crate) fn shared(source: ThresholdSource, kappa: f64, max_steps: usize) -> std::sync::Arc<Self> {
        use std::sync::{Arc, Mutex, OnceLock};
        type Cache = Mutex<Vec<(ThresholdSource, u64, usize, Arc<CusumCalibration>)>>;
        static CACHE: OnceLock<Cache> = OnceLock::new();
        let cache = CACHE.get_or_init(|| Mutex::new(Vec::new()));
        let fresh = || Arc::new(Self { kappa, source, by_steps: (0..max_steps).map(|_| OnceLock::new()).collect() });
        // A poisoned lock only means another thread panicked while holding it; the list is
        // still whole (entries are pushed complete).
        let mut list = cache.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        if let Some((.., c)) = list.iter().find(|(s, k, m, _)| *s == source && *k == kappa.to_bits() && *m == max_steps) {
            return Arc::clone(c);
        }
        let c = fresh();
        list.push((source, kappa.to_bits(), max_steps, Arc::clone(&c)));
        c
    }

    /// The threshold for `steps` monitored blocks.
    pub(crate) fn threshold(&self, steps: usize) -> Option<f64> {
        self.entry(steps).map(|e| e.threshold)
    }

    fn entry(&self, steps: usize) -> Option<&StepsCalibration> {
        let steps = steps.max(1);
        // More blocks than the table holds cannot happen with a validated config (blocks are
        // at most `max_blocks`); the last entry would be conservative for them.
        let slot = self.by_steps.get(steps - 1).or(self.by_steps.last())?;
        slot.get_or_init(|| {
            use crate::detectors::cusum::{cusum_false_alarm_probabilities, cusum_threshold_for_steps};
            let threshold = match self.source {
                ThresholdSource::FalseAlarm(alpha) => cusum_threshold_for_steps(alpha, self.kappa, steps).ok()?,
                ThresholdSource::Fixed(h) => h,
            };
            let ln_false_alarm = (0..SCALE_GRID_POINTS)
                .map(|g| {
                    let scale = (SCALE_GRID_START + g as f64 * SCALE_GRID_STEP).exp();
                    let p = cusum_false_alarm_probabilities(threshold * scale, self.kappa * scale, steps).ok()?;
                    Some(p.last().copied().unwrap_or(0.0).max(1e-300).ln())
                })
                .collect::<Option<Vec<f64>>>()?;
            Some(StepsCalibration { threshold, ln_false_alarm })
        })
        .as_ref()
    }

    /// The false-alarm probability over `steps` blocks with h and kappa scaled by `scale`
    /// (cubic interpolation of its logarithm in ln(scale); the ends of the grid beyond it).
    fn false_alarm(&self, steps: usize, scale: f64) -> Option<f64> {
        let table = &self.entry(steps)?.ln_false_alarm;
        let position = ((scale.ln() - SCALE_GRID_START) / SCALE_GRID_STEP).clamp(0.0, (SCALE_GRID_POINTS - 1) as f64);
        let i = (position.floor() as usize).min(SCALE_GRID_POINTS - 2);
        let t = position - i as f64;
        let at = |j: isize| table[j.clamp(0, SCALE_GRID_POINTS as isize - 1) as usize];
        let (p0, p1, p2, p3) = (at(i as isize - 1), at(i as isize), at(i as isize + 1), at(i as isize + 2));
        // Catmull-Rom: the cubic through p1 and p2 with the neighbours' slopes.
        let value = p1 + 0.5 * t * (p2 - p0 + t * (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3 + t * (3.0 * (p1 - p2) + p3 - p0)));
        Some(value.exp())
    }

    /// The factor by which the standardised block rates are widened for what the noise model
    /// leaves uncertain. The block rates' true standard deviation is `sqrt(lambda)` times the one
    /// assumed, with ln sqrt(lambda) ~ N(0, tau^2): tau^2 = se^2 (the AR filter's log gain as
    /// it reaches the block rates: the caller passes it times [`block_rate_sensitivity`]) +
    /// `scale_log_var` (the variance of the log of
    /// the estimated noise scale; 1/(2 df) for Gaussian noise with df residual degrees of
    /// freedom). The
    /// false-alarm probability over `steps` blocks, at h and kappa scaled by c / sqrt(lambda)
    /// and averaged over lambda (5-point Gauss-Hermite), is a convex function of lambda's
    /// spread: the factor `c >= 1` brings that average back to the threshold's own probability
    /// (bisection). The probability is the exact finite-horizon one over `steps` blocks, not
    /// Siegmund's stationary rate, whose dependence on h is that of an endless stream.
    ///
    /// `target_ratio` above 1 asks for that many times the threshold's probability instead
    /// (the break scan's unspent share added to the CUSUM's): the scale, down to the table's
    /// smallest (e^-1), at which the average reaches it.
    pub(crate) fn predictive_scale(&self, steps: usize, gain_log_se: f64, scale_log_var: f64, target_ratio: f64) -> f64 {
        use crate::detectors::noise::NORMAL_NODES;
        let tau = (gain_log_se.max(0.0).powi(2) + scale_log_var.max(0.0)).sqrt();
        let Some(nominal) = self.false_alarm(steps, 1.0) else { return 1.0 };
        let larger = target_ratio > 1.0;
        if !larger && !(tau > 0.0) {
            return 1.0;
        }
        let target = if larger { nominal * target_ratio } else { nominal };
        let averaged = |c: f64| -> f64 {
            NORMAL_NODES.iter().map(|(z, w)| w * self.false_alarm(steps, c * (-tau * z).exp()).unwrap_or(0.0)).sum()
        };
        let (mut lo, mut hi) = (if larger { SCALE_GRID_START.exp() } else { 1.0_f64 }, (6.0 * tau).exp());
        if averaged(lo) <= target {
            return lo;
        }
        if averaged(hi) > target {
            return hi;
        }
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            if averaged(mid) > target {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        hi
    }
}

/// Half-width of the log-gain errors at which [`block_rate_sensitivity`] is taken.
const SENSITIVITY_STEP: f64 = 0.2;

/// The exponent kappa with which a standardised block rate's variance grows with the long-run
/// variance a whitening error leaves (`lambda^kappa`): the CUSUM's counterpart of the break
/// scan's measured sensitivity, in closed form.
///
/// A block rate is the slope of `block_samples` whitened samples against their own line, and
/// it is standardised by the scatter about that line. Whitening AR(1) noise of coefficient
/// `lag1` with `theta` in its place leaves the ARMA(1, 1) `(1 - theta B) / (1 - lag1 B)` of
/// white noise, whose long-run variance is `((1 - theta) / (1 - lag1))^2` times the white
/// one: a log-gain error `e = ln(1 - theta) - ln(1 - lag1)` gives `lambda = e^(2e)`. The ratio
/// `R` of the slope's variance to the one the scatter implies (exact for that ARMA over L
/// evenly spaced samples) then grows as `lambda^kappa` with kappa between 0 and 1: a short
/// block's slope sees the leftover's short-run variance, as its scatter does, and cancels it
/// (L 11, lag-1 0.85: 0.16); a long block's slope sees the long-run one (L 128: 0.86).
/// Widening the block rates by the whole log-gain error (kappa 1), as the CUSUM did, took its
/// false alarms on the built-in simulator's AR(1) 0.85 curves (about 11 samples a block) from
/// its share of 0.25 % to 0.05 %.
pub(crate) fn block_rate_sensitivity(block_samples: usize, lag1: f64) -> f64 {
    let l = block_samples;
    if l < 4 || !lag1.is_finite() {
        return 1.0;
    }
    let phi = lag1.clamp(-0.99, 0.99);
    // 0.5 ln R at log-gain error e, for the leftover of whitening with theta.
    let half_log_ratio = |e: f64| -> f64 {
        let theta = (1.0 - (1.0 - phi) * e.exp()).clamp(-0.999, 0.999);
        // Autocovariances of (1 - theta B) / (1 - phi B) of unit white noise.
        let g0 = (1.0 + theta * theta - 2.0 * phi * theta) / (1.0 - phi * phi);
        let g1 = (1.0 - phi * theta) * (phi - theta) / (1.0 - phi * phi);
        let lf = l as f64;
        let a = (lf - 1.0) / 2.0;
        let cc = lf * (lf * lf - 1.0) / 12.0;
        // 1' G 1 and c' G c (c_i = i - a), lag by lag: sum_i c_i c_(i+h) over the L - h pairs.
        let (mut ones, mut centred, mut g) = (lf * g0, cc * g0, g1);
        for h in 1..l {
            let (m, hf) = ((l - h) as f64, h as f64);
            let (si, sii) = (m * (m - 1.0) / 2.0, (m - 1.0) * m * (2.0 * m - 1.0) / 6.0);
            let cross = sii + (hf - 2.0 * a) * si + m * a * (a - hf);
            ones += 2.0 * (m * g);
            centred += 2.0 * (cross * g);
            g *= phi;
        }
        // Expected scatter about the block's line: tr(M G) / (L - 2), M the line's residual maker.
        let scatter = (lf * g0 - ones / lf - centred / cc) / (lf - 2.0);
        let slope = centred / cc;
        if scatter > 0.0 && slope > 0.0 { 0.5 * (slope / scatter).ln() } else { 0.0 }
    };
    let kappa = (half_log_ratio(SENSITIVITY_STEP) - half_log_ratio(-SENSITIVITY_STEP)) / (2.0 * SENSITIVITY_STEP);
    if kappa.is_finite() { kappa.clamp(0.0, 1.0) } else { 1.0 }
}

impl Detector {
    /// The CUSUM of the block torque rates over the window, or the status that says why the
    /// window is too short or too gappy for its blocks.
    pub(super) fn cusum_row<A: Sample>(
        &self,
        angle: &[A],
        window: ElasticWindow,
        s: &mut Scratch,
    ) -> Result<CusumRow, TighteningStatus> {
        let cfg = &self.config;
        let len = window.end - window.start;
        if len < cfg.zone.min_samples {
            return Err(TighteningStatus::TooShort {
                samples: len,
                minimum: cfg.zone.min_samples,
                what: s.tested_part,
            });
        }
        let n_blocks = block_count(len, &cfg.blocks);
        let needed_blocks = cfg.blocks.min_training_blocks + 2;
        if n_blocks < needed_blocks {
            return Err(TighteningStatus::TooShort {
                samples: len,
                minimum: needed_blocks * cfg.blocks.min_block_samples,
                what: s.tested_part,
            });
        }
        // Blocks of the whitened samples, cut by angle (stop samples are already out of them;
        // a block that touches a stop is left out below, as the wind-up after it is not friction),
        // on the angle averaged in time (`smooth_wx`): the encoder's leftover staircase, whitened
        // near the unit root, flattens some blocks' slopes and passed for a falling torque rate.
        let (lag, n) = (s.lag, s.n_window);
        if n < lag + 2 {
            return Err(TighteningStatus::TooShort { samples: n, minimum: lag + 2, what: s.tested_part });
        }
        // Weighed without the angle's quantisation error. The CUSUM regresses on the angle
        // averaged in time over nine samples, whose quantisation leftover is a small part of
        // the encoder's step, and the whole step in the weights (there for the break scan's
        // start test, on the interpolated angle) flattened them: the window's quiet start was
        // weighed as if it held an error it does not, its blocks' scatter came out below the
        // loud end's, and the pooled scale left the monitored blocks' z's too wide. Independent
        // generator, CST, 2 kHz, noise of 0.01 Nm + 0.4 % under AR(1) 0.85, the same curves read
        // through a 0.01 deg encoder and re-quantised to 0.1 deg (800, the z's without the
        // widening): variance 1.048 and 1.127 with the step in the weights, 1.045 and 1.028
        // without it, 1.226 at 0.1 deg with twice the step.
        if s.quantised_weights {
            s.weigh_by_growth(s.growth);
        }
        let gain = 1.0 - s.noise.coefficients.iter().sum::<f64>();
        // Within the window only: past its end the tool brakes up to the peak, and an average
        // reaching into those samples pulled the last samples' angle back, which steepened the
        // last block's slope (independent generator, CST, white noise: the last block's z had
        // mean +0.39 and made half the CUSUM's false alarms).
        time_smoothed_angle(&s.xs[..n.min(s.xs.len())], &s.index, TIME_SMOOTHING, &mut s.smoothed);
        weigh(&s.smoothed, &s.weights, &mut s.weighted);
        whiten(&s.weighted, &s.noise.coefficients, &mut s.smooth_wx);
        block_stats_whitened(&s.x[lag..n], &s.smooth_wx[lag..n], &s.wy[lag..n], n_blocks, gain, &mut s.blocks);
        let blocks = &s.blocks;
        let stops = &s.stops;
        let width = blocks.width;
        let start = s.x[lag];
        let index = &s.index;
        let touches_stop = |b: usize| {
            let (lo, hi) = (start + b as f64 * width, start + (b + 1) as f64 * width);
            if stops.iter().any(|&(s0, s1)| s0 < hi && s1 >= lo) {
                return true;
            }
            // A whitened sample within `lag` samples after a stop's gap is whitened with samples
            // from before the pause, whose noise the pause has made independent of its own: its
            // innovation has (1 + phi^2) / (1 - phi^2) times the variance (9.5 at phi 0.9), and
            // it sits at the block's start, where it moves the slope most. The block holding it
            // is left out. Built-in simulator, CSDT, 2 kHz, 0.5 deg encoder, AR(1) 0.9: 27 of
            // the CUSUM's 30 false alarms in 2,000 clean curves had their largest z (up to 11)
            // in the first block after the pause.
            let st = &blocks.stats[b];
            if st.n == 0 {
                return false;
            }
            // Sample k was whitened with samples k - lag .. k - 1: a gap between any two of
            // k - lag .. k for a k of the block.
            let (first, last) = (st.first + lag, st.last + lag);
            index.get(first.saturating_sub(lag)..=last).is_some_and(|run| run.windows(2).any(|w| w[1] != w[0] + 1))
        };
        s.usable.clear();
        s.usable.extend((0..n_blocks).filter(|&b| blocks.usable(b) && !touches_stop(b)));
        let n_train = ((cfg.blocks.training_fraction * s.usable.len() as f64).ceil() as usize)
            .max(cfg.blocks.min_training_blocks);
        if s.usable.len() < n_train + 2 {
            return Err(TighteningStatus::NoElasticZone {
                reason: "too few blocks with an angle spread in the window",
            });
        }

        // Reference rate: pooled slope of the training blocks. Its variance is about 1/B^3 of
        // one block's (B training blocks), so it adds next to nothing to the monitored z's.
        let (train, monitor) = s.usable.split_at(n_train);
        let mut pooled = PooledFit::default();
        train.iter().for_each(|&b| pooled.add(&blocks.stats[b]));
        let reference_rate = pooled.slope();

        // Noise scale from every usable block's residuals about its own line. A change of
        // friction changes the slope between blocks, not the scatter within one, so monitored
        // blocks inform the scale too: about four times the training data, which matters because
        // a scale estimated from ~100 samples alone inflates the false alarms several-fold.
        // A block whose residual variance exceeds 20x the median block's (an abrupt jump inside
        // it, a spike) is left out. The cut is loose on purpose: with 3 df per block a cut at 4x
        // drops 2 % of white-noise blocks, all from the upper tail, and biases the scale low;
        // at 20x the loss is below 1e-8 (3 df) or 0.3 % (1 df).
        s.residuals.clear();
        s.residuals.extend(s.usable.iter().map(|&b| {
            let st = &blocks.stats[b];
            st.rss() / (st.n as f64 - 2.0).max(1.0)
        }));
        let mid = s.residuals.len() / 2;
        let median_var = *s.residuals.select_nth_unstable_by(mid, f64::total_cmp).1;
        let (mut rss, mut df, mut kept) = (0.0, 0.0, 0usize);
        for &b in s.usable.iter() {
            let st = &blocks.stats[b];
            let dof = (st.n as f64 - 2.0).max(1.0);
            if st.rss() / dof <= 20.0 * median_var {
                rss += st.rss();
                df += dof;
                kept += 1;
            }
        }
        // The variance of ln(noise_sd), for the widening below, from the spread of the kept
        // blocks' variances about the pooled one (the pooled variance is their df-weighted mean):
        // 1/(2 df) under Gaussian noise, but heavy tails make it larger, and on the independent
        // generator's t4 curves (13 blocks) the Gaussian value left the CUSUM at 0.60 % of clean
        // curves against its share of 0.25 %.
        let pooled_var = rss / df.max(1.0);
        let scale_log_var = if kept >= 2 && pooled_var > 0.0 {
            let spread: f64 = s
                .usable
                .iter()
                .map(|&b| {
                    let st = &blocks.stats[b];
                    let dof = (st.n as f64 - 2.0).max(1.0);
                    let r = st.rss() / dof;
                    if r <= 20.0 * median_var { (dof * (r - pooled_var)).powi(2) } else { 0.0 }
                })
                .sum();
            // var(s^2) = sum dof^2 (r - s^2)^2 / (sum dof)^2, with the k / (k - 1) of a variance
            // about an estimated mean; var(ln s) = var(s^2) / (4 s^4) (delta method).
            spread / (df * df) * kept as f64 / (kept - 1) as f64 / (4.0 * pooled_var * pooled_var)
        } else {
            0.0
        };
        let rise = s.y[n - 1] - s.y[lag];
        // Floor for noise-free or coarsely quantised torque: 1e-6 of the rise.
        let noise_sd = (rss / df.max(1.0)).sqrt().max(1e-6 * rise.abs().max(f64::MIN_POSITIVE));
        // The angle's quantisation error moves each block's slope though the average hides most
        // of it from the residuals. An error e of variance q, independent from sample to sample
        // (a tool turning several encoder steps a sample), is an error -G e in the regression's
        // torque: a block's slope still reads nearly every e (the average of a line is the line),
        // about G^2 q / Sxx_b, while the residuals about the block's averaged-angle line hold
        // less than q / 9 of it. So each block's scale gets G^2 (1 - sum phi)^2 times what the
        // average took out of that block's angle (`averaged_angle_leftover`, q (1 - 1/9) for
        // such an error; whitened, the error's low-frequency part is (1 - sum phi) e). Where the
        // tool turns less than a step a sample, the interpolation between the count's rises
        // leaves little error and the term is small. It sizes the error rather than accounting
        // for it exactly: for an independent error it overstates the slope's part for short
        // blocks (z variance 0.86 over 40 samples, see the test), a quantisation beat's slowly
        // drifting error, which the average does not see, it understates. Why per block: HDT
        // tools turn fast early in the window and slowly near the target, and one scale pooled
        // over the window left the early blocks' z's too wide. Built-in simulator, HDT, 2 kHz,
        // 0.5 deg encoder, 2,000 clean curves, the CUSUM held to about 0.7 % (the break scan's
        // unspent share): white noise 31 alarms where its alpha adds up to 13.4, t4 noise 34
        // (13.5); with this, 14 and 14. With the exact share of an independent error instead
        // (about 0.6-0.8 of the leftover for blocks of 20-40 samples), 23 and 23.
        s.angle_error.clear();
        s.angle_error.extend(blocks.stats.iter().map(|st| {
            if st.n < 3 {
                return 0.0;
            }
            let leftover = averaged_angle_leftover(&s.xs, &s.smoothed, &s.weights, st.first + lag..st.last + lag + 1);
            (reference_rate * gain).powi(2) * leftover
        }));
        let block_sd = |b: usize| (noise_sd * noise_sd + s.angle_error[b]).sqrt();

        // Standardised block rates: under white noise slope_b has variance sigma^2 / Sxx_b,
        // so z_b = (slope_b - reference) sqrt(Sxx_b) / sigma ~ N(0, 1) with no change (sigma
        // the block's: the pooled scale and the block's angle error, `block_sd`).
        let z_of = |b: usize| (blocks.stats[b].slope() - reference_rate) * blocks.stats[b].sxx_c().sqrt() / block_sd(b);
        // Dispersion pre-test: sum of squared training z's against chi-square(B). Coloured noise
        // (filters, vibration) makes block slopes vary more than white noise would; the scale is
        // widened only when that excess is significant at 0.1 %.
        let sum_z2: f64 = train.iter().map(|&b| z_of(b).powi(2)).sum();
        let k = train.len() as f64;
        let dispersion = (sum_z2 / k).sqrt();
        let inflate = if sum_z2 > chi_square_quantile(k, Z_0999) { dispersion } else { 1.0 };

        // The threshold for this many monitored blocks, and the widening for the noise model's
        // uncertainty (`CusumCalibration`): the whitening's log-gain error scaled by how much a
        // block rate of the monitored blocks' length feels it (`block_rate_sensitivity`).
        let threshold = self.cusum_calibration.threshold(monitor.len()).unwrap_or(self.threshold);
        let block_samples = monitor.iter().map(|&b| blocks.stats[b].n).sum::<usize>() / monitor.len().max(1);
        let sensitivity = block_rate_sensitivity(block_samples, s.noise.lag1_autocorrelation());
        // Where the break scan's encoder-step check leaves part of its share unspent
        // (`Detector::break_row`), the CUSUM is held to its own share plus that part: the
        // scale that brings the averaged alarm probability to it is then below 1 (h and kappa
        // scaled down together, an exact CUSUM of the same z's).
        let (alpha, target_ratio) = match self.cusum_calibration.source {
            ThresholdSource::FalseAlarm(share) => (Some(share + s.cusum_extra_alpha), (share + s.cusum_extra_alpha) / share),
            ThresholdSource::Fixed(_) => (None, 1.0),
        };
        let predictive = self.cusum_calibration.predictive_scale(monitor.len(), sensitivity * s.noise.gain_log_se, scale_log_var, target_ratio);
        s.z.clear();
        s.z.extend(monitor.iter().map(|&b| z_of(b) / (inflate * predictive)));
        let mut cusum = TwoSidedCusum::new(cfg.cusum.kappa, threshold);
        // The sample where monitored block j's evidence is complete: its last.
        let block_end = |j: usize| s.index[blocks.stats[monitor[j]].last + lag];
        let mut trace = s.trace.is_some().then(|| CusumTrace {
            threshold,
            kappa: cfg.cusum.kappa,
            ..CusumTrace::default()
        });
        for (j, &z) in s.z.iter().enumerate() {
            cusum.update(z);
            if let Some(t) = trace.as_mut() {
                let (upper, lower) = cusum.sides();
                t.angle.push(angle[block_end(j)].to_f64());
                t.z.push(z);
                t.upper.push(upper);
                t.lower.push(lower);
            }
        }
        let alarm = cusum.alarm().map(|a| {
            let change_block = &blocks.stats[monitor[a.change_step]];
            CusumAlarmRow {
                alarm_index: block_end(a.alarm_step),
                alarm_angle: angle[block_end(a.alarm_step)].to_f64(),
                side: a.side,
                change_index: s.index[change_block.first + lag],
                change_angle: angle[s.index[change_block.first + lag]].to_f64(),
            }
        });
        if let (Some(traces), Some(t)) = (s.trace.as_deref_mut(), trace) {
            traces.cusum = Some(t);
        }
        Ok(CusumRow {
            alarm,
            max_statistic: cusum.max_statistic(),
            threshold,
            alpha,
            reference_rate,
            noise_sd: noise_sd * inflate * predictive,
            noise_df: df,
            dispersion,
            blocks: monitor.len(),
            block_angle: blocks.width,
        })
    }
}

/// Mean square over the samples `range` of the weighted difference between the interpolated
/// angle `xs` and its time average `smoothed` (`weights` empty for unit weights): what the
/// average took out of the angle's quantisation error, in the weighted angle's units (see
/// `cusum_row`, the CUSUM's scale). For an error independent from sample to sample, of variance
/// q, it is q (1 - 1/9) with the nine-sample average (`TIME_SMOOTHING` either side).
fn averaged_angle_leftover(xs: &[f64], smoothed: &[f64], weights: &[f64], range: std::ops::Range<usize>) -> f64 {
    let end = range.end.min(xs.len()).min(smoothed.len());
    let (sum, count) = (range.start..end).fold((0.0, 0usize), |(sum, count), i| {
        let d = weights.get(i).copied().unwrap_or(1.0) * (xs[i] - smoothed[i]);
        (sum + d * d, count + 1)
    });
    if count > 0 { sum / count as f64 } else { 0.0 }
}

#[cfg(test)]
mod tests {
    use super::{averaged_angle_leftover, block_rate_sensitivity, CusumCalibration, ThresholdSource};

    /// The CUSUM held to more than its share (the break scan's unspent part added): the scale
    /// it divides its z's by brings the exact alarm probability over the monitored blocks to
    /// that many times the threshold's, with and without the widening's spread, and a ratio of
    /// 1 leaves the scale the widening alone gives.
    #[test]
    fn a_larger_alpha_scales_the_cusum_to_its_exact_alarm_probability() {
        use crate::detectors::cusum::cusum_false_alarm_probabilities;
        use crate::detectors::noise::NORMAL_NODES;
        let (kappa, share) = (0.5, 0.0025);
        let calibration = CusumCalibration::shared(ThresholdSource::FalseAlarm(share), kappa, 40);
        for steps in [6, 18, 30] {
            let h = calibration.threshold(steps).unwrap_or(f64::NAN);
            let exact = |c: f64| cusum_false_alarm_probabilities(h * c, kappa * c, steps).map_or(f64::NAN, |p| p[steps - 1]);
            assert!((exact(1.0) / share - 1.0).abs() < 1e-3, "{steps} blocks: threshold's probability {}", exact(1.0));
            for ratio in [1.8, 2.8, 4.0] {
                let c = calibration.predictive_scale(steps, 0.0, 0.0, ratio);
                assert!(c < 1.0, "{steps} blocks, ratio {ratio}: scale {c}");
                let p = exact(c);
                assert!((p / (share * ratio) - 1.0).abs() < 0.01, "{steps} blocks, ratio {ratio}: {p} against {}", share * ratio);
                // With the widening: the average over the scale's spread.
                let tau = 0.15_f64;
                let c = calibration.predictive_scale(steps, tau, 0.0, ratio);
                let averaged: f64 = NORMAL_NODES.iter().map(|(z, w)| w * exact(c * (-tau * z).exp())).sum();
                assert!((averaged / (share * ratio) - 1.0).abs() < 0.02, "{steps} blocks, ratio {ratio}, widened: {averaged}");
            }
            assert_eq!(calibration.predictive_scale(steps, 0.0, 0.0, 1.0), 1.0);
        }
    }

    /// The closed form against the table of benches/README.md (the same ratio computed by
    /// numpy from the ARMA(1, 1)'s MA weights and the block's residual maker): a short block
    /// barely feels the whitening's log-gain error, a long one nearly fully, and more so the
    /// weaker the colour. White noise (lag-1 0) and blocks too short for a scatter give 1.
    #[test]
    fn a_short_block_s_rate_barely_feels_the_whitening_s_gain_error() {
        for (l, lag1, table) in [(5, 0.5, 0.34), (11, 0.5, 0.63), (128, 0.5, 0.96), (5, 0.85, 0.04), (11, 0.85, 0.16), (32, 0.85, 0.50), (128, 0.85, 0.86), (16, 0.9, 0.15), (64, 0.9, 0.59)] {
            let kappa = block_rate_sensitivity(l, lag1);
            assert!((kappa - table).abs() < 0.011, "L {l}, lag-1 {lag1}: {kappa} against {table}");
        }
        assert!(block_rate_sensitivity(3, 0.85) == 1.0);
        assert!(block_rate_sensitivity(11, f64::NAN) == 1.0);
        assert!(block_rate_sensitivity(64, 0.0) > 0.95);
    }

    /// An angle error independent from sample to sample (a tool turning several encoder steps a
    /// sample), read through the nine-sample average the CUSUM regresses on: a block's slope of
    /// the error-free torque still varies by nearly G^2 q / Sxx (q the error's variance), the
    /// residuals about the block's line hold less than q / 9, and what the average took out of
    /// the angle (`averaged_angle_leftover`) is q (1 - 1/9). With it added, a block of 40
    /// samples has z variance a little under 1 (0.86: the leftover oversizes an independent
    /// error's part in a short block's slope, on the safe side); without it, over 8.
    #[test]
    fn the_averaged_angle_s_leftover_is_what_the_residuals_miss_of_the_block_slope() {
        use rand::{RngExt, SeedableRng};
        use rand_xoshiro::Xoshiro256PlusPlus;
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(17);
        let (m, step, rate, r) = (48usize, 0.37, 2.0, 0.5);
        let q = r * r / 12.0;
        let index: Vec<usize> = (0..m).collect();
        let (mut z2_with, mut z2_without, mut leftover_sum) = (0.0, 0.0, 0.0);
        let blocks = 4000;
        for _ in 0..blocks {
            let truth: Vec<f64> = (0..m).map(|i| i as f64 * step).collect();
            let xs: Vec<f64> = truth.iter().map(|x| x + r * (rng.random::<f64>() - 0.5)).collect();
            let y: Vec<f64> = truth.iter().map(|x| rate * x).collect();
            let mut smoothed = Vec::new();
            super::super::time_smoothed_angle(&xs, &index, super::super::TIME_SMOOTHING, &mut smoothed);
            // The block's line on the averaged angle, away from the run's ends (the CUSUM's
            // blocks are inside the window, where the average is over nine samples).
            let range = 4..m - 4;
            let (a, b) = crate::detectors::least_squares_line(&smoothed[range.clone()], &y[range.clone()]);
            let xm = smoothed[range.clone()].iter().sum::<f64>() / range.len() as f64;
            let sxx: f64 = smoothed[range.clone()].iter().map(|x| (x - xm).powi(2)).sum();
            let rss: f64 = range.clone().map(|i| (y[i] - a - b * smoothed[i]).powi(2)).sum();
            let residual_var = rss / (range.len() - 2) as f64;
            let leftover = averaged_angle_leftover(&xs, &smoothed, &[], range.clone());
            leftover_sum += leftover;
            let deviation = (b - rate) * sxx.sqrt();
            z2_with += deviation * deviation / (residual_var + rate * rate * leftover);
            z2_without += deviation * deviation / residual_var;
        }
        let (with, without, leftover) = (z2_with / blocks as f64, z2_without / blocks as f64, leftover_sum / blocks as f64);
        assert!((leftover / (q * 8.0 / 9.0) - 1.0).abs() < 0.05, "leftover {leftover} against {}", q * 8.0 / 9.0);
        assert!((0.8..1.02).contains(&with), "z variance with the leftover {with}");
        assert!(without > 8.0, "z variance without it {without}");
    }
}
