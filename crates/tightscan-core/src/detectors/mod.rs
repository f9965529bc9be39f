//! Change detectors and their critical values. Each works on plain slices (a series, a line's
//! residuals, block torque rates) and knows nothing of Arrow or of tightenings: the engine
//! feeds them. A new detector goes here, with its size and power tests beside it, and joins
//! the decision rule in [`crate::engine::decision`].

pub mod breakpoint;
pub mod critical_values;
pub mod cusum;
pub mod episode;
pub mod gls_breakpoint;
pub mod kde;
pub mod monitor;
pub mod noise;
pub mod pf;
pub mod sequence;
pub mod shewhart;

/// Intercept and slope of the least-squares line through `x`, `y` (slope 0 when `x` is flat):
/// the local lines of the noise model and the engine's lines through a window alike.
pub fn least_squares_line(x: &[f64], y: &[f64]) -> (f64, f64) {
    least_squares_line_through(x.iter().copied().zip(y.iter().copied()))
}

/// [`least_squares_line`] through the points of an iterator (points that are not one slice:
/// the samples either side of an episode).
pub fn least_squares_line_through<I>(points: I) -> (f64, f64)
where
    I: Iterator<Item = (f64, f64)> + Clone,
{
    let (n, sx, sy) = points.clone().fold((0.0, 0.0, 0.0), |(n, sx, sy), (x, y)| (n + 1.0, sx + x, sy + y));
    let (mx, my) = (sx / n, sy / n);
    let (mut sxx, mut sxy) = (0.0, 0.0);
    for (xi, yi) in points {
        sxx += (xi - mx) * (xi - mx);
        sxy += (xi - mx) * (yi - my);
    }
    let b = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    (my - b * mx, b)
}

/// Least squares of `y` on three regressors, from `rows` of (regressors, y): the coefficients,
/// (X'X)^-1 and the residual sum of squares, or `None` where X'X is singular or the fit not
/// finite. The engine's curvature, drift, level-shift and knot fits alike.
pub fn least_squares_3<I>(rows: I) -> Option<(nalgebra::Vector3<f64>, nalgebra::Matrix3<f64>, f64)>
where
    I: Iterator<Item = ([f64; 3], f64)> + Clone,
{
    let mut xtx = nalgebra::Matrix3::<f64>::zeros();
    let mut xty = nalgebra::Vector3::<f64>::zeros();
    for (x, y) in rows.clone() {
        let row = nalgebra::Vector3::from(x);
        xtx += row * row.transpose();
        xty += row * y;
    }
    least_squares_3_from_sums(xtx, xty, rows)
}

/// [`least_squares_3`] from its sums of products X'X and X'y, summed row by row as it sums them
/// (so the result is the same to the last bit): for fits that share two of their regressors and
/// their sums, as the curvature check's drift knots do.
pub fn least_squares_3_from_sums<I>(xtx: nalgebra::Matrix3<f64>, xty: nalgebra::Vector3<f64>, rows: I) -> Option<(nalgebra::Vector3<f64>, nalgebra::Matrix3<f64>, f64)>
where
    I: Iterator<Item = ([f64; 3], f64)>,
{
    let inv = xtx.try_inverse()?;
    let beta = inv * xty;
    let rss: f64 = rows.map(|(x, y)| (y - beta[0] * x[0] - beta[1] * x[1] - beta[2] * x[2]).powi(2)).sum();
    (beta.iter().all(|b| b.is_finite()) && rss.is_finite()).then_some((beta, inv, rss))
}

#[cfg(test)]
#[allow(clippy::expect_used)] // a failed expect is a failed test
mod tests {
    use super::{least_squares_3, least_squares_3_from_sums};

    /// Sums of products taken separately, each row by row as `least_squares_3` takes them, give
    /// the same fit to the last bit (the curvature check's drift knots rely on it; equality of
    /// floats on purpose).
    #[test]
    fn the_fit_from_sums_is_the_fit_to_the_last_bit() {
        let n = 500;
        let a: Vec<f64> = (0..n).map(|i| 0.7 + (i as f64 * 0.37).sin() * 1e-3).collect();
        let b: Vec<f64> = (0..n).map(|i| i as f64 * 0.013 - 2.0).collect();
        let c: Vec<f64> = (0..n).map(|i| ((i as f64 - 180.0).max(0.0) * 0.01).powi(2)).collect();
        let y: Vec<f64> = (0..n).map(|i| 1.0 + 0.5 * b[i] + 0.2 * c[i] + (i as f64 * 1.7).cos() * 0.03).collect();
        let rows = || (0..n).map(|i| ([a[i], b[i], c[i]], y[i]));
        let direct = least_squares_3(rows()).expect("fits");
        let sum = |f: &dyn Fn(usize) -> f64| (0..n).fold(0.0, |s, i| s + f(i));
        let (aa, ab, ac, bb, bc, cc) = (sum(&|i| a[i] * a[i]), sum(&|i| a[i] * b[i]), sum(&|i| a[i] * c[i]), sum(&|i| b[i] * b[i]), sum(&|i| b[i] * c[i]), sum(&|i| c[i] * c[i]));
        let xtx = nalgebra::Matrix3::new(aa, ab, ac, ab, bb, bc, ac, bc, cc);
        let xty = nalgebra::Vector3::new(sum(&|i| a[i] * y[i]), sum(&|i| b[i] * y[i]), sum(&|i| c[i] * y[i]));
        let from_sums = least_squares_3_from_sums(xtx, xty, rows()).expect("fits");
        assert_eq!(direct, from_sums);
    }
}
