//! The decision rule: which detectors decide `change_detected`, how their alarms combine
//! (any, K-of-n, or a table of detector responses, METHODS.md section 5), how the rule's alpha
//! is split between them (the union bound, not a calibration to any simulator).

use crate::detectors::breakpoint::MIN_SEGMENT;
use crate::engine::rows::{DecisionRow, RowResult};
use crate::engine::status::TighteningStatus;
use crate::engine::Detector;

/// A detector that can take part in the decision rule.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DetectorKind {
    /// sup-LR break scan of the elastic line.
    Break,
    /// L1 sign-residual monitoring.
    L1,
    /// CUSUM of the block torque rate.
    Cusum,
    /// Kernel-density test of the line residuals (needs `residual_tests.kde`).
    Kde,
    /// Particle-filter fault test (needs `pf.enabled`).
    Pf,
}

impl DetectorKind {
    /// Name used in `detectors_fired` and in configurations.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Break => "break",
            Self::L1 => "l1",
            Self::Cusum => "cusum",
            Self::Kde => "kde",
            Self::Pf => "pf",
        }
    }
    /// Parses a name of [`DetectorKind::as_str`].
    pub fn parse(name: &str) -> Option<Self> {
        [Self::Break, Self::L1, Self::Cusum, Self::Kde, Self::Pf].into_iter().find(|k| k.as_str() == name)
    }
    /// Share weight in the rule's alpha split. The break scan gets the largest share: it sees a
    /// change anywhere in the window and is the most powerful of the four on simulated faults
    /// (benches/detection_quality.py); the others mainly add robustness.
    pub(super) fn weight(self) -> f64 {
        match self {
            Self::Break => 3.0,
            Self::L1 | Self::Cusum | Self::Kde | Self::Pf => 1.0,
        }
    }
}

/// How the detectors' alarms combine into `change_detected`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum DecisionRule {
    /// Any detector of the rule fires. With each detector at its share of alpha, the union
    /// bound holds the rule's false-alarm rate at alpha or below (Bonferroni).
    Any,
    /// At least k detectors fire: a subset of `Any`'s alarms, so still at most alpha
    /// (conservative; fewer false alarms, less power).
    AtLeast(usize),
    /// A table of detector responses, one row per pattern: each row names detectors that must
    /// fire (`true`) or stay silent (`false`); detectors it does not name do not matter. A change
    /// is detected when any row matches. Every row must require a detector to fire, so the
    /// table's alarms are a subset of `Any`'s and the rate stays at most alpha. A detector that
    /// could not run counts as silent.
    Table(Vec<Vec<(DetectorKind, bool)>>),
}

/// The decision rule and its false-alarm budget.
#[derive(Clone, Debug, PartialEq)]
pub struct DecisionConfig {
    /// False-alarm probability per tightening of `change_detected`.
    pub alpha: f64,
    /// How alarms combine.
    pub rule: DecisionRule,
    /// Detectors of the rule (others are computed and reported, but do not decide).
    pub detectors: Vec<DetectorKind>,
}

impl Default for DecisionConfig {
    fn default() -> Self {
        // L1 is computed and reported but not in the default rule: inside one curve its
        // boundary, growing like (1 + k/m) over a horizon of three training lengths, needs a
        // sign bias the noisy block rates never reach (recall 0.3 % on simulated faults), and
        // its share of alpha is worth more to the break scan. It is the right tool across
        // tightenings (`monitor_sequence`), where sequences are long.
        Self { alpha: 0.01, rule: DecisionRule::Any, detectors: vec![DetectorKind::Break, DetectorKind::Cusum] }
    }
}

impl DecisionConfig {
    /// Alpha of detector `kind`: its weighted share of `alpha` when it is in the rule (the
    /// union bound: the rule's false-alarm rate is at most `alpha` whatever the data, when each
    /// detector holds its own size), else the whole alpha. No calibration to a simulator: a rule
    /// mapped through a curve measured on our own simulated curves (1.6 x the nominal alpha at
    /// 0.01, to make up for alarms the encoder-step check drops there) ran at 1.4-2.1 % on
    /// curves we did not generate (benches/size_grid.py, independent generator).
    pub fn share(&self, kind: DetectorKind) -> f64 {
        if !self.detectors.contains(&kind) {
            return self.alpha;
        }
        let total: f64 = self.detectors.iter().map(|d| d.weight()).sum();
        self.alpha * kind.weight() / total
    }
}

/// Level of the curvature test that guards a claim: a window is called curved, rather than
/// changed, when its quadratic term is significant at this level and a quadratic fits it at
/// least as well as the best break. Small, so that straight windows are almost never called
/// curved; a real misfit (the plastic joints of ../shared/data) has p far below it.
pub const MISFIT_ALPHA: f64 = 1e-3;

impl Detector {
    /// The status once the rule has decided. A window too short or too gappy for the CUSUM's
    /// blocks is still analysed when another detector of the rule ran (the break scan needs 20
    /// samples, the CUSUM 50): the row is `ok`, and the columns of the detector that could not
    /// run are null. When nothing of the rule ran, a short window names what the least demanding
    /// detector needs.
    pub(super) fn settle_status(&self, row: &mut RowResult) {
        // Misfit is not a change: a claim stands only where the straight elastic line fits, or
        // where a break explains the window better than a smooth curve does (METHODS.md
        // section 5: a test whose null model does not fit rejects every time).
        if let (Some(d), Some(b)) = (&row.decision, &row.breaks) {
            if let Some(p) = b.curvature_p_value {
                if d.detected && p < MISFIT_ALPHA && b.smooth_fits_better {
                    row.decision = None;
                    row.status = TighteningStatus::ModelMisfit { curvature_p_value: p };
                    return;
                }
            }
        }
        if row.decision.is_some() {
            if matches!(row.status, TighteningStatus::TooShort { .. } | TighteningStatus::NoElasticZone { .. }) {
                row.status = TighteningStatus::Ok;
            }
        } else if let TighteningStatus::TooShort { minimum, what, .. } = &mut row.status {
            if what.starts_with("elastic window") && self.config.decision.detectors.contains(&DetectorKind::Break) {
                // The break scan needs two minimum segments of whitened samples, and whitening
                // takes the autoregression's order from the front.
                *minimum = (*minimum).min(2 * MIN_SEGMENT + row.noise_order);
            }
        }
    }

    /// The decision rule over the detectors that could run. `None` when none of the rule's
    /// detectors ran (the tightening could not be analysed).
    pub(super) fn decide(&self, r: &RowResult) -> Option<DecisionRow> {
        let d = &self.config.decision;
        // (ran, fired, change start) per detector, in order of how well each places the change:
        // the break scan's arg max is good to a sample, L1 and CUSUM give the alarm time.
        let state = |kind: DetectorKind| -> Option<(bool, Option<(usize, f64)>)> {
            match kind {
                DetectorKind::Break => r.breaks.map(|b| (b.alarm, Some((b.change_index, b.change_angle)))),
                DetectorKind::L1 => r.l1.map(|l| (l.alarm_index.is_some(), l.alarm_index.zip(l.alarm_angle))),
                DetectorKind::Kde => r.residual.and_then(|k| k.kde).map(|k| (k.alarm, k.change_index.zip(k.change_angle))),
                DetectorKind::Pf => r.pf.as_ref().map(|p| (p.alarm, p.onset.map(|o| (o.index, o.angle)))),
                DetectorKind::Cusum => r.cusum.as_ref().map(|c| {
                    (c.alarm.is_some(), c.alarm.as_ref().map(|a| (a.change_index, a.change_angle)))
                }),
            }
        };
        let order = [DetectorKind::Break, DetectorKind::L1, DetectorKind::Kde, DetectorKind::Pf, DetectorKind::Cusum];
        let fired: Vec<&str> = order.iter().filter(|&&k| state(k).is_some_and(|s| s.0)).map(|k| k.as_str()).collect();
        let in_rule: Vec<DetectorKind> = order.iter().copied().filter(|k| d.detectors.contains(k)).collect();
        if in_rule.iter().all(|&k| state(k).is_none()) {
            return None;
        }
        let fires = |k: DetectorKind| state(k).is_some_and(|s| s.0);
        let count = in_rule.iter().filter(|&&k| fires(k)).count();
        // The detectors whose alarms place the change: all of the rule's, or those the matching
        // row of the table requires to fire.
        let (detected, matched_row) = match &d.rule {
            DecisionRule::Any => (count >= 1, None),
            DecisionRule::AtLeast(k) => (count >= *k, None),
            DecisionRule::Table(rows) => {
                let row = rows.iter().find(|row| row.iter().all(|&(k, want)| fires(k) == want));
                (row.is_some(), row)
            }
        };
        let locates = |k: DetectorKind| matched_row.map_or(in_rule.contains(&k), |row| row.contains(&(k, true)));
        let change = if detected {
            order.iter().filter(|&&k| locates(k)).filter_map(|&k| state(k).filter(|s| s.0).and_then(|s| s.1)).next()
        } else {
            None
        };
        Some(DecisionRow { detected, change, fired: fired.join(",") })
    }
}
