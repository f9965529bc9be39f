//! The break step: the sup-LR scan for one break of the elastic line and Chow's predictive
//! test of the last samples up to the peak, with the encoder-step check that keeps angle
//! quantisation from passing for a friction change.

use crate::detectors::breakpoint::{min_segment, sup_lr_critical_value, sup_lr_p_value, sup_lr_scan, tail_test};
use crate::engine::input::Sample;
use crate::engine::rows::BreakRow;
use crate::engine::Detector;
use crate::physics::torque_rate::ElasticWindow;

use super::Scratch;

/// Encoder resolution of an angle series (relative, sorted non-decreasing within runs): the
/// smallest positive difference between consecutive samples, when angles repeat or step by
/// it often enough to be a grid (a quarter of the steps at most twice it); 0 for unquantised
/// angles.
fn angle_resolution(x: &[f64]) -> f64 {
    let mut smallest = f64::INFINITY;
    for w in x.windows(2) {
        let d = w[1] - w[0];
        if d > 1e-9 && d < smallest {
            smallest = d;
        }
    }
    if !smallest.is_finite() {
        return 0.0;
    }
    // A grid: most steps are whole multiples of the smallest one.
    let on_grid = x
        .windows(2)
        .filter(|w| {
            let q = (w[1] - w[0]) / smallest;
            (q - q.round()).abs() < 0.05
        })
        .count();
    if on_grid * 10 >= 9 * (x.len() - 1) {
        smallest
    } else {
        0.0
    }
}

impl Detector {
    /// sup-LR scan over the window's samples, leaving out those in a stop range (a CSDT pause:
    /// relaxation at standstill and the wind-up after it are not friction), and the end test
    /// over the window's last samples plus those between its end and the peak (`tail_end`,
    /// the peak's index; `None` when the curve yields, whose end is bent on purpose).
    pub(super) fn break_row<A: Sample, T: Sample>(
        &self,
        angle: &[A],
        torque: &[T],
        window: ElasticWindow,
        tail_end: Option<usize>,
        s: &mut Scratch,
    ) -> Option<BreakRow> {
        let a0 = angle[window.start].to_f64();
        let t0 = torque[window.start].to_f64();
        s.x.clear();
        s.y.clear();
        s.index.clear();
        let outside_stops = |x: f64, stops: &[(f64, f64)]| !stops.iter().any(|&(lo, hi)| x >= lo && x <= hi);
        for i in window.start..window.end {
            let x = angle[i].to_f64() - a0;
            if outside_stops(x, &s.stops) {
                s.x.push(x);
                s.y.push(torque[i].to_f64() - t0);
                s.index.push(i);
            }
        }
        let n = s.x.len();
        let scan = sup_lr_scan(&s.x, &s.y, min_segment(n), &mut s.prefix)?;
        let breaks = &self.config.breaks;
        let scan_alpha = self.break_alpha * (1.0 - breaks.tail_fraction);
        let critical_value = sup_lr_critical_value(n, scan_alpha).ok()?;
        // Angle quantisation: where the angle advanced per sample is close to a multiple of the
        // encoder resolution r, the quantisation error drifts slowly and wraps by r, which is a
        // torque step of G r against the recorded angle (G the torque rate): one encoder step.
        // These steps made most of the scan's excess false alarms on simulated curves (all 87
        // clean curves with p <= 0.001 in 20,000 had |jump| = 0.75-1.9 G r). A break is only
        // credited when its jump exceeds `min_jump_steps` encoder steps (default 1.5), or when
        // it is large enough (twice the critical value) that a step cannot explain it.
        let resolution = angle_resolution(&s.x);
        let (dx, dy) = (s.x[n - 1] - s.x[0], s.y[n - 1] - s.y[0]);
        let encoder_step = if dx > 0.0 { (dy / dx).abs() * resolution } else { 0.0 };
        let beyond_step = |jump: f64| encoder_step <= 0.0 || jump.abs() > breaks.min_jump_steps * encoder_step;
        let scan_alarm = scan.statistic > critical_value && (beyond_step(scan.jump) || scan.statistic > 2.0 * critical_value);

        // End test: every tail the scan cannot isolate (shorter than its minimum segment), up to
        // the peak. The samples past the window are appended for the test and removed again:
        // the residual tests and L1 use the window alone.
        let tail = if breaks.tail_fraction > 0.0 {
            if let Some(end) = tail_end {
                for i in window.end..=end.min(angle.len() - 1) {
                    let x = angle[i].to_f64() - a0;
                    if outside_stops(x, &s.stops) {
                        s.x.push(x);
                        s.y.push(torque[i].to_f64() - t0);
                        s.index.push(i);
                    }
                }
            }
            let extra = s.x.len() - n;
            let t = tail_test(&s.x, &s.y, min_segment(n) - 1 + extra, &mut s.prefix).map(|t| (t, s.index[t.start]));
            s.x.truncate(n);
            s.y.truncate(n);
            s.index.truncate(n);
            t
        } else {
            None
        };
        let tail_alpha = self.break_alpha * breaks.tail_fraction;
        let tail_alarm = tail.is_some_and(|(t, _)| t.p_value <= tail_alpha && (beyond_step(t.deviation) || t.p_value <= 0.01 * tail_alpha));

        let (change_index, jump) = match tail {
            Some((t, at)) if tail_alarm && !scan_alarm => (at, t.deviation),
            _ => (s.index[scan.split], scan.jump),
        };
        Some(BreakRow {
            alarm: scan_alarm || tail_alarm,
            statistic: scan.statistic,
            critical_value,
            p_value: sup_lr_p_value(n, scan.statistic),
            tail_p_value: tail.map(|(t, _)| t.p_value),
            change_index,
            change_angle: angle[change_index].to_f64(),
            jump,
        })
    }
}
