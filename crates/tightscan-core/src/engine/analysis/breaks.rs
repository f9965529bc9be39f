//! The break step: the sup-LR scan for one break of the elastic line and Chow's predictive
//! test of the last samples up to the peak, with the encoder-step check that keeps angle
//! quantisation from passing for a friction change.

use crate::detectors::{least_squares_3, least_squares_3_from_sums, least_squares_line as line, least_squares_line_through};
use crate::detectors::episode::{episode_critical_value, episode_predictive_p_value, episode_scan};
use crate::detectors::breakpoint::{min_segment, tail_test};
use crate::detectors::gls_breakpoint::{gls_critical_value, gls_predictive_p_value, gls_sup_lr_scan, gls_whitening_sensitivity};
use crate::engine::input::Sample;
use crate::engine::rows::BreakRow;
use crate::engine::traces::BreakTrace;
use crate::engine::Detector;

use super::Scratch;

impl Detector {
    /// sup-LR scan over the window's whitened samples (stops left out, see
    /// [`Scratch::window_samples`]), and the end test over the window's last samples plus those
    /// between its end and the peak. The statistics come from the whitened line, whose errors
    /// are independent; the jump they report, and the encoder-step check on it, are in torque
    /// units, from the recorded samples either side of the split.
    pub(super) fn break_row<A: Sample>(&self, angle: &[A], s: &mut Scratch) -> Option<BreakRow> {
        let lag = s.lag;
        let n = s.n_window;
        s.cusum_extra_alpha = 0.0;
        if n <= lag {
            return None;
        }
        let (wx, wy) = (&s.wx[lag..], &s.wy[lag..]);
        let nw = n - lag;
        let breaks = &self.config.breaks;
        let lag1 = s.noise.lag1_autocorrelation();
        let episode_fraction = if lag1 >= EPISODE_STRONG_COLOUR_LAG1 { self.episode_fraction * EPISODE_STRONG_COLOUR_SHARE } else { self.episode_fraction };
        let scan_alpha = self.break_alpha * (1.0 - breaks.tail_fraction - breaks.head_fraction - episode_fraction);
        // A window too short for the scan gets no break row, the end and start tests included.
        // Running them alone there found 5 of 600 late HDT rises on the independent generator
        // whose windows the jump had cut short, but on the real control group s01 (no friction
        // fault) the end test claimed 11 of the 571 such whole windows at p ~ 1e-4 (its share of
        // alpha is 4e-4), against 5 claims in the 2,500 windows the scan decides.
        let mut profile = s.trace.is_some().then(Vec::new);
        // The scan is the GLS break regression (`detectors::gls_breakpoint`): its step and step
        // x angle whitened as the line is, from the weighted angle before whitening.
        let phi_sum: f64 = s.noise.coefficients.iter().sum();
        s.restarts.clear();
        s.restarts.extend((0..n.saturating_sub(1)).filter(|&k| s.index[k + 1] > s.index[k] + 1).map(|k| k + 1));
        let scan = gls_sup_lr_scan(&wx[..nw], &wy[..nw], s.weighted_x.get(..n)?, &s.noise.coefficients, &s.restarts, min_segment(nw), &mut s.gls_scratch, profile.as_mut())?;
        let critical_value = gls_critical_value(nw, phi_sum, scan_alpha);
        let (x, y) = (&s.x[..n], &s.y[..n]);
        let split = scan.split + lag;
        let xs = &s.xs[..n];
        let (al, bl) = line(&xs[..split], &y[..split]);
        let (ar, br) = line(&xs[split..], &y[split..]);
        let scan_jump = (ar + br * xs[split]) - (al + bl * xs[split]);
        // Angle quantisation: where the angle advanced per sample is close to a multiple of the
        // encoder resolution r, the quantisation error drifts slowly and wraps by r, which is a
        // torque step of G r against the recorded angle (G the torque rate): one encoder step.
        // These steps made most of the scan's excess false alarms on simulated curves (all 87
        // clean curves with p <= 0.001 in 20,000 had |jump| = 0.75-1.9 G r). A break is only
        // credited when its jump exceeds `min_jump_steps` encoder steps (default 1.5), or when
        // it is large enough that a step cannot explain it ([`beyond_encoder_artefact`]).
        let resolution = s.encoder_resolution;
        let (dx, dy) = (x[n - 1] - x[0], y[n - 1] - y[0]);
        let encoder_step = encoder_step_torque(x, y, resolution);
        let beyond_step = |jump: f64| encoder_step <= 0.0 || jump.abs() > breaks.min_jump_steps * encoder_step;
        // What the check leaves of the scan's alpha goes to the CUSUM (`cusum_alpha`): on a
        // clean window the scan alarms at its share, but only the alarms whose jump passes the
        // check count, and where the encoder step is many times the jump's noise almost none do
        // (0.5 deg encoders: the scan fired on 0.00-0.15 % of clean curves against a share of
        // 0.45 %, and the rule on 0.12-0.45 % against its 1 %).
        // The whitened window's one-line RSS: here, and in the curvature guard's comparison.
        let whitened_line_rss = line_rss(&wx[..nw], &wy[..nw]);
        if self.scan_share_to_cusum && encoder_step > 0.0 && nw > 2 {
            // The long-run sd of the window's noise in torque units: the whitened line's
            // innovations over the whitening's gain, on the weights' scale.
            let gain = (1.0 - phi_sum).abs().max(1e-6);
            let mean_weight = if s.weights.len() >= n { s.weights[..n].iter().sum::<f64>() / n as f64 } else { 1.0 };
            let long_run_sd = (whitened_line_rss / (nw - 2) as f64).sqrt() / mean_weight.max(1e-12) / gain;
            s.cusum_extra_alpha = scan_alpha * unspent_scan_share(encoder_step, long_run_sd, nw, breaks.min_jump_steps);
        }
        // The whitening's own uncertainty: where the AR fit leaves the long-run variance
        // uncertain, the scan is judged by its p-value averaged over it
        // (`sup_lr_predictive_p_value`), with the statistic growing as that variance to the
        // power kappa (`scan_sensitivity`); for white noise by the table's critical value.
        let se = s.noise.gain_log_se * scan_sensitivity(nw, lag1, gls_whitening_sensitivity);
        let p_value = gls_predictive_p_value(nw, phi_sum, scan.statistic, se);
        let significant = if se > 0.0 { p_value <= scan_alpha } else { scan.statistic > critical_value };
        let scan_alarm = significant
            && (beyond_step(scan_jump) || beyond_encoder_artefact(scan.statistic, critical_value, || slope_change_lr(&wx[..nw], &wy[..nw], scan.split)));

        // Episode scan: a stretch of the window off the line that the line before and after it
        // shares, as an intermittent friction fault leaves (`detectors::episode`). Not where the
        // tool restarts: after a pause, or from a window that starts after a controller step.
        let episode_alpha = self.break_alpha * episode_fraction;
        // The episode scan is a GLS regression as the break scan is: the scan's spread of the
        // whitening's error (`se`, the GLS scan's sensitivity). (Its own, measured as the GLS
        // scan's was, is lower under strong colour, 0.38 against 0.54 at n 250 and phi 0.85;
        // with it the independent generator's 500 Hz CST cells under AR(1) 0.85-0.9 claimed
        // 1.5-2.0 % of clean curves, windows of a few hundred samples whose AR fit is less sure
        // than its standard error says.)
        let episode_se = se;
        let episode = if episode_fraction > 0.0 {
            s.transients.clear();
            if !s.starts_at_level {
                s.transients.push(0);
            }
            s.transients.extend((lag..n.saturating_sub(1)).filter(|&k| s.index[k + 1] > s.index[k] + 1).map(|k| k + 1 - lag));
            episode_scan(&wx[..nw], &wy[..nw], &s.noise.coefficients, &s.transients, &mut s.episode_prefix)
        } else {
            None
        };
        let episode = episode.and_then(|scan| {
            let critical = episode_critical_value(nw, phi_sum, episode_alpha).ok()?;
            let p_value = episode_predictive_p_value(nw, phi_sum, scan.statistic, episode_se);
            let significant = if episode_se > 0.0 { p_value <= episode_alpha } else { scan.statistic > critical };
            // Its level in torque units, recorded samples against the line through those
            // outside it; the encoder-step check as for a break (no slope to tell an encoder
            // offset by: only the multiple of the critical value).
            let (first, end) = (scan.start + lag, scan.end + lag);
            let level = deviation_from_outside(&xs[..n], &y[..n], first, end);
            let alarm = significant && (beyond_step(level) || scan.statistic > ARTEFACT_MULTIPLE * critical);
            Some(Episode { statistic: scan.statistic, p_value, first, last: end - 1, onset: scan.onset + lag, level, alarm })
        });
        let episode_alarm = episode.is_some_and(|e| e.alarm);

        // End test: every tail the scan cannot isolate (shorter than its minimum segment), up to
        // the peak (the samples past the window, which only this test uses). Its p-value is
        // averaged over the whitening's uncertainty by tail length (`tail_test`): on a slow
        // channel that uncertainty is large (a few hundred samples of rundown at 500 Hz) and
        // the exact F tail claimed 3-5 of 183 clean CST curves under AR(1) 0.85 (0 with the
        // average), and 4-5 % of clean 2 kHz curves with a 0.5 deg encoder (0.3-1.3 %).
        // Ending the test one sample before a peak the tool braked into (its shut-off and the
        // release's start are in that sample, and at 500 Hz it lay 0.6-1.2 Nm below the line)
        // was tried and dropped: a large friction rise in the last one to three samples lives
        // in that very sample, and the built-in simulator's recall of such rises fell from
        // above 0.98 to 0.87.
        let tail = if breaks.tail_fraction > 0.0 {
            let extra = s.x.len() - n;
            tail_test(wx, wy, min_segment(nw) - 1 + extra, s.noise.gain_log_se, true, &mut s.prefix).map(|t| {
                let start = t.start + lag;
                let deviation = mean_deviation((&s.xs[..start], &s.y[..start]), (&s.xs[start..], &s.y[start..]));
                (t, start, deviation)
            })
        } else {
            None
        };
        // The start test alarms beyond an encoder step, or far enough below its alpha that a
        // step cannot explain it. The end test only beyond the step: its last samples are the
        // tool's stop (braking, the final angle's quantisation, the release's start), which
        // move the torque off the line by up to an encoder step or two, and whitening makes a
        // deviation of a sample or two from strongly correlated noise look tiny in p. At 500 Hz
        // with a 0.5 deg encoder under AR(1) 0.85, 35 of 955 clean CST curves alarmed there
        // (stop samples 0.1-2.3 steps from the line, p < 1e-6); the start test's own such
        // alarms find real changes (HDT, 2 kHz, 0.5 deg, 3-15 %: recall 0.953, 0.875 without).
        let end_alarm = |p_value: f64, alpha: f64, deviation: f64| p_value <= alpha && (beyond_step(deviation) || p_value <= ARTEFACT_P_FRACTION * alpha);
        // The stop's own scale: the tool brakes within the peak's sample, and a skew between the
        // torque and angle channels of up to half a sample moves that sample's torque by the
        // torque rate times half a sample's advance, which on a slow channel is many encoder
        // steps. Independent generator, CST 500 Hz, 0.5 deg encoder, AR(1) 0.85: the braked
        // sample lay 0.55 Nm (about one step) under the line on the true angle, and the end test
        // claimed 10 of 619 clean curves at p 1e-5 to 1e-14 once the encoder's grid was found.
        let stop_step = if dx > 0.0 && n > 1 { (dy / dx).abs() * resolution.max(0.5 * dx / (n - 1) as f64) } else { 0.0 };
        let beyond_stop = |deviation: f64| stop_step <= 0.0 || deviation.abs() > breaks.min_jump_steps * stop_step;
        let tail_alarm = tail.is_some_and(|(t, _, dev)| t.p_value <= self.break_alpha * breaks.tail_fraction && beyond_stop(dev));

        // Start test: the end test on the window read backwards, over every head the scan
        // cannot isolate (shorter than its minimum segment). The head is the part before the
        // change; the change is at the first sample after it. Its deviation, in torque units, is
        // that of the recorded samples up to there (the filter's past included) from the line
        // fitted after them.
        // Not where the window starts after a controller step or a pause: the speed changes
        // there and the torque's transient is no friction change. On the real control group s01
        // the start test claimed 11 such windows (6-11 deg long, after the controller's last
        // step) at p = 1e-4 to 1e-23.
        let head = if breaks.head_fraction > 0.0 && s.starts_at_level {
            s.reversed_x.clear();
            s.reversed_x.extend(wx[..nw].iter().rev());
            s.reversed_y.clear();
            s.reversed_y.extend(wy[..nw].iter().rev());
            // Its p-value is averaged over the whitening's uncertainty on every head length:
            // on clean independent-generator curves (CST, AR(1) 0.9, 3,000) the start test's
            // p-values were too small over their whole range with the exact F tail (1.8 % at or
            // below 0.01, white noise 0.3 %) and 0.2 % with the average.
            tail_test(&s.reversed_x, &s.reversed_y, min_segment(nw) - 1, s.noise.gain_log_se, false, &mut s.prefix).map(|t| {
                let first_after = nw - t.start + lag;
                let deviation = mean_deviation((&xs[first_after..], &y[first_after..]), (&xs[..first_after], &y[..first_after]));
                (t, first_after, deviation)
            })
        } else {
            None
        };
        let head_alarm = head.is_some_and(|(t, _, dev)| end_alarm(t.p_value, self.break_alpha * breaks.head_fraction, dev));

        let (curvature_p_value, smooth_fits_better) = match curvature(&s.xs[..n], &s.weights, wx, &wy[..nw], &s.noise.coefficients, s.snug_x, &mut s.line_residuals) {
            Some((p, rss_quad, rss_drift)) => {
                let mut rss_break = whitened_line_rss * (-scan.statistic / nw as f64).exp();
                if let Some((_, first_after, _)) = head.filter(|_| head_alarm) {
                    // The head's own line and the line after it, as the scan's two lines.
                    let k = first_after - lag;
                    rss_break = rss_break.min(line_rss(&wx[..k], &wy[..k]) + line_rss(&wx[k..nw], &wy[k..nw]));
                }
                if let Some(e) = episode.filter(|e| e.alarm) {
                    // The line with the episode's level shift, as another break.
                    rss_break = rss_break.min(whitened_line_rss * (-e.statistic / nw as f64).exp());
                }
                (Some(p), rss_quad <= rss_break && rss_quad <= rss_drift)
            }
            None => (None, false),
        };
        // Split k (a prefix length of the whitened window) starts the right segment at whitened
        // sample k, sample k + lag of the window.
        let first = min_segment(nw).max(3);
        let split_angles: Option<Vec<f64>> = profile.as_ref().map(|lr| (first..first + lr.len()).map(|k| change_start_angle(angle, s, k + lag)).collect());
        let episode_angles = episode.map(|e| (angle[s.index[e.first]].to_f64(), angle[s.index[e.last]].to_f64()));
        if let (Some(traces), Some(lr), Some(split_angles)) = (s.trace.as_deref_mut(), profile, split_angles) {
            traces.breaks = Some(BreakTrace {
                angle: split_angles,
                lr,
                critical_value,
                decision_value: if se > 0.0 { predictive_critical_value(nw, phi_sum, scan_alpha, se) } else { critical_value },
                significant,
                scan_alarm,
                tail_alarm,
                head_alarm,
                episode: episode_angles,
                episode_alarm,
            });
        }
        // Where the break is: the scan's best split unless only the end or the start test alarmed.
        // (first changed sample of the window, jump)
        let (first_changed, jump) = match (tail, head) {
            _ if scan_alarm => (split, scan_jump),
            (Some((_, at, dev)), _) if tail_alarm => (at, dev),
            (_, Some((_, first_after, dev))) if head_alarm => (first_after, -dev),
            _ if episode_alarm => episode.map_or((split, scan_jump), |e| (e.onset, e.level)),
            _ => (split, scan_jump),
        };
        let change_index = s.index[first_changed];
        let change_angle = change_start_angle(angle, s, first_changed);
        Some(BreakRow {
            alarm: scan_alarm || tail_alarm || head_alarm || episode_alarm,
            statistic: scan.statistic,
            critical_value,
            p_value,
            tail_p_value: tail.map(|(t, ..)| t.p_value),
            head_p_value: head.map(|(t, ..)| t.p_value),
            episode_p_value: episode.map(|e| e.p_value),
            change_index,
            change_angle,
            jump,
            curvature_p_value,
            smooth_fits_better,
        })
    }
}

/// Torque of one encoder step along a window's line: the rate between its first and last
/// samples (`x` the recorded angle, `y` the torque) times the encoder's `resolution`, what an
/// angle quantisation error of one step moves the torque by; 0 where the angle does not advance.
pub(super) fn encoder_step_torque(x: &[f64], y: &[f64], resolution: f64) -> f64 {
    match (x.first(), x.last(), y.first(), y.last()) {
        (Some(x0), Some(x1), Some(y0), Some(y1)) if x1 - x0 > 0.0 => ((y1 - y0) / (x1 - x0)).abs() * resolution,
        _ => 0.0,
    }
}

/// The share of the break scan's alpha its encoder-step check leaves unspent on a clean window,
/// for the CUSUM to spend: 1 - [`scan_share_passing_check`] at the check's jump over the jump's
/// null sd, which for two lines split at the window's middle is 4 `long_run_sd` / sqrt(n) (the
/// sd of each line's end, 2 / sqrt(n / 2) of the noise's). At any size of the encoder's
/// quantisation against the noise: the CUSUM's scale takes the quantisation error each block's
/// slope carries (`cusum_row`). It was held back where that error passed half the long-run sd,
/// while the CUSUM's scale did not take it: on the white-noise cells with a 0.5 deg encoder the
/// CUSUM ran at 1.6-4.4 times its share. With the per-block scale and the share handed over at
/// every size, the size grid's (2,000 curves a cell) cells under the band fell from 20 to 16
/// (built-in) and 23 to 16 (independent); four white or t4 cells with a 0.5 deg encoder went over
/// it (1.55-1.75 %), where the scan alone claims 0.55-0.9 % of clean curves against its share of
/// 0.45 %: its own alarms on the encoder's beat passing the check, not the CUSUM's.
fn unspent_scan_share(encoder_step: f64, long_run_sd: f64, n: usize, min_jump_steps: f64) -> f64 {
    if !(long_run_sd > 0.0 && encoder_step > 0.0 && n > 0) {
        return 0.0;
    }
    let jump_sd = 4.0 * long_run_sd / (n as f64).sqrt();
    1.0 - scan_share_passing_check(min_jump_steps * encoder_step / jump_sd)
}

/// Fraction of the break scan's null alarms whose jump passes the encoder-step check, by the
/// check's jump in units of the jump's null sd (4 sigma_lr / sqrt(n)). Monte Carlo of the
/// scan on white-noise lines (n 250 and 1,000, alarms at 0.3 and 1 %; `benches/scan_check_share.py`),
/// the larger of the cells at each point: AR(1) 0.85 noise passes less (0.6 at 4, 0 from 8),
/// so the table is the upper envelope, which keeps the size at most alpha.
const SCAN_CHECK_PASSING: [(f64, f64); 11] =
    [(2.0, 1.0), (3.0, 0.98), (4.0, 0.9), (5.0, 0.5), (6.0, 0.3), (7.0, 0.22), (8.0, 0.15), (10.0, 0.07), (12.0, 0.04), (14.0, 0.02), (16.0, 0.0)];

/// [`SCAN_CHECK_PASSING`] at `steps` (linear between its points; 1 below the first, 0 beyond
/// the last).
fn scan_share_passing_check(steps: f64) -> f64 {
    let first = SCAN_CHECK_PASSING[0];
    if !(steps > first.0) {
        return first.1;
    }
    for w in SCAN_CHECK_PASSING.windows(2) {
        let ((x0, y0), (x1, y1)) = (w[0], w[1]);
        if steps <= x1 {
            return y0 + (y1 - y0) * (steps - x0) / (x1 - x0);
        }
    }
    0.0
}

/// Fraction of a test's alpha below which its alarm stands whatever its size against an
/// encoder step (the start test's, and pf's).
pub(super) const ARTEFACT_P_FRACTION: f64 = 0.01;

/// The sup-LR statistic whose predictive p-value ([`gls_predictive_p_value`], non-increasing
/// in the statistic) is `alpha`, by bisection: the level the scan's profile must pass where the
/// noise model's uncertainty widens the test.
fn predictive_critical_value(n: usize, phi_sum: f64, alpha: f64, gain_log_se: f64) -> f64 {
    let (mut lo, mut hi) = (0.0_f64, 1.0_f64);
    while gls_predictive_p_value(n, phi_sum, hi, gain_log_se) > alpha && hi < 1e6 {
        (lo, hi) = (hi, 2.0 * hi);
    }
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if gls_predictive_p_value(n, phi_sum, mid, gain_log_se) > alpha {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    hi
}

/// Whether a break whose jump is within the encoder-step check is still credited: its statistic
/// is above [`ARTEFACT_MULTIPLE`] times the critical value, or above twice it with the change
/// of slope alone significant (`slope_lr`, computed only then, above the critical value).
///
/// Why: a friction drift is a kink, whose jump at the split is about 0, so the jump alone
/// cannot credit it. What the encoder leaves in the interpolated angle (a beat turning or
/// wrapping, a pause) is an offset of a fraction of a step between two stretches, a level
/// shift with the slope unchanged, and where the noise is small against an encoder step the
/// scan finds it far beyond its critical value. At twice the critical value alone, 0.5 deg
/// encoders at 500 Hz and 2 kHz made 2.1-2.7 % false alarms of clean curves (1,200 each:
/// built-in CST 2 kHz, CSDT 500 Hz; independent CSDT 2 kHz), breaks of 0.1-0.8 steps at 2-4
/// times the critical value; with this rule 1.0-1.3 %. The cost, 3-15 % changes at 2 kHz and
/// 0.5 deg (independent generator): abrupt CST 0.993 -> 0.970, CSDT 0.973 -> 0.955, HDT 0.958
/// -> 0.948 (an abrupt friction change is a torque jump first, T = F K(mu) with F continuous, and
/// one under an encoder step and a half is an encoder artefact's size). The slope condition
/// alone, at twice the critical value, kept the false alarms at 0.6-1.1 % but lost the abrupt
/// changes (0.900-0.930); three times the critical value alone lost incipient ones (the
/// `test_detection_power` set, CST 3-15 %, 0.1 deg: 0.900 -> 0.875; 0.890 with this rule).
fn beyond_encoder_artefact(statistic: f64, critical_value: f64, slope_lr: impl FnOnce() -> f64) -> bool {
    statistic > ARTEFACT_MULTIPLE * critical_value || (statistic > 2.0 * critical_value && slope_lr() > critical_value)
}

/// The multiple of the scan's critical value above which a break within the encoder-step check
/// is credited without more ([`beyond_encoder_artefact`]).
const ARTEFACT_MULTIPLE: f64 = 3.0;

/// Likelihood-ratio statistic of the change of slope at split `k` of the whitened window: two
/// lines (one each side) against one line with a level shift at `k`, n ln(RSS_shift / RSS_two).
/// A friction change turns the torque rate; an encoder offset between two stretches only shifts
/// the level.
fn slope_change_lr(x: &[f64], y: &[f64], k: usize) -> f64 {
    let n = x.len();
    if k < 2 || n < k + 2 || y.len() != n {
        return 0.0;
    }
    let rss_two = line_rss(&x[..k], &y[..k]) + line_rss(&x[k..], &y[k..]);
    let rows = x.iter().zip(y).enumerate().map(|(i, (&xi, &yi))| ([1.0, xi, if i >= k { 1.0 } else { 0.0 }], yi));
    match least_squares_3(rows) {
        Some((_, _, rss_shift)) if rss_two > 0.0 => n as f64 * (rss_shift / rss_two).ln(),
        _ => 0.0,
    }
}

/// Where a change whose first changed sample is window sample `j` started: between that sample
/// and the one before it, halfway, on the interpolated angle. The recorded angle of the first
/// changed sample was reported before: it lies after the onset by up to a sample's advance, and
/// a floor-quantised angle also lags the true one. Median abrupt onset error
/// (benches/detection_quality.py, 1,500 faulty curves a cell): independent generator 2 kHz
/// 0.175 -> 0.125 deg, 1 kHz 0.390 -> 0.249, AR(1) 0.5 0.166 -> 0.123; built-in 2 kHz 0.051 ->
/// 0.049, 1 kHz 0.099 -> 0.095, 10 kHz 0.038 -> 0.013; independent 10 kHz 0.031 -> 0.047 (500).
pub(super) fn change_start_angle<A: Sample>(angle: &[A], s: &Scratch, j: usize) -> f64 {
    let recorded = angle[s.index[j]].to_f64();
    match (s.x.get(j), s.xs.get(j), j.checked_sub(1).and_then(|i| s.xs.get(i))) {
        (Some(x), Some(xs), Some(before)) => recorded - x + 0.5 * (before + xs),
        (Some(x), Some(xs), None) => recorded - x + xs,
        _ => recorded,
    }
}

/// Lag-1 autocorrelation of the window's noise model from which the episode scan runs at
/// [`EPISODE_STRONG_COLOUR_SHARE`] of its share of alpha, the rest going to the break scan.
/// Any split of the break detector's alpha is a valid test; this one follows where the share is
/// spent. On clean curves under AR(1) 0.85 (detection-quality clean sets, 1,500 curves a
/// generator) the episode scan's p-value fell below 0.05 on 1.9-2.0 % of them (4.1-7.3 % under
/// white noise): with the whitening's uncertainty averaged over, it spends about 0.4 of its share
/// there. Halved there: on the size grid's AR(1) 0.85 / 0.9 cells (54 a generator, 2,000 curves)
/// 39 -> 44 of the built-in simulator's cells in band and 42 -> 43 of the independent
/// generator's, for 0.3 / 0.7 points of 15-45 % recall under AR(1) 0.85 (97.9 -> 97.6 %,
/// 88.6 -> 87.9 %).
const EPISODE_STRONG_COLOUR_LAG1: f64 = 0.7;
/// See [`EPISODE_STRONG_COLOUR_LAG1`].
const EPISODE_STRONG_COLOUR_SHARE: f64 = 0.5;

/// What the episode scan found, in window samples.
#[derive(Clone, Copy)]
struct Episode {
    statistic: f64,
    /// Its p-value, averaged over the whitening's uncertainty.
    p_value: f64,
    /// First and last sample of the strongest stretch in the window (stops left out).
    first: usize,
    last: usize,
    /// First sample of the earliest stretch the statistic took: where the episodes begin.
    onset: usize,
    /// Mean deviation of its recorded samples from the line through those outside it.
    level: f64,
    alarm: bool,
}

/// Mean deviation of the samples `[first, end)` from the least-squares line through the others,
/// in torque units: an episode's level.
fn deviation_from_outside(x: &[f64], y: &[f64], first: usize, end: usize) -> f64 {
    let points = |range: std::ops::Range<usize>| x[range.clone()].iter().copied().zip(y[range].iter().copied());
    let (a, b) = least_squares_line_through(points(0..first).chain(points(end..x.len())));
    points(first..end).map(|(xi, yi)| yi - a - b * xi).sum::<f64>() / (end - first) as f64
}

/// Mean deviation of the samples `tested` from the least-squares line through `fitted`, in
/// torque units: the size of an end or start test's departure.
fn mean_deviation((fit_x, fit_y): (&[f64], &[f64]), (x, y): (&[f64], &[f64])) -> f64 {
    let (a, b) = line(fit_x, fit_y);
    x.iter().zip(y).map(|(xi, yi)| yi - a - b * xi).sum::<f64>() / x.len() as f64
}

/// Residual sum of squares of the least-squares line through `x`, `y`.
fn line_rss(x: &[f64], y: &[f64]) -> f64 {
    let (a, b) = line(x, y);
    x.iter().zip(y).map(|(xi, yi)| (yi - a - b * xi).powi(2)).sum()
}

/// The goodness-of-fit check of the straight elastic line: the quadratic term of the window,
/// fitted on the whitened samples (constant, angle and angle squared, each whitened with the
/// noise model `phi`), with its two-sided p-value from the t distribution on n - 3 degrees of
/// freedom, the quadratic's residual sum of squares, and the smallest residual sum of squares
/// of a friction drift that starts inside the window (the line, plus `(x - x_k)+ (x - x_snug)`
/// from a knot `x_k`, knots from [`DRIFT_KNOTS`] of the window's span; `snug_x` is the snug
/// angle in window coordinates).
///
/// Why the drift: a friction coefficient that grows linearly from an onset `x_k` (an incipient
/// fault) adds `F b (x - x_k)+` to the torque, with the clamp force `F = k (x - x_snug)`
/// linear in the angle from the snug: the line turns at the onset, by a kink `k b (x_k -
/// x_snug)` in its slope and a parabola after it. A smooth curve over the whole window (a
/// plastic joint, a nonlinear elastic zone) is bent from its start. A drift that starts at the
/// window's very start cannot be told from such a curve within one tightening; one that starts
/// later fits better than any smooth curve does, and is a change, not a misfit. `xs` is the smoothed angle of the
/// whole window (the filter's past included); `wx`, `wy` the whitened angle and torque from the
/// first whitened sample on; `weights` those of noise that grows with the torque (empty: none),
/// applied to the square as to the others.
fn curvature(xs: &[f64], weights: &[f64], wx: &[f64], wy: &[f64], phi: &[f64], snug_x: f64, scratch: &mut Vec<f64>) -> Option<(f64, f64, f64)> {
    use statrs::distribution::{ContinuousCDF, StudentsT};
    let n = wy.len();
    if n < 8 {
        return None;
    }
    // Whitened square of the angle: the square is taken on the smoothed angle and then
    // filtered, as the other regressors were.
    let lag = phi.len();
    let span = xs.last().copied().unwrap_or(0.0).max(f64::MIN_POSITIVE);
    let squares: Vec<f64> =
        xs.iter().enumerate().map(|(i, x)| (x / span).powi(2) * weights.get(i).copied().unwrap_or(1.0)).collect();
    crate::detectors::noise::whiten(&squares, phi, scratch);
    let wq = scratch.get(lag..lag + n)?;
    let gain = 1.0 - phi.iter().sum::<f64>();
    let (beta, inv, rss) = least_squares_3((0..n).map(|k| ([gain, wx[k], wq[k]], wy[k])))?;
    let df = (n - 3) as f64;
    let se = (rss / df * inv[(2, 2)]).sqrt();
    if !(se > 0.0) {
        return None;
    }
    let t = beta[2] / se;
    let p = 2.0 * StudentsT::new(0.0, 1.0, df).ok()?.sf(t.abs());
    let (first, last) = (xs.first().copied().unwrap_or(0.0), xs.last().copied().unwrap_or(0.0));
    // The drift fits share the constant and the angle with each other: their sums of products
    // are summed once, in the order `least_squares_3` sums them, and only the ramp's are summed
    // per knot (the same fits to the last bit, for a third of the work).
    let (mut s_gg, mut s_gx, mut s_xx, mut s_gy, mut s_xy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for k in 0..n {
        s_gg += gain * gain;
        s_gx += gain * wx[k];
        s_xx += wx[k] * wx[k];
        s_gy += gain * wy[k];
        s_xy += wx[k] * wy[k];
    }
    let mut ramps = Vec::with_capacity(xs.len());
    let mut rss_drift = f64::INFINITY;
    for fraction in DRIFT_KNOTS {
        let knot = first + fraction * (last - first);
        ramps.clear();
        ramps.extend(xs.iter().enumerate().map(|(i, x)| {
            let force = if snug_x.is_finite() && snug_x < *x { x - snug_x } else { x - knot };
            (x - knot).max(0.0) * force / (span * span) * weights.get(i).copied().unwrap_or(1.0)
        }));
        crate::detectors::noise::whiten(&ramps, phi, scratch);
        let Some(wr) = scratch.get(lag..lag + n) else { continue };
        let (mut s_gr, mut s_xr, mut s_rr, mut s_ry) = (0.0, 0.0, 0.0, 0.0);
        for k in 0..n {
            s_gr += gain * wr[k];
            s_xr += wx[k] * wr[k];
            s_rr += wr[k] * wr[k];
            s_ry += wr[k] * wy[k];
        }
        let xtx = nalgebra::Matrix3::new(s_gg, s_gx, s_gr, s_gx, s_xx, s_xr, s_gr, s_xr, s_rr);
        let xty = nalgebra::Vector3::new(s_gy, s_xy, s_ry);
        if let Some((_, _, rss_k)) = least_squares_3_from_sums(xtx, xty, (0..n).map(|k| ([gain, wx[k], wr[k]], wy[k]))) {
            rss_drift = rss_drift.min(rss_k);
        }
    }
    Some((p, rss, rss_drift))
}

/// Knots of the drift model of [`curvature`], as fractions of the window's angle span: every
/// 0.03 up to 0.15, every 0.05 from 0.18. A drift from the window's very start is a parabola, as
/// a curve bent from its start is, but one from 0.03-0.15 of it still bends the line only from
/// there. With knots from 0.18 only, 10 of the 20 misses among 1,068 changes of 15-45 % on the
/// independent generator (white noise, 2 kHz, 0.1 deg) were such drifts called
/// `model_misfit` (onset 0.03-0.17 of the tested window); with these knots 3 were, and the
/// clean curves' false alarms (the size grid, 270 cells of 2,000: one alarm more in all) and
/// the claims on the real control group s01 (11 of 2,513) stayed as they were. From 0.18 the
/// guard had let 94 % of incipient drifts (CST, 3-45 %) be claimed, 77 % with knots from 0.33
/// and 65 % without the drift model.
const DRIFT_KNOTS: [f64; 20] = [
    0.03, 0.06, 0.09, 0.12, 0.15, 0.18, 0.23, 0.28, 0.33, 0.38, 0.43, 0.48, 0.53, 0.58, 0.63, 0.68, 0.73, 0.78, 0.83, 0.88,
];

/// Lag-1 autocorrelation of the noise model from which, in windows shorter than
/// [`NEAR_UNIT_ROOT_WINDOW`] whitened samples, the scan's p-value treats the statistic as
/// growing with the long-run variance to at least [`NEAR_UNIT_ROOT_KAPPA`].
const NEAR_UNIT_ROOT_LAG1: f64 = 0.9;
/// See [`NEAR_UNIT_ROOT_LAG1`].
const NEAR_UNIT_ROOT_WINDOW: usize = 250;
/// See [`NEAR_UNIT_ROOT_LAG1`] and [`scan_sensitivity`].
const NEAR_UNIT_ROOT_KAPPA: f64 = 1.0;

/// The exponent kappa with which the scan's (and the episode scan's) statistic grows with the
/// long-run variance a whitening error leaves: the measured sensitivity (`measured`: the GLS
/// scan's [`gls_whitening_sensitivity`], 0.01-0.82, or the two-line kind's
/// [`whitening_sensitivity`], 0.04-0.92, by window length and colour), at least
/// [`NEAR_UNIT_ROOT_KAPPA`] in short windows whose noise model is near the unit root.
///
/// Why the exception: whitening with a coefficient near 1 nearly differences the window, and
/// then the window's own small departures from a line (its shape near the snug) stand out
/// against the small innovations (the whitened angle is then nearly constant, so the null
/// line can hardly follow a bend, and a break can). The windows that alarm had their noise
/// fitted at lag-1 0.91-0.99 for a true 0.9, 30-80 whitened samples long: the pure-noise Monte
/// Carlo behind the tables cannot show this, it has no shape: with the true phi and no
/// whitening error at all, the rule claimed 2.6 % of 4,000 clean independent-generator CST
/// curves under AR(1) 0.9 (HDT 0.9 %, CSDT 1.3 %). On clean CST curves under AR(1) 0.9 (1,000
/// curves, seed 76) the GLS scan with the measured kappa alone claimed 3.4 %; with the floor
/// at 1 (the two-line scan's exception) 1.0 %, at 0.7 / 0.5 / 0.4 / 0.3: 1.1 / 1.1 / 1.3 /
/// 2.0 %. The floor was 0.5 while the noise model came from 64-sample blocks alone, whose wide
/// standard error of the gain did part of its work; with the longer blocks of strong colour
/// (`STRONG_COLOUR` in the analysis module) that error halves, and 4,000 clean CST curves
/// under AR(1) 0.9 (seed 1003) claimed 2.1 % at 0.5 and 1.23 % at 1 (CSDT 0.85 %, HDT
/// 0.50 %, CST under 0.85 0.65 %). Abrupt changes on 400 CST curves under AR(1) 0.9 (seed 77)
/// are found as often as with the 64-sample noise model and the floor at 0.5: 3-15 % in 0.815
/// (0.815 before), 15-45 % in 0.965 (0.915).
fn scan_sensitivity(nw: usize, lag1: f64, measured: fn(usize, f64) -> f64) -> f64 {
    let kappa = measured(nw, lag1);
    if lag1 >= NEAR_UNIT_ROOT_LAG1 && nw < NEAR_UNIT_ROOT_WINDOW {
        kappa.max(NEAR_UNIT_ROOT_KAPPA)
    } else {
        kappa
    }
}

#[cfg(test)]
#[allow(clippy::expect_used)] // a failed expect is a failed test
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// The share of the scan's alpha the CUSUM takes: none where the check's jump is within two
    /// of its null sd (the scan spends its share), all of it from sixteen (a 0.5 deg encoder
    /// against low noise), falling in between, whatever the quantisation's size against the noise.
    #[test]
    fn the_scan_hands_the_cusum_only_the_share_its_encoder_check_leaves() {
        let mut last = 1.0;
        for k in 0..=200 {
            let share = scan_share_passing_check(k as f64 * 0.1);
            assert!(share <= last && (0.0..=1.0).contains(&share), "{share} at {}", k as f64 * 0.1);
            last = share;
        }
        assert_eq!(scan_share_passing_check(1.0), 1.0);
        assert_eq!(scan_share_passing_check(16.0), 0.0);
        assert_eq!(scan_share_passing_check(f64::NAN), 1.0);
        // n = 400: the jump's null sd is a fifth of the long-run sd, and 1.5 steps over it is
        // 7.5 steps per long-run sd.
        let (n, long_run_sd) = (400, 1.0);
        assert_eq!(unspent_scan_share(0.2, long_run_sd, n, 1.5), 0.0);
        assert!((unspent_scan_share(1.0, long_run_sd, n, 1.5) - (1.0 - scan_share_passing_check(7.5))).abs() < 1e-12);
        // n = 1,600: the jump's null sd a tenth of it, 1.5 steps of 1.2 over it 18.
        assert_eq!(unspent_scan_share(1.2, long_run_sd, 1600, 1.5), 1.0);
        // Quantisation 1.8 / sqrt(12) = 0.52 of the long-run sd: handed over as any other (the
        // CUSUM's scale takes the angle error), 1.5 steps 13.5 jump sds.
        assert!((unspent_scan_share(1.8, long_run_sd, n, 1.5) - (1.0 - scan_share_passing_check(13.5))).abs() < 1e-12);
        assert_eq!(unspent_scan_share(0.0, long_run_sd, n, 1.5), 0.0);
        assert_eq!(unspent_scan_share(1.0, 0.0, n, 1.5), 0.0);
    }

    /// (rss of the quadratic, smallest rss of a drift) of a window whose torque is a line plus
    /// `bend(x)`, with white noise of sd 0.02, 300 samples over 30 deg, the snug 15 deg before it.
    fn fits(bend: impl Fn(f64) -> f64, seed: u64) -> (f64, f64) {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let xs: Vec<f64> = (0..300).map(|i| i as f64 * 0.1).collect();
        let y: Vec<f64> = xs
            .iter()
            .map(|&x| {
                let e: f64 = StandardNormal.sample(&mut rng);
                2.0 + 1.5 * x + bend(x) + 0.02 * e
            })
            .collect();
        let mut scratch = Vec::new();
        let (_, rss_quad, rss_drift) = curvature(&xs, &[], &xs, &y, &[], -15.0, &mut scratch).expect("fits");
        (rss_quad, rss_drift)
    }

    #[test]
    fn a_drift_that_starts_inside_the_window_fits_better_than_a_smooth_curve() {
        // Friction growing by 10 % over the rest of the window from 40 % of it: the torque
        // turns at the onset (force times drift), as an incipient fault makes it.
        for seed in 0..5 {
            let (quad, drift) = fits(|x| 0.01 * (x - 12.0).max(0.0) * (x + 15.0), seed);
            assert!(drift < quad, "seed {seed}: drift {drift} quadratic {quad}");
            // From a tenth of the window: still a turn, not a curve bent from the start (with
            // knots from 0.18 of the window only, the quadratic fitted it better).
            let (quad, drift) = fits(|x| 0.01 * (x - 3.0).max(0.0) * (x + 15.0), seed);
            assert!(drift < quad, "seed {seed}: onset at a tenth: drift {drift} quadratic {quad}");
        }
    }

    #[test]
    fn a_curve_bent_from_the_window_start_is_smooth_not_a_drift() {
        // A plastic joint: the torque rate falls steadily over the whole window.
        for seed in 0..5 {
            let (quad, drift) = fits(|x| -0.004 * x * x, seed);
            assert!(quad < drift, "seed {seed}: drift {drift} quadratic {quad}");
        }
    }

    /// The slope-change statistic sees a kink (a friction change turning the torque rate) and
    /// not a level shift of the same size at the split (an encoder offset), under white noise.
    #[test]
    fn the_slope_change_statistic_sees_a_kink_and_not_a_level_shift() {
        let (n, k) = (200, 120);
        let x: Vec<f64> = (0..n).map(|i| i as f64 * 0.1).collect();
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
        let noise: Vec<f64> = (0..n).map(|_| 0.01 * <StandardNormal as Distribution<f64>>::sample(&StandardNormal, &mut rng)).collect();
        let shift: Vec<f64> = (0..n).map(|i| 1.0 + 0.5 * x[i] + if i >= k { 0.05 } else { 0.0 } + noise[i]).collect();
        let kink: Vec<f64> = (0..n).map(|i| 1.0 + 0.5 * x[i] + if i >= k { 0.01 * (x[i] - x[k]) } else { 0.0 } + noise[i]).collect();
        let (on_shift, on_kink) = (slope_change_lr(&x, &shift, k), slope_change_lr(&x, &kink, k));
        // One degree of freedom under the null: a chi-square(1) is below 6.6 with 99 %.
        assert!(on_shift < 6.6, "level shift: {on_shift}");
        assert!(on_kink > 30.0, "kink: {on_kink}");
        // Degenerate splits give 0, not a panic.
        assert_eq!(slope_change_lr(&x, &kink, 0), 0.0);
        assert_eq!(slope_change_lr(&x, &kink, n), 0.0);
        assert_eq!(slope_change_lr(&x[..3], &kink[..3], 1), 0.0);
    }
}
