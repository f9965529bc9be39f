//! The configuration of the per-tightening analysis: one plain struct per detector and per
//! physics step, gathered in [`DetectConfig`]. Validation and the thresholds these settings
//! imply live in [`super::Detector::new`].

use crate::engine::decision::DecisionConfig;
use crate::physics::phases::YieldConfig;
use crate::physics::torque_rate::{BlockConfig, ElasticZoneConfig};

/// Two-sided CUSUM settings, in sigma units of the standardised block torque rate.
#[derive(Clone, Debug, PartialEq)]
pub struct CusumConfig {
    /// Drift (reference value); kappa = delta/2 is optimal for a shift of delta sigma.
    pub kappa: f64,
    /// In-control average run length, in blocks, that sets one threshold for every tightening
    /// (Siegmund). `None`: each tightening's threshold is the one at which the CUSUM alarms
    /// within its monitored blocks with probability equal to the CUSUM's share of alpha (the
    /// exact finite-horizon probability, `detectors::cusum::cusum_false_alarm_probabilities`).
    pub arl0: Option<f64>,
    /// Explicit threshold h; overrides `arl0` when set.
    pub threshold: Option<f64>,
}

impl Default for CusumConfig {
    fn default() -> Self {
        Self { kappa: 0.5, arl0: None, threshold: None }
    }
}

/// Joint data for the friction coefficient, used where the table has no column of that name
/// (a column value, when present and not null, wins over these).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FrictionConfig {
    /// ISO thread designation for every tightening, e.g. "M8" or "M10x1.25".
    pub thread: Option<String>,
    /// Pitch P \[mm\], overriding the thread table.
    pub pitch_mm: Option<f64>,
    /// Pitch diameter d2 \[mm\], overriding the thread table.
    pub d2_mm: Option<f64>,
    /// Effective bearing diameter Dkm \[mm\], overriding the thread table.
    pub dkm_mm: Option<f64>,
    /// Joint stiffness \[kN/deg\]: gives `mu_tot` from the torque rate without clamp force.
    pub joint_stiffness: Option<f64>,
}

/// The sup-LR break scan of the elastic line (see [`crate::detectors::breakpoint`]).
#[derive(Clone, Debug, PartialEq)]
pub struct BreakConfig {
    /// False-alarm probability per tightening of the scan alone; `None`: its share of the
    /// decision rule's alpha.
    pub alpha: Option<f64>,
    /// Smallest credited torque jump, in torque steps of one encoder increment (G r); a
    /// quantised angle makes jumps of one step (see `break_row`). 0 disables the check.
    pub min_jump_steps: f64,
    /// Share of the break detector's alpha given to the end-of-window test
    /// ([`crate::detectors::breakpoint::tail_test`]); the scan keeps the rest. 0 switches the tail test off.
    pub tail_fraction: f64,
    /// Share of the break detector's alpha given to the start-of-window test (the end test run
    /// backwards: the first samples against the line fitted after them); 0 switches it off.
    pub head_fraction: f64,
    /// Share of the break detector's alpha given to the episode scan
    /// ([`crate::detectors::episode`]: a stretch of the window off the line that the line
    /// before and after it shares, as an intermittent friction fault leaves); 0 switches it off.
    /// Where the window's noise is strongly coloured (lag-1 0.7 or more) the scan runs at half
    /// this share and the break scan keeps the rest (`engine/analysis/breaks.rs`,
    /// `EPISODE_STRONG_COLOUR_SHARE`).
    pub episode_fraction: f64,
}

impl Default for BreakConfig {
    fn default() -> Self {
        // A twentieth each is plenty: the end test is there for changes whose last samples
        // deviate by tens of noise sd (a friction rise that makes the tool stop at once), which
        // it finds at any alpha; the scan's power on small mid-window changes is worth the rest.
        // (With a tenth each the scan kept 80 %, and the rule's pooled size over the built-in
        // simulator's noise grid fell to 0.69 %, below 0.7 x alpha; with a twentieth each, 90 %
        // as before the start test, 0.70 %, at the same recall: benches/size_grid.py --quick.)
        // 1.5 steps: at 1.0 the credited false alarms of clean constant-speed curves still had
        // jumps of 1.1-1.5 steps (median 1.24; 178 in 20,000 CST curves), enough to lift the
        // union bound above its nominal rate at small alpha (1.36 x at 0.005). At 1.5 the union
        // bound holds at every alpha measured (0.82 x at 0.005); recall of 3-5 % changes went
        // from 99.5 % to 99.1 % (12,000 faulty curves).
        // The head test mirrors it for a change in the window's first samples, which the scan
        // cannot isolate either: an abrupt friction change there makes the torque jump by the
        // clamp force times the change of the torque factor (tens of noise sd at 20 % of the
        // rise), which the scan, held ten samples from the window's start, credits to its
        // first admissible split with a poor fit. On the independent generator (CST and HDT,
        // abrupt 15-45 %) 14 of 21 missed changes lay within those first samples.
        // The episode scan gets three tenths: an intermittent episode of 3-15 % friction is a
        // pulse of a few noise sds over a few samples, which needs the alpha; a step or a
        // drift is found by the scan, whose critical value rises by about 0.5 (of 17) for it.
        // Independent generator, 2 kHz, 0.1 deg, white, all fault kinds (1,500 faulty curves):
        // recall of 3-15 % changes 0.849 -> 0.874 (intermittent 3-10 %: 0.744 -> 0.826), of
        // 15-45 % 0.979 -> 0.980; false alarms of the rates x encoders grid unchanged within a
        // curve or two per cell (benches/size_grid.py).
        Self { alpha: None, min_jump_steps: 1.5, tail_fraction: 0.05, head_fraction: 0.05, episode_fraction: 0.3 }
    }
}

/// L1 (sign-residual) sequential monitoring of the elastic line, torque on angle (on clamp
/// force when the table has it), trained on the first `training_fraction` of the window
/// ([`crate::detectors::monitor`]; Huskova and Koubkova 2005).
#[derive(Clone, Debug, PartialEq)]
pub struct L1Config {
    /// Boundary exponent, 0 <= gamma < 1/2 (a table value: 0, 0.1, 0.15, 0.25, 0.35, 0.45, 0.49).
    pub gamma: f64,
    /// False-alarm probability per tightening; `None`: its share of the decision rule's alpha.
    pub alpha: Option<f64>,
}

impl Default for L1Config {
    fn default() -> Self {
        // gamma = 0.25: between the late-change power of gamma = 0 and the early-change speed
        // of gamma near 1/2, whose critical values converge slowly (METHODS.md section 3).
        Self { gamma: 0.25, alpha: None }
    }
}

/// Tests on the residuals of the elastic line: the kernel-density (L2 / MMD) change test and
/// the classical k-sigma chart.
#[derive(Clone, Debug, PartialEq)]
pub struct ResidualTestConfig {
    /// Share of the window's samples, from its start, that forms the reference.
    pub training_fraction: f64,
    /// Run the kernel-density test (about 1 ms per tightening with 199 permutations; off by
    /// default so a batch keeps its speed).
    pub kde: bool,
    /// False-alarm probability per tightening of the kernel-density test; `None`: its share of
    /// the decision rule's alpha.
    pub kde_alpha: Option<f64>,
    /// Permutations of the kernel-density test.
    pub kde_permutations: usize,
    /// Seed of the permutations; tightening `i` of a batch uses `seed + i`.
    pub kde_seed: u64,
    /// Limit of the k-sigma chart (3 for the classical chart).
    pub shewhart_k: f64,
}

impl Default for ResidualTestConfig {
    fn default() -> Self {
        Self { training_fraction: 0.25, kde: false, kde_alpha: None, kde_permutations: 499, kde_seed: 0, shewhart_k: 3.0 }
    }
}

/// The particle-filter fault test ([`crate::detectors::pf`]): opt-in, it costs about
/// `particles` Kalman steps per sample.
#[derive(Clone, Debug, PartialEq)]
pub struct PfDetectConfig {
    /// Run it.
    pub enabled: bool,
    /// Particles of the filter.
    pub particles: usize,
    /// False-alarm probability per tightening; `None`: its share of the decision rule's alpha.
    pub alpha: Option<f64>,
    /// Seed of the filter; tightening `i` of a batch uses `seed + i`, so results do not depend
    /// on the threads.
    pub seed: u64,
    /// Report the posterior mean torque rate after every tested sample (`pf_friction`, a list
    /// per tightening: for plots).
    pub friction_track: bool,
}

impl Default for PfDetectConfig {
    fn default() -> Self {
        Self { enabled: false, particles: 256, alpha: None, seed: 0, friction_track: false }
    }
}

/// Everything `detect` needs.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DetectConfig {
    /// Elastic window finder.
    pub zone: ElasticZoneConfig,
    /// Yield detection.
    pub yield_zone: YieldConfig,
    /// Thread geometry and joint stiffness for `mu_tot`.
    pub friction: FrictionConfig,
    /// Blocks and training window.
    pub blocks: BlockConfig,
    /// CUSUM.
    pub cusum: CusumConfig,
    /// Break scan.
    pub breaks: BreakConfig,
    /// L1 monitoring.
    pub l1: L1Config,
    /// How the detectors decide `change_detected`.
    pub decision: DecisionConfig,
    /// Residual tests (kernel density, k-sigma).
    pub residual_tests: ResidualTestConfig,
    /// Particle-filter fault test.
    pub pf: PfDetectConfig,
}
