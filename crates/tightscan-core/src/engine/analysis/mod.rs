//! The analysis of one tightening, as a short sequence of named steps: check the channels,
//! find the phases and the elastic window, estimate the friction, then run each detector on
//! the window (break scan and end test, residual tests, L1 monitoring, CUSUM of the block
//! torque rates). Each detector step lives in its own file and fills its part of the row.

mod breaks;
mod cusum;
pub(super) use cusum::{CusumCalibration, ThresholdSource};
mod friction;
mod l1;
mod pf;
mod residuals;

use crate::engine::input::{ChannelRow, Sample, Samples, TighteningTable};
use crate::engine::rows::{PhaseRow, RowResult};
use crate::engine::schema;
use crate::engine::status::TighteningStatus;
use crate::engine::traces::DetectorTraces;
use crate::engine::Detector;
use crate::physics::phases::{find_phases, PhaseScratch, Phases, MIN_FIT_SAMPLES};
use crate::detectors::noise::{estimate_noise_in, whiten, NoiseModel, NoiseScratch};
use crate::physics::torque_rate::{
    after_is_longer, difference_noise_sd, encoder_resolution_at, resumed_after_time_gap, stop_ranges, without_relaxation, RelaxationFree,
    BACK_ON_LINE_SDS, Blocks, ElasticWindow, WindowError,
};

use friction::FrictionInput;

/// Per-worker scratch space, reused across tightenings.
#[derive(Default)]
pub(super) struct Scratch {
    blocks: Blocks,
    z: Vec<f64>,
    usable: Vec<usize>,
    residuals: Vec<f64>,
    stops: Vec<(f64, f64)>,
    phases: PhaseScratch,
    force: Vec<f64>,
    x: Vec<f64>,
    y: Vec<f64>,
    index: Vec<usize>,
    prefix: Vec<(f64, f64, f64, f64, f64)>,
    /// Prefix sums of the episode scan, and where the tool restarts in the window (the first
    /// sample after a pause; the window's first when it starts after a controller step).
    episode_prefix: Vec<(f64, f64)>,
    transients: Vec<usize>,
    line_residuals: Vec<f64>,
    bits: Vec<u64>,
    block_first: Vec<usize>,
    has_force: bool,
    regressor: Vec<f64>,
    /// The whitened window read backwards, for the start test of [`Detector::break_row`].
    reversed_x: Vec<f64>,
    reversed_y: Vec<f64>,
    /// The tested window starts where the elastic window does (at its torque level), not after
    /// a controller step or a pause: only then does the start test run.
    starts_at_level: bool,
    /// Samples of the window in `x`, `y`, `index` (stops left out); past it, up to the peak,
    /// those only the end test uses.
    n_window: usize,
    /// The window's noise model, and `x`, `y` (and clamp force) whitened with it; the first
    /// `lag` whitened samples have no past and are not used.
    noise: NoiseModel,
    noise_scratch: NoiseScratch,
    /// Standardised noise of the rundown before the window, for the tail fit of
    /// [`Scratch::gaussianise_heavy_tails`].
    rundown_noise: Vec<f64>,
    /// The rundown's stretch of `noise_t`, `noise_y` and the block length its noise was taken
    /// in, and the window's first torque: what [`Scratch::weigh_by_growth`] weighs again with.
    rundown_blocks: (std::ops::Range<usize>, usize),
    t0: f64,
    /// The noise's growth with the torque the window is weighed by, `sd ~ 1 + growth T`
    /// ([`window_growth`]; 0 where the noise model found none).
    growth: f64,
    /// Whether the weights now in `weights` (and the samples `wx`, `wy` weighed by them) carry
    /// the angle's quantisation error, and whether the shared ones, those every detector but
    /// the CUSUM and the filter reads, did.
    quantised_weights: bool,
    shared_quantised: bool,
    lag: usize,
    wx: Vec<f64>,
    wy: Vec<f64>,
    wf: Vec<f64>,
    /// The angle of `x` with the encoder's quantisation averaged out: the regressor the line is
    /// fitted on (the torque follows the true angle, not the recorded steps).
    xs: Vec<f64>,
    /// The encoder's grid in the window's recorded angle ([`encoder_resolution_at`], 0 where it
    /// is not quantised) and whether `xs` is its centred moving average ([`smooth_angle`]):
    /// found once, for the break scan's encoder-step check and the particle filter's angle.
    encoder_resolution: f64,
    angle_averaged: bool,
    /// Share of alpha the break scan cannot spend under its encoder-step check, which the
    /// CUSUM spends instead ([`Detector::break_row`]; 0 unless `scan_share_to_cusum`).
    cusum_extra_alpha: f64,
    /// Recorded angles just before the window (window coordinates), for [`smooth_angle`].
    context: Vec<f64>,
    /// `xs` averaged in time and whitened (weighted as `wx`): the CUSUM's block regressor
    /// ([`time_smoothed_angle`]).
    smooth_wx: Vec<f64>,
    smoothed: Vec<f64>,
    /// Each CUSUM block's slope variance from the angle's quantisation error that the pooled
    /// residuals miss (`cusum_row`).
    angle_error: Vec<f64>,
    noise_t: Vec<f64>,
    noise_y: Vec<f64>,
    /// Weights of the samples in `x` (empty: all 1): the inverse of the noise sd where the noise
    /// grows with the torque ([`NoiseModel::sd_slope`]), 1 at the window's mean torque. The
    /// whitened samples are of the weighted ones.
    weights: Vec<f64>,
    weighted: Vec<f64>,
    /// `xs` weighted, before whitening: the GLS break scan whitens its step regressors from it.
    weighted_x: Vec<f64>,
    gls_scratch: crate::detectors::gls_breakpoint::GlsScratch,
    /// Whitened samples of the window that follow a stop left out (the GLS scan's restarts).
    restarts: Vec<usize>,
    /// The snug angle in window coordinates (negative: before the window), where the clamp
    /// force starts: a friction drift's torque grows with the force times the drift.
    snug_x: f64,
    /// What part of the elastic window is tested, as a status names it (the window before or
    /// after a pause of the tool, or the whole window).
    tested_part: &'static str,
    /// Where the controller's step changes, in the current tightening.
    step_changes: Vec<usize>,
    /// When set, the detector steps record what they computed along the window into it
    /// ([`Detector::traces`]); the batch leaves it `None`, and records nothing.
    pub(super) trace: Option<Box<DetectorTraces>>,
}

/// 1 % point of the likelihood ratio of a Student t against the normal
/// ([`crate::detectors::noise::fit_student_t`]): the normal sits on the boundary of the t
/// family (nu infinite), so the null distribution is half a point mass at 0 and half a
/// chi-square with 1 degree of freedom (Self and Liang 1987), whose 1 % point is the
/// chi-square's 2 % point.
const HEAVY_TAIL_LR: f64 = 5.41;
/// The Student t fit of [`Scratch::gaussianise_heavy_tails`] runs only where the score
/// statistic for heavy tails ([`crate::detectors::noise::heavy_tail_score`], about standard
/// normal for Gaussian noise) reaches this: the likelihood ratio beyond [`HEAVY_TAIL_LR`] is
/// about a score of 2.3, and of 769 windows whose fit found heavy tails (the benches'
/// compare sets: simulated, independent generator with AR(1), t4 and encoder noise, real
/// Rexroth runs) none had a score below 1.58. Below 1, seven windows in ten, the fit (a
/// third of a detect's instructions) is skipped.
const HEAVY_TAIL_SCREEN: f64 = 1.0;
/// Fewer whitened samples than this, the window's front and the rundown's together, leave the
/// tails too uncertain to act on.
const MIN_TAIL_SAMPLES: usize = 30;
/// Fewest whitened samples of the window's front whose own scale the Student t fit takes (the
/// degrees of freedom are shared with the rundown's). The front alone had to hold
/// [`MIN_TAIL_SAMPLES`]: a slow channel's windows (500 Hz, 21-37 samples under HDT) were never
/// made Gaussian, and the start test took a t4 spike among their first samples for a change
/// (built-in HDT, 500 Hz, 0.01 deg, t4: 4.3 % false alarms, 19 of 26 break alarms the start
/// test's at p 1e-4 to 1e-20 on a straight noise-free line).
const MIN_FRONT_SAMPLES: usize = 10;

/// The part of the elastic window the detectors test, as a `too_short` status names it: the
/// whole window, or the part a controller event leaves (a step change, or a pause of the tool
/// after which the torque relaxed and was wound up again; [`without_relaxation`]).
const TESTED_WHOLE: &str = "elastic window";
const TESTED_AFTER_STEP: &str = "elastic window after the controller's last step change";
const TESTED_AFTER_PAUSE: &str = "elastic window after the tool's last pause";
const TESTED_BEFORE_PAUSE: &str = "elastic window before the tool paused and the torque relaxed";

/// Samples per block of the local quadratics the noise model is estimated from: long against
/// a 50 Hz filter's correlation time at 2 kHz (at 32 samples the estimate of phi 0.85 spread
/// half as much again), short enough that a friction change's kink hardly shows about a
/// quadratic in one.
const NOISE_BLOCK: usize = 64;
/// A long window (a fast channel: 400 samples and more at 10 kHz) gets its noise model from
/// blocks of a quarter of its length, up to [`MAX_NOISE_BLOCK`], over the rundown alone when
/// that holds [`MIN_RUNDOWN_BLOCKS`] of them: the local quadratics of a block take out
/// what is slower than the block, so 64-sample blocks never saw the slow part of the noise
/// that a scan over 400 samples does (under AR(1) 0.85 at 10 kHz the whitened residuals kept a
/// correlation of 0.1 at lags 1-5, and the scan's false alarms were 3-5 %).
const WINDOW_BLOCKS: usize = 4;
const MAX_NOISE_BLOCK: usize = 512;
/// Long blocks the rundown must hold for the long-window noise fit.
const MIN_RUNDOWN_BLOCKS: usize = 6;
/// Lag-1 autocorrelation of the noise model above which it is re-estimated with blocks of
/// twice [`NOISE_BLOCK`] (the moment solve's bound on a reflection is 0.995).
const NEAR_UNIT_ROOT: f64 = 0.99;
/// Lag-1 autocorrelation of the 64-sample fit above which the noise model is re-estimated
/// with blocks of twice [`NOISE_BLOCK`] and that fit is used. Under strong colour a 64-sample
/// quadratic takes out much of the noise's own slow part, and the bias correction that puts it
/// back spreads the estimate: on AR(1) noise plus a bent line (1,500 samples in two
/// stretches, 2,000 draws) the error of ln(1 - phi) has sd 0.21 / 0.52 at phi 0.85 / 0.9 with
/// 64-sample blocks and 0.13 / 0.21 with 128. The longer blocks are not the default because a
/// friction change's kink shows more about a longer quadratic: with 128-sample blocks
/// everywhere the built-in simulator's white-noise 3-15 % changes were found in 94.5 % instead
/// of 99.3 %. Under colour this strong the noise, not the kink, dominates a block. Measured
/// with [`STRONG_COLOUR_AGREEMENT`] (`benches/detection_quality.py --n 1500`, AR(1) 0.85):
/// 15-45 / 3-15 % changes found 79.5 / 44.6 % -> 83.8 / 53.1 % on the independent generator
/// (false alarms 0.47 % both), 93.6 / 83.3 -> 96.1 / 89.2 % on the built-in simulator (0.67 %
/// both). Below 0.7 it changes nothing measurable (the AR(1) 0.5 cells).
const STRONG_COLOUR: f64 = 0.7;
/// How much higher than the 64-sample fit's the longer blocks' lag-1 autocorrelation may come
/// out for their fit to be used ([`STRONG_COLOUR`]). On genuinely coloured noise the two agree
/// to a few hundredths; a friction change inside the window (a kink, or the steps of an
/// intermittent fault on white noise that the 64-sample fit already read as lag-1 0.7 and
/// more) shows more about the longer quadratics and drives their fit towards the unit root.
/// Without this check the built-in simulator's white-noise 3-15 % changes were found in 97.6 %
/// instead of 98.5 %, and the over-whitened clean curves fell below the nominal rate
/// (independent CSDT / HDT under AR(1) 0.9: 0.43 / 0.33 % of 4,000 at alpha 0.01; with it
/// 0.85 / 0.50 %).
const STRONG_COLOUR_AGREEMENT: f64 = 0.05;
/// Half-width in samples of [`time_smoothed_angle`]. Short: the torque follows the angle's own
/// fast motion (a speed ripple) too, and an average over 16 samples either side took the
/// built-in simulator's clean curves from 0.73 to 2.2 % false alarms; over 4, 0.73 %.
const TIME_SMOOTHING: usize = 4;
/// Samples before the window the noise model may use at least: the channel's noise is the same
/// in the rundown, and a thousand samples pin phi near 1 where a window's few hundred do not.
const NOISE_HISTORY: usize = 1024;
/// Samples before the window whose encoder counts help interpolate the window's staircase.
const ENCODER_CONTEXT: usize = 256;

impl Scratch {
    /// The samples the detectors use, in window coordinates (angle and torque relative to the
    /// window's first sample): the window without its stop ranges (a CSDT pause: relaxation at
    /// standstill and the wind-up after it are not friction), then, when `tail_end` is given
    /// (the peak's index; `None` when the curve yields, whose end is bent on purpose), the
    /// samples between the window's end and the peak. Then the noise model of the window and
    /// the whitened samples ([`crate::detectors::noise`]), fitted over the window and the
    /// curve's samples `rundown` (the rundown after the tool's start-up, before the seating).
    fn window_samples<A: Sample, T: Sample>(&mut self, angle: &[A], torque: &[T], window: ElasticWindow, tail_end: Option<usize>, rundown: std::ops::Range<usize>) {
        let a0 = angle[window.start].to_f64();
        let t0 = torque[window.start].to_f64();
        self.x.clear();
        self.y.clear();
        self.index.clear();
        let last = tail_end.map_or(window.end, |end| (end + 1).min(angle.len()).max(window.end));
        for i in window.start..last {
            let x = angle[i].to_f64() - a0;
            if !self.stops.iter().any(|&(lo, hi)| x >= lo && x <= hi) {
                self.x.push(x);
                self.y.push(torque[i].to_f64() - t0);
                self.index.push(i);
            }
        }
        self.n_window = self.index.partition_point(|&i| i < window.end);
        let n = self.n_window;
        // The samples just before the window add knots to the staircase's interpolation: a window
        // of 40 samples on a beat of 30 holds one or two.
        let context = window.start.saturating_sub(ENCODER_CONTEXT);
        self.context.clear();
        if self.index.first() == Some(&window.start) {
            self.context.extend(angle[context..window.start].iter().map(|a| a.to_f64() - a0));
        }
        (self.encoder_resolution, self.angle_averaged) = smooth_angle(&self.context, &self.x, &self.index, n, a0, &mut self.xs);
        // The noise is the channel's, the same before the window as in it, and the window alone
        // (a few hundred samples) leaves the autoregression too uncertain where it matters
        // most, near phi = 1: an error of 0.05 in phi = 0.85 leaves 1.8 times the variance a
        // white-noise test expects. So it is estimated over the window and the rundown before
        // it (at least NOISE_HISTORY samples, or three windows' worth), torque on sample number:
        // local fits in time follow the torque's own course, at standstill too. With 300-sample
        // windows and three windows before, the estimates of phi 0.85 spread over 0.67-0.86
        // and the clean curves of the independent generator got 7-11 % false alarms at alpha
        // 1 %; with the rundown, 2.8-3.8 %.
        let first = window.start.saturating_sub(NOISE_HISTORY.max(3 * (window.end - window.start)));
        self.noise_y.clear();
        self.noise_y.extend(torque[first..window.end].iter().map(|t| t.to_f64()));
        self.noise_t.clear();
        self.noise_t.extend((0..self.noise_y.len()).map(|i| i as f64));
        // Two stretches: the rundown up to the seating, and the window. The seating between
        // them bends faster than a local quadratic over a block follows, and a block across it
        // reads the bend as strong correlation.
        let rundown_end = rundown.end.saturating_sub(first).min(window.start - first);
        let rundown = rundown.start.saturating_sub(first).min(rundown_end)..rundown_end;
        // The window's stretch is cut where its stops were left out (a CSDT pause: the
        // relaxation at standstill and the wind-up after it): a block across a pause reads the
        // relaxation's kinks as correlation, and under AR(1) noise of phi 0.9 one CSDT curve in
        // ten had its phi estimated at the bound (0.995), 5.7 % false alarms of the CUSUM.
        let mut segments = vec![rundown];
        let mut run_start = 0;
        for k in 1..=n {
            if k == n || self.index[k] != self.index[k - 1] + 1 {
                if k > run_start {
                    segments.push(self.index[run_start] - first..self.index[k - 1] + 1 - first);
                }
                run_start = k;
            }
        }
        let long_block = (n / WINDOW_BLOCKS).min(MAX_NOISE_BLOCK);
        let on_rundown = long_block > NOISE_BLOCK && segments[0].len() >= MIN_RUNDOWN_BLOCKS * long_block;
        let fitted = if on_rundown { &segments[..1] } else { &segments[..] };
        // On the rundown alone where the blocks are long: a friction change inside the window,
        // read about a long block's quadratic, passes for correlation (with the window in, the
        // built-in simulator's recall fell 0.972 -> 0.952 on 3-15 % changes).
        let block = if on_rundown { long_block } else { NOISE_BLOCK };
        self.noise = estimate_noise_in(&self.noise_t, &self.noise_y, fitted, block, &mut self.noise_scratch);
        let lag1 = self.noise.lag1_autocorrelation();
        // (refit above this lag-1, how far above the first fit's the longer one may come out:
        // on the rundown only below it)
        let (refit_above, may_rise) = if on_rundown { (NEAR_UNIT_ROOT, None) } else { (STRONG_COLOUR, Some(STRONG_COLOUR_AGREEMENT)) };
        if lag1 > refit_above {
            // Strong colour: the 64-sample blocks' estimate spreads widely ([`STRONG_COLOUR`]),
            // and blocks twice as long pin it. On the rundown alone the blocks are already long
            // and only the unit-root bound is at stake: near phi = 1 the local quadratics of one
            // block leave moments that barely tell phi 0.9 from 0.995 (under AR(1) noise of phi
            // 0.9, 6 % of the built-in simulator's curves had phi at the moment solve's bound,
            // and 13-29 % of those raised a false alarm), and blocks twice as long tell them
            // apart.
            let longer = estimate_noise_in(&self.noise_t, &self.noise_y, fitted, 2 * block, &mut self.noise_scratch);
            // A white fit of the longer blocks is no answer: it is what the solve returns when
            // too few blocks remain (a slow channel), not evidence against correlation.
            let longer_lag1 = longer.lag1_autocorrelation();
            let agrees = may_rise.map_or(longer_lag1 < lag1, |rise| longer_lag1 <= lag1 + rise);
            if !longer.coefficients.is_empty() && agrees {
                self.noise = longer;
            }
        }
        self.lag = self.noise.coefficients.len();
        self.rundown_blocks = (segments[0].clone(), block);
        self.t0 = t0;
        // The window is weighed by the noise's growth as the fitted sd line gives it over the
        // window (`window_growth`, as the particle filter was first), not by the noise model's
        // `sd_slope`, whose intercept is floored at a tenth of the loudest block's sd to keep a
        // proportional noise from giving the quiet rundown unbounded weight. That floor flattened
        // the window's weights: on the independent generator's transducer (0.01 Nm + 0.4 % of
        // the torque, s1 / s0 = 0.4 per Nm; floored 0.1-0.2) the weighted noise still grew by a
        // fifth along the window, and the CUSUM's last blocks' z's had variance 1.2-1.4 against
        // the first's 1.0 (benches/README.md, size grid).
        self.growth = window_growth(self.noise.sd_line, &self.xs[..n], &self.y[..n], t0);
        self.weigh_and_whiten(self.growth, true);
        self.shared_quantised = self.quantised_weights;
        let phi = &self.noise.coefficients;
        self.wf.clear();
        if self.has_force {
            // The clamp force of these samples, weighted (`noise_y` keeps the torque, for
            // [`Scratch::weigh_by_growth`]).
            self.weighted.clear();
            self.weighted.extend(self.index.iter().enumerate().map(|(k, &i)| self.force[i] * self.weights.get(k).copied().unwrap_or(1.0)));
            whiten(&self.weighted, phi, &mut self.wf);
        }
        self.gaussianise_heavy_tails();
    }

    /// Heavy-tailed noise (a transducer's spikes, EMI, a t distribution with few degrees of
    /// freedom) is made Gaussian before the tests. The break scan and the end test are F tests
    /// whose size holds for Gaussian noise only: under t4 noise a single outlying last sample
    /// passed the end test with p 1e-6, 8.7 % false alarms on the independent generator's clean
    /// CST curves. Where the whitened residuals of the line through the window's front (all but
    /// its last minimum segment) are heavy-tailed -- a Student t fitted to them by maximum
    /// likelihood beats the normal at the 1 % level ([`HEAVY_TAIL_LR`]) -- every whitened torque
    /// from that line on, up to the peak, is replaced by its normal score: the Gaussian quantile
    /// of its probability under that t (a probability integral transform). A spike of a t4
    /// window then carries the weight a Gaussian outlier of the same probability would, while a
    /// friction change of tens of noise sds in the last sample still stands out (its t
    /// probability is tiny), which clipping at a fixed number of sds lost. The t's degrees of
    /// freedom came from the sample kurtosis before (`nu = 4 + 6 / g2`, behind a kurtosis test):
    /// biased high, and the test missed a third of t4 windows of 100 samples, which left 3.2 %
    /// (CST) and 5.4 % (HDT) false alarms on the independent generator's t4 curves.
    fn gaussianise_heavy_tails(&mut self) {
        use statrs::distribution::{ContinuousCDF, Normal, StudentsT};
        let (lag, n) = (self.lag, self.n_window);
        // The front of the window only: a late friction change, which only the end test can
        // see, would itself look like a heavy tail of the whole window's residuals.
        let front = n.saturating_sub(crate::detectors::breakpoint::min_segment(n.saturating_sub(lag)));
        if front < lag + MIN_FRONT_SAMPLES
            || front - lag + self.rundown_noise.len() < MIN_TAIL_SAMPLES
            || front > self.wx.len()
            || self.wy.len() != self.wx.len()
        {
            return;
        }
        let (a, b) = crate::detectors::least_squares_line(&self.wx[lag..front], &self.wy[lag..front]);
        self.weighted.clear();
        self.weighted.extend(self.wx[lag..front].iter().zip(&self.wy[lag..front]).map(|(x, y)| y - a - b * x));
        // The tails are judged on the window's front and the rundown before it together (the
        // channel's noise is the same in both; a window of 60 samples alone told t4 from a
        // normal in half the cases), with one degrees of freedom and a scale for each.
        // The fit only where the score test of the same hypothesis does not already rule heavy
        // tails out ([`HEAVY_TAIL_SCREEN`]).
        if crate::detectors::noise::heavy_tail_score(&[&self.rundown_noise, &self.weighted]) < HEAVY_TAIL_SCREEN {
            return;
        }
        let Some(fit) = crate::detectors::noise::fit_student_t_groups(&[&self.rundown_noise, &self.weighted]) else {
            return;
        };
        let t_scale = fit.scales.get(1).copied().unwrap_or(f64::NAN);
        if !(fit.lr > HEAVY_TAIL_LR && t_scale > 0.0) {
            return;
        }
        let nu = fit.nu;
        let (Ok(t), Ok(normal)) = (StudentsT::new(0.0, 1.0, nu), Normal::new(0.0, 1.0)) else {
            return;
        };
        // The normal scores are put back on the Gaussian scale of the same body (the normal
        // whose median absolute value is the t's), so the window's line stays in Nm.
        let normal_scale = t_scale * t.inverse_cdf(0.75) / normal.inverse_cdf(0.75);
        if !(t_scale > 0.0) {
            return;
        }
        for (x, y) in self.wx[lag..].iter().zip(self.wy[lag..].iter_mut()) {
            let fit = a + b * x;
            let r = (*y - fit) / t_scale;
            // The lower tail's probability, mirrored for positive residuals: 1 - cdf loses the
            // digits that a change of many sds has.
            let tail = t.cdf(-r.abs()).max(f64::MIN_POSITIVE);
            let score = -normal.inverse_cdf(tail);
            *y = fit + normal_scale * score.copysign(r);
        }
    }

    /// The weights of noise that grows with the torque: `w_i = 1 / (1 + kappa T_i)`, with `T_i`
    /// the straight elastic line through the window (absolute torque, `t0` its first sample) and
    /// kappa the noise model's `sd_slope`. Weighted least squares in disguise, and exact for
    /// the tests: with the sd affine in the angle, `sd_i = c0 + c1 x_i`, the weighted line
    /// `y_i w_i = a w_i + b x_i w_i + u_i` is, since `w_i = (1 - c1 x_i w_i) / c0`, again a
    /// straight line `y_i w_i = a / c0 + (b - a c1 / c0) (x_i w_i) + u_i` in the weighted angle,
    /// with a constant intercept and errors of one variance; a change of `a` or `b` stays a
    /// change of it. So every detector runs unchanged on the weighted samples.
    fn noise_weights(&mut self, t0: f64, kappa: f64, angle_error: bool) {
        self.weights.clear();
        self.quantised_weights = false;
        let n = self.n_window;
        if !(kappa > 0.0) || n < 2 {
            return;
        }
        let (a, b) = crate::detectors::least_squares_line(&self.xs[..n], &self.y[..n]);
        let mean_level = t0 + self.y[..n].iter().sum::<f64>() / n as f64;
        // The angle's quantisation error, in torque: the torque rate times an error uniform over
        // the encoder step r, sd |b| r / sqrt(12), at every level of the window alike, in units
        // of the noise sd's intercept (`s0 = s1 / kappa`). The noise model, fitted to torque on
        // sample number, never sees it, and where the noise grows with the torque the window's
        // first samples got the weight of their small torque noise alone: at 2 kHz with a 0.5 deg
        // encoder an HDT tool turns three counts a sample there (nothing tells where within its
        // step the shaft is), about 0.1 Nm of error against 0.03-0.07 Nm of noise, and the start
        // test claimed 3.2 % of clean curves. The whole step, not what the interpolation between
        // the count's rises may leave of it (the error over the sample's advance where the tool
        // turns less than a step a sample): with that, the independent generator's clean CST
        // curves at 2 kHz with a 0.5 deg encoder under AR(1) noise of phi 0.85 / 0.9 gave 4.9 /
        // 7.3 % false alarms (1.0 / 0.8 % with the whole step; benches/README.md).
        let s1 = self.noise.sd_line.1;
        let quantisation = if angle_error && s1 > 0.0 { b.abs() * self.encoder_resolution / 12.0_f64.sqrt() * kappa / s1 } else { 0.0 };
        let quantisation = if quantisation.is_finite() { quantisation } else { 0.0 };
        let sd = |level: f64| (1.0 + kappa * level.max(0.0)).hypot(quantisation);
        let reference = sd(mean_level);
        self.weights.extend(self.xs.iter().map(|x| reference / sd(t0 + a + b * x)));
        self.quantised_weights = quantisation > 0.0;
    }

    /// The window weighted and whitened again (`weights`, `wx`, `wy`, the rundown's noise and
    /// the heavy tails' normal scores) for noise whose sd grows as `1 + kappa T` instead of
    /// the noise model's `sd_slope`. The clamp force (`wf`) keeps the shared weights. For the
    /// particle filter, which runs after every other detector has read the shared samples.
    /// Without the angle's quantisation error: with it, the filter's false alarms at alpha 0.05
    /// on the independent generator's clean curves (2 kHz, 0.5 deg encoder, white noise, 600 a
    /// strategy) rose from 20.0 / 28.3 / 17.3 % to 30.0 / 42.5 / 25.2 % (CST / CSDT / HDT): its
    /// excess there grows as the noise falls against the quantisation, and flatter weights give
    /// the quiet samples' quantisation more say (benches/README.md, pf section).
    pub(super) fn weigh_by_growth(&mut self, kappa: f64) {
        self.weigh_and_whiten(kappa, false);
        self.gaussianise_heavy_tails();
    }

    /// The shared samples again (weighed by `growth` with the angle's quantisation error),
    /// where a detector before the caller weighed them without it.
    pub(super) fn restore_shared_weights(&mut self) {
        if self.shared_quantised && !self.quantised_weights {
            self.weigh_and_whiten(self.growth, true);
            self.gaussianise_heavy_tails();
        }
    }

    /// The window's angle and torque weighted for noise whose sd grows as `1 + kappa T` and
    /// whitened by the noise model (`weights`, `wx`, `wy`), and the rundown's noise
    /// standardised with the same growth (the heavy-tail fit's reference).
    fn weigh_and_whiten(&mut self, kappa: f64, angle_error: bool) {
        self.noise_weights(self.t0, kappa, angle_error);
        let phi = &self.noise.coefficients;
        weigh(&self.xs, &self.weights, &mut self.weighted_x);
        whiten(&self.weighted_x, phi, &mut self.wx);
        weigh(&self.y, &self.weights, &mut self.weighted);
        whiten(&self.weighted, phi, &mut self.wy);
        self.rundown_noise.clear();
        let (rundown, block) = self.rundown_blocks.clone();
        crate::detectors::noise::block_noise(&self.noise_t, &self.noise_y, rundown, block, phi, kappa, &mut self.rundown_noise);
    }
}


/// The angle `xs` (encoder staircase already interpolated) averaged over `half_width` samples
/// either side, in time, within each run of consecutive samples (`index`), the average narrowed
/// symmetrically at a run's ends so that an angle linear in time passes unchanged.
///
/// Why: near the unit root the whitened regressor `x_t - phi x_{t-1}` is mostly the angle's
/// sample-to-sample change, and what is left of the encoder's staircase after interpolation is
/// such a change: errors in the regressor, which only ever flatten a block's whitened slope. The
/// CUSUM compares block slopes, so their spread from block to block read as decreases of the
/// torque rate: under AR(1) 0.9 with a 0.1 deg encoder (independent generator, CST, 2 kHz) 18
/// CUSUM alarms in 2,000 clean curves, all `decrease`, block-slope dispersion 1.21; none and
/// 0.90 with the average (and none, 0.91, with a 0.01 deg encoder either way).
fn time_smoothed_angle(xs: &[f64], index: &[usize], half_width: usize, out: &mut Vec<f64>) {
    out.clear();
    let n = xs.len().min(index.len());
    let mut start = 0;
    while start < n {
        let mut end = start + 1;
        while end < n && index[end] == index[end - 1] + 1 {
            end += 1;
        }
        for t in start..end {
            let h = half_width.min(t - start).min(end - 1 - t);
            out.push(xs[t - h..=t + h].iter().sum::<f64>() / (2 * h + 1) as f64);
        }
        start = end;
    }
    out.extend_from_slice(&xs[n..]);
}

/// Largest ratio of the noise sd at the window's loudest end to that at its quietest that the
/// window's weights take from the fitted sd line ([`window_growth`]).
const MAX_WINDOW_SD_RATIO: f64 = 10.0;

/// The growth `kappa` of the noise sd with the torque, `sd ~ 1 + kappa T`, that the window is
/// weighed by for every detector, from the noise model's fitted sd line `(s0, s1)` (`sd = s0 + s1 T`,
/// [`crate::detectors::noise::NoiseModel::sd_line`]) over the window's straight line in the
/// angle `xs` (torque `y` from `t0`, the window's first absolute torque).
///
/// Why not the noise model's `sd_slope`: that floors `s0` at a tenth of the loudest 8-sample
/// block's sd over the rundown and the window, to keep a purely proportional noise from giving
/// the quiet rundown unbounded weight. But the loudest block is where a heavy tail's spike, the
/// seating's bend or a pause's relaxation sits: on the independent generator's t4 CSDT curves
/// (0.01 Nm + 0.4 % of the torque: s1 / s0 = 0.4 per Nm) the line came out at about 0.4, the
/// floored slope at 0.06-0.2, and the filter, which weighs most the loud end where the change
/// evidence lies, read the unweighted growth there as a kink. Only the window's samples are
/// weighed, so the bound that matters is on the sd across the window: `s0` is raised only as
/// far as keeps the fitted sd at the window's loud end within [`MAX_WINDOW_SD_RATIO`] of its
/// quiet end (and positive), the same tenth, but of the fitted line's range where the weights
/// apply. 0 where no growth was found.
///
/// Measured (benches/pf_quality.py --trace, 1,799-1,800 clean curves a cell, alpha 0.05):
/// independent CSDT t4 8.28 -> 5.95 %, CSDT white 7.12 -> 5.73 %, CST white 6.67 -> 5.67 %;
/// the weighted window's residuals no longer grow along it (mean log sd ratio of its last
/// third to its first, HDT white: 0.098 -> 0.006). The strong-colour cells fall to the
/// p-value's own level for iid innovations on the same windows (CST AR(1) 0.9 2.78 -> 1.61 %,
/// iid 1.33-1.61 %): the mis-weighting had lifted them. The built-in simulator's constant
/// noise rarely shows a growth, and its cells are as they were. The other detectors kept the
/// floored slope until the CUSUM's over-dispersion on the same curves was traced to it
/// (benches/README.md, size grid): weighed by this growth, the rule's clean false alarms on
/// the independent generator went 0.96 -> 0.90 % pooled over the size grid at 2,000 curves a
/// cell, with recall unchanged or up.
pub(super) fn window_growth((s0, s1): (f64, f64), xs: &[f64], y: &[f64], t0: f64) -> f64 {
    let n = xs.len().min(y.len());
    if !(s1 > 0.0) || n < 2 {
        return 0.0;
    }
    let (a, b) = crate::detectors::least_squares_line(&xs[..n], &y[..n]);
    let (x_lo, x_hi) = xs[..n].iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    let (t_a, t_b) = ((t0 + a + b * x_lo).max(0.0), (t0 + a + b * x_hi).max(0.0));
    let (quiet, loud) = (t_a.min(t_b), t_a.max(t_b));
    let ratio = MAX_WINDOW_SD_RATIO;
    let bounded = s1 * (loud - ratio * quiet) / (ratio - 1.0);
    let growth = s1 / s0.max(bounded).max(1e-3 * s1 * loud);
    if growth.is_finite() && growth > 0.0 { growth } else { 0.0 }
}

/// `v` times `weights` into `out` (`v` itself when there are no weights).
fn weigh(v: &[f64], weights: &[f64], out: &mut Vec<f64>) {
    out.clear();
    if weights.is_empty() {
        out.extend_from_slice(v);
    } else {
        out.extend(v.iter().zip(weights).map(|(v, w)| v * w));
    }
}

/// Where one tightening sits in the table, and what the table says of its controller steps.
#[derive(Clone, Copy, Debug)]
struct Curve<'a> {
    /// Row of the tightening in the batch (seeds the kernel-density test's permutations).
    row: usize,
    /// Samples where the controller's step changes (empty without a step channel).
    step_changes: &'a [usize],
    /// The time channel, when the table has it.
    time: Option<Samples<'a>>,
}

/// The part of the elastic window the detectors test when the controller changed step inside
/// it: from where the last step inside the window is back on the elastic line the step before
/// had reached (its highest torque, extended at the elastic torque rate `rate` over the angle
/// since). A step change stops or slows the tool (the torque relaxes, then winds up again faster
/// than friction would raise it) and changes the speed, and with it the speed-dependent
/// friction: a break at the change is the controller's, not a friction change (real Rexroth
/// runs: pre-tightening to 1.1 Nm, then the final step at low speed, both inside the elastic
/// window; a few change from thread forming to pre-tightening inside it as well). The old level
/// alone is reached while the socket still winds up, and the kink where the wind-up meets the
/// line was found as a break.
fn last_step_window<A: Sample, T: Sample>(
    angle: &[A],
    torque: &[T],
    window: ElasticWindow,
    rate: f64,
    step_changes: &[usize],
    scratch: &mut Vec<f64>,
) -> ElasticWindow {
    let Some(&c) = step_changes.iter().rev().find(|&&c| c > window.start && c < window.end) else {
        return window;
    };
    let high = (window.start..c).max_by(|&p, &q| torque[p].to_f64().total_cmp(&torque[q].to_f64())).unwrap_or(c);
    let (level, from) = (torque[high].to_f64(), angle[high].to_f64());
    let rate = if rate > 0.0 { rate } else { 0.0 };
    // The highest torque sits above the line by its noise: back on the line within a few sds.
    let tolerance = BACK_ON_LINE_SDS * difference_noise_sd(angle, torque, window, rate, scratch);
    let on_line = |k: &usize| torque[*k].to_f64() >= level + rate * (angle[*k].to_f64() - from).max(0.0) - tolerance;
    let regained = (c..window.end)
        .find(on_line)
        .or_else(|| (c..window.end).find(|&k| torque[k].to_f64() >= level))
        .unwrap_or(c);
    ElasticWindow { start: regained, ..window }
}

/// The part of the window after the last stop the recorder did not sample (a gap in the time
/// channel, see [`resumed_after_time_gap`]), when it is at least as long as the part before;
/// otherwise the part before the stop, and the curve past it is not tested (the second value:
/// true when the window was cut there). A controller that pauses inside the final rise starts a
/// new segment: on the real Rexroth runs the torque is nearly flat before the pause and rises
/// after it, and one line through both is a misfit, not a friction change. A stop the recorder
/// did sample (a run of unchanged angle, the simulator's CSDT pause) joins one elastic line and
/// is only left out ([`stop_ranges`]).
fn around_unsampled_stop<T: Sample>(
    torque: &[T],
    window: ElasticWindow,
    time: Option<Samples<'_>>,
    scratch: &mut Vec<f64>,
) -> (ElasticWindow, bool) {
    let resumed = match time {
        Some(Samples::F32(t)) => resumed_after_time_gap(torque, t, window, scratch),
        Some(Samples::F64(t)) => resumed_after_time_gap(torque, t, window, scratch),
        None => None,
    };
    match resumed {
        Some((high, k)) if after_is_longer(window.start, high, k, window.end) => (ElasticWindow { start: k, ..window }, false),
        Some((high, _)) => (ElasticWindow { end: high + 1, ..window }, true),
        None => (window, false),
    }
}

/// Steps of the angle, in encoder steps, up to which [`sawtooth`] counts them: a tool turning
/// this many steps a sample or more moves the quantisation error's phase by a different part of
/// a step each sample, no slow sawtooth.
const SAWTOOTH_STEPS: f64 = 8.0;

/// True when the steps of `x` take at least two multiples of `resolution` below
/// [`SAWTOOTH_STEPS`], the rarer in at least 5 % of those steps.
fn sawtooth(x: &[f64], resolution: f64) -> bool {
    let mut counts = [0usize; SAWTOOTH_STEPS as usize];
    let mut steps = 0usize;
    for w in x.windows(2) {
        let q = ((w[1] - w[0]) / resolution).round();
        if (0.0..SAWTOOTH_STEPS).contains(&q) {
            counts[q as usize] += 1;
            steps += 1;
        }
    }
    counts.sort_unstable();
    steps > 0 && counts[6] * 20 >= steps
}

/// The knots of an encoder staircase: where the shaft crossed an encoder count, as (sample
/// time, angle less the carrier), over samples `t` (consecutive, or k = 0) and their recorded
/// angles `a`. The carrier is a whole number `k` of steps per sample, `carrier` = k x `resolution`
/// in angle per sample. With an advance of s = k + d steps per sample the recorded angle less k
/// steps a sample is the count of a slow ramp of d steps a sample: it moves by one step every
/// 1/|d| samples, a beat that the whitened regression reads as structure (a 0.5 deg encoder at
/// 2 kHz on a tool turning 1.03 steps a sample: a one-step sawtooth of 30 samples, 4-6 % false
/// alarms of the break test on clean curves). Between its moves the beat is interpolated as a
/// slow encoder's count is. k = 0 is the slow encoder itself: its count only rises, and a
/// running maximum keeps an encoder dithering on an edge from making moves of its own.
fn encoder_knots(t: &[f64], a: &[f64], carrier: f64, resolution: f64, window_end: f64, knots: &mut Vec<(f64, f64)>) {
    knots.clear();
    let Some(&t_ref) = t.first() else { return };
    if carrier == 0.0 {
        // A rise first seen after a gap (a CSDT pause left out) happened somewhere in the gap,
        // not half a sample before: it is no knot.
        let mut high = a[0];
        let mut previous = t_ref;
        for (&t, &a) in t.iter().zip(a).skip(1) {
            if a > high + 0.5 * resolution {
                if t == previous + 1.0 {
                    knots.push((t - 0.5, a));
                }
                high = a;
            }
            previous = t;
        }
        return;
    }
    let mut level = a[0];
    for (&t, &a) in t.iter().zip(a).skip(1) {
        let beat = a - carrier * (t - t_ref);
        // A move of the beat by one step: the shaft crossed the boundary between the two
        // levels, the higher one, half a sample before the sample that shows it. Past the
        // window (`window_end`) a move by several steps in one sample is no knot: the tool
        // brakes within the sample, and when the shaft crossed the level is not known. Taken
        // at half a sample, it held the braking tool at full speed for that half, a step ahead
        // of the shaft once clamped to the cell: a slow channel's last samples sat a step
        // ahead of the line (independent generator, CST 500 Hz, 0.1 deg encoder, AR(1) 0.85,
        // 1,000 clean curves: the end test's claims 10 -> 20, every added jump negative).
        // Inside the window such moves stay knots: an HDT tool slows through it, two steps
        // off the carrier at its ends, and without them the built-in simulator's clean curves
        // alarmed at 1.27 % instead of 0.97 % (6,000, alpha 0.01).
        let moved = (beat - level).abs();
        if moved > 0.5 * resolution {
            if moved < 1.5 * resolution || t <= window_end {
                knots.push((t - 0.5, beat.max(level)));
            }
            level = beat;
        }
    }
}

/// The least-squares quadratic in time through `knots` (four about the interval it is used on),
/// as (its centre time, its coefficients in time from that centre), or `None` where they do not
/// fix one.
fn quadratic_through(knots: &[(f64, f64)]) -> Option<(f64, nalgebra::Vector3<f64>)> {
    let centre = knots.iter().map(|k| k.0).sum::<f64>() / knots.len() as f64;
    let rows = knots.iter().map(|&(t, a)| ([1.0, t - centre, (t - centre).powi(2)], a));
    crate::detectors::least_squares_3(rows).map(|(c, _, _)| (centre, c))
}

/// The recorded angle `x` with its encoder quantisation taken out, into `out`, where the
/// encoder is coarse against the angle per sample. Whitening amplifies what changes from sample
/// to sample, and quantisation error is such a change: on the raw angle a whitened regressor is
/// mostly encoder steps, and the block slopes mostly noise. `index` holds the samples' numbers
/// (the time axis: stops are left out of `x`). The first `n` samples are the window, the rest
/// the samples past it up to the peak.
///
/// Where the encoder count rises at most every third sample, the angle is interpolated linearly
/// in time between the rises: the shaft passed the new count between the sample before a rise
/// and the rise, so half a sample before it is where the recorded angle is exact, whatever the
/// speed. Where rises are denser, a centred moving average over about two encoder steps' worth
/// of samples, narrowed symmetrically at the window's ends so a straight line passes unchanged.
/// The moving average alone, capped at 65 samples, left most of a 0.5 deg encoder's sawtooth at
/// 10 kHz (an encoder step every 14-100 samples as an HDT tool slows): 13 % false alarms on
/// clean white-noise curves.
///
/// Returns the encoder's grid of `x[..n]` ([`encoder_resolution_at`]; `origin` is the recorded
/// angle `x` is measured from) and whether the result is that moving average.
fn smooth_angle(context: &[f64], x: &[f64], index: &[usize], n: usize, origin: f64, out: &mut Vec<f64>) -> (f64, bool) {
    out.clear();
    let resolution = encoder_resolution_at(&x[..n], origin);
    let found = resolution;
    let step = if n > 1 { (x[n - 1] - x[0]) / (n - 1) as f64 } else { 0.0 };
    if !(resolution > 0.0 && step > 0.0) || index.len() < n {
        out.extend_from_slice(x);
        return (found, false);
    }
    // The rises of the count (a running maximum, so that an encoder dithering on an edge does
    // not make rises of its own), each at half a sample before the sample that shows it; the
    // samples past the window (up to the peak) too, so that the end test compares like with
    // like: the recorded angle is floor-quantised, half a step behind on average, and a window
    // interpolated against a recorded tail made 22 % false alarms of the end test.
    let m = x.len().min(index.len());
    // One time axis for the context (the consecutive samples just before the window) and the
    // window with its tail.
    let before = context.len();
    let t_first = index[0] as f64;
    let times: Vec<f64> = (0..before).map(|j| t_first - (before - j) as f64).chain(index[..m].iter().map(|&i| i as f64)).collect();
    let angles: Vec<f64> = context.iter().chain(&x[..m]).copied().collect();
    // A carrier only where the window's samples are consecutive. Around a CSDT pause the tool
    // brakes, stands and winds up again: no whole number of steps a sample fits, and carrying
    // one through the runs on either side of the pause raised the false alarms of clean CSDT
    // curves (0.5 deg encoder, 2 kHz) from 3.3 % to 4.3 %. A slow encoder's rises (k = 0) hold
    // across the gaps.
    let consecutive = index[..n].windows(2).all(|w| w[1] == w[0] + 1);
    // A carrier needs a real encoder grid and a beat that moves inside the window: every step
    // a whole number of encoder steps (to a hundredth), at least one of them not k. A fine
    // encoder at a low rate passes `encoder_resolution`'s looser check with its smallest step
    // as the "resolution" (500 Hz, 0.01 deg: 120 or 121 counts a sample, within 5 % of one
    // "step"), and its beat, a cell of one such step, turned 0 % false alarms into 4.6 %. A
    // tool turning 2.02 steps a sample shows steps of 2 and 3 encoder steps only, and the
    // smallest step is then two: the grid is looked for at a half, a third and a quarter of it.
    let mut k = 0.0;
    let mut grid = resolution;
    if consecutive && n > 1 {
        for divisor in 1..=4 {
            let r = resolution / divisor as f64;
            let kk = ((x[n - 1] - x[0]) / (n - 1) as f64 / r).round();
            let (mut on_grid, mut moves) = (true, 0usize);
            for w in x[..n].windows(2) {
                let q = (w[1] - w[0]) / r;
                on_grid &= (q - q.round()).abs() < 0.01;
                moves += usize::from(q.round() != kk);
            }
            if on_grid {
                if kk >= 1.0 && moves > 0 {
                    (k, grid) = (kk, r);
                }
                break;
            }
        }
    }
    let resolution = grid;
    let carrier = k * resolution;
    // Each consecutive run is a staircase of its own (the tail past the window may have stops
    // left out too), its phase unknown to the others.
    let mut segments = Vec::new();
    let mut start = 0;
    for i in 1..=times.len() {
        if i == times.len() || (carrier > 0.0 && times[i] != times[i - 1] + 1.0) {
            segments.push(start..i);
            start = i;
        }
    }
    let window_start = t_first - 0.5;
    let window_end = index[n - 1] as f64;
    let mut knots = Vec::new();
    let mut segment_knots = Vec::with_capacity(segments.len());
    let (mut up_to_end, mut in_window) = (0, 0);
    for range in &segments {
        encoder_knots(&times[range.clone()], &angles[range.clone()], carrier, resolution, window_end, &mut knots);
        up_to_end += knots.iter().filter(|&&(t, _)| t < window_end).count();
        in_window += knots.iter().filter(|&&(t, _)| t >= window_start && t < window_end).count();
        segment_knots.push(knots.clone());
    }
    if up_to_end >= 3 && 3 * in_window <= n {
        for (range, knots) in segments.iter().zip(&segment_knots) {
            let t_ref = times[range.start];
            // Knots and samples of the run inside the window (before it the tool may run
            // faster, past it it brakes).
            let inside = |t: f64| t >= window_start && t < window_end;
            let dense = (knots.iter().filter(|&&(t, _)| inside(t)).count(), times[range.clone()].iter().filter(|&&t| inside(t)).count());
            let mut j = 0;
            let mut local = (usize::MAX, None);
            // The run's gaps, as (the last sample before, the first after): a slow encoder's
            // run goes on across them.
            let gaps: Vec<(f64, f64)> = if carrier == 0.0 {
                times[range.clone()].windows(2).filter(|w| w[1] != w[0] + 1.0).map(|w| (w[0], w[1])).collect()
            } else {
                Vec::new()
            };
            for p in range.clone().filter(|&p| p >= before) {
                let (t, recorded) = (times[p], angles[p]);
                // Past the window, a sample that moved more than a step off the carrier (the
                // tool braking to the target) is the centre of its encoder cell: no knot tells
                // where in the cell the shaft is, and the cell's centre is unbiased where the
                // line through the last knots, clamped to the cell, sits at its top.
                if carrier > 0.0 && t > window_end && p > range.start && (recorded - angles[p - 1] - carrier).abs() > 1.5 * resolution {
                    out.push(recorded + 0.5 * resolution);
                    continue;
                }
                // A run whose count moves at every other sample or faster (a tool winding up
                // after a CSDT pause, or braking) is left as recorded: its knots are no surer
                // than the samples, and interpolating them turned 3.3 % false alarms of clean
                // CSDT curves (0.5 deg encoder, 2 kHz) into 5.3 %.
                if knots.len() < 2 || 3 * dense.0 > dense.1 {
                    out.push(recorded);
                    continue;
                }
                while j + 2 < knots.len() && knots[j + 1].0 <= t {
                    j += 1;
                }
                let ((t0, a0), (t1, a1)) = (knots[j], knots[j + 1]);
                // Before the first rise and after the last the line is extrapolated, but never
                // out of the encoder's cell: the shaft is at or past the recorded count and
                // short of the next (a tool braking after its last rise).
                // Where the beat turns (a tool slowing through a whole number of steps a
                // sample, HDT), two knots sit at one level with the beat above it between them,
                // which a straight line reads as flat: up to a third of a step low over tens of
                // samples. There the quadratic through those two knots and their neighbours
                // (built-in simulator, HDT 2 kHz, 0.5 deg, white noise: 7.5-9.2 % false alarms
                // of clean curves, 0.8-1.2 % with it). Elsewhere the line: the beat bends little
                // between knots that climb, and a quadratic through knots a sample unsure in
                // time strayed further than the line on a slow encoder's staircase.
                if local.0 != j && j >= 1 && j + 2 < knots.len() && a0 == a1 {
                    local = (j, quadratic_through(&knots[j - 1..j + 3]));
                }
                // A slow encoder's two knots either side of a gap (a CSDT pause: the tool turns
                // on to the stop, stands, and winds up again) are no line's ends: each side is
                // the line of its own knots, extrapolated to the gap. The line across it took
                // the tool's last turn before the stop for standstill, the run before the pause
                // up to a step behind the run after it (built-in simulator, CSDT 10 kHz, 0.5 deg
                // encoder, white noise: 15 % false alarms of clean curves, 0.5 % side by side;
                // independent generator 6.3 -> 0.3 %).
                let gap = gaps.iter().find(|&&(lo, hi)| lo >= t0 && hi <= t1 + 1.0);
                let beat = match (local, gap) {
                    (_, Some(&(lo, hi))) => {
                        if t <= lo {
                            if j >= 1 {
                                let (tp, ap) = knots[j - 1];
                                ap + (a0 - ap) * (t - tp) / (t0 - tp)
                            } else {
                                a0
                            }
                        } else if t >= hi && j + 2 < knots.len() {
                            let (tn, an) = knots[j + 2];
                            a1 + (an - a1) * (t - t1) / (tn - t1)
                        } else {
                            a1
                        }
                    }
                    ((jj, Some((centre, c))), None) if jj == j && t >= t0 && t <= t1 => c[0] + c[1] * (t - centre) + c[2] * (t - centre).powi(2),
                    _ => a0 + (a1 - a0) * (t - t0) / (t1 - t0),
                };
                out.push((beat + carrier * (t - t_ref)).clamp(recorded, recorded + resolution));
            }
        }
        out.extend_from_slice(&x[m..]);
        return (found, false);
    }
    // Dense rises: averaged only where the quantisation error drifts, where the steps between
    // samples take two or more multiples of the encoder step r (an advance per sample that is
    // not a whole number of
    // steps), so the error is a slow sawtooth of one step that passes for structure. A constant
    // multiple (a fine encoder, or a speed that is a whole number of steps per sample) leaves a
    // constant or small white error, which the noise model absorbs; and an average across a
    // sharp change of speed (the tool braking at the target) would bend the angle.
    if !sawtooth(&x[..n], resolution) {
        out.extend_from_slice(x);
        return (found, false);
    }
    let half = ((resolution / step).ceil() as usize).min(32);
    // Within the window only (its last samples excepted, below): past it the tool brakes to the
    // target, and an average across that change of speed would bend the angle of the window's
    // last samples and of the tail.
    // (The prefix sums reach `half` samples into the tail, for the window's last samples.)
    let m = x.len().min(index.len());
    let summed = (n + half).min(m).max(n);
    let mut prefix = Vec::with_capacity(summed + 1);
    prefix.push(0.0);
    for v in &x[..summed] {
        prefix.push(prefix[prefix.len() - 1] + v);
    }
    // A sample whose average spans a step of SAWTOOTH_STEPS or more keeps its recorded angle: an
    // HDT tool at 500 Hz slows from 6 to 2 deg a sample through the window's first samples and
    // below 0.8 deg (8 steps of a 0.1 deg encoder) near the target, where the window's slow
    // steps made it a sawtooth. The average over the fast start bent the angle there by a third
    // of the change of speed a sample, a tenth of a degree and more against a quantisation
    // error of 0.03 deg sd, and the start test claimed it (independent generator, HDT 500 Hz,
    // 0.1 deg encoder, t4 noise, 1,351 clean curves decided: 3.03 % false alarms, 0.81 % with
    // the recorded angle there; the start test at p <= 0.01 on 6.8 % of another set's curves,
    // 0.7 % without the average).
    // The window's last samples average across its end into the tail (the samples up to the
    // peak) where the tail goes on without a gap. The window ends where the recorded angle
    // last stays below the trim's limit, which is always the last sample of an encoder level:
    // its shaft sits near the top of the cell, the recorded angle a whole step behind where
    // the window's other samples are half a step behind on average. The average narrowed to
    // the window kept that sample as recorded and the one before it half so: on the built-in
    // simulator's HDT curves (2 kHz, 0.5 deg encoder, white noise, 300) the last sample's
    // angle lay 0.17 deg (a third of a step) behind the rest against the true angle, the one
    // before it 0.06 deg, and the CUSUM's last block read the steeper torque against it as a
    // rise of friction (its z had mean +1.05, 0.00 on the true angle). Across the end: -0.006
    // and +0.006 deg. The tail's first samples sit as far the other way (the first sample of
    // the next level). Not where the tool has slowed within the average's reach past the end
    // (its advance there short of the one before by more than a step and a half).
    out.extend((0..n).map(|i| {
        let h = half.min(i).min(n - 1 - i);
        let across = n - 1 - i < half
            && i >= half
            && i + half < m
            && index[i + half] == index[i] + half
            && (x[i] - x[i - half]) - (x[i + half] - x[i]) <= 1.5 * resolution;
        let (lo, hi) = if across { (i - half, i + half) } else { (i - h, i + h) };
        if x[lo..=hi].windows(2).any(|w| w[1] - w[0] >= SAWTOOTH_STEPS * resolution) {
            return x[i];
        }
        (prefix[hi + 1] - prefix[lo]) / (hi + 1 - lo) as f64
    }));
    out.extend_from_slice(&x[n..]);
    (found, true)
}

impl Detector {
    /// The analysis of row `i` of `table`; `seed_row` numbers it for the kernel-density test's
    /// permutations (its row in the batch the caller analyses).
    pub(super) fn analyse_row(&self, table: &TighteningTable<'_>, i: usize, seed_row: usize, scratch: &mut Scratch) -> RowResult {
        let (angle, torque) = match (table.angle.row(i), table.torque.row(i)) {
            (ChannelRow::Present { samples: a, .. }, ChannelRow::Present { samples: t, .. }) => (a, t),
            _ => return RowResult::failed(TighteningStatus::NullTightening, 0),
        };
        let n = angle.len();
        let channels = [&table.angle, &table.torque].into_iter().chain(table.optional.iter());
        // Checks run in a fixed order (lengths, nulls, non-finite) so the status names the
        // first problem a person would have to fix.
        let mut rows = Vec::with_capacity(5);
        for c in channels {
            match c.row(i) {
                ChannelRow::Null => {
                    // A missing optional channel is not an error; a null required one is.
                    if c.name == schema::ANGLE || c.name == schema::TORQUE {
                        return RowResult::failed(TighteningStatus::NullTightening, 0);
                    }
                }
                ChannelRow::Present { samples, null_count } => rows.push((c.name, samples, null_count)),
            }
        }
        for &(name, s, _) in &rows {
            if s.len() != n {
                return RowResult::failed(
                    TighteningStatus::LengthMismatch { channel: name, len: s.len(), expected: n },
                    n,
                );
            }
        }
        if n == 0 {
            return RowResult::failed(TighteningStatus::Empty, 0);
        }
        for &(name, _, nulls) in &rows {
            if nulls > 0 {
                return RowResult::failed(TighteningStatus::NullValues { channel: name, count: nulls }, n);
            }
        }
        for &(name, s, _) in &rows {
            let bad = s.non_finite_count();
            if bad > 0 {
                return RowResult::failed(TighteningStatus::NonFinite { channel: name, count: bad }, n);
            }
        }
        if n < self.config.zone.min_samples {
            return RowResult::failed(
                TighteningStatus::TooShort { samples: n, minimum: self.config.zone.min_samples, what: "curve" },
                n,
            );
        }
        let mut step_changes = std::mem::take(&mut scratch.step_changes);
        match table.step.as_ref().and_then(|c| c.step_changes(i, &mut step_changes)) {
            Some(len) if len != n => {
                scratch.step_changes = step_changes;
                return RowResult::failed(TighteningStatus::LengthMismatch { channel: schema::STEP, len, expected: n }, n);
            }
            Some(_) => {}
            None => step_changes.clear(),
        }
        let friction = self.friction_input(table, i, scratch);
        let time = table.channel(schema::TIME).and_then(|c| match c.row(i) {
            ChannelRow::Present { samples, .. } => Some(samples),
            ChannelRow::Null => None,
        });
        let curve = Curve { row: seed_row, step_changes: &step_changes, time };
        let result = match (angle, torque) {
            (Samples::F32(a), Samples::F32(t)) => self.analyse_curve(a, t, friction, curve, scratch),
            (Samples::F32(a), Samples::F64(t)) => self.analyse_curve(a, t, friction, curve, scratch),
            (Samples::F64(a), Samples::F32(t)) => self.analyse_curve(a, t, friction, curve, scratch),
            (Samples::F64(a), Samples::F64(t)) => self.analyse_curve(a, t, friction, curve, scratch),
        };
        scratch.step_changes = step_changes;
        result
    }

    /// The steps of one curve. A step that fails after the phases are found still reports what
    /// came before it: the phases and the friction estimate need far fewer samples than the
    /// detectors (a short real curve keeps its torque rate).
    fn analyse_curve<A: Sample, T: Sample>(
        &self,
        angle: &[A],
        torque: &[T],
        friction: std::result::Result<FrictionInput, TighteningStatus>,
        curve: Curve<'_>,
        s: &mut Scratch,
    ) -> RowResult {
        let (n, row) = (angle.len(), curve.row);
        let phases = match self.phases(angle, torque, s) {
            Ok(p) => p,
            Err(status) => return RowResult::failed(status, n),
        };
        let window = last_step_window(angle, torque, phases.window, phases.torque_rate, curve.step_changes, &mut s.residuals);
        // An unknown thread is named first: it is a fix to the data that applies to every row.
        let (friction_row, friction_status) = match friction {
            Ok(f) => (self.friction_row(torque, &phases, f, s), TighteningStatus::Ok),
            Err(status) => (None, status),
        };
        s.tested_part = if window.start > phases.window.start { TESTED_AFTER_STEP } else { TESTED_WHOLE };
        let (window, cut_at_gap) = around_unsampled_stop(torque, window, curve.time, &mut s.residuals);
        if cut_at_gap {
            s.tested_part = TESTED_BEFORE_PAUSE;
        } else if window.start > phases.window.start && s.tested_part == TESTED_WHOLE {
            s.tested_part = TESTED_AFTER_PAUSE;
        }
        stop_ranges(angle, torque, window, &mut s.stops);
        let mut tail_end = (phases.yield_angle.is_none() && !cut_at_gap).then_some(phases.peak_index);
        let relaxation = without_relaxation(
            angle,
            torque,
            window,
            phases.torque_rate,
            phases.peak_index,
            &s.stops,
            &mut s.residuals,
        );
        let window = match relaxation {
            Some(RelaxationFree::Resumed(resumed)) => {
                s.tested_part = TESTED_AFTER_PAUSE;
                stop_ranges(angle, torque, resumed, &mut s.stops);
                resumed
            }
            Some(RelaxationFree::EndsBeforeDip(cut)) => {
                s.tested_part = TESTED_BEFORE_PAUSE;
                tail_end = None;
                stop_ranges(angle, torque, cut, &mut s.stops);
                cut
            }
            None => window,
        };
        // The rundown's noise blocks end as far before the snug as the elastic window starts
        // after it: the seating lies between.
        let snug_index = angle.partition_point(|a| a.to_f64() < phases.snug_angle).min(phases.window.start);
        // And no later than the seating zone the prevailing torque leaves out: on a slow
        // channel the window starts at the snug (a rise of 5-10 deg per sample at 500 Hz) and
        // the mirror above left the seating's bend in the last block (18 times the noise
        // variance of the block before it), which made the noise model white under AR(1) 0.85.
        let rundown_end = snug_index.saturating_sub(phases.window.start - snug_index).min(phases.seating_start);
        // And they begin once the tool runs: its start-up (the torque from 0 to the prevailing
        // level within a sample or two) is a step, not noise. Of a slow channel's three or four
        // blocks, the one holding it had 5-7 times the median block's variance (the outlier
        // cut is 8) and a lag-1 correlation of 0, and it dominated the pooled moments: under
        // AR(1) 0.85 at 500 Hz phi came out below 0.5 in 7 % of the curves, a fifth of which
        // raised a false alarm (none below 0.5 with the start-up left out).
        let level = 0.5 * phases.prevailing_torque;
        let rundown_start = if level > 0.0 { torque[..rundown_end.min(torque.len())].iter().position(|t| t.to_f64() >= level).unwrap_or(0) } else { 0 };
        s.window_samples(angle, torque, window, tail_end, rundown_start..rundown_end);
        s.snug_x = phases.snug_angle - angle[window.start].to_f64();
        s.starts_at_level = window.start == phases.window.start;
        let breaks = self.break_row(angle, s);
        let residual = self.residual_row(angle, row, s);
        let l1 = self.l1_row(angle, s);
        let cusum = self.cusum_row(angle, window, s);
        let pf = if self.config.pf.enabled { self.pf_row(angle, row, s) } else { None };
        let status = match &cusum {
            Err(status) if friction_status.is_ok() => status.clone(),
            _ => friction_status,
        };
        RowResult {
            status,
            n_samples: n,
            window: Some((angle[phases.window.start].to_f64(), angle[phases.window.end - 1].to_f64())),
            tested_start: Some(angle[window.start].to_f64()),
            tested_end: window.end.checked_sub(1).map(|last| angle[last].to_f64()),
            phases: Some(PhaseRow {
                prevailing_torque: phases.prevailing_torque,
                snug_angle: phases.snug_angle,
                yield_angle: phases.yield_angle,
                peak_torque: phases.peak_torque,
                peak_angle: angle[phases.peak_index].to_f64(),
                torque_rate: phases.torque_rate,
            }),
            friction: friction_row,
            noise_lag1: Some(s.noise.lag1_autocorrelation()),
            noise_order: s.lag,
            breaks,
            residual,
            l1,
            cusum: cusum.ok(),
            pf,
            decision: None,
        }
    }

    /// Phases and elastic window, or the status that says why there are none.
    fn phases<A: Sample, T: Sample>(&self, angle: &[A], torque: &[T], s: &mut Scratch) -> Result<Phases, TighteningStatus> {
        let first = angle[0].to_f64();
        if angle.iter().all(|a| a.to_f64() == first) {
            return Err(TighteningStatus::FlatSignal { channel: schema::ANGLE });
        }
        // Flat means no range at all, whatever the sign; a curve that varies is never flat.
        let (mut i_low, mut low, mut high) = (0, f64::INFINITY, f64::NEG_INFINITY);
        for (i, t) in torque.iter().enumerate() {
            let t = t.to_f64();
            if t < low {
                (i_low, low) = (i, t);
            }
            high = high.max(t);
        }
        if high <= low {
            return Err(TighteningStatus::FlatSignal { channel: schema::TORQUE });
        }
        // The phase finder looks for a rise of positive torque to a peak. A curve whose largest
        // torque in magnitude is negative (a loosening curve: breakaway, then the torque runs
        // out towards 0) has no such rise; analysed as one, its "rundown" sits at the top and
        // its "elastic line" is a fragment of the run-out, with a snug angle far off the curve.
        if -low > high {
            return Err(TighteningStatus::Loosening { peak_torque: low, peak_angle: angle[i_low].to_f64() });
        }
        let phases = find_phases(angle, torque, &self.config.zone, &self.config.yield_zone, &mut s.phases).map_err(|e| match e {
            WindowError::FlatTorque => TighteningStatus::FlatSignal { channel: schema::TORQUE },
            WindowError::NoRise => {
                TighteningStatus::NoElasticZone { reason: "torque varies but never rises above its prevailing (rundown) level" }
            }
            WindowError::TooShort(len) => {
                TighteningStatus::TooShort { samples: len, minimum: MIN_FIT_SAMPLES, what: "elastic window" }
            }
            WindowError::AngleStuck => {
                TighteningStatus::NoElasticZone { reason: "angle does not advance while torque rises" }
            }
        })?;
        // The snug angle is extrapolated (the elastic line down to the prevailing torque). Off
        // the recorded angles it describes no part of this curve, and neither does the window
        // it was drawn through: no result may rest on it.
        let (a_min, a_max) = angle.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), a| (lo.min(a.to_f64()), hi.max(a.to_f64())));
        if !(phases.snug_angle >= a_min && phases.snug_angle <= a_max) {
            return Err(TighteningStatus::NoElasticZone {
                reason: "the elastic line meets the prevailing torque outside the curve's angles (snug angle off the curve)",
            });
        }
        Ok(phases)
    }
}

#[cfg(test)]
mod tests {
    use super::{sawtooth, smooth_angle, time_smoothed_angle, Scratch, TIME_SMOOTHING};

    /// A rundown at 1 Nm, a quadratic seating to 20 Nm and an elastic line to 80 Nm over
    /// `window` samples (`clean`), and that torque with noise of sd 0.01 Nm + 0.4 % of it.
    fn growing_noise_curve(rundown: usize, window: usize, seating: usize, seed: u64) -> (Vec<f64>, Vec<f64>) {
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed);
        let clean: Vec<f64> = (0..rundown + window)
            .map(|k| match k {
                k if k < rundown - seating => 1.0,
                k if k < rundown => 1.0 + 19.0 * ((k + seating - rundown) as f64 / seating as f64).powi(2),
                k => 20.0 + 60.0 * (k - rundown) as f64 / window as f64,
            })
            .collect();
        let torque = clean
            .iter()
            .map(|t| {
                let u: f64 = StandardNormal.sample(&mut rng);
                t + (0.01 + 0.004 * t) * u
            })
            .collect();
        (clean, torque)
    }

    /// The weights carry the angle's quantisation error (the torque rate times an error uniform
    /// over the encoder's step) beside the noise that grows with the torque: read through a 0.5
    /// deg encoder, the window's first samples are not weighed as if their small torque noise
    /// were all their error (first / last weight 2.24; 2.92 for the growth alone). Unquantised,
    /// the weights follow the growth alone.
    #[test]
    fn the_angle_s_quantisation_error_flattens_the_weights() {
        use crate::physics::torque_rate::ElasticWindow;
        let (rundown, window, seating) = (1500, 200, 200);
        let (_, torque) = growing_noise_curve(rundown, window, seating, 29);
        // The shaft's advance varies a little from sample to sample, as a real tool's does (an
        // unquantised angle of exactly equal steps reads as a grid of that step).
        let shaft: Vec<f64> = (0..rundown + window).map(|k| 0.37 * k as f64 + 0.123 + 0.02 * (0.7 * k as f64).sin()).collect();
        // First / last weight of the window, the encoder's grid, the fitted growth and rate.
        let weigh = |angle: &[f64]| {
            let mut s = Scratch::default();
            s.window_samples(angle, &torque, ElasticWindow { start: rundown, end: rundown + window, peak: 80.0 }, None, 0..rundown - seating);
            let n = s.n_window;
            let (a, b) = crate::detectors::least_squares_line(&s.xs[..n], &s.y[..n]);
            let level = |k: usize| s.t0 + a + b * s.xs[k];
            (s.weights[0] / s.weights[n - 1], s.encoder_resolution, s.growth, s.noise.sd_line.1, b, level(0), level(n - 1))
        };
        let (free, r, kappa, _, _, lo, hi) = weigh(&shaft);
        assert_eq!(r, 0.0);
        assert!(kappa > 0.0);
        assert!((free - (1.0 + kappa * hi) / (1.0 + kappa * lo)).abs() < 1e-9, "unquantised: {free}");
        let quantised: Vec<f64> = shaft.iter().map(|a| (a / 0.5).floor() * 0.5).collect();
        let (ratio, r, kappa, s1, rate, lo, hi) = weigh(&quantised);
        assert!((r - 0.5).abs() < 1e-9, "encoder grid {r}");
        // 0.81 Nm/deg x 0.5 deg / sqrt(12): 0.12 Nm, against 0.09 Nm of noise at the start.
        let q = rate.abs() * r / 12.0_f64.sqrt() * kappa / s1;
        let expected = (1.0 + kappa * hi).hypot(q) / (1.0 + kappa * lo).hypot(q);
        assert!((ratio - expected).abs() < 1e-9, "quantised: {ratio} against {expected}");
        assert!(ratio < 0.8 * free, "the quantisation error left the weights at {ratio} ({free} without)");
    }

    /// A curve whose noise sd is 0.01 Nm + 0.4 % of the torque (the independent generator's
    /// transducer): a 1,300-sample rundown at 1 Nm, a 200-sample seating bend up to 20 Nm, then
    /// the window, 20 -> 80 Nm over 600 samples. The noise model's fitted line finds the growth
    /// (s1 / s0 0.37 per Nm, true 0.4), its floored slope 0.09. The window every detector tests
    /// is weighed by the fitted line (`window_growth`): its noise has one sd (the weight times
    /// the true sd varies by 1 % over the window). Weighed by the floored slope, as it was
    /// before, the noise still grew along it by 26 %. Weighed again for the filter by the same
    /// growth, the samples differ from the shared ones only by the angle's quantisation error,
    /// which an unquantised angle does not have: bit for bit the same.
    #[test]
    fn the_window_weighed_by_the_fitted_growth_has_one_noise_level() {
        use crate::physics::torque_rate::ElasticWindow;
        let (rundown, window) = (1500, 600);
        let seating = 200;
        let (clean, torque) = growing_noise_curve(rundown, window, seating, 23);
        // Unquantised, its advance varying a little as a real tool's does (equal steps read as an
        // encoder's grid, whose quantisation error the weights would carry).
        let angle: Vec<f64> = (0..rundown + window).map(|k| 0.37 * k as f64 + 0.02 * (0.7 * k as f64).sin()).collect();
        let mut s = Scratch::default();
        s.window_samples(&angle, &torque, ElasticWindow { start: rundown, end: rundown + window, peak: 80.0 }, None, 0..rundown - seating);
        let (s0, s1) = s.noise.sd_line;
        assert!(s1 > 0.0 && (0.3..0.5).contains(&(s1 / s0)), "sd line {s0} + {s1} T");
        assert!(s.noise.sd_slope < 0.75 * s1 / s0, "the noise model's slope {} is floored", s.noise.sd_slope);
        assert_eq!(s.growth, super::window_growth(s.noise.sd_line, &s.xs[..s.n_window], &s.y[..s.n_window], s.t0));
        // max / min over the window of the weight times the true sd: 1 for weights of 1 / sd.
        let spread = |s: &Scratch| -> f64 {
            let n = s.n_window;
            let level: Vec<f64> = (0..n).map(|k| s.weights[k] * (0.01 + 0.004 * clean[s.index[k]])).collect();
            level.iter().copied().fold(0.0, f64::max) / level.iter().copied().fold(f64::INFINITY, f64::min)
        };
        let shared = spread(&s);
        assert!(shared < 1.05, "the shared window's weighted sd varies by {shared}");
        let (wx, wy) = (s.wx.clone(), s.wy.clone());
        s.weigh_by_growth(s.growth);
        assert!(s.wx == wx && s.wy == wy);
        s.weigh_by_growth(s.noise.sd_slope);
        let floored = spread(&s);
        assert!(floored > 1.15, "the floored slope's weighted sd varies by {floored}");
    }

    /// The angle a floor-quantising encoder of step `r` records of the shaft's `truth`.
    fn floor_recorded(truth: &[f64], r: f64) -> Vec<f64> {
        truth.iter().map(|a| (a / r).floor() * r).collect()
    }

    /// `n` samples of the shaft's angle from `start`, turning by `advance(i)` after sample i.
    fn shaft(start: f64, n: usize, advance: impl Fn(usize) -> f64) -> Vec<f64> {
        (0..n)
            .scan(start, |angle, i| {
                let at = *angle;
                *angle += advance(i);
                Some(at)
            })
            .collect()
    }

    /// A slow encoder (a 0.5 deg step every 17 samples) on a tool that pauses (CSDT): the
    /// samples of the pause are left out, and the tool turned on for 40 samples after the last
    /// rise before it. Each side of the gap is interpolated from its own knots, to a fifth of a
    /// step; the line from the last knot before the gap to the first after it was 0.58 of a
    /// step off there.
    #[test]
    fn a_slow_encoder_is_interpolated_on_each_side_of_a_pause() {
        let r = 0.5;
        let speed = 0.03;
        let before: Vec<usize> = (0..840).collect();
        let after: Vec<usize> = (1340..2140).collect();
        let index: Vec<usize> = before.iter().chain(&after).copied().collect();
        let truth: Vec<f64> = index
            .iter()
            .map(|&i| if i < 840 { 0.13 + speed * i as f64 } else { 0.13 + speed * 839.0 + 0.2 + speed * (i - 1340) as f64 })
            .collect();
        let recorded = floor_recorded(&truth, r);
        let n = index.len();
        let mut out = Vec::new();
        smooth_angle(&[], &recorded, &index, n, 0.0, &mut out);
        assert_eq!(out.len(), n);
        let errors: Vec<f64> = out.iter().zip(&truth).map(|(a, b)| a - b).collect();
        // Between the first rise and the last (the ends are extrapolated).
        let inner = &errors[20..n - 20];
        let mean = inner.iter().sum::<f64>() / inner.len() as f64;
        let worst = inner.iter().map(|e| (e - mean).abs()).fold(0.0, f64::max);
        assert!(worst < 0.2 * r, "interpolated angle off by {:.3} steps", worst / r);
    }

    /// An HDT tool at 500 Hz with a 0.1 deg encoder: 6 deg a sample at the window's start,
    /// slowing to 0.3 near the target. The slow end makes the window's steps a sawtooth, but
    /// where the tool turns many steps a sample the angle keeps its recording (off by less than
    /// a step): averaged over three samples it was bent by a third of the change of speed, up
    /// to 2.4 steps off.
    #[test]
    fn a_fast_tool_s_angle_is_not_averaged_through_its_change_of_speed() {
        let r = 0.1;
        let n = 60;
        let truth = shaft(0.037, n, |t| 6.0 * (-(t as f64) / 10.0).exp() + 0.3);
        let recorded = floor_recorded(&truth, r);
        let index: Vec<usize> = (0..n).collect();
        assert!(sawtooth(&recorded, r), "the slow end makes no sawtooth: the test misses its path");
        let mut out = Vec::new();
        smooth_angle(&[], &recorded, &index, n, 0.0, &mut out);
        let worst = out[..20].iter().zip(&truth).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        assert!(worst < r, "the fast start's angle off by {:.2} steps", worst / r);
    }

    /// A 0.5 deg encoder on a tool turning 0.27 deg a sample (2 kHz): the count rises every
    /// sample or two, and the window's angle is the recorded one averaged over two samples
    /// either side. The window ends, as the phase finder's trim ends it, at the last sample of
    /// an encoder level, whose shaft is near the top of the cell. Averaged with the tail after
    /// it, the window's last samples are as far behind the shaft as the others (to 0.03 deg,
    /// over phases of the encoder); narrowed to the window the last was 0.13 deg further behind
    /// (0.17 on the built-in simulator's HDT curves), which the CUSUM's last block read as a
    /// rise of the torque rate.
    #[test]
    fn the_window_s_last_samples_are_averaged_across_its_end() {
        let r = 0.5;
        let (n_all, tail) = (260, 20);
        let mut offsets = [0.0; 2];
        let phases = [0.03, 0.17, 0.31, 0.46, 0.62, 0.77, 0.91];
        for phase in phases {
            let truth = shaft(100.0 + phase * r, n_all, |_| 0.27);
            let recorded = floor_recorded(&truth, r);
            // The last sample of a level, with `tail` samples after it.
            let n = (1..n_all - tail).rev().find(|&i| recorded[i] > recorded[i - 1]).unwrap_or_else(|| panic!("no rise"));
            let (x, t) = (&recorded[..n + tail], &truth[..n + tail]);
            let index: Vec<usize> = (0..x.len()).collect();
            let mut out = Vec::new();
            let (_, averaged) = smooth_angle(&[], x, &index, n, 0.0, &mut out);
            assert!(averaged, "phase {phase}: not the moving average's path");
            let error = |i: usize| out[i] - t[i];
            let inner = (20..n - 20).map(error).sum::<f64>() / (n - 40) as f64;
            for (k, offset) in offsets.iter_mut().enumerate() {
                *offset += (error(n - 1 - k) - inner) / phases.len() as f64;
            }
        }
        for (k, offset) in offsets.iter().enumerate() {
            assert!(offset.abs() < 0.03, "sample {} before the window's end: {offset:.3} deg off the rest", k);
        }
    }

    /// A tool slowing through one encoder step a sample (HDT near the target): the beat rises,
    /// turns and falls, and around the turn two knots sit at one level with the shaft above it
    /// between them. The interpolated angle follows the turn to a small part of a step, at any
    /// phase of the encoder; a straight line between the knots there was 0.37 of a step low
    /// at one of these phases.
    #[test]
    fn a_beat_that_turns_as_the_tool_slows_is_followed_through_the_turn() {
        let r = 0.5;
        let (before, n) = (256, 120);
        for phase in [0.05, 0.2, 0.37, 0.5, 0.65, 0.8, 0.95] {
            // Steps a sample: 1.1 at the window's start, 1.0 forty samples in, 0.8 at its end;
            // constant before the window.
            let steps = |i: usize| -> f64 {
                let t = i as f64 - before as f64;
                if t < 0.0 { 1.1 * t } else { 1.1 * t - 0.00125 * t * t }
            };
            let truth: Vec<f64> = (0..before + n).map(|i| (phase + steps(i)) * r + 100.0).collect();
            let recorded = floor_recorded(&truth, r);
            let index: Vec<usize> = (before..before + n).collect();
            let mut out = Vec::new();
            smooth_angle(&recorded[..before], &recorded[before..], &index, n, 0.0, &mut out);
            let worst = out.iter().zip(&truth[before..]).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
            assert!(worst < 0.2 * r, "phase {phase}: interpolated angle off by {:.3} steps", worst / r);
        }
    }

    /// A 0.5 deg encoder at 2 kHz on a tool turning 1.03 encoder steps a sample (about 1000
    /// deg/s): the count rises every sample, by two steps every 33rd, so the recorded angle is
    /// off by a sawtooth of one step over 33 samples. In a 40-sample window that is one or two
    /// moves of the beat; with the 256 samples before the window as context the interpolation
    /// follows the true angle to a tenth of a step. Speeds of 0.97 (the beat falls) and 2.02
    /// steps a sample likewise.
    #[test]
    fn an_encoder_beat_is_interpolated_with_the_samples_before_the_window() {
        let r = 0.5;
        for speed in [1.03, 0.97, 2.02] {
            let (before, n, tail) = (256, 40, 20);
            let truth: Vec<f64> = (0..before + n + tail).map(|i| 0.37 + speed * r * i as f64).collect();
            let recorded = floor_recorded(&truth, r);
            let index: Vec<usize> = (before..before + n + tail).collect();
            let mut out = Vec::new();
            smooth_angle(&recorded[..before], &recorded[before..], &index, n, 0.0, &mut out);
            let errors: Vec<f64> = out.iter().zip(&truth[before..]).map(|(a, b)| a - b).collect();
            let recorded_errors: Vec<f64> = recorded[before..].iter().zip(&truth[before..]).map(|(a, b)| a - b).collect();
            let spread = |e: &[f64]| e.iter().copied().fold(f64::NEG_INFINITY, f64::max) - e.iter().copied().fold(f64::INFINITY, f64::min);
            assert!(spread(&recorded_errors[..n]) > 0.5 * r, "speed {speed}: the recorded angle has no beat to take out");
            assert!(spread(&errors[..n]) < 0.1 * r, "speed {speed}: interpolated angle off by {}", spread(&errors[..n]));
        }
    }

    /// A 0.5 deg encoder at 10 kHz on a tool that slows from 0.05 to 0.005 deg per sample (a
    /// rise every 10 to 100 samples): the interpolated angle follows the true one to a small
    /// fraction of a step, where the recorded one is off by up to a whole step.
    #[test]
    fn the_encoder_staircase_is_interpolated_between_its_rises() {
        let r = 0.5;
        let n = 4000;
        let truth = shaft(0.13, n, |i| 0.05 - 0.045 * i as f64 / n as f64);
        let recorded = floor_recorded(&truth, r);
        let index: Vec<usize> = (0..n).collect();
        let mut out = Vec::new();
        smooth_angle(&[], &recorded, &index, n, 0.0, &mut out);
        assert_eq!(out.len(), n);
        let worst = |v: &[f64]| {
            let errors: Vec<f64> = v.iter().zip(&truth).map(|(a, b)| a - b).collect();
            let mean = errors.iter().sum::<f64>() / n as f64;
            errors.iter().map(|e| (e - mean).abs()).fold(0.0, f64::max)
        };
        assert!(worst(&recorded) > 0.4 * r);
        // Between the first and last rise (the ends are extrapolated)
        assert!(
            worst(&out) < 0.05 * r,
            "interpolated angle off by {}",
            worst(&out)
        );
        // A fine encoder (a rise at every sample) and a straight line pass unchanged.
        let line: Vec<f64> = (0..n).map(|i| 1.0 + 0.1 * i as f64).collect();
        smooth_angle(&[], &line, &index, n, 0.0, &mut out);
        assert_eq!(out, line);
    }

    #[test]
    fn the_time_average_keeps_lines_and_runs_and_damps_what_changes_from_sample_to_sample() {
        // A line in time passes unchanged, ends included; a run after a gap (a stop left out)
        // is averaged on its own, so a step between runs stays a step.
        let index: Vec<usize> = (0..40).chain(60..100).collect();
        let line: Vec<f64> = index.iter().map(|&i| 0.5 + 0.25 * i as f64).collect();
        let mut out = Vec::new();
        time_smoothed_angle(&line, &index, TIME_SMOOTHING, &mut out);
        assert_eq!(out.len(), line.len());
        assert!(out.iter().zip(&line).all(|(a, b)| (a - b).abs() < 1e-9), "{out:?}");
        // An alternating error of +-e (a staircase's leftover at two samples a step) shrinks to
        // e / 9 inside the run, and what whitening near the unit root keeps of it with it.
        let jagged: Vec<f64> = line.iter().enumerate().map(|(k, v)| v + if k % 2 == 0 { 0.01 } else { -0.01 }).collect();
        time_smoothed_angle(&jagged, &index, TIME_SMOOTHING, &mut out);
        let inner = 10..30;
        assert!(inner.clone().all(|k| (out[k] - line[k]).abs() <= 0.01 / 9.0 + 1e-12));
        let whitened_error = |v: &[f64]| inner.clone().map(|k| ((v[k] - line[k]) - 0.9 * (v[k - 1] - line[k - 1])).abs()).fold(0.0, f64::max);
        assert!(whitened_error(&out) < 0.15 * whitened_error(&jagged));
    }
}

