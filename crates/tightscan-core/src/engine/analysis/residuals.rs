//! The residual step: the classical k-sigma chart and the kernel-density (L2 / MMD) test on the
//! residuals of the robust elastic line (METHODS.md section 4).

use crate::detectors::kde::{kde_change_test, kde_density, silverman_bandwidth, KdeTestConfig, KdeWindow};
use crate::detectors::shewhart::shewhart_scan;
use crate::engine::input::Sample;
use crate::engine::rows::{KdeRow, ResidualRow};
use crate::engine::traces::{KdeTrace, DENSITY_POINTS};
use crate::engine::Detector;
use crate::physics::phases::robust_line;

use super::Scratch;

impl Detector {
    /// Tests on the residuals of the robust elastic line over the window's whitened samples
    /// (the break scan's, see [`Scratch::window_samples`]): the k-sigma chart always, the
    /// kernel-density test when enabled. The line is refitted to exactly the samples tested: the
    /// phase finder's line also saw the stop of a CSDT pause (relaxation at standstill, then the
    /// wind-up), whose pull left structure in the residuals (the kernel-density test alarmed on
    /// half of the clean CSDT curves). Under no change the whitened residuals are close to
    /// exchangeable, which the permutation test needs; a change leaves residuals whose level or
    /// spread differs before and after it.
    pub(super) fn residual_row<A: Sample>(&self, angle: &[A], row: usize, s: &mut Scratch) -> Option<ResidualRow> {
        let cfg = &self.config.residual_tests;
        let (lag, n_window) = (s.lag, s.n_window);
        if n_window <= lag {
            return None;
        }
        let (wx, wy) = (&s.wx[lag..n_window], &s.wy[lag..n_window]);
        let line = robust_line(wx, wy, &mut s.bits)?;
        s.line_residuals.clear();
        s.line_residuals.extend(wx.iter().zip(wy).map(|(x, y)| y - line.intercept - line.slope * x));
        let n = s.line_residuals.len();
        let training = ((cfg.training_fraction * n as f64).round() as usize).max(2);
        let chart = shewhart_scan(&s.line_residuals, training, cfg.shewhart_k).ok()?;
        let at = |k: usize| (s.index[k + lag], angle[s.index[k + lag]].to_f64());
        let mut out = ResidualRow {
            shewhart_alarm: chart.alarm_index.is_some(),
            shewhart_max_abs_z: chart.max_abs_z,
            shewhart_alarm_index: chart.alarm_index.map(|k| at(k).0),
            shewhart_alarm_angle: chart.alarm_index.map(|k| at(k).1),
            kde: None,
        };
        if cfg.kde {
            // Sliding windows as wide as the reference: twice the power of a growing window for
            // a change in mid-window (detectors/kde tests), at the same exact size.
            let test = KdeTestConfig {
                alpha: self.kde_alpha,
                permutations: cfg.kde_permutations,
                window: KdeWindow::Sliding { width: training.max(20) },
                seed: cfg.kde_seed.wrapping_add(row as u64),
                ..KdeTestConfig::default()
            };
            let result = kde_change_test(&s.line_residuals, training, &test);
            let compared = result.as_ref().map_or(training..n, |k| k.peak_start..k.peak_end);
            if let Ok(k) = result {
                out.kde = Some(KdeRow {
                    alarm: k.alarm,
                    statistic: k.statistic,
                    p_value: k.p_value,
                    change_index: k.change_start.map(|c| at(c).0),
                    change_angle: k.change_start.map(|c| at(c).1),
                });
            }
            if s.trace.is_some() {
                self.density_trace(angle, training, compared, true, s);
            }
        } else if s.trace.is_some() {
            self.density_trace(angle, training, training..n, false, s);
        }
        Some(out)
    }

    /// Records the kernel densities of the line residuals of the reference (the first
    /// `training`) and of `compared`, with the test's bandwidth, when tracing.
    fn density_trace<A: Sample>(&self, angle: &[A], training: usize, compared: std::ops::Range<usize>, tested: bool, s: &mut Scratch) {
        let residuals = &s.line_residuals;
        if training < 2 || training > residuals.len() || compared.start >= compared.end || compared.end > residuals.len() {
            return;
        }
        let (before, after) = (&residuals[..training], &residuals[compared.clone()]);
        let (Ok(bandwidth), Some(traces)) = (silverman_bandwidth(before), s.trace.as_deref_mut()) else { return };
        let (lo, hi) = residuals.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &r| (lo.min(r), hi.max(r)));
        let (lo, hi) = (lo - 3.0 * bandwidth, hi + 3.0 * bandwidth);
        let step = (hi - lo) / (DENSITY_POINTS - 1) as f64;
        let grid: Vec<f64> = (0..DENSITY_POINTS).map(|i| lo + step * i as f64).collect();
        let lag = s.lag;
        let at = |k: usize| angle[s.index[k + lag]].to_f64();
        traces.kde = Some(KdeTrace {
            before: kde_density(before, bandwidth, &grid),
            after: kde_density(after, bandwidth, &grid),
            grid,
            bandwidth,
            before_angles: (at(0), at(training - 1)),
            after_angles: (at(compared.start), at(compared.end - 1)),
            tested,
        });
    }
}
