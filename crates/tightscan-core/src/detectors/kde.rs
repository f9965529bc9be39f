//! Kernel density test statistics for a change in the residual distribution (METHODS.md
//! section 4).
//!
//! The statistic is the L2 distance between Gaussian kernel density estimates (bandwidth h) of
//! a reference sample X (n points: the training residuals) and a test sample Y (m points):
//!
//! ```text
//! T = (1/n^2) sum_ij phi(X_i - X_j) + (1/m^2) sum_ij phi(Y_i - Y_j)
//!     - (2/(nm)) sum_ij phi(X_i - Y_j)
//! ```
//!
//! with phi the normal density of scale sigma = sqrt(2) h, because
//! int K_h(x - a) K_h(x - b) dx = phi_{sqrt(2) h}(a - b). T is exactly the biased squared maximum
//! mean discrepancy MMD^2_b with that kernel; dropping the i = j terms of the two self sums gives
//! the unbiased MMD^2_u (Gretton et al. 2012, JMLR 13, eqs. 3 and 5).
//!
//! Three evaluations of the same number ([`KdeEvaluation`]):
//! - exact: the three double sums, O((n + m)^2) kernel evaluations;
//! - binned: linear binning onto a grid, then a direct convolution with the kernel truncated at
//!   6 sigma, O(n + m + G w) (Wand 1994, J. Comput. Graph. Stat. 3; Hall and Wand 1996,
//!   J. Multivar. Anal. 56). The error is second order in the grid step;
//! - spectral: Parseval on the empirical characteristic functions (ECF) phi_X, phi_Y,
//!   T = (1/pi) int_0^inf |phi_X(t) - phi_Y(t)|^2 exp(-h^2 t^2) dt (the KDE is the Fourier
//!   transform of the ECF damped by exp(-h^2 t^2 / 2)), by the trapezoidal rule. By Poisson
//!   summation that rule is the same T with the kernel wrapped on a circle of circumference
//!   2 pi / step, so its only errors are aliasing (pairs farther apart than the circle allows)
//!   and truncation at t_max; both are below 1e-7 relative with the spacing and cut-off used
//!   here. Each sample contributes a fixed feature vector exp(i t_k x); with their prefix sums
//!   the ECF of any window is one difference of two rows, so a window costs O(Q) whatever
//!   its length: the change scan ([`kde_change_test`]) runs on it, and its permutations move
//!   whole blocks, which costs one difference per block.
//!
//! The test compares the training window with windows after it and takes the maximum of the
//! standardised statistic over windows; its null distribution comes from block permutations of
//! the whole series, which keeps the false-alarm probability of the whole scan at alpha (one
//! p-value per series, in the spirit of Westfall and Young's max-T adjustment).

use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

use crate::error::{Result, TightscanError};

/// 1 / sqrt(2 pi), the normalising constant of the standard normal density.
const INV_SQRT_2PI: f64 = 0.398_942_280_401_432_7;

/// Silverman's rule of thumb, h = 0.9 min(sd, IQR / 1.34) n^(-1/5) (Silverman 1986, Density
/// Estimation, eq. 3.31): the factor.
const SILVERMAN_FACTOR: f64 = 0.9;
/// IQR of the standard normal is 1.349; Silverman rounds to 1.34.
const SILVERMAN_IQR_DIVISOR: f64 = 1.34;

/// Grid points per kernel standard deviation sigma = sqrt(2) h for the binned evaluation.
/// Linear binning spreads a point over two nodes with variance t (1 - t) step^2 (t its
/// fractional grid position), step^2 / 6 on average, so a binned pair sees the kernel with
/// about step^2 / 3 of extra variance: E phi_s(d + e) = phi_sqrt(s^2 + Var e)(d) to second
/// order (the heat equation). The grid kernel therefore has variance sigma^2 - step^2 / 3,
/// which cancels that on average; what is left is the scatter of t (1 - t) between points,
/// which averages out over pairs. Self pairs (i = j) get the exact phi(0). Measured worst
/// relative error of T over the cases of `binned_matches_exact` (H0 cases are the hard ones,
/// T being small there): 6.8e-4 at 8 points per sigma, 1.6e-4 at 16 (3.5e-3 and 8.8e-4 without
/// the variance correction); 16 keeps a factor 5 from the 1e-3 target.
const BINS_PER_SIGMA: f64 = 16.0;
/// Kernel truncation of the binned convolution, in sigmas: phi(6 sigma) / phi(0) = 1.5e-8.
const KERNEL_CUTOFF_SIGMAS: f64 = 6.0;
/// Largest grid of the binned evaluation (8 MB of f64); beyond it (an extreme outlier stretches
/// the range) the exact sums are used instead.
const MAX_GRID_POINTS: usize = 1 << 20;
/// [`KdeEvaluation::Auto`] uses the exact sums up to this many points in X and Y together: at
/// that size they cost about 30k kernel evaluations, tens of microseconds.
const AUTO_EXACT_MAX_POINTS: usize = 256;

/// Spectral cut-off t_max = SPECTRAL_CUTOFF / h: the omitted tail of
/// int exp(-h^2 t^2) dt is erfc(4) / erf(inf) = 1.5e-8 of the whole.
const SPECTRAL_CUTOFF: f64 = 4.0;
/// The wrapped kernel's circle exceeds the data range by this many sigmas, so the nearest alias
/// of any pair sits at least 6 sigma away: phi(6 sigma) / phi(0) = 1.5e-8.
const SPECTRAL_ALIAS_SIGMAS: f64 = 6.0;
/// Node count is rounded up to a multiple of this so the inner loops run on whole SIMD lanes.
const LANES: usize = 4;
/// Recompute exp(i k step u) directly every this many nodes instead of by recurrence, which
/// bounds the rounding drift of the recurrence to 64 multiplications (~1e-14).
const RESYNC_EVERY: usize = 64;
/// Largest spectral node count the scan accepts: the range of the residuals is then about
/// 1,600 bandwidths. Beyond that the feature table (N x 2Q values) grows past 16 kB per sample.
pub const MAX_SPECTRAL_NODES: usize = 1024;

/// Smallest test segment of the change-start estimate: a KDE of fewer points is too noisy to
/// place a change.
const CHANGE_MIN_SEGMENT: usize = 10;

/// Which MMD^2 estimator.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum MmdEstimator {
    /// All pairs, i = j included: T is exactly the L2 distance between the two KDEs, >= 0.
    #[default]
    Biased,
    /// Self sums without i = j, divided by n (n - 1) and m (m - 1): unbiased for the
    /// population MMD^2, mean 0 under H0, can be negative. Needs n, m >= 2.
    Unbiased,
}

/// How to evaluate the statistic.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum KdeEvaluation {
    /// Exact up to 256 points in X and Y together, binned above.
    #[default]
    Auto,
    /// The double sums.
    Exact,
    /// Linear binning and a truncated kernel convolution (relative error < 1e-3).
    Binned,
    /// Trapezoidal rule on the ECFs (relative error < 1e-6).
    Spectral,
}

/// L2 distance between the Gaussian KDEs of `x` and `y` with bandwidth `h` (the biased MMD^2),
/// evaluated exactly for small samples and by binning for large ones.
///
/// NaN if either sample is empty, a value is not finite or `h` is not positive.
pub fn kde_l2_distance(x: &[f64], y: &[f64], h: f64) -> f64 {
    kde_statistic(x, y, h, MmdEstimator::Biased, KdeEvaluation::Auto)
}

/// Squared MMD between `x` and `y` with the kernel phi_{sqrt(2) h}, by the chosen estimator and
/// evaluation. NaN for empty samples, non-finite values, `h <= 0`, and for the unbiased
/// estimator with fewer than 2 points in a sample.
pub fn kde_statistic(
    x: &[f64],
    y: &[f64],
    h: f64,
    estimator: MmdEstimator,
    evaluation: KdeEvaluation,
) -> f64 {
    let min_len = match estimator {
        MmdEstimator::Biased => 1,
        MmdEstimator::Unbiased => 2,
    };
    let all_finite = x.iter().chain(y).all(|v| v.is_finite());
    if x.len() < min_len || y.len() < min_len || !all_finite || !(h.is_finite() && h > 0.0) {
        return f64::NAN;
    }
    let need_self = estimator == MmdEstimator::Unbiased;
    let parts = match evaluation {
        KdeEvaluation::Exact => Some(exact_parts(x, y, h)),
        KdeEvaluation::Binned => binned_parts(x, y, h, BINS_PER_SIGMA, need_self),
        KdeEvaluation::Spectral => spectral_parts(x, y, h),
        KdeEvaluation::Auto if x.len() + y.len() <= AUTO_EXACT_MAX_POINTS => {
            Some(exact_parts(x, y, h))
        }
        KdeEvaluation::Auto => binned_parts(x, y, h, BINS_PER_SIGMA, need_self),
    };
    // Binned and spectral decline only when the range is so wide (extreme outliers) that their
    // grids would be huge; the exact sums have no such limit.
    let parts = parts.unwrap_or_else(|| exact_parts(x, y, h));
    parts.estimate(estimator, x.len(), y.len())
}

/// The pieces every evaluation produces, from which both estimators follow.
#[derive(Clone, Copy, Debug)]
struct MmdParts {
    /// T = A_XX + A_YY - 2 A_XY with A_XX = (1/n^2) sum_ij k(X_i, X_j) etc.
    biased: f64,
    /// A_XX - kappa_X, kappa_X the mean self-kernel k(X_i, X_i) (phi(0) when exact).
    excess_x: f64,
    /// A_YY - kappa_Y.
    excess_y: f64,
}

impl MmdParts {
    /// MMD^2_u = MMD^2_b + (A_XX - kappa_X)/(n - 1) + (A_YY - kappa_Y)/(m - 1): the X part of
    /// MMD^2_b is S_XX / n^2, that of MMD^2_u is (S_XX - n kappa_X) / (n (n - 1)), and their
    /// difference is (S_XX / n^2 - kappa_X) / (n - 1).
    fn estimate(self, estimator: MmdEstimator, n: usize, m: usize) -> f64 {
        match estimator {
            MmdEstimator::Biased => self.biased,
            MmdEstimator::Unbiased => {
                self.biased + self.excess_x / (n as f64 - 1.0) + self.excess_y / (m as f64 - 1.0)
            }
        }
    }
}

/// Sum over i, j of exp(-d^2 / (2 sigma^2)), d = a_i - b_j.
fn cross_exp_sum(a: &[f64], b: &[f64], sigma: f64) -> f64 {
    let c = -0.5 / (sigma * sigma);
    a.iter().map(|&u| b.iter().map(|&v| f64::exp(c * (u - v) * (u - v))).sum::<f64>()).sum()
}

/// Sum over i != j of exp(-d^2 / (2 sigma^2)), d = a_i - a_j, as twice the i < j half.
fn self_exp_sum_off_diagonal(a: &[f64], sigma: f64) -> f64 {
    let c = -0.5 / (sigma * sigma);
    let mut sum = 0.0;
    for (i, &u) in a.iter().enumerate() {
        sum += a[i + 1..].iter().map(|&v| f64::exp(c * (u - v) * (u - v))).sum::<f64>();
    }
    2.0 * sum
}

fn exact_parts(x: &[f64], y: &[f64], h: f64) -> MmdParts {
    let sigma = std::f64::consts::SQRT_2 * h;
    let k0 = INV_SQRT_2PI / sigma;
    let (n, m) = (x.len() as f64, y.len() as f64);
    let sxx_off = k0 * self_exp_sum_off_diagonal(x, sigma);
    let syy_off = k0 * self_exp_sum_off_diagonal(y, sigma);
    let sxy = k0 * cross_exp_sum(x, y, sigma);
    let a_xx = (sxx_off + n * k0) / (n * n);
    let a_yy = (syy_off + m * k0) / (m * m);
    MmdParts { biased: a_xx + a_yy - 2.0 * sxy / (n * m), excess_x: a_xx - k0, excess_y: a_yy - k0 }
}

/// Grid of the binned evaluation: `points` nodes lo, lo + step, ...
struct BinGrid {
    lo: f64,
    step: f64,
    points: usize,
}

impl BinGrid {
    /// Linear binning (Jones and Lotwick 1983): a point at fractional grid position b + t puts
    /// weight 1 - t on node b and t on node b + 1, which keeps each point's mass and mean.
    /// Returns the summed binned self-kernel (1 - t)^2 k0 + t^2 k0 + 2 t (1 - t) k1 of the
    /// points (k0, k1 the grid kernel at 0 and one step): the i = j part of the binned double
    /// sum, which the caller swaps for the exact phi(0).
    fn bin(&self, values: &[f64], counts: &mut [f64], k0: f64, k1: f64) -> f64 {
        let mut diagonal = 0.0;
        for &v in values {
            let pos = (v - self.lo) / self.step;
            // pos >= 0 by construction of lo; the last node is kept free for the right weight.
            let b = (pos.floor().max(0.0) as usize).min(self.points - 2);
            let t = pos - b as f64;
            counts[b] += 1.0 - t;
            counts[b + 1] += t;
            let cross = t * (1.0 - t);
            diagonal += k0 * (1.0 - 2.0 * cross) + 2.0 * k1 * cross;
        }
        diagonal
    }
}

/// Direct convolution of grid `counts` with the symmetric kernel truncated at w steps,
/// `kernel_full[j] = phi((j - w) step)` for j = 0..=2w, scattered column by column so the inner
/// loop is a contiguous multiply-add: O(G w).
fn convolve(counts: &[f64], kernel_full: &[f64], w: usize) -> Vec<f64> {
    let g = counts.len();
    let mut out = vec![0.0; g];
    for (b, &c) in counts.iter().enumerate() {
        if c == 0.0 {
            continue;
        }
        let lo = b.saturating_sub(w);
        let hi = (b + w + 1).min(g);
        // Node a gets phi((a - b) step) = kernel_full[a - b + w].
        let k = &kernel_full[lo + w - b..hi + w - b];
        for (o, &kv) in out[lo..hi].iter_mut().zip(k) {
            *o += c * kv;
        }
    }
    out
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(u, v)| u * v).sum()
}

/// Binned evaluation with `bins_per_sigma` grid points per kernel sd; None if the grid would
/// exceed [`MAX_GRID_POINTS`]. The self parts are computed only when `need_self` (two
/// convolutions instead of one).
fn binned_parts(
    x: &[f64],
    y: &[f64],
    h: f64,
    bins_per_sigma: f64,
    need_self: bool,
) -> Option<MmdParts> {
    binned_parts_with(x, y, h, bins_per_sigma, need_self, true)
}

/// [`binned_parts`] with the grid-variance correction optional (off only to measure it).
fn binned_parts_with(
    x: &[f64],
    y: &[f64],
    h: f64,
    bins_per_sigma: f64,
    need_self: bool,
    correct_variance: bool,
) -> Option<MmdParts> {
    let sigma = std::f64::consts::SQRT_2 * h;
    let (lo, hi) = min_max(x.iter().chain(y))?;
    let step = sigma / bins_per_sigma;
    let span = (hi - lo) / step;
    if span.is_nan() || span >= (MAX_GRID_POINTS - 2) as f64 {
        return None;
    }
    let grid = BinGrid { lo, step, points: span.floor() as usize + 2 };
    let w = (KERNEL_CUTOFF_SIGMAS * bins_per_sigma).ceil() as usize;
    // Kernel with the binning variance taken out (see BINS_PER_SIGMA); the root is real for
    // step < sqrt(3) sigma, and step = sigma / 16 here.
    let sigma_grid =
        if correct_variance { (sigma * sigma - step * step / 3.0).sqrt() } else { sigma };
    let kernel_full: Vec<f64> =
        (0..=2 * w).map(|j| normal_density((j as f64 - w as f64) * step, sigma_grid)).collect();
    // Exact phi(0) for the self pairs, which binning does not average: their binned value
    // (`diag_*`) is swapped for it.
    let k0 = INV_SQRT_2PI / sigma;
    let (n, m) = (x.len() as f64, y.len() as f64);
    let mut cx = vec![0.0; grid.points];
    let mut cy = vec![0.0; grid.points];
    let diag_x = grid.bin(x, &mut cx, kernel_full[w], kernel_full[w + 1]);
    let diag_y = grid.bin(y, &mut cy, kernel_full[w], kernel_full[w + 1]);
    if need_self {
        let kcx = convolve(&cx, &kernel_full, w);
        let kcy = convolve(&cy, &kernel_full, w);
        let a_xx = (dot(&cx, &kcx) - diag_x + n * k0) / (n * n);
        let a_yy = (dot(&cy, &kcy) - diag_y + m * k0) / (m * m);
        let a_xy = dot(&cx, &kcy) / (n * m);
        Some(MmdParts {
            biased: a_xx + a_yy - 2.0 * a_xy,
            excess_x: a_xx - k0,
            excess_y: a_yy - k0,
        })
    } else {
        // d' K d with d the difference of the normalised bin weights: no cancellation between
        // the three large sums.
        let d: Vec<f64> = cx.iter().zip(&cy).map(|(a, b)| a / n - b / m).collect();
        let kd = convolve(&d, &kernel_full, w);
        let biased = dot(&d, &kd) - diag_x / (n * n) - diag_y / (m * m) + k0 / n + k0 / m;
        Some(MmdParts { biased, excess_x: f64::NAN, excess_y: f64::NAN })
    }
}

/// The Gaussian kernel density estimate of `sample` with bandwidth `h` at each point of `at`:
/// the densities whose L2 distance the test statistic is (for plots of what it compared).
/// Empty when `sample` is empty or `h` is not positive.
pub fn kde_density(sample: &[f64], h: f64, at: &[f64]) -> Vec<f64> {
    if sample.is_empty() || !(h.is_finite() && h > 0.0) {
        return Vec::new();
    }
    let n = sample.len() as f64;
    at.iter().map(|&u| sample.iter().map(|&v| normal_density(u - v, h)).sum::<f64>() / n).collect()
}

/// Normal density of scale `sigma` at `u`.
fn normal_density(u: f64, sigma: f64) -> f64 {
    let z = u / sigma;
    INV_SQRT_2PI / sigma * f64::exp(-0.5 * z * z)
}

/// (min, max) of finite values; None for an empty iterator.
fn min_max<'a>(values: impl Iterator<Item = &'a f64>) -> Option<(f64, f64)> {
    values.fold(None, |acc, &v| match acc {
        None => Some((v, v)),
        Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
    })
}

/// Frequency nodes t_k = k step (k = 1..=Q) of the spectral evaluation and their trapezoidal
/// weights (step / pi) exp(-h^2 t_k^2). The t = 0 node carries |phi_X(0) - phi_Y(0)|^2 = 0 and
/// is left out.
#[derive(Clone, Debug)]
struct SpectralGrid {
    step: f64,
    center: f64,
    weights: Vec<f64>,
}

impl SpectralGrid {
    /// Nodes for data in [lo, hi] and bandwidth h; None if more than [`MAX_SPECTRAL_NODES`]
    /// would be needed.
    fn new(lo: f64, hi: f64, h: f64) -> Option<Self> {
        let sigma = std::f64::consts::SQRT_2 * h;
        // Circle of circumference range + 6 sigma: the trapezoidal rule with step 2 pi / circle
        // equals T with phi replaced by its wrapped version sum_j phi(d + j circle), and for
        // |d| <= range every alias j != 0 is at least 6 sigma away.
        let circle = (hi - lo) + SPECTRAL_ALIAS_SIGMAS * sigma;
        let step = 2.0 * std::f64::consts::PI / circle;
        let needed = (SPECTRAL_CUTOFF / (h * step)).ceil();
        if needed.is_nan() || needed > MAX_SPECTRAL_NODES as f64 {
            return None;
        }
        let q = (needed as usize).max(1).div_ceil(LANES) * LANES;
        let weights = (1..=q)
            .map(|k| {
                let t = k as f64 * step;
                step / std::f64::consts::PI * f64::exp(-(h * t) * (h * t))
            })
            .collect();
        Some(Self { step, center: 0.5 * (lo + hi), weights })
    }

    fn nodes(&self) -> usize {
        self.weights.len()
    }

    /// Writes exp(i t_k (v - center)), k = 1..=Q, into `row` as [Re_1..Re_Q, Im_1..Im_Q].
    /// Centring does not change T (both ECFs turn by the same phase) and keeps the phases small.
    fn features(&self, v: f64, row: &mut [f64]) {
        let q = self.nodes();
        let (re, im) = row.split_at_mut(q);
        let theta = self.step * (v - self.center);
        let (s1, c1) = theta.sin_cos();
        let (mut c, mut s) = (c1, s1);
        for k in 0..q {
            if k > 0 && k % RESYNC_EVERY == 0 {
                (s, c) = ((k + 1) as f64 * theta).sin_cos();
            }
            re[k] = c;
            im[k] = s;
            (c, s) = (c * c1 - s * s1, s * c1 + c * s1);
        }
    }

    /// Prefix sums of the features of a series: row i (2Q values) is the sum over
    /// values[0..i], so any range sum is one difference of two rows.
    fn prefix_sums(&self, values: &[f64]) -> Vec<f64> {
        let width = 2 * self.nodes();
        let mut prefix = vec![0.0; (values.len() + 1) * width];
        let mut row = vec![0.0; width];
        for (i, &v) in values.iter().enumerate() {
            self.features(v, &mut row);
            let (done, rest) = prefix.split_at_mut((i + 1) * width);
            let previous = &done[i * width..];
            for ((p, &q), &r) in rest[..width].iter_mut().zip(previous).zip(&row) {
                *p = q + r;
            }
        }
        prefix
    }

    /// Mean feature vector (the ECF at the nodes) of `values`.
    fn ecf(&self, values: &[f64]) -> Vec<f64> {
        let width = 2 * self.nodes();
        let mut sum = vec![0.0; width];
        let mut row = vec![0.0; width];
        for &v in values {
            self.features(v, &mut row);
            add_row(&mut sum, &row);
        }
        let inv = 1.0 / values.len() as f64;
        sum.iter_mut().for_each(|s| *s *= inv);
        sum
    }
}

fn add_row(acc: &mut [f64], row: &[f64]) {
    for (a, r) in acc.iter_mut().zip(row) {
        *a += r;
    }
}

/// sum_k w_k |phi_X(t_k) - inv_k * S_Y(t_k)|^2, with S_Y the summed features of a window of
/// 1 / inv_k samples: the trapezoidal T. Four independent accumulators let the compiler keep
/// the reduction in SIMD registers (a single one would serialise on the additions).
fn weighted_gap(phi_x: &[f64], sum_y: &[f64], inv_k: f64, weights: &[f64]) -> f64 {
    let q = weights.len();
    let (xr, xi) = phi_x.split_at(q);
    let (yr, yi) = sum_y.split_at(q);
    let mut acc = [0.0; LANES];
    let chunks = weights
        .chunks_exact(LANES)
        .zip(xr.chunks_exact(LANES).zip(xi.chunks_exact(LANES)))
        .zip(yr.chunks_exact(LANES).zip(yi.chunks_exact(LANES)));
    for ((w, (ar, ai)), (br, bi)) in chunks {
        for l in 0..LANES {
            let dr = ar[l] - inv_k * br[l];
            let di = ai[l] - inv_k * bi[l];
            acc[l] += w[l] * (dr * dr + di * di);
        }
    }
    acc.iter().sum()
}

/// sum_k w_k (|phi(t_k)|^2 - 1): A_XX - phi(0) under the trapezoidal rule (the t = 0 node and
/// the wrapped phi(0) cancel), for the unbiased estimator.
fn weighted_self_excess(phi: &[f64], weights: &[f64]) -> f64 {
    let q = weights.len();
    let (re, im) = phi.split_at(q);
    weights.iter().zip(re.iter().zip(im)).map(|(w, (a, b))| w * (a * a + b * b - 1.0)).sum()
}

fn spectral_parts(x: &[f64], y: &[f64], h: f64) -> Option<MmdParts> {
    let (lo, hi) = min_max(x.iter().chain(y))?;
    let grid = SpectralGrid::new(lo, hi, h)?;
    let phi_x = grid.ecf(x);
    let phi_y = grid.ecf(y);
    Some(MmdParts {
        biased: weighted_gap(&phi_x, &phi_y, 1.0, &grid.weights),
        excess_x: weighted_self_excess(&phi_x, &grid.weights),
        excess_y: weighted_self_excess(&phi_y, &grid.weights),
    })
}

/// Silverman's bandwidth of a reference sample, 0.9 min(sd, IQR / 1.34) n^(-1/5) (Silverman
/// 1986, eq. 3.31; R's `bw.nrd0`). The IQR uses linearly interpolated quantiles (R type 7).
/// If the IQR is 0 (many ties) the sd alone is used, as `bw.nrd0` does.
///
/// Errors if there are fewer than 2 values, a value is not finite, or the sample is constant.
pub fn silverman_bandwidth(reference: &[f64]) -> Result<f64> {
    let n = reference.len();
    if n < 2 {
        return Err(TightscanError::parameter(
            "reference",
            format!("needs at least 2 values for a bandwidth, got {n}"),
        ));
    }
    if let Some(i) = reference.iter().position(|v| !v.is_finite()) {
        return Err(TightscanError::parameter("reference", format!("value {i} is not finite")));
    }
    let nf = n as f64;
    let mean = reference.iter().sum::<f64>() / nf;
    let sd = (reference.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / (nf - 1.0)).sqrt();
    let mut sorted = reference.to_vec();
    sorted.sort_by(f64::total_cmp);
    let iqr = quantile_type7(&sorted, 0.75) - quantile_type7(&sorted, 0.25);
    let spread = if iqr > 0.0 { sd.min(iqr / SILVERMAN_IQR_DIVISOR) } else { sd };
    if spread.is_nan() || spread <= 0.0 {
        return Err(TightscanError::parameter(
            "reference",
            "values are constant: the bandwidth would be 0",
        ));
    }
    Ok(SILVERMAN_FACTOR * spread * nf.powf(-0.2))
}

/// Quantile of a sorted sample by linear interpolation between order statistics (Hyndman and
/// Fan 1996, type 7): position (n - 1) p.
fn quantile_type7(sorted: &[f64], p: f64) -> f64 {
    let pos = (sorted.len() - 1) as f64 * p;
    let lo = pos.floor() as usize;
    let hi = (lo + 1).min(sorted.len() - 1);
    let t = pos - lo as f64;
    sorted[lo] + t * (sorted[hi] - sorted[lo])
}

/// Monte Carlo permutation p-value p = (1 + #{T*_b >= T}) / (B + 1) (Davison and Hinkley 1997,
/// eq. 4.11; Phipson and Smyth 2010): counting the observed statistic among the permuted ones
/// makes P(p <= alpha) <= alpha exactly under exchangeability, for any B. A NaN in `null`
/// counts as exceeding (conservative); a NaN `observed` gives NaN.
pub fn permutation_pvalue(observed: f64, null: &[f64]) -> f64 {
    if observed.is_nan() {
        return f64::NAN;
    }
    let exceed = null.iter().filter(|&&t| t >= observed || t.is_nan()).count();
    (1 + exceed) as f64 / (null.len() + 1) as f64
}

/// Critical value matching [`permutation_pvalue`]: with k the largest integer such that
/// k / (B + 1) <= alpha, it is the k-th largest permuted value, and p <= alpha exactly when the
/// observed statistic is strictly above it. +inf if k = 0 (B too small for this alpha).
pub fn permutation_critical_value(null: &[f64], alpha: f64) -> f64 {
    let k = allowed_exceedances(null.len(), alpha);
    if k == 0 {
        return f64::INFINITY;
    }
    let mut sorted = null.to_vec();
    // Descending, NaN first (a NaN counts as exceeding in the p-value).
    sorted.sort_by(|a, b| match (a.is_nan(), b.is_nan()) {
        (true, false) => std::cmp::Ordering::Less,
        (false, true) => std::cmp::Ordering::Greater,
        _ => b.total_cmp(a),
    });
    sorted[k - 1]
}

/// Largest k with k / (B + 1) <= alpha, computed with the same division as the p-value so the
/// two agree exactly at the boundary (alpha = 0.05, B = 199 gives k = 10).
fn allowed_exceedances(permutations: usize, alpha: f64) -> usize {
    let total = (permutations + 1) as f64;
    let mut k = (alpha * total).floor().max(0.0) as usize;
    k = k.min(permutations + 1);
    while k > 0 && k as f64 / total > alpha {
        k -= 1;
    }
    while k <= permutations && (k + 1) as f64 / total <= alpha {
        k += 1;
    }
    k.min(permutations)
}

/// A block order of a series of length `total`: the first `total mod block_len` samples stay
/// in place, then come the whole blocks of `block_len` consecutive samples in the order
/// `blocks`. Scans read a permuted series through it as a list of contiguous pieces of the
/// original series, so a range of the permuted series costs one prefix-sum difference per
/// block it touches instead of one addition per sample.
#[derive(Clone, Debug)]
struct BlockOrder {
    head: usize,
    block_len: usize,
    blocks: Vec<usize>,
}

impl BlockOrder {
    fn identity(total: usize, block_len: usize) -> Self {
        let block_len = block_len.max(1);
        Self { head: total % block_len, block_len, blocks: (0..total / block_len).collect() }
    }

    /// Uniformly random order of the blocks (Fisher-Yates).
    fn shuffle<R: Rng + ?Sized>(&mut self, rng: &mut R) {
        self.blocks.shuffle(rng);
    }

    /// Cursor at position `pos` of the permuted series.
    fn cursor(&self, pos: usize) -> Cursor {
        let rel = pos.saturating_sub(self.head);
        Cursor { pos, block: rel / self.block_len, offset: rel % self.block_len }
    }

    /// Moves `cursor` forward to position `to` (no-op if it is there already), calling
    /// `f(lo, hi)` with the original index ranges that make up the positions passed, in order;
    /// ranges adjacent in the original series are merged. Scans move their cursors only
    /// forward, so no division is needed per step.
    fn advance(&self, cursor: &mut Cursor, to: usize, mut f: impl FnMut(usize, usize)) {
        let mut pending: Option<(usize, usize)> = None;
        while cursor.pos < to {
            let (lo, hi) = if cursor.pos < self.head {
                let e = to.min(self.head);
                (cursor.pos, e)
            } else {
                let len = (self.block_len - cursor.offset).min(to - cursor.pos);
                let lo = self.head + self.blocks[cursor.block] * self.block_len + cursor.offset;
                cursor.offset += len;
                if cursor.offset == self.block_len {
                    cursor.offset = 0;
                    cursor.block += 1;
                }
                (lo, lo + len)
            };
            cursor.pos += hi - lo;
            pending = match pending {
                Some((plo, phi)) if phi == lo => Some((plo, hi)),
                Some((plo, phi)) => {
                    f(plo, phi);
                    Some((lo, hi))
                }
                None => Some((lo, hi)),
            };
        }
        if let Some((lo, hi)) = pending {
            f(lo, hi);
        }
    }

    /// Calls `f(lo, hi)` with the original index ranges that make up positions [a, b).
    fn pieces(&self, a: usize, b: usize, f: impl FnMut(usize, usize)) {
        let mut cursor = self.cursor(a);
        self.advance(&mut cursor, b, f);
    }
}

/// Position in a block-ordered series: `pos` in the permuted series, and (past the fixed head)
/// the index into `blocks` and the offset inside that block.
#[derive(Clone, Copy, Debug)]
struct Cursor {
    pos: usize,
    block: usize,
    offset: usize,
}

/// A block permutation of 0..n: the series is cut into blocks of `block_len` consecutive
/// indices and the blocks are put in uniformly random order, which keeps the dependence within
/// blocks (the idea of the moving-block bootstrap, Kuensch 1989, Ann. Stat. 17). The
/// n mod `block_len` first indices stay in place: with them fixed the block orders form a
/// group, and B random elements of a group plus the identity make the permutation test exact
/// for any data whose distribution is invariant under that group (Hemerik and Goeman 2018,
/// JRSS B 80), i.i.d. series in particular. `block_len` 0 is treated as 1.
pub fn block_permutation<R: Rng + ?Sized>(n: usize, block_len: usize, rng: &mut R) -> Vec<usize> {
    let mut order = BlockOrder::identity(n, block_len);
    order.shuffle(rng);
    let mut indices = Vec::with_capacity(n);
    order.pieces(0, n, |lo, hi| indices.extend(lo..hi));
    indices
}

/// Block length (and default window stride) used when none is given: round(N^(1/3)), the
/// order that balances the bias and variance of block resampling for the variance of smooth
/// statistics (Hall, Horowitz and Jing 1995, Biometrika 82).
pub fn default_block_len(n: usize) -> usize {
    ((n as f64).cbrt().round() as usize).max(1)
}

/// Test windows Y of the scan; X is always the training window r[0..training).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KdeWindow {
    /// Y = r[training..end) for every evaluated end >= training + `min_len`: grows with the
    /// series, like sequential monitoring; best for persistent changes.
    Growing {
        /// Smallest test window (at least 2).
        min_len: usize,
    },
    /// Y = r[end - width..end) for every evaluated end >= training + width: for transient
    /// (intermittent) changes that a growing window would dilute.
    Sliding {
        /// Window width (at least 2).
        width: usize,
    },
    /// One window, Y = r[training..N): the plain two-sample permutation test.
    Whole,
}

/// Configuration of [`kde_change_test`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KdeTestConfig {
    /// False-alarm probability of the whole scan, in (0, 1).
    pub alpha: f64,
    /// Number B of permutations. Make alpha (B + 1) an integer (199 or 499 for alpha = 0.05),
    /// else the test is conservative by the rounding.
    pub permutations: usize,
    /// Block length L of the block permutation; None chooses round(N^(1/3))
    /// ([`default_block_len`]). Some(1) is the plain permutation, as exact and more powerful
    /// for i.i.d. residuals. With dependent residuals the blocks keep only lags inside a
    /// block: for lag-1 autocorrelation rho (AR(1)-like) the long-run variance of the
    /// statistic's leading, mean-like component is seen short by 2 rho / (L (1 - rho^2)), and
    /// the size is about P(chi2_1 > chi2_1(1 - alpha) (1 - 2 rho / (L (1 - rho^2)))): 6.8 % at
    /// alpha = 0.05, rho = 0.5, L = 10, and 5.4 % at L = 40 (measured 6.3 % and 5.5 % at
    /// N = 1,000; without blocks 24 %). Strongly dependent residuals need L well above
    /// N^(1/3). Blocks cost power: a change makes the blocks internally homogeneous, which
    /// inflates the permutation null like dependence would (critical value 4.5 instead of
    /// 2.2 for a 1.5 sd step, L = 8 vs 1, in the tests), delaying `alarm_end`.
    pub block_len: Option<usize>,
    /// Test windows.
    pub window: KdeWindow,
    /// Evaluate every `stride`-th window end (the series end always); None chooses
    /// round(N^(1/3)). Each permutation costs O((N / L + windows) Q) with the block prefix
    /// sums, so the stride sets the cost; the price is a detection time known to `stride`
    /// samples. The change-start estimate stays per sample.
    pub stride: Option<usize>,
    /// Weight exponent of the window sizes, in [0, 1/2]: window k enters the maximum as
    /// S_k (k / (n + k))^(1 - 2 gamma). It is the gamma of the monitoring boundary
    /// g(m, k) = c sqrt(m) (1 + k/m) (k/(m + k))^gamma of METHODS.md section 3: for the
    /// mean-like component of T, S_k is Q^2 / Var(Q) and Q^2 / g^2 = S_k (k/(m+k))^(1-2 gamma)
    /// / c^2. gamma = 1/2 weighs all windows alike, which is fastest for early changes but
    /// lets the many short, nearly independent windows raise the critical value (the
    /// Darling-Erdos effect); smaller gamma discounts short windows. It matters for growing
    /// windows only (sliding windows share one length). Power against a 0.5 sd shift at the
    /// middle of N = 400 (training 100): 0.42, 0.38, 0.33, 0.26 at gamma = 0, 0.25, 0.4, 0.5;
    /// the default 0.25 is section 3's reference value.
    pub gamma: f64,
    /// Seed of the permutations (xoshiro256++).
    pub seed: u64,
}

impl Default for KdeTestConfig {
    fn default() -> Self {
        Self {
            alpha: 0.05,
            permutations: 199,
            block_len: None,
            window: KdeWindow::Growing { min_len: 20 },
            stride: None,
            gamma: 0.25,
            seed: 0,
        }
    }
}

/// Outcome of [`kde_change_test`]. Windows are half-open index ranges [start, end) into the
/// residual series.
#[derive(Clone, Debug, PartialEq)]
pub struct KdeTestResult {
    /// Test quantity: max over windows of S_k (k / (n + k))^(1 - 2 gamma), with
    /// S_k = (n k / (n + k)) T the standardised statistic, n the training length, k the window
    /// length, T the biased MMD^2. Under H0 E T = (1/n + 1/k)(phi(0) - E phi(X - X'))
    /// exactly for i.i.d. data and S_k tends to one weighted sum of chi-squares whatever n and
    /// k (Gretton et al. 2012), so S_k has one null law for all window sizes (checked in the
    /// tests: mean, sd and 95 % point agree for k = 20 and k = 300).
    pub statistic: f64,
    /// Permutation p-value (1 + #{S*_b >= S}) / (B + 1) of the maximum.
    pub p_value: f64,
    /// p_value <= alpha.
    pub alarm: bool,
    /// Critical value of the maximum ([`permutation_critical_value`]): alarm iff
    /// statistic > critical_value.
    pub critical_value: f64,
    /// Start of the window where the maximum occurred.
    pub peak_start: usize,
    /// End (exclusive) of the window where the maximum occurred.
    pub peak_end: usize,
    /// Start of the first window whose S exceeds the critical value (Some iff alarm). For
    /// sliding windows it bounds the change start from below: a window that exceeds must
    /// contain changed data. For growing windows it is the training end.
    pub alarm_start: Option<usize>,
    /// End of that window: the detection time, the first evaluated end at which the scan,
    /// read as a sequential procedure with boundary `critical_value`, would have stopped.
    pub alarm_end: Option<usize>,
    /// Estimated change start (Some iff alarm): argmax over c in [training, alarm_end - 10]
    /// of S (unweighted) between the training window and r[c..alarm_end). Under a
    /// step change at c0 its expectation grows with the pure post-change samples for c >= c0
    /// and is diluted by pre-change ones for c < c0, so it peaks at c0 (the logic of the
    /// CUSUM's last-zero estimate).
    pub change_start: Option<usize>,
    /// Bandwidth h, from the training window by Silverman's rule, fixed under permutation.
    pub bandwidth: f64,
    /// Block length used.
    pub block_len: usize,
    /// Window-end stride used.
    pub stride: usize,
    /// Number of windows in the maximum.
    pub windows_evaluated: usize,
    /// Number of spectral nodes Q (cost per window).
    pub spectral_nodes: usize,
}

/// Windows of the scan, in order of their ends (starts are non-decreasing too).
struct WindowPlan {
    starts: Vec<usize>,
    ends: Vec<usize>,
    /// n k / (n + k).
    scale: Vec<f64>,
}

fn plan_windows(
    total: usize,
    training: usize,
    window: KdeWindow,
    stride: usize,
    gamma: f64,
) -> Result<WindowPlan> {
    let available = total - training;
    let (first_end, width) = match window {
        KdeWindow::Growing { min_len } => {
            if min_len < 2 || min_len > available {
                return Err(TightscanError::parameter(
                    "min_len",
                    format!("must be in [2, {available}] (samples after training), got {min_len}"),
                ));
            }
            (training + min_len, None)
        }
        KdeWindow::Sliding { width } => {
            if width < 2 || width > available {
                return Err(TightscanError::parameter(
                    "width",
                    format!("must be in [2, {available}] (samples after training), got {width}"),
                ));
            }
            (training + width, Some(width))
        }
        KdeWindow::Whole => (total, None),
    };
    let mut ends: Vec<usize> = (first_end..=total).step_by(stride).collect();
    if ends.last() != Some(&total) {
        ends.push(total);
    }
    let starts: Vec<usize> = ends.iter().map(|&e| width.map_or(training, |w| e - w)).collect();
    let n = training as f64;
    let scale = starts
        .iter()
        .zip(&ends)
        .map(|(&s, &e)| {
            let k = (e - s) as f64;
            n * k / (n + k) * (k / (n + k)).powf(1.0 - 2.0 * gamma)
        })
        .collect();
    Ok(WindowPlan { starts, ends, scale })
}

/// acc += P[hi] - P[lo]: the summed features of original samples lo..hi.
fn add_range(acc: &mut [f64], prefix: &[f64], width: usize, lo: usize, hi: usize) {
    let p_lo = &prefix[lo * width..(lo + 1) * width];
    let p_hi = &prefix[hi * width..(hi + 1) * width];
    for ((a, u), v) in acc.iter_mut().zip(p_hi).zip(p_lo) {
        *a += u - v;
    }
}

/// acc -= P[hi] - P[lo].
fn sub_range(acc: &mut [f64], prefix: &[f64], width: usize, lo: usize, hi: usize) {
    let p_lo = &prefix[lo * width..(lo + 1) * width];
    let p_hi = &prefix[hi * width..(hi + 1) * width];
    for ((a, u), v) in acc.iter_mut().zip(p_hi).zip(p_lo) {
        *a -= u - v;
    }
}

/// The scan over one block order of the series, on prefix sums of the spectral features.
struct SpectralScan<'a> {
    /// P[i] = sum of the features of samples 0..i, (N + 1) rows of 2Q.
    prefix: &'a [f64],
    weights: &'a [f64],
    width: usize,
    training: usize,
    plan: &'a WindowPlan,
    phi_x: Vec<f64>,
    sum_y: Vec<f64>,
}

impl<'a> SpectralScan<'a> {
    fn new(prefix: &'a [f64], weights: &'a [f64], training: usize, plan: &'a WindowPlan) -> Self {
        let width = 2 * weights.len();
        Self {
            prefix,
            weights,
            width,
            training,
            plan,
            phi_x: vec![0.0; width],
            sum_y: vec![0.0; width],
        }
    }

    /// Max of S over the windows of the series read in block order `order`; fills `profile`
    /// (one S per window) when given. The training ECF costs one prefix difference per block,
    /// each window O(Q) plus one prefix difference per block its head or tail crosses.
    fn run(&mut self, order: &BlockOrder, mut profile: Option<&mut [f64]>) -> f64 {
        let (prefix, width) = (self.prefix, self.width);
        self.phi_x.fill(0.0);
        self.sum_y.fill(0.0);
        let phi_x = &mut self.phi_x;
        let mut head = order.cursor(0);
        order.advance(&mut head, self.training, |lo, hi| add_range(phi_x, prefix, width, lo, hi));
        let inv_n = 1.0 / self.training as f64;
        phi_x.iter_mut().for_each(|v| *v *= inv_n);
        let sum_y = &mut self.sum_y;
        let mut tail = head;
        let mut best = f64::NEG_INFINITY;
        for j in 0..self.plan.ends.len() {
            let (start, end) = (self.plan.starts[j], self.plan.ends[j]);
            order.advance(&mut head, end, |lo, hi| add_range(sum_y, prefix, width, lo, hi));
            order.advance(&mut tail, start, |lo, hi| sub_range(sum_y, prefix, width, lo, hi));
            let inv_k = 1.0 / (end - start) as f64;
            let s = self.plan.scale[j] * weighted_gap(&self.phi_x, sum_y, inv_k, self.weights);
            if let Some(p) = profile.as_deref_mut() {
                p[j] = s;
            }
            best = best.max(s);
        }
        best
    }

    /// Change-start estimate on the original order (phi_x must hold the observed training
    /// ECF, as after `run` on the identity order): argmax over c of S between the training
    /// window and r[c..end), for segments of at least `min_segment` samples.
    fn change_start(&mut self, end: usize, min_segment: usize) -> usize {
        let n = self.training as f64;
        let (mut best, mut best_c) = (f64::NEG_INFINITY, self.training);
        for c in (self.training..=end - min_segment).rev() {
            self.sum_y.fill(0.0);
            add_range(&mut self.sum_y, self.prefix, self.width, c, end);
            let k = (end - c) as f64;
            let t = weighted_gap(&self.phi_x, &self.sum_y, 1.0 / k, self.weights);
            let s = n * k / (n + k) * t;
            if s > best {
                (best, best_c) = (s, c);
            }
        }
        best_c
    }
}

/// Scan for a change in the distribution of `residuals` after the first `training` values
/// (METHODS.md sections 4 and 5).
///
/// X = r[0..training) is the reference; for each test window Y (see [`KdeWindow`]) the biased
/// MMD^2 T(X, Y) with Silverman's bandwidth of X is standardised to S_k = (n k / (n + k)) T,
/// weighted by (k / (n + k))^(1 - 2 gamma) (see [`KdeTestConfig::gamma`]), and the test
/// quantity is the maximum over windows. Its null distribution comes from B block
/// permutations of the whole series ([`block_permutation`]), each rescanned with the same
/// bandwidth and windows, so the probability of any false alarm over the whole scan is at most
/// alpha (exactly, for exchangeable residuals; approximately, for weakly dependent ones).
///
/// T is evaluated spectrally (see the module documentation) on prefix sums of the per-sample
/// features exp(i t_k r): a permutation costs O((N / L + windows) Q), Q the node count (about
/// 0.64 (range / h + 8.5), typically 16-32). With the defaults (B = 199, L = stride =
/// round(N^(1/3))) a series of 1,000 residuals takes about 1 ms on one core; stride 1 about
/// 3-6 ms (`kde_timing` in the tests prints the figures).
///
/// Errors (InvalidParameter) for: non-finite residuals, training < 2 or fewer than 2 samples
/// after it, alpha outside (0, 1), B with alpha (B + 1) < 1 (no p-value could reach alpha),
/// block length 0 or giving fewer than 2 blocks, stride 0, window sizes out of range, constant
/// training residuals, or a residual range above ~1,600 bandwidths ([`MAX_SPECTRAL_NODES`]).
pub fn kde_change_test(
    residuals: &[f64],
    training: usize,
    config: &KdeTestConfig,
) -> Result<KdeTestResult> {
    let total = residuals.len();
    if let Some(i) = residuals.iter().position(|v| !v.is_finite()) {
        return Err(TightscanError::parameter("residuals", format!("value {i} is not finite")));
    }
    if training < 2 || training + 2 > total {
        return Err(TightscanError::parameter(
            "training",
            format!("needs >= 2 samples and >= 2 after it; got {training} of {total}"),
        ));
    }
    if !(config.alpha > 0.0 && config.alpha < 1.0) {
        return Err(TightscanError::parameter(
            "alpha",
            format!("must be in (0, 1), got {}", config.alpha),
        ));
    }
    let b = config.permutations;
    if allowed_exceedances(b, config.alpha) == 0 {
        return Err(TightscanError::parameter(
            "permutations",
            format!(
                "{b} permutations cannot give a p-value <= {} (smallest is 1/(B+1))",
                config.alpha
            ),
        ));
    }
    let block_len = config.block_len.unwrap_or_else(|| default_block_len(total));
    if block_len == 0 || total / block_len < 2 {
        return Err(TightscanError::parameter(
            "block_len",
            format!("must be >= 1 and give >= 2 blocks of {total} samples, got {block_len}"),
        ));
    }
    let stride = config.stride.unwrap_or_else(|| default_block_len(total));
    if stride == 0 {
        return Err(TightscanError::parameter("stride", "must be >= 1"));
    }
    if !(0.0..=0.5).contains(&config.gamma) {
        return Err(TightscanError::parameter(
            "gamma",
            format!("must be in [0, 0.5], got {}", config.gamma),
        ));
    }
    let plan = plan_windows(total, training, config.window, stride, config.gamma)?;
    let h = silverman_bandwidth(&residuals[..training]).map_err(|_| {
        TightscanError::parameter("training", "training residuals are constant: no bandwidth")
    })?;
    let (lo, hi) = min_max(residuals.iter()).unwrap_or((0.0, 0.0));
    let grid = SpectralGrid::new(lo, hi, h).ok_or_else(|| {
        TightscanError::parameter(
            "residuals",
            format!(
                "range {:.3e} is {:.0} bandwidths wide; the scan supports up to ~1,600 \
                 ({MAX_SPECTRAL_NODES} spectral nodes)",
                hi - lo,
                (hi - lo) / h,
            ),
        )
    })?;
    let prefix = grid.prefix_sums(residuals);
    let mut scan = SpectralScan::new(&prefix, &grid.weights, training, &plan);

    let mut order = BlockOrder::identity(total, block_len);
    let mut profile = vec![0.0; plan.ends.len()];
    let statistic = scan.run(&order, Some(&mut profile));
    // The observed training ECF, for the change-start estimate below.
    let observed_phi_x = scan.phi_x.clone();

    let mut rng = Xoshiro256PlusPlus::seed_from_u64(config.seed);
    let null: Vec<f64> = (0..b)
        .map(|_| {
            order.shuffle(&mut rng);
            scan.run(&order, None)
        })
        .collect();
    let p_value = permutation_pvalue(statistic, &null);
    let critical_value = permutation_critical_value(&null, config.alpha);
    let alarm = p_value <= config.alpha;

    let peak = profile
        .iter()
        .enumerate()
        .fold(0, |best, (j, &s)| if s > profile[best] { j } else { best });
    let first = if alarm { profile.iter().position(|&s| s > critical_value) } else { None };
    let change_start = first.map(|j| {
        let end = plan.ends[j];
        scan.phi_x = observed_phi_x;
        scan.change_start(end, CHANGE_MIN_SEGMENT.min(end - training))
    });
    Ok(KdeTestResult {
        statistic,
        p_value,
        alarm,
        critical_value,
        peak_start: plan.starts[peak],
        peak_end: plan.ends[peak],
        alarm_start: first.map(|j| plan.starts[j]),
        alarm_end: first.map(|j| plan.ends[j]),
        change_start,
        bandwidth: h,
        block_len,
        stride,
        windows_evaluated: plan.ends.len(),
        spectral_nodes: grid.nodes(),
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)] // a failed unwrap is a failed test
mod tests;
