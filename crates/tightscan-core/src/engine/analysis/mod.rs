//! The analysis of one tightening, as a short sequence of named steps: check the channels,
//! find the phases and the elastic window, estimate the friction, then run each detector on
//! the window (break scan and end test, residual tests, L1 monitoring, CUSUM of the block
//! torque rates). Each detector step lives in its own file and fills its part of the row.

mod breaks;
mod cusum;
mod friction;
mod l1;
mod residuals;

use crate::engine::input::{ChannelRow, Sample, Samples, TighteningTable};
use crate::engine::rows::{PhaseRow, RowResult};
use crate::engine::schema;
use crate::engine::status::TighteningStatus;
use crate::engine::Detector;
use crate::physics::phases::{find_phases, PhaseScratch, Phases, MIN_FIT_SAMPLES};
use crate::physics::torque_rate::{stop_ranges, Blocks, WindowError};

use friction::FrictionInput;

/// Per-worker scratch space, reused across tightenings.
#[derive(Default)]
pub(super) struct Scratch {
    blocks: Blocks,
    z: Vec<f64>,
    usable: Vec<usize>,
    residuals: Vec<f64>,
    stops: Vec<(f64, f64)>,
    phases: PhaseScratch,
    force: Vec<f64>,
    x: Vec<f64>,
    y: Vec<f64>,
    index: Vec<usize>,
    prefix: Vec<(f64, f64, f64, f64, f64)>,
    line_residuals: Vec<f64>,
    bits: Vec<u64>,
    block_first: Vec<usize>,
    has_force: bool,
    regressor: Vec<f64>,
}


impl Detector {
    pub(super) fn analyse_row(&self, table: &TighteningTable<'_>, i: usize, scratch: &mut Scratch) -> RowResult {
        let (angle, torque) = match (table.angle.row(i), table.torque.row(i)) {
            (ChannelRow::Present { samples: a, .. }, ChannelRow::Present { samples: t, .. }) => (a, t),
            _ => return RowResult::failed(TighteningStatus::NullTightening, 0),
        };
        let n = angle.len();
        let channels = [&table.angle, &table.torque].into_iter().chain(table.optional.iter());
        // Checks run in a fixed order (lengths, nulls, non-finite) so the status names the
        // first problem a person would have to fix.
        let mut rows = Vec::with_capacity(5);
        for c in channels {
            match c.row(i) {
                ChannelRow::Null => {
                    // A missing optional channel is not an error; a null required one is.
                    if c.name == schema::ANGLE || c.name == schema::TORQUE {
                        return RowResult::failed(TighteningStatus::NullTightening, 0);
                    }
                }
                ChannelRow::Present { samples, null_count } => rows.push((c.name, samples, null_count)),
            }
        }
        for &(name, s, _) in &rows {
            if s.len() != n {
                return RowResult::failed(
                    TighteningStatus::LengthMismatch { channel: name, len: s.len(), expected: n },
                    n,
                );
            }
        }
        if n == 0 {
            return RowResult::failed(TighteningStatus::Empty, 0);
        }
        for &(name, _, nulls) in &rows {
            if nulls > 0 {
                return RowResult::failed(TighteningStatus::NullValues { channel: name, count: nulls }, n);
            }
        }
        for &(name, s, _) in &rows {
            let bad = s.non_finite_count();
            if bad > 0 {
                return RowResult::failed(TighteningStatus::NonFinite { channel: name, count: bad }, n);
            }
        }
        if n < self.config.zone.min_samples {
            return RowResult::failed(
                TighteningStatus::TooShort { samples: n, minimum: self.config.zone.min_samples, what: "curve" },
                n,
            );
        }
        let friction = self.friction_input(table, i, scratch);
        match (angle, torque) {
            (Samples::F32(a), Samples::F32(t)) => self.analyse_curve(a, t, friction, i, scratch),
            (Samples::F32(a), Samples::F64(t)) => self.analyse_curve(a, t, friction, i, scratch),
            (Samples::F64(a), Samples::F32(t)) => self.analyse_curve(a, t, friction, i, scratch),
            (Samples::F64(a), Samples::F64(t)) => self.analyse_curve(a, t, friction, i, scratch),
        }
    }

    /// The steps of one curve. A step that fails after the phases are found still reports what
    /// came before it: the phases and the friction estimate need far fewer samples than the
    /// detectors (a short real curve keeps its torque rate).
    fn analyse_curve<A: Sample, T: Sample>(
        &self,
        angle: &[A],
        torque: &[T],
        friction: std::result::Result<FrictionInput, TighteningStatus>,
        row: usize,
        s: &mut Scratch,
    ) -> RowResult {
        let n = angle.len();
        let phases = match self.phases(angle, torque, s) {
            Ok(p) => p,
            Err(status) => return RowResult::failed(status, n),
        };
        let window = phases.window;
        // An unknown thread is named first: it is a fix to the data that applies to every row.
        let (friction_row, friction_status) = match friction {
            Ok(f) => (self.friction_row(torque, &phases, f, s), TighteningStatus::Ok),
            Err(status) => (None, status),
        };
        stop_ranges(angle, torque, window, &mut s.stops);
        let tail_end = phases.yield_angle.is_none().then_some(phases.peak_index);
        let breaks = self.break_row(angle, torque, window, tail_end, s);
        let residual = self.residual_row(angle, &phases.line, row, s);
        let l1 = self.l1_row(angle, s);
        let cusum = self.cusum_row(angle, torque, window, s);
        let status = match &cusum {
            Err(status) if friction_status.is_ok() => status.clone(),
            _ => friction_status,
        };
        RowResult {
            status,
            n_samples: n,
            window: Some((angle[window.start].to_f64(), angle[window.end - 1].to_f64())),
            phases: Some(PhaseRow {
                prevailing_torque: phases.prevailing_torque,
                snug_angle: phases.snug_angle,
                yield_angle: phases.yield_angle,
                peak_torque: phases.peak_torque,
                peak_angle: angle[phases.peak_index].to_f64(),
                torque_rate: phases.torque_rate,
            }),
            friction: friction_row,
            breaks,
            residual,
            l1,
            cusum: cusum.ok(),
            decision: None,
        }
    }

    /// Phases and elastic window, or the status that says why there are none.
    fn phases<A: Sample, T: Sample>(&self, angle: &[A], torque: &[T], s: &mut Scratch) -> Result<Phases, TighteningStatus> {
        let first = angle[0].to_f64();
        if angle.iter().all(|a| a.to_f64() == first) {
            return Err(TighteningStatus::FlatSignal { channel: schema::ANGLE });
        }
        find_phases(angle, torque, &self.config.zone, &self.config.yield_zone, &mut s.phases).map_err(|e| match e {
            WindowError::FlatTorque => TighteningStatus::FlatSignal { channel: schema::TORQUE },
            WindowError::TooShort(len) => {
                TighteningStatus::TooShort { samples: len, minimum: MIN_FIT_SAMPLES, what: "elastic window" }
            }
            WindowError::AngleStuck => {
                TighteningStatus::NoElasticZone { reason: "angle does not advance while torque rises" }
            }
        })
    }
}
