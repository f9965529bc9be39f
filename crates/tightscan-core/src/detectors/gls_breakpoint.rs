//! The break scan as a GLS regression: the sup-LR test for one break of the elastic line under
//! AR(p) noise, with the break's regressors whitened as the line's are.
//!
//! Why: a friction change is a step of the torque, `D_t (c + d x_t)` with `D_t = 1[t >= k]`.
//! Whitened with the noise filter `1 - sum phi_j L^j`, the step is no step any more: it is
//! `c + d x_t` at the first sample and `gain (c + d x_t)`-like after it (`gain = 1 - sum phi`),
//! so under strong colour (phi 0.85, gain 0.15) most of the step's evidence is in its first p
//! whitened samples. The two-line scan ([`crate::detectors::breakpoint::sup_lr_scan`]) fits a
//! line to each side of the split on the whitened window and leaves those samples in its
//! residuals; the GLS regression `[1, w(x), w(D), w(D x)]` puts them where they belong. It
//! differs from the two-line fit only in the p rows after the split: for t = k + i, i < p,
//!
//! ```text
//! w(D)_t   = 1 - sum_{j <= i} phi_j
//! w(D x)_t = x_t - sum_{j <= i} phi_j x_{t-j}
//! ```
//!
//! and beyond them `w(D)_t = gain`, `w(D x)_t = w(x)_t`. Measured on the independent
//! generator's AR(1) 0.85 curves before this was built (benches/gls_lead.py, numpy, matched
//! 1 % false alarms): recall 63.9 / 26.8 % (two lines) against 83.7 / 61.1 % (GLS) on
//! 15-45 / 3-15 % changes. At phi = 0 the two are the same statistic.
//!
//! Its null distribution depends on the design, here on how much of the whitened step sits in
//! its first sample: quantiles by window length and by the sum of the AR coefficients
//! ([`GLS_SUP_LR_QUANTILES`]); near the unit root the whitened step is nearly an impulse, and
//! the scan nearly a search for the largest of n outliers, whose quantiles grow like 2 ln n
//! rather than like the two-line scan's ln ln n.

use nalgebra::{Matrix2, Vector2};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;

use crate::detectors::breakpoint::{interpolate, interpolate_alpha, quantiles_p_value, BreakScan, SUP_LR_QUANTILES, TABLE_ALPHA};

/// Scratch of [`gls_sup_lr_scan`]: suffix sums of (1, wx, wy, wx^2, wx wy) over the rows kept,
/// and which rows are kept.
#[derive(Clone, Debug, Default)]
pub struct GlsScratch {
    suffix: Vec<[f64; 5]>,
    keep: Vec<bool>,
}

/// sup-LR of the GLS break regression over every split with at least `min_segment` whitened
/// samples each side.
///
/// `wx`, `wy`: the whitened regressor and torque from the first whitened sample on (n of them,
/// errors independent under no change); `x`: the regressor *before* whitening, from p samples
/// earlier (`x[t + p]` is the sample `wx[t]` was whitened from, at least n + p of them); `phi`:
/// the AR coefficients the window was whitened with (p of them). The split k is the first
/// whitened sample of the right segment. `profile`, when given, receives `LR_k` of every split
/// scanned, in order. `None` when no split is admissible or nothing is left to explain.
///
/// `restarts`: samples of `x` where the series restarts after a gap (the first sample after a
/// tool's stop that the window leaves out). The p whitened samples from each were filtered
/// with a past from before the gap, which is no past of theirs; they are left out of every
/// regression, as the conditional likelihood of an AR series that restarts leaves its first p
/// samples out. Left in, a split there makes the whitened step's first sample an impulse
/// regressor on that one odd sample: on the independent generator's clean CSDT curves (a pause
/// mid-window) under AR(1) 0.85 / 0.9 the scan claimed 3.6 / 5.3 % (1,000 each).
#[allow(clippy::too_many_arguments)]
pub fn gls_sup_lr_scan(
    wx: &[f64],
    wy: &[f64],
    x: &[f64],
    phi: &[f64],
    restarts: &[usize],
    min_segment: usize,
    scratch: &mut GlsScratch,
    mut profile: Option<&mut Vec<f64>>,
) -> Option<BreakScan> {
    let n = wx.len();
    let p = phi.len();
    let min_segment = min_segment.max(3);
    if n < 2 * min_segment || wy.len() != n || x.len() < n + p {
        return None;
    }
    let gain = 1.0 - phi.iter().sum::<f64>();
    let GlsScratch { suffix, keep } = scratch;
    keep.clear();
    keep.resize(n, true);
    for &r in restarts {
        // x[r] is whitened sample r - p.
        keep.iter_mut().take(r).skip(r.saturating_sub(p)).for_each(|k| *k = false);
    }
    // Suffix sums: suffix[t] over the kept samples t..n.
    suffix.clear();
    suffix.resize(n + 1, [0.0; 5]);
    let mut yy = 0.0;
    for t in (0..n).rev() {
        let s = suffix[t + 1];
        suffix[t] = if keep[t] {
            yy += wy[t] * wy[t];
            [s[0] + 1.0, s[1] + wx[t], s[2] + wy[t], s[3] + wx[t] * wx[t], s[4] + wx[t] * wy[t]]
        } else {
            s
        };
    }
    let all = suffix[0];
    let n_used = all[0] as usize;
    // The null regression on Z = [1, wx] (the constant stands for the whitened intercept, gain:
    // the same span).
    let ztz = Matrix2::new(all[0], all[1], all[1], all[3]);
    let ztz_inv = ztz.try_inverse()?;
    let zty = Vector2::new(all[2], all[4]);
    let rss0 = yy - zty.dot(&(ztz_inv * zty));
    if !(rss0 > 0.0) || !rss0.is_finite() {
        return None;
    }
    let mut best: Option<(f64, usize, f64, f64)> = None; // (rss, k, c, d)
    for k in min_segment..=(n - min_segment) {
        let m = (k + p).min(n);
        let s = suffix[m];
        // u = w(D), v = w(D x): their cross-products with 1, wx, wy and each other.
        let (mut u1, mut ux, mut uy, mut uu) = (gain * s[0], gain * s[1], gain * s[2], gain * gain * s[0]);
        let (mut v1, mut vx, mut vy, mut vv, mut uv) = (s[1], s[3], s[4], s[3], gain * s[1]);
        let mut c = 1.0;
        for i in 0..(m - k) {
            let t = k + i;
            if i > 0 {
                c -= phi[i - 1];
            }
            if !keep[t] {
                continue;
            }
            let mut v = x[t + p];
            for j in 1..=i {
                v -= phi[j - 1] * x[t + p - j];
            }
            u1 += c;
            ux += c * wx[t];
            uy += c * wy[t];
            uu += c * c;
            v1 += v;
            vx += v * wx[t];
            vy += v * wy[t];
            vv += v * v;
            uv += c * v;
        }
        // Frisch-Waugh: project u and v off Z.
        let (zu, zv) = (Vector2::new(u1, ux), Vector2::new(v1, vx));
        let (azu, azv) = (ztz_inv * zu, ztz_inv * zv);
        let g = Matrix2::new(uu - zu.dot(&azu), uv - zu.dot(&azv), uv - zv.dot(&azu), vv - zv.dot(&azv));
        let h = Vector2::new(uy - azu.dot(&zty), vy - azv.dot(&zty));
        let (rss, coef) = match g.try_inverse() {
            Some(inv) if g.determinant() > 1e-12 * g[(0, 0)] * g[(1, 1)] => {
                let coef = inv * h;
                ((rss0 - h.dot(&coef)).max(0.0), coef)
            }
            _ => (rss0, Vector2::zeros()),
        };
        if let Some(prof) = profile.as_deref_mut() {
            prof.push(likelihood_ratio(n_used, rss0, rss));
        }
        if best.is_none_or(|(b, ..)| rss < b) {
            best = Some((rss, k, coef[0], coef[1]));
        }
    }
    let (rss, split, c, d) = best?;
    Some(BreakScan { statistic: likelihood_ratio(n_used, rss0, rss), split, jump: c + d * x[split + p], slope_change: d })
}

/// `LR = n ln(RSS_0 / RSS)`, floored as the two-line scan's is.
fn likelihood_ratio(n: usize, rss0: f64, rss: f64) -> f64 {
    n as f64 * (rss0 / rss.max(1e-300 * rss0)).ln()
}

/// Sums of the AR coefficients at which [`GLS_SUP_LR_QUANTILES`] was simulated (AR(1) with
/// that coefficient); 0 is the two-line scan's table [`SUP_LR_QUANTILES`].
pub const GLS_PHI: [f64; 8] = [0.0, 0.3, 0.5, 0.7, 0.85, 0.9, 0.95, 0.99];

/// (1 - alpha) quantiles of the GLS sup-LR under no change, AR(1) noise of coefficient
/// [`GLS_PHI`]`[j + 1]` whitened with it, samples evenly spaced, segments of at least
/// `min_segment(n)`: `[phi][n]` rows follow [`TABLE_N`](crate::detectors::breakpoint::TABLE_N), columns [`TABLE_ALPHA`]. Made by
/// `simulate_gls_quantiles(n, phi, 100_000, 20261127 + n)` (the ignored test
/// `regenerate_gls_table` prints it).
pub static GLS_SUP_LR_QUANTILES: [[[f64; 8]; 8]; 7] = [
    [ // phi 0.3
        [4.855, 7.612, 9.491, 11.275, 13.592, 15.301, 17.046, 20.443], // n = 30
        [6.413, 9.143, 10.943, 12.696, 14.812, 16.362, 17.885, 21.721], // n = 60
        [7.226, 9.945, 11.746, 13.404, 15.497, 17.107, 18.740, 22.026], // n = 120
        [7.708, 10.453, 12.243, 13.945, 16.100, 17.712, 19.284, 22.738], // n = 250
        [7.878, 10.637, 12.471, 14.181, 16.433, 18.078, 19.554, 23.086], // n = 500
        [7.949, 10.748, 12.586, 14.284, 16.395, 18.036, 19.626, 23.103], // n = 1000
        [8.009, 10.844, 12.660, 14.387, 16.525, 18.106, 19.631, 23.647], // n = 2000
        [8.034, 10.846, 12.656, 14.373, 16.605, 18.197, 19.756, 23.459], // n = 4000
    ],
    [ // phi 0.5
        [5.212, 7.908, 9.739, 11.491, 13.760, 15.417, 17.115, 20.631], // n = 30
        [6.929, 9.605, 11.339, 13.000, 15.140, 16.703, 18.342, 21.893], // n = 60
        [7.795, 10.498, 12.246, 13.905, 15.965, 17.546, 19.138, 22.525], // n = 120
        [8.320, 11.058, 12.843, 14.532, 16.670, 18.279, 19.742, 23.166], // n = 250
        [8.487, 11.261, 13.085, 14.812, 17.067, 18.631, 20.239, 23.623], // n = 500
        [8.483, 11.313, 13.181, 14.886, 17.036, 18.677, 20.284, 23.743], // n = 1000
        [8.458, 11.327, 13.162, 14.911, 17.064, 18.614, 20.163, 24.087], // n = 2000
        [8.384, 11.238, 13.071, 14.794, 17.010, 18.624, 20.176, 23.949], // n = 4000
    ],
    [ // phi 0.7
        [5.454, 8.101, 9.887, 11.624, 13.813, 15.477, 17.200, 20.834], // n = 30
        [7.427, 9.981, 11.672, 13.256, 15.399, 16.991, 18.620, 22.404], // n = 60
        [8.535, 11.093, 12.768, 14.364, 16.395, 18.035, 19.662, 23.049], // n = 120
        [9.277, 11.920, 13.634, 15.267, 17.368, 18.931, 20.420, 23.768], // n = 250
        [9.598, 12.349, 14.143, 15.854, 18.003, 19.625, 21.204, 24.659], // n = 500
        [9.648, 12.485, 14.340, 16.038, 18.209, 19.809, 21.481, 25.238], // n = 1000
        [9.545, 12.456, 14.321, 16.085, 18.195, 19.820, 21.412, 25.113], // n = 2000
        [9.302, 12.221, 14.094, 15.848, 18.076, 19.725, 21.453, 25.352], // n = 4000
    ],
    [ // phi 0.85
        [5.596, 8.211, 9.965, 11.726, 13.892, 15.595, 17.200, 21.139], // n = 30
        [7.710, 10.215, 11.866, 13.444, 15.568, 17.205, 18.770, 22.211], // n = 60
        [8.979, 11.436, 13.055, 14.612, 16.689, 18.282, 19.838, 23.205], // n = 120
        [10.057, 12.530, 14.180, 15.720, 17.763, 19.210, 20.782, 24.060], // n = 250
        [10.828, 13.437, 15.144, 16.743, 18.835, 20.324, 21.839, 25.565], // n = 500
        [11.343, 14.051, 15.833, 17.499, 19.564, 21.086, 22.665, 26.424], // n = 1000
        [11.527, 14.384, 16.236, 17.951, 20.055, 21.663, 23.173, 26.872], // n = 2000
        [11.343, 14.296, 16.196, 17.985, 20.171, 21.841, 23.507, 27.312], // n = 4000
    ],
    [ // phi 0.9
        [5.648, 8.255, 10.013, 11.691, 13.930, 15.551, 17.232, 20.979], // n = 30
        [7.810, 10.293, 11.952, 13.525, 15.628, 17.194, 18.682, 21.953], // n = 60
        [9.087, 11.531, 13.153, 14.758, 16.754, 18.263, 19.796, 23.218], // n = 120
        [10.249, 12.687, 14.290, 15.828, 17.815, 19.314, 20.843, 24.265], // n = 250
        [11.204, 13.726, 15.377, 16.986, 18.985, 20.471, 21.906, 25.801], // n = 500
        [12.014, 14.633, 16.315, 17.907, 19.953, 21.444, 22.968, 26.525], // n = 1000
        [12.556, 15.327, 17.104, 18.758, 20.858, 22.361, 23.968, 27.547], // n = 2000
        [12.688, 15.580, 17.455, 19.231, 21.357, 22.883, 24.532, 28.178], // n = 4000
    ],
    [ // phi 0.95
        [5.655, 8.268, 10.029, 11.742, 13.887, 15.594, 17.156, 20.889], // n = 30
        [7.879, 10.351, 11.999, 13.581, 15.659, 17.164, 18.697, 22.110], // n = 60
        [9.218, 11.650, 13.266, 14.844, 16.876, 18.297, 19.834, 23.437], // n = 120
        [10.403, 12.827, 14.433, 15.935, 17.908, 19.420, 21.064, 24.335], // n = 250
        [11.466, 13.928, 15.564, 17.169, 19.132, 20.646, 22.041, 25.757], // n = 500
        [12.525, 15.028, 16.643, 18.205, 20.185, 21.689, 23.201, 26.580], // n = 1000
        [13.559, 16.111, 17.802, 19.370, 21.380, 22.939, 24.333, 28.025], // n = 2000
        [14.368, 17.080, 18.814, 20.435, 22.433, 23.912, 25.364, 28.645], // n = 4000
    ],
    [ // phi 0.99
        [5.635, 8.257, 10.013, 11.746, 13.911, 15.646, 17.227, 20.953], // n = 30
        [7.902, 10.384, 12.021, 13.604, 15.684, 17.225, 18.759, 22.436], // n = 60
        [9.331, 11.763, 13.386, 14.950, 16.973, 18.485, 19.969, 23.074], // n = 120
        [10.615, 13.022, 14.614, 16.132, 18.153, 19.614, 21.202, 24.616], // n = 250
        [11.716, 14.173, 15.815, 17.347, 19.345, 20.803, 22.267, 25.913], // n = 500
        [12.832, 15.292, 16.900, 18.452, 20.425, 21.894, 23.276, 26.887], // n = 1000
        [13.986, 16.456, 18.102, 19.661, 21.626, 23.072, 24.511, 27.744], // n = 2000
        [15.182, 17.706, 19.328, 20.878, 22.794, 24.232, 25.562, 28.723], // n = 4000
    ],
];

/// How the GLS statistic's null quantiles grow with a whitening error, as
/// [`crate::detectors::breakpoint::WHITENING_SENSITIVITY`] is for the two-line scan (rows
/// [`TABLE_N`](crate::detectors::breakpoint::TABLE_N), columns [`crate::detectors::breakpoint::SENSITIVITY_LAG1`], the 0.995
/// quantile, log-gain error +0.5, AR(1) windows whitened with the wrong coefficient and the
/// GLS regressors built with it; 30,000 windows per cell with common random numbers, the
/// ignored test `gls_whitening_sensitivity_experiment`). Lower than the two-line scan's under
/// strong colour (n 4,000, phi 0.85: 0.77 against 0.92): the split's first whitened samples,
/// where the GLS statistic draws much of its evidence, carry the short-run variance, which a
/// whitening error hardly moves.
pub static GLS_WHITENING_SENSITIVITY: [[f64; 7]; 8] = [
    [0.55, 0.55, 0.48, 0.33, 0.15, 0.07, 0.01], // n = 30
    [0.57, 0.61, 0.59, 0.46, 0.28, 0.18, 0.04], // n = 60
    [0.58, 0.66, 0.65, 0.58, 0.42, 0.34, 0.17], // n = 120
    [0.60, 0.69, 0.71, 0.67, 0.54, 0.44, 0.31], // n = 250
    [0.60, 0.71, 0.75, 0.73, 0.63, 0.54, 0.40], // n = 500
    [0.61, 0.73, 0.76, 0.76, 0.69, 0.63, 0.50], // n = 1000
    [0.63, 0.76, 0.80, 0.80, 0.76, 0.70, 0.56], // n = 2000
    [0.63, 0.76, 0.81, 0.82, 0.77, 0.73, 0.62], // n = 4000
];

/// The GLS statistic's sensitivity kappa to a whitening error ([`GLS_WHITENING_SENSITIVITY`]),
/// interpolated as [`crate::detectors::breakpoint::whitening_sensitivity`] is.
pub fn gls_whitening_sensitivity(n: usize, lag1: f64) -> f64 {
    crate::detectors::breakpoint::sensitivity_from(&GLS_WHITENING_SENSITIVITY, n, lag1)
}

/// Null quantiles of the GLS scan by Monte Carlo: `reps` windows of n evenly spaced samples
/// whose noise is AR(1) with coefficient `phi`, whitened with it (so the whitened errors are
/// i.i.d. N(0, 1) and only the design depends on phi); the (1 - alpha) quantile for each alpha
/// of [`TABLE_ALPHA`].
pub fn simulate_gls_quantiles(n: usize, phi: f64, reps: usize, seed: u64) -> Vec<f64> {
    let seg = crate::detectors::breakpoint::min_segment(n);
    let x: Vec<f64> = (0..=n).map(|i| i as f64 / n as f64 - 0.5).collect();
    let wx: Vec<f64> = x.windows(2).map(|w| w[1] - phi * w[0]).collect();
    let coefficients = [phi];
    let stats: Vec<f64> = (0..reps)
        .into_par_iter()
        .map_init(
            || (Vec::with_capacity(n), GlsScratch::default()),
            |(y, suffix): &mut (Vec<f64>, GlsScratch), r| {
                let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ (r as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
                y.clear();
                y.extend((0..n).map(|_| <StandardNormal as Distribution<f64>>::sample(&StandardNormal, &mut rng)));
                gls_sup_lr_scan(&wx, y, &x, &coefficients, &[], seg, suffix, None).map_or(0.0, |b| b.statistic)
            },
        )
        .collect();
    crate::detectors::breakpoint::upper_quantiles(stats)
}

/// The null quantiles ([`TABLE_ALPHA`]) of the GLS scan for n whitened samples and AR
/// coefficients summing to `phi_sum`: interpolated linearly in ln n and in `phi_sum` (clamped
/// to [`GLS_PHI`]; an AR(p) model is read as the AR(1) of the same gain, whose whitened step
/// has the same level after its first samples).
pub fn gls_quantiles(n: usize, phi_sum: f64) -> [f64; 8] {
    quantiles_by_phi(|j| if j == 0 { &SUP_LR_QUANTILES } else { &GLS_SUP_LR_QUANTILES[j - 1] }, n, phi_sum)
}

/// The null quantiles ([`TABLE_ALPHA`]) of a statistic tabulated at each of [`GLS_PHI`]
/// (`table(j)` the table at `GLS_PHI[j]`, rows [`TABLE_N`](crate::detectors::breakpoint::TABLE_N)),
/// for n samples and AR coefficients summing to `phi_sum`, interpolated as [`gls_quantiles`] says.
pub(crate) fn quantiles_by_phi<'a>(table: impl Fn(usize) -> &'a [[f64; 8]; 8], n: usize, phi_sum: f64) -> [f64; 8] {
    let last = GLS_PHI[GLS_PHI.len() - 1];
    let phi = if phi_sum.is_finite() { phi_sum.clamp(0.0, last) } else { 0.0 };
    let j = (1..GLS_PHI.len()).find(|&j| phi <= GLS_PHI[j]).unwrap_or(GLS_PHI.len() - 1);
    let t = (phi - GLS_PHI[j - 1]) / (GLS_PHI[j] - GLS_PHI[j - 1]);
    std::array::from_fn(|c| {
        let (a, b) = (interpolate(table(j - 1), n, |row| row[c]), interpolate(table(j), n, |row| row[c]));
        a + t * (b - a)
    })
}

/// Critical value of the GLS scan at `alpha` (clamped to [`TABLE_ALPHA`]), linear in ln alpha.
pub fn gls_critical_value(n: usize, phi_sum: f64, alpha: f64) -> f64 {
    interpolate_alpha(&gls_quantiles(n, phi_sum), alpha.clamp(TABLE_ALPHA[TABLE_ALPHA.len() - 1], TABLE_ALPHA[0]))
}

/// p-value of a GLS scan statistic averaged over the whitening's uncertainty, as
/// [`crate::detectors::breakpoint::sup_lr_predictive_p_value`] is for the two-line scan
/// (`gain_log_se` times the statistic's sensitivity: the caller's).
pub fn gls_predictive_p_value(n: usize, phi_sum: f64, statistic: f64, gain_log_se: f64) -> f64 {
    quantiles_predictive_p_value(&gls_quantiles(n, phi_sum), statistic, gain_log_se)
}

/// p-value of `statistic` from its null quantiles `q` (columns [`TABLE_ALPHA`]), averaged over
/// the whitening's uncertainty as [`gls_predictive_p_value`] is.
pub(crate) fn quantiles_predictive_p_value(q: &[f64; 8], statistic: f64, gain_log_se: f64) -> f64 {
    if !(gain_log_se > 0.0) {
        return quantiles_p_value(q, statistic);
    }
    crate::detectors::noise::NORMAL_NODES.iter().map(|(z, w)| w * quantiles_p_value(q, statistic * (-2.0 * gain_log_se * z).exp())).sum()
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
mod tests {
    use super::*;
    use crate::detectors::breakpoint::{min_segment, sup_lr_scan, TABLE_N};

    /// AR(p) noise, whitened x and y, the raw x (p samples of past) for a window of n.
    fn window(n: usize, phi: &[f64], step_at: Option<(usize, f64)>, seed: u64) -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>) {
        let p = phi.len();
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let x: Vec<f64> = (0..n + p).map(|i| i as f64 * 0.1).collect();
        let mut e = vec![0.0; n + p + 200];
        for t in p..e.len() {
            e[t] = phi.iter().enumerate().map(|(j, c)| c * e[t - 1 - j]).sum::<f64>() + 0.05 * <StandardNormal as Distribution<f64>>::sample(&StandardNormal, &mut rng);
        }
        let y: Vec<f64> = (0..n + p)
            .map(|i| 1.0 + 0.8 * x[i] + e[i + 200] + step_at.map_or(0.0, |(k, h)| if i >= k + p { h * (1.0 + 0.1 * x[i]) } else { 0.0 }))
            .collect();
        let whiten = |v: &[f64]| -> Vec<f64> { (p..n + p).map(|t| v[t] - phi.iter().enumerate().map(|(j, c)| c * v[t - 1 - j]).sum::<f64>()).collect() };
        (whiten(&x), whiten(&y), x, y)
    }

    /// Each split's LR against a brute-force least-squares fit of [1, wx, w(D), w(Dx)], AR(2).
    #[test]
    fn scan_matches_brute_force_gls() {
        let phi = [0.6, 0.25];
        let n = 90;
        let (wx, wy, x, _) = window(n, &phi, Some((50, 0.3)), 3);
        let mut profile = Vec::new();
        let scan = gls_sup_lr_scan(&wx, &wy, &x, &phi, &[], 10, &mut GlsScratch::default(), Some(&mut profile)).unwrap();
        let p = phi.len();
        let rss = |cols: &dyn Fn(usize) -> Vec<f64>, q: usize| {
            let mut xtx = nalgebra::DMatrix::<f64>::zeros(q, q);
            let mut xty = nalgebra::DVector::<f64>::zeros(q);
            for (t, yt) in wy.iter().enumerate() {
                let r = nalgebra::DVector::from_vec(cols(t));
                xtx += &r * r.transpose();
                xty += &r * *yt;
            }
            let beta = xtx.try_inverse().unwrap() * xty;
            (0..n).map(|t| (wy[t] - nalgebra::DVector::from_vec(cols(t)).dot(&beta)).powi(2)).sum::<f64>()
        };
        let rss0 = rss(&|t| vec![1.0, wx[t]], 2);
        for (i, k) in (10..=n - 10).enumerate() {
            // Whiten the raw step and step x angle, exactly.
            let d = |s: usize| if s >= k + p { 1.0 } else { 0.0 };
            let cols = |t: usize| {
                let s = t + p;
                let wd = d(s) - phi.iter().enumerate().map(|(j, c)| c * d(s - 1 - j)).sum::<f64>();
                let wdx = d(s) * x[s] - phi.iter().enumerate().map(|(j, c)| c * d(s - 1 - j) * x[s - 1 - j]).sum::<f64>();
                vec![1.0, wx[t], wd, wdx]
            };
            let lr = n as f64 * (rss0 / rss(&cols, 4)).ln();
            assert!((lr - profile[i]).abs() < 1e-6 * lr.max(1.0), "k {k}: brute {lr} scan {}", profile[i]);
        }
        assert_eq!(scan.split, 50);
    }

    /// At phi = 0 the GLS regression is the two-line fit.
    #[test]
    fn white_noise_gives_the_two_line_statistic() {
        let (wx, wy, x, _) = window(200, &[], Some((120, 0.02)), 9);
        let gls = gls_sup_lr_scan(&wx, &wy, &x, &[], &[], 10, &mut GlsScratch::default(), None).unwrap();
        let two = sup_lr_scan(&wx, &wy, 10, &mut Vec::new()).unwrap();
        assert_eq!(gls.split, two.split);
        assert!((gls.statistic - two.statistic).abs() < 1e-8 * two.statistic, "{gls:?} {two:?}");
    }

    /// Under AR(1) 0.85 a step of 3 innovation sds is found far more often by the GLS scan than
    /// by the two lines, each at its own 1 % critical value (simulated here with the same
    /// design): the lead this module was built on.
    #[test]
    fn gls_has_the_power_the_two_lines_lack_under_strong_colour() {
        let (n, phi) = (150, 0.85);
        let seg = min_segment(n);
        let reps = 400;
        let crit_two = {
            let mut s: Vec<f64> = (0..2000)
                .map(|r| {
                    let (wx, wy, ..) = window(n, &[phi], None, 10_000 + r);
                    sup_lr_scan(&wx, &wy, seg, &mut Vec::new()).map_or(0.0, |b| b.statistic)
                })
                .collect();
            s.sort_by(f64::total_cmp);
            s[1980]
        };
        let crit_gls = gls_critical_value(n, phi, 0.01);
        let (mut two, mut gls) = (0, 0);
        for r in 0..reps {
            let (wx, wy, x, _) = window(n, &[phi], Some((90, 0.15)), 50_000 + r);
            two += usize::from(sup_lr_scan(&wx, &wy, seg, &mut Vec::new()).is_some_and(|b| b.statistic > crit_two));
            gls += usize::from(gls_sup_lr_scan(&wx, &wy, &x, &[phi], &[], seg, &mut GlsScratch::default(), None).is_some_and(|b| b.statistic > crit_gls));
        }
        let (two, gls) = (two as f64 / reps as f64, gls as f64 / reps as f64);
        assert!(gls > 0.8 && gls > two + 0.4, "power: two lines {two}, GLS {gls}");
    }

    /// The GLS statistic of a window simulated by
    /// [`crate::detectors::breakpoint::simulate_miswhitened_quantiles`] (n samples, x from
    /// -0.5, whitened with `phi_hat`).
    pub(super) fn miswhitened_gls(n: usize, phi_hat: f64) -> impl Fn(&[f64], &[f64]) -> f64 + Sync {
        let x: Vec<f64> = (0..=n).map(|i| i as f64 / n as f64 - 0.5).collect();
        let seg = min_segment(n);
        move |wx: &[f64], wy: &[f64]| gls_sup_lr_scan(wx, wy, &x, &[phi_hat], &[], seg, &mut GlsScratch::default(), None).map_or(0.0, |b| b.statistic)
    }

    /// Size against the table at alpha 0.05 and 0.01, at window lengths and AR coefficients
    /// between the table's points (the interpolation in both is checked), fresh seeds: within
    /// 4 binomial sd. The two-line scan's table (what the GLS scan would be judged by without its
    /// own) fails the phi 0.9 cells at n 700.
    #[test]
    fn gls_size_matches_nominal() {
        for (n, phi) in [(45, 0.6), (180, 0.875), (700, 0.93)] {
            let reps = 8_000;
            let stats = {
                let x: Vec<f64> = (0..=n).map(|i| i as f64 / n as f64 - 0.5).collect();
                let wx: Vec<f64> = x.windows(2).map(|w| w[1] - phi * w[0]).collect();
                let mut rng = Xoshiro256PlusPlus::seed_from_u64(1234 + n as u64);
                (0..reps)
                    .map(|_| {
                        let y: Vec<f64> = (0..n).map(|_| <StandardNormal as Distribution<f64>>::sample(&StandardNormal, &mut rng)).collect();
                        gls_sup_lr_scan(&wx, &y, &x, &[phi], &[], min_segment(n), &mut GlsScratch::default(), None).map_or(0.0, |b| b.statistic)
                    })
                    .collect::<Vec<f64>>()
            };
            for alpha in [0.05, 0.01] {
                let crit = gls_critical_value(n, phi, alpha);
                let rate = stats.iter().filter(|&&s| s > crit).count() as f64 / reps as f64;
                let sd = (alpha * (1.0 - alpha) / reps as f64).sqrt();
                assert!((rate - alpha).abs() < 4.0 * sd, "n {n} phi {phi} alpha {alpha}: rate {rate}");
                // p-values agree with the critical value.
                assert!((gls_predictive_p_value(n, phi, crit, 0.0) - alpha).abs() < 1e-6 * alpha.max(1.0) + 1e-9);
            }
        }
        // At phi 0 the table is the two-line scan's.
        assert_eq!(gls_quantiles(250, 0.0), SUP_LR_QUANTILES[3]);
        assert!(gls_critical_value(700, 0.93, 0.01) > crate::detectors::breakpoint::sup_lr_critical_value(700, 0.01).unwrap() + 2.0);
    }

    /// Two cells of the GLS sensitivity table re-simulated with other seeds (6,000 windows):
    /// within 0.1. The two-line scan's table differs from it by 0.15 in the second cell.
    #[test]
    fn gls_whitening_sensitivity_table_matches_simulation() {
        use crate::detectors::breakpoint::{simulate_miswhitened_quantiles, SENSITIVITY_LAG1};
        for (n, j) in [(120, 2), (1000, 4)] {
            let phi = SENSITIVITY_LAG1[j];
            let phi_hat = 1.0 - (1.0 - phi) * f64::exp(0.5);
            let q0 = simulate_miswhitened_quantiles(n, phi, 0.0, 6000, 55 + n as u64, miswhitened_gls(n, phi))[6];
            let q = simulate_miswhitened_quantiles(n, phi, 0.5, 6000, 55 + n as u64, miswhitened_gls(n, phi_hat))[6];
            let kappa = (q / q0).ln();
            let table = GLS_WHITENING_SENSITIVITY[TABLE_N.iter().position(|&m| m == n).unwrap()][j];
            assert!((kappa - table).abs() < 0.1, "n {n} phi {phi}: simulated {kappa:.3}, table {table}");
            assert!((gls_whitening_sensitivity(n, phi) - table).abs() < 1e-12);
        }
    }

    /// Rows after a restart are left out: a wild whitened sample there (a pause's relaxation
    /// filtered with the past before it) makes no break, and the statistic is that of the
    /// window without those rows.
    #[test]
    fn rows_after_a_restart_are_left_out() {
        let phi = [0.85];
        let n = 200;
        let (wx, mut wy, x, _) = window(n, &phi, None, 21);
        let clean = gls_sup_lr_scan(&wx, &wy, &x, &phi, &[], 10, &mut GlsScratch::default(), None).unwrap();
        wy[120] += 2.0; // whitened sample 120 is x[121]'s
        let spiked = gls_sup_lr_scan(&wx, &wy, &x, &phi, &[], 10, &mut GlsScratch::default(), None).unwrap();
        let skipped = gls_sup_lr_scan(&wx, &wy, &x, &phi, &[121], 10, &mut GlsScratch::default(), None).unwrap();
        assert!(spiked.statistic > 50.0 && spiked.split == 120, "{spiked:?}");
        assert!(skipped.statistic < clean.statistic + 5.0, "clean {clean:?} skipped {skipped:?}");
    }

    #[test]
    #[ignore = "prints the GLS statistic's sensitivity to a whitening error (a few minutes)"]
    fn gls_whitening_sensitivity_experiment() {
        use crate::detectors::breakpoint::{simulate_miswhitened_quantiles, SENSITIVITY_LAG1};
        let reps: usize = std::env::var("REPS").ok().and_then(|v| v.parse().ok()).unwrap_or(20_000);
        let delta = 0.5;
        for n in TABLE_N {
            let mut row = Vec::new();
            for phi in SENSITIVITY_LAG1 {
                let seed = 20_261_128 + n as u64;
                let phi_hat = 1.0 - (1.0 - phi) * f64::exp(delta);
                let q0 = simulate_miswhitened_quantiles(n, phi, 0.0, reps, seed, miswhitened_gls(n, phi))[6];
                let qd = simulate_miswhitened_quantiles(n, phi, delta, reps, seed, miswhitened_gls(n, phi_hat))[6];
                row.push(format!("{:.2}", (qd / q0).ln() / (2.0 * delta)));
            }
            println!("    [{}], // n = {n}", row.join(", "));
        }
    }

    #[test]
    #[ignore = "regenerates the GLS table (a few minutes on two cores)"]
    fn regenerate_gls_table() {
        let reps: usize = std::env::var("REPS").ok().and_then(|v| v.parse().ok()).unwrap_or(100_000);
        for &phi in &GLS_PHI[1..] {
            println!("    [ // phi {phi}");
            for n in TABLE_N {
                let q = simulate_gls_quantiles(n, phi, reps, 20_261_127 + n as u64);
                let row: Vec<String> = q.iter().map(|v| format!("{v:.3}")).collect();
                println!("        [{}], // n = {n}", row.join(", "));
            }
            println!("    ],");
        }
    }
}
