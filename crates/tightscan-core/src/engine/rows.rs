//! What the analysis of one tightening found, step by step, before it becomes one row of the
//! result columns ([`super::columns`]). A step that could not run leaves its part `None`, and
//! its columns null.

use crate::detectors::cusum::CusumSide;
use crate::engine::status::TighteningStatus;
use crate::physics::friction::FrictionEstimate;

/// Result of one tightening.
#[derive(Clone, Debug)]
pub(super) struct RowResult {
    pub(super) status: TighteningStatus,
    pub(super) n_samples: usize,
    pub(super) window: Option<(f64, f64)>,
    /// Angle where the samples the detectors test start (later than the window's start after a
    /// controller event inside it).
    pub(super) tested_start: Option<f64>,
    /// Angle of the last window sample the detectors test (earlier than the window's end when a
    /// pause of the tool came too late in it to test after).
    pub(super) tested_end: Option<f64>,
    pub(super) phases: Option<PhaseRow>,
    pub(super) friction: Option<FrictionEstimate>,
    /// Lag-1 autocorrelation of the window's noise model.
    pub(super) noise_lag1: Option<f64>,
    /// Order of the window's noise autoregression: the samples pre-whitening takes from the
    /// front of the window, which the break scan then lacks.
    pub(super) noise_order: usize,
    pub(super) breaks: Option<BreakRow>,
    pub(super) residual: Option<ResidualRow>,
    pub(super) l1: Option<L1Row>,
    pub(super) cusum: Option<CusumRow>,
    pub(super) pf: Option<PfRow>,
    pub(super) decision: Option<DecisionRow>,
}

/// The particle-filter fault test ([`crate::detectors::pf`]).
#[derive(Clone, Debug)]
pub(super) struct PfRow {
    pub(super) alarm: bool,
    pub(super) statistic: f64,
    pub(super) p_value: f64,
    pub(super) fault_probability: f64,
    /// Posterior median of the change and the ends of its 90 % credible interval (given a
    /// change); `None` when no particle is in the fault mode.
    pub(super) onset: Option<PfOnset>,
    /// Posterior mean torque rate after each tested sample (empty unless asked).
    pub(super) friction: Vec<f64>,
}

#[derive(Clone, Copy, Debug)]
pub(super) struct PfOnset {
    pub(super) index: usize,
    pub(super) angle: f64,
    pub(super) lo_angle: f64,
    pub(super) hi_angle: f64,
}

#[derive(Clone, Copy, Debug)]
pub(super) struct L1Row {
    pub(super) alarm_index: Option<usize>,
    pub(super) alarm_angle: Option<f64>,
    pub(super) max_ratio: f64,
    pub(super) statistic_at_alarm: Option<f64>,
    pub(super) boundary_at_alarm: Option<f64>,
    pub(super) gamma: f64,
    pub(super) alpha: f64,
}

#[derive(Clone, Debug)]
pub(super) struct DecisionRow {
    pub(super) detected: bool,
    pub(super) change: Option<(usize, f64)>,
    pub(super) fired: String,
}

#[derive(Clone, Copy, Debug, Default)]
pub(super) struct ResidualRow {
    pub(super) shewhart_alarm: bool,
    pub(super) shewhart_max_abs_z: f64,
    pub(super) shewhart_alarm_index: Option<usize>,
    pub(super) shewhart_alarm_angle: Option<f64>,
    pub(super) kde: Option<KdeRow>,
}

#[derive(Clone, Copy, Debug)]
pub(super) struct KdeRow {
    pub(super) alarm: bool,
    pub(super) statistic: f64,
    pub(super) p_value: f64,
    pub(super) change_index: Option<usize>,
    pub(super) change_angle: Option<f64>,
}

#[derive(Clone, Copy, Debug)]
pub(super) struct BreakRow {
    pub(super) alarm: bool,
    pub(super) statistic: f64,
    pub(super) critical_value: f64,
    pub(super) p_value: f64,
    pub(super) tail_p_value: Option<f64>,
    pub(super) head_p_value: Option<f64>,
    pub(super) episode_p_value: Option<f64>,
    pub(super) change_index: usize,
    pub(super) change_angle: f64,
    pub(super) jump: f64,
    /// Two-sided p-value of the window's curvature, and whether a quadratic fits it at least
    /// as well as the best break (see `break_row`).
    pub(super) curvature_p_value: Option<f64>,
    pub(super) smooth_fits_better: bool,
}

#[derive(Clone, Copy, Debug)]
pub(super) struct PhaseRow {
    pub(super) prevailing_torque: f64,
    pub(super) snug_angle: f64,
    pub(super) yield_angle: Option<f64>,
    pub(super) peak_torque: f64,
    pub(super) peak_angle: f64,
    pub(super) torque_rate: f64,
}

#[derive(Clone, Debug)]
pub(super) struct CusumRow {
    pub(super) alarm: Option<CusumAlarmRow>,
    pub(super) max_statistic: f64,
    pub(super) threshold: f64,
    /// The CUSUM's false-alarm probability for this tightening: its share of alpha plus what
    /// the break scan's encoder-step check left unspent; `None` for a threshold set by hand.
    pub(super) alpha: Option<f64>,
    pub(super) reference_rate: f64,
    pub(super) noise_sd: f64,
    pub(super) noise_df: f64,
    pub(super) dispersion: f64,
    pub(super) blocks: usize,
    pub(super) block_angle: f64,
}

#[derive(Clone, Debug)]
pub(super) struct CusumAlarmRow {
    pub(super) alarm_index: usize,
    pub(super) alarm_angle: f64,
    pub(super) side: CusumSide,
    pub(super) change_index: usize,
    pub(super) change_angle: f64,
}

impl RowResult {
    pub(super) fn failed(status: TighteningStatus, n_samples: usize) -> Self {
        Self {
            status,
            n_samples,
            window: None,
            tested_start: None,
            tested_end: None,
            phases: None,
            friction: None,
            noise_lag1: None,
            noise_order: 0,
            breaks: None,
            residual: None,
            l1: None,
            cusum: None,
            pf: None,
            decision: None,
        }
    }
    pub(super) fn alarm(&self) -> Option<&CusumAlarmRow> {
        self.cusum.as_ref().and_then(|c| c.alarm.as_ref())
    }
}
