//! Scan for one episode of the elastic line: a stretch `[start, end)` of the window whose level
//! is shifted while the line before and after it is one and the same (the epidemic alternative:
//! Levin and Kline 1985, "The CUSUM test of homogeneity with an application in spontaneous
//! abortion epidemiology", Statistics in Medicine 4; Yao 1993, "Tests for change-points with
//! epidemic alternatives", Biometrika 80).
//!
//! Why this detector: an intermittent friction fault raises (or lowers) the friction for a
//! stretch and lets it return. With the torque `T = F K(mu)` and the clamp force `F` following
//! the angle, the torque leaves the line by `F dK` for that stretch and comes back to it: a
//! pulse, not a break. The one-break scan ([`crate::detectors::breakpoint`]) fits two lines and
//! is judged by the residuals they leave, which a pulse in the middle of the window keeps
//! large: on the independent generator it missed 3-4 % of intermittent episodes of 15-45 %
//! whose pulses stood tens of noise sds above the line (a few samples each on a fast tool).
//!
//! Statistic, for an episode `[k1, k2)` of `m = k2 - k1` samples, `z` its indicator:
//!
//! ```text
//! LR_{k1,k2} = n ln(RSS_0 / (RSS_0 - (z'e)^2 / z'Mz)),     sup over admissible episodes
//! ```
//!
//! with `e` the residuals of the line through the whole window and `M` the projection off the
//! line (so `z'Mz = m - (sum over the episode of (1, x)) (X'X)^-1 (...)'`). Every term comes
//! from prefix sums: O(1) per episode. Self-normalised like the break scan (its noise variance
//! is the window's own), so it runs on the same whitened, Gaussianised samples.
//!
//! Admissible episodes: at least [`MIN_EPISODE`] samples, at least [`min_segment`]`(n)`
//! samples outside, and half that before and after. Their ends lie on a grid of at most
//! [`EPISODE_GRID`] + 1 positions (every sample up to that many; an even grid beyond), which
//! bounds the cost at about
//! `EPISODE_GRID^2 / 2` episodes for any window and defines the statistic the table is for.

use crate::detectors::breakpoint::{min_segment, predictive_p_value, simulate_null_quantiles, table_critical_value, TABLE_ALPHA};
use crate::error::{Result, TightscanError};

/// Shortest episode, in samples. One or two samples would make the scan an outlier test, whose
/// size rests on the noise's extreme tail rather than on its variance.
pub const MIN_EPISODE: usize = 3;

/// Most episode end positions per window (see the module docs).
pub const EPISODE_GRID: usize = 240;

/// Result of one episode scan.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EpisodeScan {
    /// sup-LR statistic.
    pub statistic: f64,
    /// First sample of the episode.
    pub start: usize,
    /// One past its last sample.
    pub end: usize,
    /// Level of the episode against the line (the fitted shift, in the units of `y`).
    pub level: f64,
}

/// The episode scan of `x`, `y` (centred near zero, as for the break scan). `None` when no
/// episode is admissible or the line leaves no residual variance.
///
/// `transients`: sample positions where the tool restarted (the first sample after a pause, or
/// the window's first where it starts after a controller step). No episode is admitted within
/// its own length of one: the torque dips and recovers there with the tool's speed, not with
/// friction (on the built-in simulator's clean CSDT curves at 10 kHz, 16 of 19 episodes
/// significant at their share held the pause).
pub fn episode_scan(x: &[f64], y: &[f64], transients: &[usize], scratch: &mut Vec<(f64, f64)>) -> Option<EpisodeScan> {
    let n = x.len();
    let outside = min_segment(n);
    if y.len() != n || n < outside + MIN_EPISODE || n < 4 {
        return None;
    }
    let (a, b) = crate::detectors::least_squares_line(x, y);
    // (X'X)^-1 of the line's design [1, x], for the projection of the indicator.
    let (sx, sxx) = x.iter().fold((0.0, 0.0), |(s, q), v| (s + v, q + v * v));
    let nf = n as f64;
    let det = nf * sxx - sx * sx;
    if !(det > 0.0) {
        return None;
    }
    let (g00, g01, g11) = (sxx / det, -sx / det, nf / det);
    // Prefix sums of x and of the line's residuals.
    scratch.clear();
    scratch.push((0.0, 0.0));
    let mut rss0 = 0.0;
    let (mut px, mut pe) = (0.0, 0.0);
    for (xi, yi) in x.iter().zip(y) {
        let e = yi - a - b * xi;
        rss0 += e * e;
        px += xi;
        pe += e;
        scratch.push((px, pe));
    }
    if !(rss0 > 0.0) {
        return None;
    }
    // Episodes lie inside the window, half a minimum segment from either end: one that
    // touches an end is a break, which the break scan and the end and start tests judge with
    // their own care for the tool's start and stop (at 500 Hz, HDT windows of 20-30 samples,
    // the braking in the last five samples and the seating's bend in the first three were
    // significant episodes in 1 % of clean curves).
    let margin = outside / 2;
    let (count, position) = grid(n);
    let mut best: Option<(f64, usize, usize, f64)> = None; // (reduction, k1, k2, level)
    for i in 0..count {
        let k1 = position(i);
        if k1 < margin {
            continue;
        }
        for k2 in (i + 1..count).map(&position) {
            if k2 + margin > n {
                break;
            }
            let m = k2 - k1;
            if m < MIN_EPISODE {
                continue;
            }
            if n - m < outside {
                break;
            }
            if transients.iter().any(|&g| g + m >= k1 && g <= k2 + m) {
                continue;
            }
            let (s1, sxe) = (m as f64, scratch[k2].0 - scratch[k1].0);
            let se = scratch[k2].1 - scratch[k1].1;
            let zmz = s1 - (g00 * s1 * s1 + 2.0 * g01 * s1 * sxe + g11 * sxe * sxe);
            if !(zmz > 1e-9 * s1) {
                continue;
            }
            let reduction = se * se / zmz;
            if best.is_none_or(|(r, ..)| reduction > r) {
                best = Some((reduction, k1, k2, se / zmz));
            }
        }
    }
    let (reduction, start, end, level) = best?;
    let rss = (rss0 - reduction).max(1e-300 * rss0);
    Some(EpisodeScan { statistic: nf * (rss0 / rss).ln(), start, end, level })
}

/// The episode end positions for n samples, as their count and the i-th: every position 0..=n
/// up to [`EPISODE_GRID`] samples, else `EPISODE_GRID + 1` positions spread evenly (rounded;
/// more than a sample apart, so none repeats).
fn grid(n: usize) -> (usize, impl Fn(usize) -> usize) {
    let dense = n <= EPISODE_GRID;
    let count = if dense { n + 1 } else { EPISODE_GRID + 1 };
    (count, move |i: usize| if dense { i } else { ((i * n) as f64 / EPISODE_GRID as f64).round() as usize })
}

/// (1 - alpha) quantiles of the episode scan's statistic under no change, i.i.d. Gaussian
/// noise, samples evenly spaced: rows follow [`TABLE_N`](crate::detectors::breakpoint::TABLE_N),
/// columns [`TABLE_ALPHA`]. Made by `simulate_episode_quantiles(n, 100_000, 20261126 + n)` for
/// each n (the ignored test `regenerate_episode_table` prints it; about 30 s on two cores).
pub static EPISODE_LR_QUANTILES: [[f64; 8]; 8] = [
    [6.060, 8.927, 10.840, 12.659, 14.973, 16.637, 18.349, 22.480], // n = 30
    [8.118, 10.918, 12.784, 14.545, 16.735, 18.412, 19.996, 23.626], // n = 60
    [9.733, 12.477, 14.251, 15.940, 18.091, 19.679, 21.225, 24.983], // n = 120
    [11.193, 13.870, 15.614, 17.264, 19.431, 20.868, 22.569, 26.148], // n = 250
    [11.344, 13.975, 15.711, 17.330, 19.446, 21.071, 22.708, 26.321], // n = 500
    [11.598, 14.176, 15.866, 17.471, 19.512, 21.085, 22.560, 25.908], // n = 1000
    [11.570, 14.151, 15.800, 17.431, 19.521, 21.063, 22.728, 26.109], // n = 2000
    [11.529, 14.100, 15.798, 17.385, 19.370, 20.930, 22.418, 25.931], // n = 4000
];

/// Null quantiles by Monte Carlo: `reps` series of n evenly spaced samples with i.i.d. N(0,1)
/// noise, the (1 - alpha) quantile for each alpha of [`TABLE_ALPHA`].
pub fn simulate_episode_quantiles(n: usize, reps: usize, seed: u64) -> Vec<f64> {
    simulate_null_quantiles(n, reps, seed, |x, y| episode_scan(x, y, &[], &mut Vec::new()).map_or(0.0, |s| s.statistic))
}

/// Critical value of the episode scan at `alpha` for n samples (the table, interpolated as the
/// break scan's is).
pub fn episode_critical_value(n: usize, alpha: f64) -> Result<f64> {
    if !(alpha >= TABLE_ALPHA[TABLE_ALPHA.len() - 1] && alpha <= TABLE_ALPHA[0]) {
        return Err(TightscanError::parameter(
            "alpha",
            format!("must be in [{}, {}] for the shipped episode table, got {alpha}", TABLE_ALPHA[7], TABLE_ALPHA[0]),
        ));
    }
    Ok(table_critical_value(&EPISODE_LR_QUANTILES, n, alpha))
}

/// p-value of an episode statistic of a pre-whitened window, averaged over the whitening's
/// uncertainty as the break scan's is ([`crate::detectors::breakpoint::sup_lr_predictive_p_value`]).
pub fn episode_predictive_p_value(n: usize, statistic: f64, gain_log_se: f64) -> f64 {
    predictive_p_value(&EPISODE_LR_QUANTILES, n, statistic, gain_log_se)
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
mod tests {
    use super::*;
    use crate::detectors::breakpoint::TABLE_N;
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    use rand_xoshiro::Xoshiro256PlusPlus;
    use rayon::prelude::*;

    fn evenly_spaced(n: usize) -> Vec<f64> {
        (0..n).map(|i| i as f64 / n as f64 - 0.5).collect()
    }

    fn normal(rng: &mut Xoshiro256PlusPlus) -> f64 {
        <StandardNormal as Distribution<f64>>::sample(&StandardNormal, rng)
    }

    /// The prefix-sum statistic equals least squares with the episode's indicator as a third
    /// regressor, at the episode it reports, and no other admissible episode beats it.
    #[test]
    fn scan_matches_brute_force() {
        let n = 70;
        let x = evenly_spaced(n);
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        let y: Vec<f64> = (0..n).map(|i| 1.0 + 2.0 * x[i] + if (30..36).contains(&i) { 0.8 } else { 0.0 } + 0.2 * normal(&mut rng)).collect();
        let s = episode_scan(&x, &y, &[], &mut Vec::new()).unwrap();
        let line_rss = |rows: &dyn Fn(usize) -> [f64; 3]| crate::detectors::least_squares_3((0..n).map(|i| (rows(i), y[i]))).unwrap();
        let (a, b) = crate::detectors::least_squares_line(&x, &y);
        let rss0: f64 = (0..n).map(|i| (y[i] - a - b * x[i]).powi(2)).sum();
        let mut best = (f64::INFINITY, 0, 0);
        for k1 in 0..n {
            for k2 in k1 + MIN_EPISODE..=n {
                if n - (k2 - k1) < min_segment(n) || k1 < min_segment(n) / 2 || k2 + min_segment(n) / 2 > n {
                    continue;
                }
                let (_, _, rss) = line_rss(&|i| [1.0, x[i], if (k1..k2).contains(&i) { 1.0 } else { 0.0 }]);
                if rss < best.0 {
                    best = (rss, k1, k2);
                }
            }
        }
        assert_eq!((s.start, s.end), (best.1, best.2));
        assert_eq!((s.start, s.end), (30, 36));
        assert!((s.statistic - n as f64 * (rss0 / best.0).ln()).abs() < 1e-6 * s.statistic, "{} vs {}", s.statistic, n as f64 * (rss0 / best.0).ln());
        assert!((s.level - 0.8).abs() < 0.25, "{s:?}");
    }

    /// Size against the table at alpha 0.05 and 0.01, between table rows and on the grid's
    /// far side, fresh seeds: within 4 binomial sd.
    #[test]
    fn size_matches_nominal() {
        for n in [45, 180, 700] {
            let reps = 20_000;
            let x = evenly_spaced(n);
            let stats: Vec<f64> = (0..reps)
                .into_par_iter()
                .map_init(Vec::new, |scratch, r| {
                    let mut rng = Xoshiro256PlusPlus::seed_from_u64(4_242 + r as u64 * 31 + n as u64);
                    let y: Vec<f64> = (0..n).map(|_| normal(&mut rng)).collect();
                    episode_scan(&x, &y, &[], scratch).unwrap().statistic
                })
                .collect();
            for alpha in [0.05, 0.01] {
                let c = episode_critical_value(n, alpha).unwrap();
                let rate = stats.iter().filter(|&&s| s > c).count() as f64 / reps as f64;
                let sd = (alpha * (1.0 - alpha) / reps as f64).sqrt();
                assert!((rate - alpha).abs() < 4.0 * sd + 0.002, "n {n} alpha {alpha}: {rate}");
            }
        }
    }

    /// Power where the break scan is weak: a pulse of `height` noise sds over `width` samples
    /// in the middle of an n-sample window (the line of a friction episode on a fast tool).
    /// (episode scan's alarms, of them placed within a sample, break scan's alarms), at 0.01.
    fn pulse_power(n: usize, width: usize, height: f64, reps: u64) -> (usize, usize, usize) {
        let x = evenly_spaced(n);
        let (c_episode, c_break) = (episode_critical_value(n, 0.01).unwrap(), crate::detectors::breakpoint::sup_lr_critical_value(n, 0.01).unwrap());
        let (at, to) = (n / 2 - width / 2, n / 2 - width / 2 + width);
        let (mut episode, mut placed, mut broken) = (0, 0, 0);
        for r in 0..reps {
            let mut rng = Xoshiro256PlusPlus::seed_from_u64(90_000 + r);
            let y: Vec<f64> = (0..n).map(|i| 5.0 * x[i] + if (at..to).contains(&i) { height } else { 0.0 } + normal(&mut rng)).collect();
            let s = episode_scan(&x, &y, &[], &mut Vec::new()).unwrap();
            if s.statistic > c_episode {
                episode += 1;
                placed += usize::from(s.start.abs_diff(at) <= 1 && s.end.abs_diff(to) <= 1);
            }
            broken += usize::from(crate::detectors::breakpoint::sup_lr_scan(&x, &y, min_segment(n), &mut Vec::new()).unwrap().statistic > c_break);
        }
        (episode, placed, broken)
    }

    /// Measured (400 series each): n 100, 4 samples at 3.5 sd: episode 396 (382 placed), break
    /// 76; n 200, 8 samples at 2.5 sd: 397 (334), break 153.
    #[test]
    fn finds_a_pulse_the_break_scan_misses() {
        for (n, width, height) in [(100, 4, 3.5), (200, 8, 2.5)] {
            let (episode, placed, broken) = pulse_power(n, width, height, 400);
            assert!(episode >= 388, "n {n}: episode scan found {episode} of 400");
            assert!(placed as f64 >= 0.8 * episode as f64, "n {n}: placed {placed} of {episode}");
            assert!(broken <= 200, "n {n}: break scan found {broken} of 400");
        }
    }

    #[test]
    fn short_or_flat_input_gives_none_and_bad_alpha_is_named() {
        assert!(episode_scan(&[0.0; 5], &[1.0; 5], &[], &mut Vec::new()).is_none());
        let x = evenly_spaced(30);
        assert!(episode_scan(&x, &x, &[], &mut Vec::new()).is_none());
        assert!(episode_critical_value(100, 0.2).is_ok());
        assert!(episode_critical_value(100, 0.6).is_err());
    }

    #[test]
    #[ignore = "regenerates the shipped table (about 30 s on two cores)"]
    fn regenerate_episode_table() {
        for n in TABLE_N {
            let q = simulate_episode_quantiles(n, 100_000, 20_261_126 + n as u64);
            let row: Vec<String> = q.iter().map(|v| format!("{v:.3}")).collect();
            println!("    [{}], // n = {n}", row.join(", "));
        }
    }
}
