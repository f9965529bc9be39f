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
    let inv = xtx.try_inverse()?;
    let beta = inv * xty;
    let rss: f64 = rows.map(|(x, y)| (y - beta[0] * x[0] - beta[1] * x[1] - beta[2] * x[2]).powi(2)).sum();
    (beta.iter().all(|b| b.is_finite()) && rss.is_finite()).then_some((beta, inv, rss))
}
