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

/// The factor by which the standardised block rates are widened for the whitening's own
/// uncertainty. With the AR filter's log gain known to a standard error `gain_log_se`, the
/// block rates' variance is `lambda` times the one assumed, `ln lambda ~ N(0, (2 se)^2)`. The
/// CUSUM's false-alarm probability over `blocks` steps, `1 - exp(-blocks / ARL)` (Siegmund's ARL
/// of the scheme on N(0, lambda / c^2) increments, i.e. with kappa and h scaled by c /
/// sqrt(lambda)), averaged over lambda (5-point Gauss-Hermite), is a convex function of lambda's
/// spread: the factor `c >= 1` brings that average back to the nominal probability (bisection).
/// 1 for white noise.
fn predictive_scale(h: f64, kappa: f64, blocks: usize, gain_log_se: f64) -> f64 {
    use crate::detectors::cusum::cusum_arl;
    use crate::detectors::noise::NORMAL_NODES;
    if !(gain_log_se > 0.0) || blocks == 0 {
        return 1.0;
    }
    let steps = blocks as f64;
    let false_alarm = |scale: f64| 1.0 - (-steps / cusum_arl(h * scale, kappa * scale, 0.0, true)).exp();
    let nominal = false_alarm(1.0);
    let averaged = |c: f64| -> f64 {
        NORMAL_NODES.iter().map(|(z, w)| w * false_alarm(c * (-gain_log_se * z).exp())).sum()
    };
    let (mut lo, mut hi) = (1.0_f64, (6.0 * gain_log_se).exp());
    if averaged(lo) <= nominal {
        return 1.0;
    }
    if averaged(hi) > nominal {
        return hi;
    }
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if averaged(mid) > nominal {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    hi
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
        let gain = 1.0 - s.noise.coefficients.iter().sum::<f64>();
        time_smoothed_angle(&s.xs, &s.index, TIME_SMOOTHING, &mut s.smoothed);
        weigh(&s.smoothed, &s.weights, &mut s.weighted);
        whiten(&s.weighted, &s.noise.coefficients, &mut s.smooth_wx);
        block_stats_whitened(&s.x[lag..n], &s.smooth_wx[lag..n], &s.wy[lag..n], n_blocks, gain, &mut s.blocks);
        let blocks = &s.blocks;
        let stops = &s.stops;
        let width = blocks.width;
        let start = s.x[lag];
        let touches_stop = |b: usize| {
            let (lo, hi) = (start + b as f64 * width, start + (b + 1) as f64 * width);
            stops.iter().any(|&(s0, s1)| s0 < hi && s1 >= lo)
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
        let (mut rss, mut df) = (0.0, 0.0);
        for &b in s.usable.iter() {
            let st = &blocks.stats[b];
            let dof = (st.n as f64 - 2.0).max(1.0);
            if st.rss() / dof <= 20.0 * median_var {
                rss += st.rss();
                df += dof;
            }
        }
        let rise = s.y[n - 1] - s.y[lag];
        // Floor for noise-free or coarsely quantised torque: 1e-6 of the rise.
        let noise_sd = (rss / df.max(1.0)).sqrt().max(1e-6 * rise.abs().max(f64::MIN_POSITIVE));

        // Standardised block rates: under white noise slope_b has variance sigma^2 / Sxx_b,
        // so z_b = (slope_b - reference) sqrt(Sxx_b) / sigma ~ N(0, 1) with no change.
        let z_of = |b: usize| (blocks.stats[b].slope() - reference_rate) * blocks.stats[b].sxx_c().sqrt() / noise_sd;
        // Dispersion pre-test: sum of squared training z's against chi-square(B). Coloured noise
        // (filters, vibration) makes block slopes vary more than white noise would; the scale is
        // widened only when that excess is significant at 0.1 %.
        let sum_z2: f64 = train.iter().map(|&b| z_of(b).powi(2)).sum();
        let k = train.len() as f64;
        let dispersion = (sum_z2 / k).sqrt();
        let inflate = if sum_z2 > chi_square_quantile(k, Z_0999) { dispersion } else { 1.0 };

        let predictive = predictive_scale(self.threshold, cfg.cusum.kappa, monitor.len(), s.noise.gain_log_se);
        s.z.clear();
        s.z.extend(monitor.iter().map(|&b| z_of(b) / (inflate * predictive)));
        let mut cusum = TwoSidedCusum::new(cfg.cusum.kappa, self.threshold);
        // The sample where monitored block j's evidence is complete: its last.
        let block_end = |j: usize| s.index[blocks.stats[monitor[j]].last + lag];
        let mut trace = s.trace.is_some().then(|| CusumTrace {
            threshold: self.threshold,
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
            threshold: self.threshold,
            reference_rate,
            noise_sd: noise_sd * inflate * predictive,
            noise_df: df,
            dispersion,
            blocks: monitor.len(),
            block_angle: blocks.width,
        })
    }
}
