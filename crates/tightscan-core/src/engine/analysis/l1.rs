//! The L1 step: sign-residual monitoring of the local torque rate (Huskova and Koubkova 2005,
//! METHODS.md section 3), on block slopes of the break scan's samples.

use crate::detectors::monitor::{monitor_l1, L1MonitorConfig};
use crate::engine::input::Sample;
use crate::engine::rows::L1Row;
use crate::engine::traces::L1Trace;
use crate::engine::Detector;

use super::Scratch;

impl Detector {
    /// L1 monitoring of the local torque rate (torque per clamp force on rig data): least-squares
    /// slopes of short equal-width blocks of the break scan's samples, monitored as a location
    /// (p = 1) after the first `residual_tests.training_fraction` of the blocks.
    ///
    /// Why slopes and not the torque itself: torque on angle is a trend regression, and the
    /// sign-residual theory (stationary regressors) does not hold for it: extrapolating the
    /// training line over three times its length tilted the signs and alarmed on 93 % of clean
    /// simulated curves. Block slopes are independent under white noise and symmetric about
    /// the true rate, so their signs about the training median are fair coins whatever each
    /// block's variance (a decelerating tool gives later blocks more samples): exactly the
    /// setting of the L1 procedure. A friction change moves the rate, so the signs tilt.
    ///
    /// Blocks are cut by angle (by clamp force on rig data) and each block's slope is taken on
    /// the whitened samples ([`Scratch::window_samples`]), so that coloured noise does not make
    /// neighbouring blocks' signs agree.
    pub(super) fn l1_row<A: Sample>(&self, angle: &[A], s: &mut Scratch) -> Option<L1Row> {
        let lag = s.lag;
        let n = s.n_window;
        let n_blocks = (n / 8).clamp(16, 200);
        if n < 3 * n_blocks {
            return None;
        }
        let use_force = s.has_force;
        let (lo, hi) = if use_force {
            let v = s.index[lag..n].iter().map(|&i| s.force[i]);
            v.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), f| (a.min(f), b.max(f)))
        } else {
            (s.x[lag], s.x[n - 1])
        };
        if !(hi > lo) {
            return None;
        }
        let width = (hi - lo) / n_blocks as f64;
        // Per block: n, sum r, sum y, sum rr, sum ry of the whitened regressor r and torque y,
        // and the first sample's position.
        let mut sums = vec![(0.0f64, 0.0f64, 0.0f64, 0.0f64, 0.0f64, usize::MAX); n_blocks];
        let regressor = if use_force { &s.wf } else { &s.wx };
        for (k, (&r, &y)) in regressor.iter().zip(&s.wy).enumerate().take(n).skip(lag) {
            let position = if use_force { s.force[s.index[k]] - lo } else { s.x[k] - lo };
            let b = ((position / width) as usize).min(n_blocks - 1);
            let e = &mut sums[b];
            e.0 += 1.0;
            e.1 += r;
            e.2 += y;
            e.3 += r * r;
            e.4 += r * y;
            e.5 = e.5.min(k);
        }
        // A block's whitened regressor spreads about as its position does, times the filter's
        // gain at low frequency; the same relative floor as for the unwhitened slopes.
        let gain: f64 = 1.0 - s.noise.coefficients.iter().sum::<f64>();
        let floor = 1e-9 * (width * gain).powi(2);
        s.regressor.clear();
        s.block_first.clear(); // position (into s.x) of each usable block's first sample
        for e in &sums {
            let sxx = e.3 - e.1 * e.1 / e.0.max(1.0);
            if e.0 >= 3.0 && sxx > floor {
                s.regressor.push((e.4 - e.1 * e.2 / e.0) / sxx);
                s.block_first.push(e.5);
            }
        }
        let blocks = s.regressor.len();
        let training = ((self.config.residual_tests.training_fraction * blocks as f64).round() as usize).max(10);
        if training + 5 > blocks {
            return None;
        }
        let config = L1MonitorConfig {
            gamma: self.config.l1.gamma,
            alpha: self.l1_alpha,
            critical_value: Some(self.l1_critical_value),
            keep_path: s.trace.is_some(),
            ..L1MonitorConfig::new(training)
        };
        let result = monitor_l1(&[], &s.regressor, &config).ok()?;
        // The last sample of usable block b: when its evidence was complete.
        let block_end = |b: usize| {
            let next_first = s.block_first.get(b + 1).copied().unwrap_or(n);
            s.index[next_first.saturating_sub(1).min(n - 1)]
        };
        let at = result.alarm_index.map(&block_end);
        if let (Some(traces), Some(path)) = (s.trace.as_deref_mut(), result.path.as_ref()) {
            // The location model's quadratic form is Q^2 / m and its boundary g^2 / m: both
            // times m, square-rooted, are |Q| and g.
            let m = result.training as f64;
            traces.l1 = Some(L1Trace {
                angle: (0..path.statistic.len()).map(|j| angle[block_end(training + j)].to_f64()).collect(),
                statistic: path.statistic.iter().map(|q| (q * m).sqrt()).collect(),
                boundary: path.boundary.iter().map(|g| (g * m).sqrt()).collect(),
                critical_value: result.critical_value,
                gamma: result.gamma,
                training: result.training,
            });
        }
        Some(L1Row {
            alarm_index: at,
            alarm_angle: at.map(|i| angle[i].to_f64()),
            max_ratio: result.max_ratio,
            statistic_at_alarm: result.statistic_at_alarm,
            boundary_at_alarm: result.boundary_at_alarm,
            gamma: result.gamma,
            alpha: result.alpha,
        })
    }
}
