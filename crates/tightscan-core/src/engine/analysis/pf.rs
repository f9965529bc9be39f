//! The particle-filter step: the fault test of [`crate::detectors::pf`] over the window's
//! whitened samples, the same samples the break scan tests, judged by the null table
//! ([`crate::detectors::pf::pf_null_p_value`]).

use crate::detectors::noise::whiten;
use crate::detectors::pf::{onset_posterior, pf_fault_test_whitened, pf_predictive_p_value, ChangeDirection, PfConfig, WhitenedLine};
use crate::engine::input::Sample;
use crate::engine::rows::{PfOnset, PfRow};
use crate::engine::Detector;

use super::breaks::change_start_angle;
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
        let line = WhitenedLine { intercept: Some(&intercept[lag..n]), x: &s.wx[lag..n], pivot_x: &s.xs[lag..n], y: &s.wy[lag..n], restarts: &restarts };
        let res = pf_fault_test_whitened(&line, self.pf_alpha, &filter)?;
        // The null table's p-value (Ville's bound, res.p_value, holds too, but at 10-100 times
        // the simulated tail it leaves most of alpha unused), averaged over the whitening's
        // uncertainty: the AR fit's error leaves colour the table does not have.
        let p_value = pf_predictive_p_value(res.statistic, n - lag, s.noise.gain_log_se);
        let alarm = p_value <= self.pf_alpha;
        // Where: a friction change steps the torque and turns its line about the snug (where the
        // clamp force starts); the kink model put simulated changes 2-4 samples early. The
        // change's sample is placed by its exact posterior given a change (`onset_posterior`:
        // the marginal likelihood of every candidate sample, the data after the change
        // included), not by the filter's surviving paths, which share their jump times after
        // resampling. Run only for an alarm, so clean curves cost one filter.
        let placed = if alarm {
            let weighted_x: Vec<f64> = s.xs[..n].iter().zip(&s.weighted[..n]).map(|(x, w)| x * w).collect();
            let direction = ChangeDirection { weight: &s.weighted[..n], weighted_x: &weighted_x, pivot: s.snug_x, phi: &s.noise.coefficients };
            onset_posterior(&line, &direction, &filter).or(res.onset)
        } else {
            res.onset
        };
        // Angles on the interpolated angle (the encoder's quantisation averaged out, as the
        // break scan's change angle): the recorded angle of a 0.1 deg encoder at 2 kHz is a
        // staircase, and an interval between two recorded angles missed the built-in
        // simulator's onsets in 41-54 % of CST alarms (the onset lay past its recorded end).
        let interpolated = |j: usize| -> Option<f64> {
            let i = *s.index.get(j)?;
            Some(angle.get(i)?.to_f64() - s.x.get(j)? + s.xs.get(j)?)
        };
        let onset = placed.and_then(|(mid, lo, hi)| {
            let (mid, lo, hi) = (mid + lag, lo + lag, hi + lag);
            let index = *s.index.get(mid)?;
            // A jump "at sample k" happened after sample k - 1 and by sample k: the interval
            // runs from the sample before its earliest jump to its latest jump, and the change
            // angle is halfway between the median's sample and the one before it.
            let before = |j: usize| interpolated(j.saturating_sub(1));
            let at_mid = interpolated(mid)?;
            let angle = change_start_angle(angle, s, mid);
            Some(PfOnset { index, angle, lo_angle: before(lo).unwrap_or(at_mid).min(angle), hi_angle: interpolated(hi)?.max(angle) })
        });
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
