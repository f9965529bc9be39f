//! The particle-filter step: the fault test of [`crate::detectors::pf`] over the window's
//! whitened samples, the same samples the break scan tests, judged by the null table
//! ([`crate::detectors::pf::pf_null_p_value`]).

use crate::detectors::pf::{pf_fault_test, pf_null_p_value, PfConfig};
use crate::engine::input::Sample;
use crate::engine::rows::{PfOnset, PfRow};
use crate::engine::Detector;

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
        let filter = PfConfig { particles: cfg.particles, seed: cfg.seed.wrapping_add(row as u64), ..PfConfig::default() };
        let res = pf_fault_test(&s.wx[lag..n], &s.wy[lag..n], self.pf_alpha, &filter)?;
        // The null table's p-value: Ville's bound (res.p_value) holds too, but at 10-100 times
        // the simulated tail it leaves most of alpha unused.
        let p_value = pf_null_p_value(res.statistic, n - lag);
        let at = |k: usize| s.index.get(k + lag).map(|&i| (i, angle[i].to_f64()));
        let onset = res.onset.and_then(|(mid, lo, hi)| {
            let (index, angle) = at(mid)?;
            Some(PfOnset { index, angle, lo_angle: at(lo)?.1, hi_angle: at(hi)?.1 })
        });
        Some(PfRow {
            alarm: p_value <= self.pf_alpha,
            statistic: res.statistic,
            p_value,
            fault_probability: res.fault_probability,
            onset,
        })
    }
}
