//! Phases of a tightening curve: rundown (prevailing torque), alignment to snug, elastic
//! clamping, post-yield (METHODS.md section 1).
//!
//! How each is found, and why:
//! - **Snug** by the tangent method: the elastic line, extrapolated back, meets the prevailing
//!   (rundown) torque level at the snug angle. This is the angle where clamp force would start
//!   if the joint had no seating zone, which is what the torque-angle relation of the elastic
//!   zone is referred to (F = k (theta - theta_snug)); a threshold-torque snug point would move
//!   with friction and prevailing torque instead.
//! - **Where the final rise starts** by a hinge fit: a flat level joined continuously to a line,
//!   `T = c + G (theta - theta_k)+`, fitted by least squares for every candidate knee in one pass
//!   of suffix sums. Torque levels relative to the curve's minimum fail on thread-forming and
//!   locking screws, whose rundown torque can be half the final torque (the real Rexroth runs);
//!   the hinge needs no level.
//! - **Elastic window**: from `start_fraction` to `end_fraction` of the rise from the prevailing
//!   torque to the peak, walking forward from the knee, then trimmed at both ends by angle, and
//!   cut before the yield point when there is one.
//! - **Yield**: the gradient falls. Local gradients over equal-angle blocks after the first half
//!   of the window are compared with the elastic gradient; yield starts at the first block from
//!   which every later block stays below `yield_gradient_fraction` of it.
//! - **Robust line**: Huber M-estimation (k = 1.345, 95 % efficiency under Gaussian noise) by
//!   iteratively reweighted least squares with a MAD scale, so a spike or a short relaxation does
//!   not tilt the torque rate.

use crate::sample::Sample;
use crate::physics::torque_rate::{ElasticWindow, ElasticZoneConfig, WindowError};

/// Phases of one curve. Angles in the unit of the angle channel (deg), torques in Nm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Phases {
    /// Index of the highest torque.
    pub peak_index: usize,
    /// Highest torque.
    pub peak_torque: f64,
    /// Prevailing (rundown) torque: median torque over the rundown before the rise.
    pub prevailing_torque: f64,
    /// Snug angle: the robust elastic line meets the prevailing torque here.
    pub snug_angle: f64,
    /// Elastic window, trimmed; its `peak` is `peak_torque`.
    pub window: ElasticWindow,
    /// Robust torque rate over the window \[Nm/deg\].
    pub torque_rate: f64,
    /// The robust line of that rate, in window coordinates: x = angle - angle at
    /// `window.start`, y = torque - torque at `window.start`.
    pub line: Line,
    /// Start of the post-yield zone, when the gradient falls before the peak.
    pub yield_angle: Option<f64>,
    /// First sample of the seating zone before the final rise (a tenth of the rise's angle
    /// span before its knee), which the prevailing torque leaves out: the rundown before it
    /// is level torque plus noise.
    pub seating_start: usize,
}

/// Settings of the phase finder beyond the elastic window's.
#[derive(Clone, Debug, PartialEq)]
pub struct YieldConfig {
    /// Yield starts where the local gradient stays below this fraction of the elastic one.
    pub gradient_fraction: f64,
}

impl Default for YieldConfig {
    fn default() -> Self {
        // Yield-controlled tightening stops at a gradient drop of typically 50 % or less of the
        // elastic gradient; below half, the curve has left the linear zone for certain.
        Self { gradient_fraction: 0.5 }
    }
}

/// A straight line `y = intercept + slope x` with the robust scale of its residuals.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Line {
    /// Value at x = 0.
    pub intercept: f64,
    /// Slope.
    pub slope: f64,
    /// Robust residual scale (1.4826 MAD, i.e. the sd under Gaussian noise).
    pub scale: f64,
}

/// Weighted least-squares line through (x, y) with weights w; `None` without x spread.
fn weighted_line(x: &[f64], y: &[f64], w: Option<&[f64]>) -> Option<(f64, f64)> {
    let (mut sw, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for i in 0..x.len() {
        let wi = w.map_or(1.0, |w| w[i]);
        sw += wi;
        sx += wi * x[i];
        sy += wi * y[i];
    }
    if sw <= 0.0 {
        return None;
    }
    let (mx, my) = (sx / sw, sy / sw);
    let (mut sxx, mut sxy) = (0.0, 0.0);
    for i in 0..x.len() {
        let wi = w.map_or(1.0, |w| w[i]);
        let dx = x[i] - mx;
        sxx += wi * dx * dx;
        sxy += wi * dx * (y[i] - my);
    }
    if sxx <= 0.0 || !sxx.is_finite() {
        return None;
    }
    let slope = sxy / sxx;
    Some((my - slope * mx, slope))
}

/// Median of `v` (reorders it). `v` must not be empty.
fn median_in_place(v: &mut [f64]) -> f64 {
    let len = v.len();
    let mid = len / 2;
    let (lo, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    let m = *m;
    if len % 2 == 1 {
        m
    } else {
        let below = lo.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        0.5 * (below + m)
    }
}

/// Median of non-negative floats given as bit patterns (reorders them); `v` must not be empty.
fn median_of_non_negative_bits(v: &mut [u64]) -> f64 {
    let len = v.len();
    let mid = len / 2;
    let (lo, m, _) = v.select_nth_unstable(mid);
    let m = f64::from_bits(*m);
    if len % 2 == 1 {
        m
    } else {
        let below = lo.iter().copied().max().map_or(m, f64::from_bits);
        0.5 * (below + m)
    }
}

/// Fewest window samples for the phases and the robust torque rate. The detectors need more
/// (`ElasticZoneConfig::min_samples`, checked by the caller): a short real curve still gets its
/// phases and friction estimate, which is what monitoring across tightenings uses.
pub const MIN_FIT_SAMPLES: usize = 10;

/// Huber k for 95 % asymptotic efficiency at the normal.
const HUBER_K: f64 = 1.345;
/// MAD to sd under Gaussian noise.
const MAD_TO_SD: f64 = 1.482_602_218_505_602;

/// Robust straight line by Huber IRLS. `scratch` is reused; returns `None` when x has no
/// spread. Four reweighting steps from the least-squares start, each re-estimating the MAD
/// scale. Not always converged: against 200 steps, on 400 simulated windows the slope's median
/// relative difference is 3e-7 but its 95th percentile 0.8 % (windows holding a CSDT pause or a
/// fault converge slowly). Re-estimating the scale in the first two steps only was tried for
/// speed and dropped: it doubled that percentile.
pub fn robust_line(x: &[f64], y: &[f64], scratch: &mut Vec<u64>) -> Option<Line> {
    let n = x.len();
    let (mut a, mut b) = weighted_line(x, y, None)?;
    // Sums are taken about the unweighted means, so the one-pass weighted sums below do not
    // cancel (the window's x and y are far from zero at its end).
    let (mx, my) = (x.iter().sum::<f64>() / n as f64, y.iter().sum::<f64>() / n as f64);
    let mut scale = 0.0;
    for _ in 0..4 {
        // Absolute residuals as their IEEE bit patterns: for non-negative floats the integer
        // order is the numeric order, and integer selection is the cheaper median.
        scratch.clear();
        scratch.extend((0..n).map(|i| (y[i] - a - b * x[i]).abs().to_bits()));
        scale = MAD_TO_SD * median_of_non_negative_bits(scratch);
        if scale <= 0.0 || !scale.is_finite() {
            // Over half the residuals are exactly zero: the least-squares line is exact there.
            break;
        }
        // Huber weights and the weighted least-squares sums in one pass.
        let cut = HUBER_K * scale;
        let (mut sw, mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for i in 0..n {
            let r = (y[i] - a - b * x[i]).abs();
            let w = if r <= cut { 1.0 } else { cut / r };
            let (dx, dy) = (x[i] - mx, y[i] - my);
            sw += w;
            sx += w * dx;
            sy += w * dy;
            sxx += w * dx * dx;
            sxy += w * dx * dy;
        }
        let vxx = sxx - sx * sx / sw;
        if !(sw > 0.0 && vxx > 0.0 && vxx.is_finite()) {
            break;
        }
        b = (sxy - sx * sy / sw) / vxx;
        a = my + sy / sw - b * (mx + sx / sw);
    }
    Some(Line { intercept: a, slope: b, scale })
}

/// Knee of the continuous broken line `T = c + g1 theta + d (theta - theta_k)+` (d > 0: steeper
/// after the knee) fitted by least squares over samples `[0, end)`; returns the knee's sample
/// index. The rundown is given a slope of its own because real rundowns are not flat: a
/// thread-forming screw's torque grows by half over 1,500 deg of rundown as more thread
/// engages, and a flat-plus-line model then puts its knee into that slow ramp. Candidates are the
/// samples themselves, each costing O(1) from suffix sums.
fn hinge_knee<A: Sample, T: Sample>(angle: &[A], torque: &[T], end: usize) -> Option<usize> {
    if end < 8 {
        return None;
    }
    // Centre both variables on the last sample so sums of squares do not cancel badly over
    // thousands of degrees.
    let a_ref = angle[end - 1].to_f64();
    let t_ref = torque[end - 1].to_f64();
    let n = end as f64;
    let (mut gx, mut gxx, mut gy, mut gxy) = (0.0, 0.0, 0.0, 0.0);
    for i in 0..end {
        let (x, y) = (angle[i].to_f64() - a_ref, torque[i].to_f64() - t_ref);
        gx += x;
        gxx += x * x;
        gy += y;
        gxy += x * y;
    }
    // The broken line is the straight line plus d u, u = (x - x_j)+. By Frisch-Waugh-Lovell the
    // best d and the drop in RSS it buys come from u and y with the line [1, x] projected out:
    // with r the residuals of the straight line and P u = u - [1 x] (X'X)^-1 X'u,
    //   d = u'r / u'Pu,   RSS_j = RSS_line - (u'r)^2 / u'Pu,
    // where u'r and u'Pu follow from the suffix sums in O(1): about a fifth of the work of
    // solving the 3 x 3 normal equations for every candidate.
    let det = n * gxx - gx * gx;
    if !(det > 0.0) {
        return None;
    }
    let g0 = (n * gxy - gx * gy) / det;
    let c0 = (gy - g0 * gx) / n;
    // (X'X)^-1 = [[gxx, -gx], [-gx, n]] / det.
    let (i11, i12, i22) = (gxx / det, -gx / det, n / det);
    // Walk the knee from the end backwards, accumulating suffix sums of samples after it.
    let (mut cnt, mut s1, mut s2, mut sy, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    let mut best = (f64::NEG_INFINITY, None);
    for j in (3..end - 1).rev() {
        let (xj1, yj1) = (angle[j + 1].to_f64() - a_ref, torque[j + 1].to_f64() - t_ref);
        cnt += 1.0;
        s1 += xj1;
        s2 += xj1 * xj1;
        sy += yj1;
        sxy += xj1 * yj1;
        if cnt < 3.0 {
            continue;
        }
        let xj = angle[j].to_f64() - a_ref;
        // u_i = (x_i - x_j)+ over the samples after j.
        let su = s1 - xj * cnt;
        let suu = s2 - 2.0 * xj * s1 + xj * xj * cnt;
        let sxu = s2 - xj * s1;
        let suy = sxy - xj * sy;
        let ur = suy - c0 * su - g0 * sxu;
        let upu = suu - (i11 * su * su + 2.0 * i12 * su * sxu + i22 * sxu * sxu);
        if !(upu > 1e-12 * suu) || ur <= 0.0 {
            // u (nearly) on the line, or a knee that flattens the curve (d <= 0).
            continue;
        }
        let gain = ur * ur / upu;
        if gain > best.0 {
            best = (gain, Some(j));
        }
    }
    best.1
}

/// Finds the phases of a curve whose samples are finite. `scratch` buffers are reused.
pub fn find_phases<A: Sample, T: Sample>(
    angle: &[A],
    torque: &[T],
    zone: &ElasticZoneConfig,
    yield_cfg: &YieldConfig,
    scratch: &mut PhaseScratch,
) -> Result<Phases, WindowError> {
    let n = torque.len();
    let (mut i_peak, mut peak, mut low) = (0, f64::NEG_INFINITY, f64::INFINITY);
    for (i, t) in torque.iter().enumerate() {
        let t = t.to_f64();
        if t < low {
            low = t;
        }
        if t > peak {
            peak = t;
            i_peak = i;
        }
    }
    if n == 0 || peak <= low {
        return Err(WindowError::FlatTorque);
    }
    // Top of the rise: the first sample of the last run above 95 % of the range (above the
    // yield knee of most curves, below the peak's noise).
    let top_level = low + 0.95 * (peak - low);
    let mut top = i_peak;
    while top > 0 && torque[top - 1].to_f64() >= top_level {
        top -= 1;
    }
    let knee = hinge_knee(angle, torque, top + 1).unwrap_or(0);

    // Prevailing torque: median over the rundown before the knee, over as much angle before it
    // as the rise spans after it (at least 5 samples), leaving out the seating zone just before
    // the knee (a tenth of that span).
    let a_knee = angle[knee].to_f64();
    let rise_span = (angle[i_peak].to_f64() - a_knee).max(0.0);
    let (from, to) = (a_knee - rise_span, a_knee - 0.1 * rise_span);
    scratch.values.clear();
    scratch.values.extend(
        (0..knee)
            .filter(|&i| {
                let a = angle[i].to_f64();
                a >= from && a <= to
            })
            .map(|i| torque[i].to_f64()),
    );
    if scratch.values.len() < 5 {
        scratch.values.clear();
        let first = knee.saturating_sub(5);
        scratch.values.extend((first..=knee).map(|i| torque[i].to_f64()));
    }
    let prevailing = median_in_place(&mut scratch.values).min(peak);
    let seating_start = angle[..knee].partition_point(|a| a.to_f64() <= to);

    // Window by levels of the rise above the prevailing torque, walking forward from the knee.
    let rise = peak - prevailing;
    if rise <= 0.0 {
        // The torque varies (its range was checked above) but the peak is no higher than the
        // rundown level: a curve that falls, not a flat one.
        return Err(WindowError::NoRise);
    }
    let lo = prevailing + zone.start_fraction * rise;
    let hi = prevailing + zone.end_fraction * rise;
    let mut start = knee;
    while start < i_peak && torque[start].to_f64() < lo {
        start += 1;
    }
    let mut end = start;
    while end < i_peak && torque[end].to_f64() < hi {
        end += 1;
    }
    let mut window = trim(angle, start, end, zone)?;
    // The start level is crossed by a jump when friction changes abruptly there (the torque
    // jumps by the clamp force times the change of the torque factor), and the window then
    // starts at the first sample after the change, with nothing left of the curve before it.
    // The window gets START_LEAD samples back before its (trimmed) start, so that the break
    // detector's start test sees the jump (on HDT curves, about a sample per degree at a fifth
    // of the rise; the default trim, 1 % of the span, takes about one).
    window.start = window.start.saturating_sub(START_LEAD).max(knee);

    // Robust elastic line on the first half of the window: its gradient is the yardstick for
    // the yield test (yield can only be near the top).
    let half = ElasticWindow { start: window.start, end: window.start + (window.end - window.start) / 2, peak };
    let elastic = fit(angle, torque, half, scratch).ok_or(WindowError::AngleStuck)?;
    let yield_angle = find_yield(angle, torque, window.start, i_peak, elastic.slope, yield_cfg, scratch).map(|ya| {
        // The gradient test fires well into a gradual yield transition (where the gradient has
        // halved). Walk back to where the curve leaves the elastic line: the last sample before
        // it whose shortfall below the line is within 2 robust sigmas; every later sample up to
        // the gradient onset falls short by more.
        let (a0, t0) = (angle[half.start].to_f64(), torque[half.start].to_f64());
        let shortfall = |i: usize| elastic.intercept + elastic.slope * (angle[i].to_f64() - a0) - (torque[i].to_f64() - t0);
        let limit = 2.0 * elastic.scale;
        let mut k = (half.end..=i_peak).find(|&i| angle[i].to_f64() >= ya).unwrap_or(i_peak);
        while k > half.end && shortfall(k - 1) > limit {
            k -= 1;
        }
        angle[k].to_f64().min(ya)
    });
    if let Some(ya) = yield_angle {
        // Cut the window a tenth of its span below yield: the detected onset still lies a few
        // degrees into a gradual transition (2.7 deg median on simulated curves whose gradient
        // falls over a tenth of the elastic angle), and a bent end would read as a friction change.
        let span = angle[window.end - 1].to_f64() - angle[window.start].to_f64();
        let limit = ya - 0.1 * span;
        while window.end > window.start && angle[window.end - 1].to_f64() > limit {
            window.end -= 1;
        }
        if window.end - window.start < MIN_FIT_SAMPLES {
            return Err(WindowError::TooShort(window.end - window.start));
        }
    }
    window.peak = peak;
    let line = fit(angle, torque, window, scratch).ok_or(WindowError::AngleStuck)?;
    // Tangent method: where the elastic line meets the prevailing torque (x is relative to the
    // window's first angle, y relative to its first torque).
    let a0 = angle[window.start].to_f64();
    let t0 = torque[window.start].to_f64();
    let snug_angle = if line.slope > 0.0 {
        a0 + (prevailing - t0 - line.intercept) / line.slope
    } else {
        a_knee
    };
    Ok(Phases {
        peak_index: i_peak,
        peak_torque: peak,
        prevailing_torque: prevailing,
        snug_angle,
        window,
        torque_rate: line.slope,
        line,
        yield_angle,
        seating_start,
    })
}

/// Trims `[start, end)` by `trim_fraction` of its angle span at both ends and checks its size.
fn trim<A: Sample>(angle: &[A], mut start: usize, mut end: usize, zone: &ElasticZoneConfig) -> Result<ElasticWindow, WindowError> {
    if end <= start || angle[end - 1].to_f64() <= angle[start].to_f64() {
        return if end.saturating_sub(start) < MIN_FIT_SAMPLES {
            Err(WindowError::TooShort(end.saturating_sub(start)))
        } else {
            Err(WindowError::AngleStuck)
        };
    }
    let (a_lo, a_hi) = (angle[start].to_f64(), angle[end - 1].to_f64());
    let margin = zone.trim_fraction * (a_hi - a_lo);
    while start < end && angle[start].to_f64() < a_lo + margin {
        start += 1;
    }
    while end > start && angle[end - 1].to_f64() > a_hi - margin {
        end -= 1;
    }
    if end - start < MIN_FIT_SAMPLES {
        return Err(WindowError::TooShort(end - start));
    }
    if angle[end - 1].to_f64() <= angle[start].to_f64() {
        return Err(WindowError::AngleStuck);
    }
    Ok(ElasticWindow { start, end, peak: 0.0 })
}

/// Samples given back before the window's trimmed start (see [`find_phases`]).
const START_LEAD: usize = 2;

/// Robust line of torque on angle over a window, in window coordinates.
fn fit<A: Sample, T: Sample>(angle: &[A], torque: &[T], w: ElasticWindow, s: &mut PhaseScratch) -> Option<Line> {
    let a0 = angle[w.start].to_f64();
    let t0 = torque[w.start].to_f64();
    s.x.clear();
    s.y.clear();
    s.x.extend(angle[w.start..w.end].iter().map(|a| a.to_f64() - a0));
    s.y.extend(torque[w.start..w.end].iter().map(|t| t.to_f64() - t0));
    robust_line(&s.x, &s.y, &mut s.bits)
}

/// Yield onset: the first of at least two trailing equal-angle blocks, between the window's
/// start and the peak, whose least-squares gradients all stay below the fraction of the elastic
/// gradient. Blocks are 1/20 of the elastic span wide (at least 5 samples on average), so a
/// block's gradient has about 1/sqrt(5) of one sample's relative noise.
fn find_yield<A: Sample, T: Sample>(
    angle: &[A],
    torque: &[T],
    start: usize,
    i_peak: usize,
    elastic_rate: f64,
    cfg: &YieldConfig,
    s: &mut PhaseScratch,
) -> Option<f64> {
    if elastic_rate <= 0.0 || i_peak <= start + 10 {
        return None;
    }
    let (a_start, a_peak) = (angle[start].to_f64(), angle[i_peak].to_f64());
    let span = a_peak - a_start;
    let n_blocks = ((i_peak - start) / 5).clamp(4, 40);
    if span <= 0.0 {
        return None;
    }
    let width = span / n_blocks as f64;
    s.values.clear();
    // Per block: (first angle, slope) from running sums.
    let mut i = start;
    let mut slopes: Vec<(f64, f64)> = Vec::with_capacity(n_blocks);
    for b in 0..n_blocks {
        let right = a_start + (b + 1) as f64 * width;
        let (mut k, mut sx, mut sy, mut sxx, mut sxy) = (0.0f64, 0.0, 0.0, 0.0, 0.0);
        let first = angle[i.min(i_peak)].to_f64();
        while i <= i_peak && (angle[i].to_f64() <= right || b + 1 == n_blocks) {
            let x = angle[i].to_f64() - first;
            let y = torque[i].to_f64();
            k += 1.0;
            sx += x;
            sy += y;
            sxx += x * x;
            sxy += x * y;
            i += 1;
        }
        let sxx_c = sxx - sx * sx / k.max(1.0);
        if k >= 3.0 && sxx_c > 1e-12 {
            slopes.push((first, (sxy - sx * sy / k) / sxx_c));
        }
    }
    let threshold = cfg.gradient_fraction * elastic_rate;
    let mut onset = None;
    let mut trailing = 0;
    for &(a, g) in slopes.iter().rev() {
        if g < threshold {
            onset = Some(a);
            trailing += 1;
        } else {
            break;
        }
    }
    // The peak block alone is the torque controller's stop, not yield.
    if trailing >= 2 {
        onset
    } else {
        None
    }
}

/// Reusable buffers of [`find_phases`].
#[derive(Clone, Debug, Default)]
pub struct PhaseScratch {
    values: Vec<f64>,
    bits: Vec<u64>,
    x: Vec<f64>,
    y: Vec<f64>,
}

impl PhaseScratch {
    /// Robust line of `y` on `x` with the shared buffers (used for torque on clamp force).
    pub fn robust_line_of<X: Sample, Y: Sample>(&mut self, x: &[X], y: &[Y]) -> Option<Line> {
        self.x.clear();
        self.y.clear();
        let (x0, y0) = (x.first()?.to_f64(), y.first()?.to_f64());
        self.x.extend(x.iter().map(|v| v.to_f64() - x0));
        self.y.extend(y.iter().map(|v| v.to_f64() - y0));
        robust_line(&self.x, &self.y, &mut self.bits)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    use rand_xoshiro::Xoshiro256PlusPlus;

    #[test]
    fn robust_line_ignores_spikes() {
        let x: Vec<f64> = (0..200).map(|i| i as f64 * 0.1).collect();
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        let mut y: Vec<f64> = x
            .iter()
            .map(|&v| 1.0 + 0.5 * v + 0.01 * <StandardNormal as Distribution<f64>>::sample(&StandardNormal, &mut rng))
            .collect();
        for i in (10..200).step_by(20) {
            y[i] += 3.0;
        }
        let mut scratch = Vec::new();
        let l = robust_line(&x, &y, &mut scratch).unwrap();
        assert!((l.slope - 0.5).abs() < 2e-3, "{l:?}");
        assert!((l.scale - 0.01).abs() < 3e-3, "{l:?}");
        let (_, ls) = weighted_line(&x, &y, None).unwrap();
        // Least squares is pulled by the spikes by more than the robust fit's whole error.
        assert!((ls - 0.5).abs() > 2.0 * (l.slope - 0.5).abs(), "{ls}");
    }

    /// Rundown at `prevailing` to `knee_deg`, quadratic seating over `seat` deg, then a line of
    /// `rate`; snug angle (tangent method) is knee + seat/2.
    fn curve(prevailing: f64, knee_deg: f64, seat: f64, rate: f64, peak: f64, yield_at: Option<f64>) -> (Vec<f64>, Vec<f64>) {
        let mut a = Vec::new();
        let mut t = Vec::new();
        let mut theta = 0.0;
        loop {
            let x = theta - knee_deg;
            let mut tq = if x <= 0.0 {
                prevailing
            } else if x < seat {
                prevailing + rate * x * x / (2.0 * seat)
            } else {
                prevailing + rate * (x - 0.5 * seat)
            };
            if let Some(y) = yield_at {
                if theta > y {
                    let ty = prevailing + rate * (y - knee_deg - 0.5 * seat);
                    tq = ty + 0.1 * rate * (theta - y);
                }
            }
            if tq >= peak {
                break;
            }
            a.push(theta);
            t.push(tq);
            theta += 0.1;
        }
        (a, t)
    }

    #[test]
    fn snug_and_prevailing_of_a_thread_forming_curve() {
        // Prevailing torque half the peak: the case that defeats levels relative to the minimum.
        let (a, mut t) = curve(0.7, 300.0, 4.0, 0.02, 1.4, None);
        t[0] = 0.0; // the tool starts from standstill
        let p = find_phases(&a, &t, &ElasticZoneConfig::default(), &YieldConfig::default(), &mut PhaseScratch::default()).unwrap();
        assert!((p.prevailing_torque - 0.7).abs() < 1e-9, "{p:?}");
        assert!((p.snug_angle - 302.0).abs() < 0.05, "{p:?}");
        assert!((p.torque_rate - 0.02).abs() < 1e-9, "{p:?}");
        assert!(p.yield_angle.is_none());
        assert!(a[p.window.start] > 302.0 + 0.2 * 35.0 - 1.0);
    }

    #[test]
    fn yield_is_found_and_cut_from_the_window() {
        let (a, t) = curve(0.5, 400.0, 5.0, 0.3, 25.0, Some(480.0));
        let p = find_phases(&a, &t, &ElasticZoneConfig::default(), &YieldConfig::default(), &mut PhaseScratch::default()).unwrap();
        let ya = p.yield_angle.expect("yield");
        assert!((ya - 480.0).abs() < 3.0, "{p:?}");
        assert!(a[p.window.end - 1] < 480.0);
        assert!((p.torque_rate - 0.3).abs() < 1e-6, "{p:?}");
        assert!((p.snug_angle - 402.5).abs() < 0.05, "{p:?}");
    }
}
