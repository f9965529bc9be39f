//! Shewhart k-sigma chart on residuals: the classical baseline (METHODS.md section 5).
//!
//! z_t = (r_t - mean) / sd with mean and sd of the training window; alarm at the first
//! monitored t with |z_t| > k. No run rules. The textbook k = 3 tests each sample at
//! 2 (1 - Phi(3)) = 0.27 %, so over 1,000 in-control samples it alarms falsely with probability
//! 1 - 0.9973^1000 = 93 %: k must come from the false-alarm probability wanted over the whole
//! monitored stretch ([`shewhart_k_for_alpha`]), never by habit.

use crate::error::{Result, TightscanError};

/// The textbook limit, 3 sigma.
pub const THREE_SIGMA: f64 = 3.0;

/// Outcome of [`shewhart_scan`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShewhartResult {
    /// First monitored index (into the whole series) with |z| > k, if any.
    pub alarm_index: Option<usize>,
    /// Largest |z| over the monitored samples.
    pub max_abs_z: f64,
    /// Index (into the whole series) where it occurred.
    pub max_index: usize,
    /// Training mean.
    pub mean: f64,
    /// Training standard deviation (n - 1 denominator).
    pub sd: f64,
    /// Limit k used, in sigmas.
    pub k_sigma: f64,
    /// Number of monitored samples, N - training.
    pub monitored: usize,
}

/// k-sigma chart: standardises `residuals` by the mean and sd of the first `training` values
/// and reports the first later sample with |z| > `k_sigma`.
///
/// Errors if a residual is not finite, training < 2, nothing is left to monitor, the training
/// residuals are constant, or `k_sigma` is not positive and finite.
pub fn shewhart_scan(residuals: &[f64], training: usize, k_sigma: f64) -> Result<ShewhartResult> {
    if let Some(i) = residuals.iter().position(|v| !v.is_finite()) {
        return Err(TightscanError::parameter("residuals", format!("value {i} is not finite")));
    }
    if training < 2 || training >= residuals.len() {
        return Err(TightscanError::parameter(
            "training",
            format!("needs >= 2 samples and >= 1 after it; got {training} of {}", residuals.len()),
        ));
    }
    if !(k_sigma.is_finite() && k_sigma > 0.0) {
        return Err(TightscanError::parameter("k_sigma", format!("must be > 0, got {k_sigma}")));
    }
    let train = &residuals[..training];
    let n = training as f64;
    let mean = train.iter().sum::<f64>() / n;
    let sd = (train.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / (n - 1.0)).sqrt();
    if sd.is_nan() || sd <= 0.0 {
        return Err(TightscanError::parameter("training", "training residuals are constant"));
    }
    let mut result = ShewhartResult {
        alarm_index: None,
        max_abs_z: f64::NEG_INFINITY,
        max_index: training,
        mean,
        sd,
        k_sigma,
        monitored: residuals.len() - training,
    };
    for (i, &r) in residuals.iter().enumerate().skip(training) {
        let z = ((r - mean) / sd).abs();
        if z > result.max_abs_z {
            result.max_abs_z = z;
            result.max_index = i;
        }
        if result.alarm_index.is_none() && z > k_sigma {
            result.alarm_index = Some(i);
        }
    }
    Ok(result)
}

/// Limit k such that a k-sigma chart over `n_monitored` i.i.d. N(mu, sigma^2) samples with known
/// mu and sigma alarms falsely with probability exactly `alpha`: each sample is tested at the
/// Sidak level alpha_1 = 1 - (1 - alpha)^(1/N), so k = Phi^-1(1 - alpha_1 / 2).
///
/// With mean and sd estimated from m training samples the realised rate is higher, because the
/// tail probability is convex in the estimated limits: about +0.8 percentage points at
/// alpha = 0.05, N = 1,000, m = 500 (see the tests).
pub fn shewhart_k_for_alpha(alpha: f64, n_monitored: usize) -> Result<f64> {
    if !(alpha > 0.0 && alpha < 1.0) {
        return Err(TightscanError::parameter("alpha", format!("must be in (0, 1), got {alpha}")));
    }
    if n_monitored == 0 {
        return Err(TightscanError::parameter("n_monitored", "must be >= 1"));
    }
    // 1 - (1 - alpha)^(1/N) without cancellation for small alpha / large N.
    let per_sample = -f64::exp_m1(f64::ln_1p(-alpha) / n_monitored as f64);
    // Upper quantile through the lower tail, where AS241 keeps full relative precision.
    Ok(-normal_quantile(0.5 * per_sample))
}

/// Standard normal quantile Phi^-1(p) by Wichura's algorithm AS 241 (PPND16, Applied
/// Statistics 37, 1988): rational approximations on three ranges, relative error about 1e-16.
/// -inf at 0, +inf at 1, NaN outside [0, 1].
// The coefficients keep all the digits Wichura published, so they can be checked against the
// paper; the compiler rounds them to the nearest f64.
#[allow(clippy::excessive_precision)]
pub fn normal_quantile(p: f64) -> f64 {
    if p.is_nan() || !(0.0..=1.0).contains(&p) {
        return f64::NAN;
    }
    if p == 0.0 {
        return f64::NEG_INFINITY;
    }
    if p == 1.0 {
        return f64::INFINITY;
    }
    let q = p - 0.5;
    if q.abs() <= 0.425 {
        // Central range 0.075 <= p <= 0.925: a ratio of degree-7 polynomials in 0.180625 - q^2.
        const A: [f64; 8] = [
            3.387_132_872_796_366_608,
            1.331_416_678_917_843_774_5e2,
            1.971_590_950_306_551_442_7e3,
            1.373_169_376_550_946_112_5e4,
            4.592_195_393_154_987_145_7e4,
            6.726_577_092_700_870_085_3e4,
            3.343_057_558_358_812_810_5e4,
            2.509_080_928_730_122_672_7e3,
        ];
        const B: [f64; 8] = [
            1.0,
            4.231_333_070_160_091_125_2e1,
            6.871_870_074_920_579_083_0e2,
            5.394_196_021_424_751_107_7e3,
            2.121_379_430_158_659_586_7e4,
            3.930_789_580_009_271_061_0e4,
            2.872_908_573_572_194_267_4e4,
            5.226_495_278_852_854_561_0e3,
        ];
        let r = 0.180_625 - q * q;
        return q * horner(&A, r) / horner(&B, r);
    }
    // Tails: variable sqrt(-ln(min(p, 1 - p))).
    let tail = if q < 0.0 { p } else { 1.0 - p };
    let r = (-tail.ln()).sqrt();
    let value = if r <= 5.0 {
        // Intermediate tail, down to p ~ 1.4e-11.
        const C: [f64; 8] = [
            1.423_437_110_749_683_577_34,
            4.630_337_846_156_545_295_90,
            5.769_497_221_460_691_405_50,
            3.647_848_324_763_204_605_04,
            1.270_458_252_452_368_382_58,
            2.417_807_251_774_506_117_70e-1,
            2.272_384_498_926_918_458_33e-2,
            7.745_450_142_783_414_076_40e-4,
        ];
        const D: [f64; 8] = [
            1.0,
            2.053_191_626_637_758_821_87,
            1.676_384_830_183_803_849_40,
            6.897_673_349_851_000_045_50e-1,
            1.481_039_764_274_800_745_90e-1,
            1.519_866_656_361_645_719_66e-2,
            5.475_938_084_995_344_946_00e-4,
            1.050_750_071_644_416_843_24e-9,
        ];
        let r = r - 1.6;
        horner(&C, r) / horner(&D, r)
    } else {
        // Far tail.
        const E: [f64; 8] = [
            6.657_904_643_501_103_777_20,
            5.463_784_911_164_114_369_90,
            1.784_826_539_917_291_335_80,
            2.965_605_718_285_048_912_30e-1,
            2.653_218_952_657_612_309_30e-2,
            1.242_660_947_388_078_438_60e-3,
            2.711_555_568_743_487_578_15e-5,
            2.010_334_399_292_288_132_65e-7,
        ];
        const F: [f64; 8] = [
            1.0,
            5.998_322_065_558_879_376_90e-1,
            1.369_298_809_227_358_053_10e-1,
            1.487_536_129_085_061_485_25e-2,
            7.868_691_311_456_132_591_00e-4,
            1.846_318_317_510_054_681_80e-5,
            1.421_511_758_316_445_888_70e-7,
            2.044_263_103_389_939_785_64e-15,
        ];
        let r = r - 5.0;
        horner(&E, r) / horner(&F, r)
    };
    if q < 0.0 {
        -value
    } else {
        value
    }
}

/// c[0] + c[1] x + ... + c[7] x^7.
fn horner(c: &[f64; 8], x: f64) -> f64 {
    c.iter().rev().fold(0.0, |acc, &ci| acc * x + ci)
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)] // a failed unwrap is a failed test
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{ChiSquared, Distribution, StandardNormal};
    use rand_xoshiro::Xoshiro256PlusPlus;
    use rayon::prelude::*;

    /// Standard normal cdf to ~1e-15 relative, independent of AS241: Taylor series
    /// Phi(x) = 1/2 + phi(x) sum x^(2j+1) / (1 3 ... (2j+1)) for |x| <= 3, and the Laplace
    /// continued fraction 1 - Phi(x) = phi(x) / (x + 1/(x + 2/(x + 3/(x + ...)))) beyond.
    fn normal_cdf(x: f64) -> f64 {
        let density = (-0.5 * x * x).exp() / (2.0 * std::f64::consts::PI).sqrt();
        if x.abs() <= 3.0 {
            let (mut term, mut sum) = (x, x);
            let mut j = 1.0;
            while term.abs() > 1e-18 * sum.abs().max(1e-300) {
                term *= x * x / (2.0 * j + 1.0);
                sum += term;
                j += 1.0;
            }
            return 0.5 + density * sum;
        }
        let a = x.abs();
        let mut frac = 0.0;
        for j in (1..400).rev() {
            frac = j as f64 / (a + frac);
        }
        let upper = density / (a + frac);
        if x > 0.0 {
            1.0 - upper
        } else {
            upper
        }
    }

    #[test]
    fn cdf_reference_is_right() {
        // Published values of Phi (Abramowitz and Stegun 26.2; R pnorm).
        for (x, p) in [
            (1.0, 0.841_344_746_068_542_9),
            (-3.0, 0.001_349_898_031_630_094_6),
            (-5.0, 2.866_515_718_791_939e-7),
            (-10.0, 7.619_853_024_160_527e-24),
        ] {
            assert!((normal_cdf(x) / p - 1.0).abs() < 1e-13, "Phi({x}) = {} vs {p}", normal_cdf(x));
        }
    }

    #[test]
    fn quantile_known_values() {
        for (p, z) in [
            (0.5, 0.0),
            (0.975, 1.959_963_984_540_054),
            (0.95, 1.644_853_626_951_472_2),
            (0.9, 1.281_551_565_544_600_4),
            (0.995, 2.575_829_303_548_900_4),
            (0.001_349_898_031_630_094_6, -3.0),
            (2.866_515_718_791_939e-7, -5.0),
            (7.619_853_024_160_527e-24, -10.0),
        ] {
            let got = normal_quantile(p);
            assert!((got - z).abs() < 1e-13 * z.abs().max(1.0), "Phi^-1({p}) = {got} vs {z}");
        }
        assert_eq!(normal_quantile(0.0), f64::NEG_INFINITY);
        assert_eq!(normal_quantile(1.0), f64::INFINITY);
        assert!(normal_quantile(-0.1).is_nan() && normal_quantile(1.5).is_nan());
        assert!(normal_quantile(f64::NAN).is_nan());
    }

    /// Round trip Phi(Phi^-1(p)) = p over all three ranges of AS241, including both sides of
    /// the range switches at |p - 1/2| = 0.425 and r = 5 (p = exp(-25) = 1.4e-11); symmetry.
    #[test]
    fn quantile_round_trip_and_symmetry() {
        let mut ps: Vec<f64> = (1..1000).map(|i| i as f64 / 1000.0).collect();
        ps.extend((1..=300).map(|e| 10f64.powf(-(e as f64) / 10.0)));
        ps.extend([0.075, 0.074_999_999, 0.075_000_001, (-25.0f64).exp() * 1.000_001]);
        ps.extend([1e-50, 1e-100, 1e-200, 1e-300]);
        ps.push((-25.0f64).exp() * 0.999_999);
        for &p in &ps {
            let z = normal_quantile(p);
            let back = normal_cdf(z);
            // Relative error of p from an error dz in z is |z| dz near the tails: allow 1e-13
            // relative in p, i.e. ~1e-15 absolute in z around the centre.
            assert!((back / p - 1.0).abs() < 1e-12, "p = {p:e}: z = {z}, Phi(z) = {back:e}");
        }
        // Symmetry up to the rounding of 1 - p (1.1e-16 absolute, i.e. 1.1e-16 / phi(z) in z).
        for i in 1..1000 {
            let p = i as f64 / 1000.0;
            let gap = normal_quantile(1.0 - p) + normal_quantile(p);
            assert!(gap.abs() < 1e-13, "symmetry at {p}: {gap:e}");
        }
    }

    #[test]
    fn sidak_limit() {
        // alpha over one sample: the two-sided 5 % point.
        let k1 = shewhart_k_for_alpha(0.05, 1).unwrap();
        assert!((k1 - 1.959_963_984_540_054).abs() < 1e-12);
        // 3 sigma corresponds to alpha_1 = 2 (1 - Phi(3)) per sample.
        let a1 = 2.0 * 0.001_349_898_031_630_094_6;
        let k = shewhart_k_for_alpha(a1, 1).unwrap();
        assert!((k - 3.0).abs() < 1e-12, "{k}");
        // Over N samples the per-sample level is 1 - (1 - alpha)^(1/N).
        let k1000 = shewhart_k_for_alpha(0.05, 1000).unwrap();
        let per = 2.0 * normal_cdf(-k1000);
        assert!((1.0 - (1.0 - per).powi(1000) - 0.05).abs() < 1e-12, "{k1000}");
        assert!((k1000 - 4.05).abs() < 0.01);
        assert!(shewhart_k_for_alpha(0.0, 10).is_err());
        assert!(shewhart_k_for_alpha(1.0, 10).is_err());
        assert!(shewhart_k_for_alpha(0.05, 0).is_err());
    }

    #[test]
    fn scan_finds_first_exceedance() {
        let mut r = vec![0.0; 20];
        for (i, v) in r.iter_mut().enumerate().take(10) {
            *v = if i % 2 == 0 { 1.0 } else { -1.0 };
        }
        // Training mean 0, sd sqrt(10/9) = 1.054; 3.2 -> z = 3.04 > 3, 5.0 later is the max.
        r[13] = 3.2;
        r[17] = -5.0;
        let s = shewhart_scan(&r, 10, THREE_SIGMA).unwrap();
        assert_eq!(s.alarm_index, Some(13));
        assert_eq!(s.max_index, 17);
        assert!((s.sd - (10.0f64 / 9.0).sqrt()).abs() < 1e-12);
        assert_eq!(s.monitored, 10);
        let s = shewhart_scan(&r, 10, 4.0).unwrap();
        assert_eq!(s.alarm_index, Some(17));
        assert!(shewhart_scan(&r, 1, 3.0).is_err());
        assert!(shewhart_scan(&r, 20, 3.0).is_err());
        assert!(shewhart_scan(&r, 10, 0.0).is_err());
        assert!(shewhart_scan(&[1.0, 1.0, 2.0], 2, 3.0).is_err());
    }

    /// False-alarm probability of the chart on i.i.d. N(0,1) series, training m, N monitored:
    /// Monte Carlo over `series` series.
    fn false_alarm_rate(seed: u64, series: usize, m: usize, n: usize, k: f64) -> f64 {
        let alarms: usize = (0..series)
            .into_par_iter()
            .map(|s| {
                let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ (s as u64 * 0x9E37_79B9));
                let r: Vec<f64> = (0..m + n).map(|_| StandardNormal.sample(&mut rng)).collect();
                usize::from(shewhart_scan(&r, m, k).unwrap().alarm_index.is_some())
            })
            .sum();
        alarms as f64 / series as f64
    }

    /// Expected false-alarm probability with estimated mean and sd: E[1 - (1 - p(mu, s))^N] with
    /// p(mu, s) = Phi(mu - k s) + 1 - Phi(mu + k s), mu ~ N(0, 1/m), (m - 1) s^2 ~ chi^2_(m-1),
    /// averaged over draws of (mu, s) only (the N samples are integrated exactly).
    fn estimated_parameter_rate(m: usize, n: usize, k: f64) -> f64 {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(99);
        let draws = 100_000;
        let chi2_dist = ChiSquared::new((m - 1) as f64).unwrap();
        let mut total = 0.0;
        for _ in 0..draws {
            let mu: f64 = StandardNormal.sample(&mut rng);
            let mu = mu / (m as f64).sqrt();
            let chi2: f64 = chi2_dist.sample(&mut rng);
            let s = (chi2 / (m - 1) as f64).sqrt();
            let p = normal_cdf(mu - k * s) + normal_cdf(-(mu + k * s));
            total += -f64::exp_m1(n as f64 * f64::ln_1p(-p));
        }
        total / draws as f64
    }

    /// 3 sigma over 1,000 monitored samples alarms falsely ~93 % (1 - 0.9973^1000 = 0.9331 with
    /// known parameters); the Sidak k for alpha = 0.05 holds 5 % +- 1 pp with m = 500 training
    /// samples. Both Monte Carlo rates (4,000 series: standard error 0.34 pp at 5 %, 0.40 pp at
    /// 93 %) must also match the rate expected with estimated mean and sd within 3.5 standard
    /// errors: estimation lowers the 3-sigma rate (it saturates, so the spread of the
    /// estimated limits averages below it) and raises the calibrated one (there the tail is
    /// convex in the limit).
    #[test]
    fn three_sigma_size_versus_calibrated_k() {
        let (m, n, series) = (500, 1000, 4000);
        let known_3 = 1.0 - (1.0 - 2.0 * normal_cdf(-3.0)).powi(n as i32);
        assert!((known_3 - 0.9331).abs() < 5e-4, "{known_3}");
        let k = shewhart_k_for_alpha(0.05, n).unwrap();
        for (seed, limit, nominal, tolerance) in
            [(1, THREE_SIGMA, known_3, 0.02), (2, k, 0.05, 0.01)]
        {
            let rate = false_alarm_rate(seed, series, m, n, limit);
            let expected = estimated_parameter_rate(m, n, limit);
            let se = (expected * (1.0 - expected) / series as f64).sqrt();
            eprintln!(
                "shewhart k = {limit:.4}: false alarms {rate:.4}, expected with estimated \
                 parameters {expected:.4}, with known parameters {nominal:.4}"
            );
            assert!((rate - expected).abs() < 3.5 * se, "k = {limit}: {rate} vs {expected}");
            assert!((rate - nominal).abs() < tolerance, "k = {limit}: {rate} vs {nominal}");
        }
    }
}
