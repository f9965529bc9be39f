//! Page's two-sided CUSUM and Siegmund's ARL approximation (METHODS.md section 2).
//!
//! Increments are standardised, z ~ N(mu, 1). Both the drift `kappa` and the threshold `h`
//! are in sigma units. `h` is never a habit: [`cusum_threshold`] derives it from a stated
//! in-control average run length.

use crate::error::{Result, TightscanError};

/// Siegmund's correction of the threshold for the overshoot of a Gaussian random walk:
/// b = h + 2 * 0.583 (Siegmund 1985, Sequential Analysis, eq. 2.56; 0.583 = -zeta(1/2)/sqrt(2 pi)).
pub const SIEGMUND_OVERSHOOT: f64 = 1.166;

/// One-sided ARL of the upper CUSUM S_t = max(0, S_{t-1} + z_t - kappa) with threshold `h`,
/// for increments N(`mu`, 1), by Siegmund's approximation:
/// Delta = mu - kappa, b = h + 1.166,
/// ARL = (exp(-2 Delta b) + 2 Delta b - 1) / (2 Delta^2), and b^2 at Delta = 0.
pub fn siegmund_arl_one_sided(h: f64, kappa: f64, mu: f64) -> f64 {
    let delta = mu - kappa;
    let b = h + SIEGMUND_OVERSHOOT;
    let x = 2.0 * delta * b;
    if x.abs() < 1e-6 {
        // Series of exp(-x) + x - 1 = x^2/2 - x^3/6 + ..., avoids 0/0 at Delta = 0.
        return b * b * (1.0 - x / 3.0);
    }
    (f64::exp(-x) + x - 1.0) / (2.0 * delta * delta)
}

/// ARL of the CUSUM for a mean shift `shift` (sigma units). Two-sided combines the two
/// one-sided schemes as 1/ARL = 1/ARL+ + 1/ARL- (the lower side sees the shift as -shift).
pub fn cusum_arl(h: f64, kappa: f64, shift: f64, two_sided: bool) -> f64 {
    let upper = siegmund_arl_one_sided(h, kappa, shift);
    if !two_sided {
        return upper;
    }
    let lower = siegmund_arl_one_sided(h, kappa, -shift);
    1.0 / (1.0 / upper + 1.0 / lower)
}

/// Threshold `h` (sigma units) whose in-control ARL is `arl0`, by inverting Siegmund's
/// approximation (bisection; the ARL is increasing in h).
pub fn cusum_threshold(arl0: f64, kappa: f64, two_sided: bool) -> Result<f64> {
    if !(kappa.is_finite() && kappa >= 0.0) {
        return Err(TightscanError::parameter("kappa", format!("must be >= 0, got {kappa}")));
    }
    if !arl0.is_finite() {
        return Err(TightscanError::parameter("arl0", format!("must be finite, got {arl0}")));
    }
    let arl = |h: f64| cusum_arl(h, kappa, 0.0, two_sided);
    let floor = arl(0.0);
    if arl0 < floor {
        return Err(TightscanError::parameter(
            "arl0",
            format!("{arl0} is below {floor:.3}, the in-control ARL at h = 0 for kappa = {kappa}"),
        ));
    }
    let (mut lo, mut hi) = (0.0_f64, 1.0_f64);
    while arl(hi) < arl0 {
        hi *= 2.0;
        if hi > 1e6 {
            return Err(TightscanError::parameter("arl0", format!("{arl0} is too large")));
        }
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if arl(mid) < arl0 {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo < 1e-12 {
            break;
        }
    }
    Ok(0.5 * (lo + hi))
}

/// Which side of the two-sided scheme alarmed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CusumSide {
    /// The mean rose (S+ crossed h): friction / torque rate went up.
    Increase,
    /// The mean fell (S- crossed h).
    Decrease,
}

impl CusumSide {
    /// Text used in result tables.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Increase => "increase",
            Self::Decrease => "decrease",
        }
    }
}

/// First alarm of a two-sided CUSUM.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CusumAlarm {
    /// Step (0-based) at which S crossed h.
    pub alarm_step: usize,
    /// Side that crossed.
    pub side: CusumSide,
    /// Change-start estimate: the step after the last one at which that side's S was 0
    /// (the maximum-likelihood change point for a known post-change mean; Page 1954).
    pub change_step: usize,
}

/// Streaming two-sided CUSUM (Page 1954), METHODS.md section 2:
/// S+_t = max(0, S+_{t-1} + z_t - kappa), S-_t = max(0, S-_{t-1} - z_t - kappa), S_0 = 0.
#[derive(Clone, Debug)]
pub struct TwoSidedCusum {
    kappa: f64,
    h: f64,
    s_pos: f64,
    s_neg: f64,
    // Steps after which each side last sat at zero (the change-start candidates).
    zero_pos: usize,
    zero_neg: usize,
    step: usize,
    max_statistic: f64,
    alarm: Option<CusumAlarm>,
}

impl TwoSidedCusum {
    /// New scheme with drift `kappa` and threshold `h`, both in sigma units.
    pub fn new(kappa: f64, h: f64) -> Self {
        Self {
            kappa,
            h,
            s_pos: 0.0,
            s_neg: 0.0,
            zero_pos: 0,
            zero_neg: 0,
            step: 0,
            max_statistic: 0.0,
            alarm: None,
        }
    }

    /// Feeds one standardised increment; returns the first alarm once it has happened.
    /// The recursion keeps running after the alarm so that `max_statistic` covers the whole
    /// series.
    pub fn update(&mut self, z: f64) -> Option<CusumAlarm> {
        let t = self.step;
        self.s_pos = (self.s_pos + z - self.kappa).max(0.0);
        self.s_neg = (self.s_neg - z - self.kappa).max(0.0);
        if self.s_pos == 0.0 {
            self.zero_pos = t + 1;
        }
        if self.s_neg == 0.0 {
            self.zero_neg = t + 1;
        }
        self.max_statistic = self.max_statistic.max(self.s_pos).max(self.s_neg);
        if self.alarm.is_none() {
            // Strict '>' as in METHODS.md; with continuous increments ties have probability 0.
            if self.s_pos > self.h {
                self.alarm = Some(CusumAlarm {
                    alarm_step: t,
                    side: CusumSide::Increase,
                    change_step: self.zero_pos,
                });
            } else if self.s_neg > self.h {
                self.alarm = Some(CusumAlarm {
                    alarm_step: t,
                    side: CusumSide::Decrease,
                    change_step: self.zero_neg,
                });
            }
        }
        self.step += 1;
        self.alarm
    }

    /// First alarm, if any.
    pub fn alarm(&self) -> Option<CusumAlarm> {
        self.alarm
    }

    /// Largest value either side has reached so far.
    pub fn max_statistic(&self) -> f64 {
        self.max_statistic
    }

    /// Threshold in use.
    pub fn threshold(&self) -> f64 {
        self.h
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// Run length (1-based) of the two-sided scheme on N(mu, 1) increments.
    fn run_length(rng: &mut Xoshiro256PlusPlus, kappa: f64, h: f64, mu: f64) -> usize {
        let mut c = TwoSidedCusum::new(kappa, h);
        loop {
            let z: f64 = StandardNormal.sample(rng);
            if let Some(a) = c.update(z + mu) {
                return a.alarm_step + 1;
            }
        }
    }

    fn mean_and_se(xs: &[f64]) -> (f64, f64) {
        let n = xs.len() as f64;
        let m = xs.iter().sum::<f64>() / n;
        let v = xs.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
        (m, (v / n).sqrt())
    }

    // METHODS.md section 2 table: (kappa, h, ARL0 Siegmund, ARL0 MC, delay Siegmund, delay MC).
    const TABLE: [(f64, f64, f64, f64, f64, f64); 3] = [
        (0.5, 4.0, 169.0, 170.8, 8.34, 8.34),
        (0.5, 5.0, 469.1, 476.3, 10.34, 10.31),
        (0.25, 8.0, 368.9, 377.1, 11.33, 11.35),
    ];

    #[test]
    fn siegmund_matches_methods_table() {
        for (kappa, h, arl0, _, delay, _) in TABLE {
            let a = cusum_arl(h, kappa, 0.0, true);
            let d = cusum_arl(h, kappa, 1.0, true);
            assert!((a - arl0).abs() < 0.1, "ARL0 kappa={kappa} h={h}: {a} vs {arl0}");
            assert!((d - delay).abs() < 0.01, "delay kappa={kappa} h={h}: {d} vs {delay}");
        }
        // Delta = 0 branch is continuous with its neighbours.
        let at = siegmund_arl_one_sided(4.0, 0.5, 0.5);
        let near = siegmund_arl_one_sided(4.0, 0.5, 0.5 + 1e-4);
        assert!((at - (4.0_f64 + SIEGMUND_OVERSHOOT).powi(2)).abs() < 1e-9);
        assert!((at - near).abs() < 0.01);
    }

    #[test]
    fn threshold_inverts_arl() {
        for (kappa, h, arl0, ..) in TABLE {
            let exact = cusum_arl(h, kappa, 0.0, true);
            let back = cusum_threshold(exact, kappa, true).unwrap_or(f64::NAN);
            assert!((back - h).abs() < 1e-9, "kappa={kappa}: {back} vs {h} ({arl0})");
        }
        // Two-sided halves the one-sided ARL0, so the same h serves twice the one-sided target.
        let h1 = cusum_threshold(1000.0, 0.5, false).unwrap_or(f64::NAN);
        let h2 = cusum_threshold(500.0, 0.5, true).unwrap_or(f64::NAN);
        assert!((h1 - h2).abs() < 1e-9);
        assert!(cusum_threshold(1.0, 0.5, true).is_err());
        assert!(cusum_threshold(100.0, -1.0, true).is_err());
        assert!(cusum_threshold(f64::NAN, 0.5, true).is_err());
    }

    /// Monte Carlo ARL0 and delay of the recursion itself against METHODS.md's Monte Carlo
    /// values (4,000 runs there; 20,000 here). The tolerance is 4 standard errors of the two
    /// estimates combined, so a recursion with an off-by-one or a wrong sign fails.
    #[test]
    fn monte_carlo_arl_matches_table() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(20261121);
        for (kappa, h, _, arl0_mc, _, delay_mc) in TABLE {
            let runs = 20_000;
            let rl: Vec<f64> =
                (0..runs).map(|_| run_length(&mut rng, kappa, h, 0.0) as f64).collect();
            let (m, se) = mean_and_se(&rl);
            // The table's own MC standard error: run lengths are ~geometric, sd ~ mean.
            let se_table = arl0_mc / (4000.0_f64).sqrt();
            let tol = 4.0 * (se * se + se_table * se_table).sqrt();
            assert!((m - arl0_mc).abs() < tol, "ARL0 kappa={kappa} h={h}: {m} vs {arl0_mc} (tol {tol})");

            let dl: Vec<f64> =
                (0..runs).map(|_| run_length(&mut rng, kappa, h, 1.0) as f64).collect();
            let (m, se) = mean_and_se(&dl);
            let tol = 4.0 * (2.0 * se * se).sqrt() + 0.02;
            assert!((m - delay_mc).abs() < tol, "delay kappa={kappa} h={h}: {m} vs {delay_mc}");
        }
    }

    /// Threshold chosen by `cusum_threshold` delivers its stated ARL0 (within the few percent
    /// by which Siegmund's approximation is known to err, METHODS.md table).
    #[test]
    fn threshold_delivers_stated_arl0() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
        let target = 300.0;
        let h = cusum_threshold(target, 0.5, true).unwrap_or(f64::NAN);
        let rl: Vec<f64> = (0..20_000).map(|_| run_length(&mut rng, 0.5, h, 0.0) as f64).collect();
        let (m, se) = mean_and_se(&rl);
        assert!((m / target - 1.0).abs() < 0.03 + 4.0 * se / target, "{m} vs {target}");
    }

    #[test]
    fn change_start_is_last_zero() {
        let mut c = TwoSidedCusum::new(0.5, 3.0);
        // In control (z = 0) for 10 steps, then +2 per step: S+ grows by 1.5 from step 10.
        let mut alarm = None;
        for t in 0..20 {
            let z = if t < 10 { 0.0 } else { 2.0 };
            alarm = c.update(z);
            if alarm.is_some() {
                break;
            }
        }
        let a = alarm.unwrap_or(CusumAlarm { alarm_step: 0, side: CusumSide::Decrease, change_step: 0 });
        assert_eq!(a.side, CusumSide::Increase);
        assert_eq!(a.change_step, 10);
        // S+ = 1.5 at step 10, 3.0 at 11 (not > 3), 4.5 at 12.
        assert_eq!(a.alarm_step, 12);
    }
}
