//! What each detector computed along one tightening, for plots: the CUSUM paths, the L1
//! monitoring statistic with its boundary, the break scan's likelihood-ratio profile, the
//! residual densities before and after. [`super::Detector::traces`] fills them from the same
//! analysis steps that make a result row (the steps record into [`DetectorTraces`] when asked
//! to), so a trace is of exactly the statistic the decision used: the same window, noise model,
//! whitening, standardisation and thresholds.
//!
//! Every trace has its angle axis [deg]: the angle of the curve's sample where the statistic's
//! evidence is complete (a block's last sample; for the break scan, the first sample of the
//! right segment, the change start the split would report).

/// The two-sided CUSUM of the standardised block torque rates ([`super::analysis`]'s CUSUM step).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CusumTrace {
    /// Angle of each monitored block's last sample.
    pub angle: Vec<f64>,
    /// Standardised block rate fed to the CUSUM (sigma units, after any widening).
    pub z: Vec<f64>,
    /// Upper path S+ after each block.
    pub upper: Vec<f64>,
    /// Lower path S- after each block.
    pub lower: Vec<f64>,
    /// Threshold h: an alarm at the first block where a path exceeds it.
    pub threshold: f64,
    /// Drift kappa.
    pub kappa: f64,
}

/// The L1 sign-residual monitoring of the block torque rates, on the scale of the boundary
/// `g(m, k, gamma) = c sqrt(m) (1 + k/m) (k/(m+k))^gamma`: the statistic is `|Q(m, k)|`, the
/// cumulated signs of the monitored blocks' residuals about the training median (for the
/// location model the alarm rule `Q^2 / m >= g^2 / m` is `|Q| >= g`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct L1Trace {
    /// Angle of each monitored block's last sample (k = 1, 2, ...).
    pub angle: Vec<f64>,
    /// `|Q(m, k)|`.
    pub statistic: Vec<f64>,
    /// `g(m, k, gamma)`.
    pub boundary: Vec<f64>,
    /// Critical value c.
    pub critical_value: f64,
    /// Boundary exponent gamma.
    pub gamma: f64,
    /// Training blocks m.
    pub training: usize,
}

/// The sup-LR break scan's profile: `LR_k = n ln(RSS_0 / (RSS_left,k + RSS_right,k))` for
/// every admissible split k of the whitened window.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BreakTrace {
    /// Angle of each split: halfway between its first right-hand sample and the sample before
    /// it, on the interpolated angle (the change start it would report).
    pub angle: Vec<f64>,
    /// `LR_k`.
    pub lr: Vec<f64>,
    /// The table's critical value at the scan's share of alpha (white noise).
    pub critical_value: f64,
    /// The statistic above which the scan is significant: the critical value, or, where the
    /// noise model's uncertainty widens the test (its predictive p-value), the statistic whose
    /// predictive p-value is the scan's alpha.
    pub decision_value: f64,
    /// Whether the scan was significant (before the encoder-step check on its jump).
    pub significant: bool,
    /// Whether the scan raised the alarm (significant, and a jump beyond an encoder step).
    pub scan_alarm: bool,
    /// Whether the end-of-window test raised the alarm.
    pub tail_alarm: bool,
    /// Whether the start-of-window test raised the alarm.
    pub head_alarm: bool,
    /// The episode scan's best stretch (first and last angle), where one was admissible.
    pub episode: Option<(f64, f64)>,
    /// Whether the episode scan raised the alarm.
    pub episode_alarm: bool,
}

/// Gaussian kernel densities of the elastic line's whitened residuals: the reference (the
/// first `residual_training_fraction` of the tested window) and the part after it the
/// kernel-density test found most different (its peak window; all of the rest when the test
/// is off), with the test's bandwidth (Silverman's, of the reference).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct KdeTrace {
    /// Residual values the densities are evaluated at.
    pub grid: Vec<f64>,
    /// Density of the reference residuals.
    pub before: Vec<f64>,
    /// Density of the residuals after it.
    pub after: Vec<f64>,
    /// Kernel bandwidth.
    pub bandwidth: f64,
    /// Angles of the reference's first and last sample.
    pub before_angles: (f64, f64),
    /// Angles of the compared part's first and last sample.
    pub after_angles: (f64, f64),
    /// Whether the kernel-density test ran (`kde=True`).
    pub tested: bool,
}

/// The traces of one tightening; a detector that could not run leaves its trace `None`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DetectorTraces {
    /// CUSUM paths.
    pub cusum: Option<CusumTrace>,
    /// L1 monitoring.
    pub l1: Option<L1Trace>,
    /// Break scan profile.
    pub breaks: Option<BreakTrace>,
    /// Residual densities.
    pub kde: Option<KdeTrace>,
}

/// Points of the density grid.
pub(super) const DENSITY_POINTS: usize = 200;
