//! The batch engine: one result row per input tightening, in input order, computed in parallel.
//!
//! Arrow in ([`input`] views the channels where they lie, [`schema`] says what they may be),
//! one [`analysis`] per tightening across rayon's threads, the [`decision`] rule over the
//! detectors that ran, a [`status`] for every row, and Arrow out ([`columns`], in the order of
//! the one table of result columns, [`schema::RESULT_COLUMNS`]).

mod analysis;
pub mod columns;
pub mod config;
pub mod decision;
pub mod duplicates;
pub mod input;
mod rows;
pub mod schema;
pub mod status;
#[cfg(test)]
mod trace_tests;
pub mod traces;
#[cfg(test)]
mod tests;

use std::sync::Arc;

use arrow_array::{Array, ArrayRef, Int64Array, RecordBatch};
use arrow_schema::{DataType, Field, Schema, SchemaRef};
use arrow_select::concat::concat_batches;
use rayon::prelude::*;

use crate::detectors::critical_values::critical_value_any_alpha;
use crate::detectors::cusum::{cusum_threshold, cusum_threshold_for_steps};
use crate::error::{Result, TightscanError};
use crate::physics::thread::parse_thread;
use analysis::{CusumCalibration, Scratch, ThresholdSource};
use columns::{build_columns, passthrough_fields};
use input::{to_nested, TighteningTable};
use rows::RowResult;
use schema::{Layout, TIGHTENING_ID};
use status::TighteningStatus;

pub use config::{BreakConfig, CusumConfig, DetectConfig, FrictionConfig, L1Config, PfDetectConfig, ResidualTestConfig};
pub use decision::{DecisionConfig, DecisionRule, DetectorKind};
pub use traces::{BreakTrace, CusumTrace, DetectorTraces, KdeTrace, L1Trace};

/// Validated configuration plus the threshold it implies.
#[derive(Clone, Debug)]
pub struct Detector {
    config: DetectConfig,
    /// The CUSUM's threshold at the most blocks a tightening can monitor.
    threshold: f64,
    /// Its threshold by monitored block count, and the tables of its widening.
    cusum_calibration: std::sync::Arc<analysis::CusumCalibration>,
    break_alpha: f64,
    /// Whether the break scan hands the CUSUM what its encoder-step check leaves unspent:
    /// both in the rule, each at its share (no `break_alpha`, no fixed CUSUM threshold).
    scan_share_to_cusum: bool,
    /// Share of `break_alpha` the episode scan gets: the configured one, or 0 where it or the
    /// scan's share would fall below the shipped tables' smallest alpha.
    episode_fraction: f64,
    l1_alpha: f64,
    l1_critical_value: f64,
    kde_alpha: f64,
    pf_alpha: f64,
}

impl Detector {
    /// Validates `config` and derives the CUSUM threshold.
    pub fn new(config: DetectConfig) -> Result<Self> {
        config.zone.validate()?;
        config.blocks.validate()?;
        let c = &config.cusum;
        if !(c.kappa.is_finite() && c.kappa >= 0.0) {
            return Err(TightscanError::parameter("kappa", format!("must be >= 0, got {}", c.kappa)));
        }
        let f = &config.friction;
        for (name, v) in [("pitch_mm", f.pitch_mm), ("d2_mm", f.d2_mm), ("dkm_mm", f.dkm_mm), ("joint_stiffness", f.joint_stiffness)] {
            if let Some(v) = v {
                if !(v.is_finite() && v > 0.0) {
                    return Err(TightscanError::parameter(name, format!("must be > 0, got {v}")));
                }
            }
        }
        if let Some(t) = &f.thread {
            if parse_thread(t).is_none() && !(f.pitch_mm.is_some() && f.d2_mm.is_some() && f.dkm_mm.is_some()) {
                return Err(TightscanError::parameter(
                    "thread",
                    format!("{t:?} is not in the ISO thread table (M3-M24); give pitch_mm, d2_mm and dkm_mm"),
                ));
            }
        }
        let y = config.yield_zone.gradient_fraction;
        if !(y > 0.0 && y < 1.0) {
            return Err(TightscanError::parameter("yield_gradient_fraction", format!("must be in (0, 1), got {y}")));
        }
        let r = &config.residual_tests;
        if !(r.training_fraction > 0.0 && r.training_fraction < 1.0) {
            return Err(TightscanError::parameter("residual_training_fraction", format!("must be in (0, 1), got {}", r.training_fraction)));
        }
        let d = &config.decision;
        if !(d.alpha > 0.0 && d.alpha < 0.5) {
            return Err(TightscanError::parameter("alpha", format!("must be in (0, 0.5), got {}", d.alpha)));
        }
        if d.detectors.is_empty() {
            return Err(TightscanError::parameter("detectors", "the decision rule needs at least one detector"));
        }
        if d.detectors.contains(&DetectorKind::Kde) && !r.kde {
            return Err(TightscanError::parameter("detectors", "'kde' in the rule needs kde=True"));
        }
        match &d.rule {
            DecisionRule::AtLeast(k) if *k == 0 || *k > d.detectors.len() => {
                return Err(TightscanError::parameter(
                    "rule",
                    format!("at least {k} of {} detectors cannot be asked", d.detectors.len()),
                ));
            }
            DecisionRule::Table(rows) => {
                if rows.is_empty() {
                    return Err(TightscanError::parameter("rule", "the response table has no rows"));
                }
                for (i, row) in rows.iter().enumerate() {
                    if !row.iter().any(|&(_, fires)| fires) {
                        return Err(TightscanError::parameter(
                            "rule",
                            format!("row {i} of the response table requires no detector to fire: it would alarm on clean curves"),
                        ));
                    }
                    for (j, &(kind, _)) in row.iter().enumerate() {
                        if !d.detectors.contains(&kind) {
                            return Err(TightscanError::parameter(
                                "rule",
                                format!("row {i} of the response table names '{}', which is not in detectors", kind.as_str()),
                            ));
                        }
                        if row[..j].iter().any(|&(k, _)| k == kind) {
                            return Err(TightscanError::parameter(
                                "rule",
                                format!("row {i} of the response table names '{}' twice", kind.as_str()),
                            ));
                        }
                    }
                }
            }
            _ => {}
        }
        let kde_alpha = r.kde_alpha.unwrap_or_else(|| d.share(DetectorKind::Kde));
        if !(kde_alpha > 0.0 && kde_alpha < 1.0) {
            return Err(TightscanError::parameter("kde_alpha", format!("must be in (0, 1), got {kde_alpha}")));
        }
        if r.kde && (r.kde_permutations as f64 + 1.0) * kde_alpha < 1.0 {
            return Err(TightscanError::parameter(
                "kde_permutations",
                format!(
                    "{} permutations cannot give a p-value at or below kde_alpha = {kde_alpha}; use at least {}",
                    r.kde_permutations,
                    (1.0 / kde_alpha).ceil() as usize
                ),
            ));
        }
        if d.detectors.contains(&DetectorKind::Pf) && !config.pf.enabled {
            return Err(TightscanError::parameter("detectors", "'pf' in the rule needs pf=True"));
        }
        let pf_alpha = config.pf.alpha.unwrap_or_else(|| d.share(DetectorKind::Pf));
        if !(pf_alpha > 0.0 && pf_alpha < 1.0) {
            return Err(TightscanError::parameter("pf_alpha", format!("must be in (0, 1), got {pf_alpha}")));
        }
        if !(1..=1_000_000).contains(&config.pf.particles) {
            return Err(TightscanError::parameter("pf_particles", format!("must be in 1..=1000000, got {}", config.pf.particles)));
        }
        if !(r.shewhart_k.is_finite() && r.shewhart_k > 0.0) {
            return Err(TightscanError::parameter("shewhart_k", format!("must be > 0, got {}", r.shewhart_k)));
        }
        let break_alpha = config.breaks.alpha.unwrap_or_else(|| d.share(DetectorKind::Break));
        let tail_fraction = config.breaks.tail_fraction;
        if !(0.0..1.0).contains(&tail_fraction) {
            return Err(TightscanError::parameter("break_tail_fraction", format!("must be in [0, 1), got {tail_fraction}")));
        }
        let head_fraction = config.breaks.head_fraction;
        if !(0.0..1.0).contains(&head_fraction) || head_fraction + tail_fraction >= 1.0 {
            return Err(TightscanError::parameter(
                "break_head_fraction",
                format!("must be in [0, 1) and leave the scan a share (break_head_fraction + break_tail_fraction < 1), got {head_fraction}"),
            ));
        }
        let episode_fraction = config.breaks.episode_fraction;
        if !(0.0..1.0).contains(&episode_fraction) || episode_fraction + head_fraction + tail_fraction >= 1.0 {
            return Err(TightscanError::parameter(
                "break_episode_fraction",
                format!(
                    "must be in [0, 1) and leave the scan a share (break_episode_fraction + break_head_fraction + break_tail_fraction < 1), got {episode_fraction}"
                ),
            ));
        }
        // The episode scan runs where its share and the scan's both stay within the shipped
        // tables (alpha 0.001 and up: a rule alpha of about 0.0045 and up with the default
        // split); below that the scan keeps the whole share, as before the episode scan was
        // added, so a small alpha that worked still works.
        let episode_fraction = if break_alpha * episode_fraction >= 0.001 && break_alpha * (1.0 - tail_fraction - head_fraction - episode_fraction) >= 0.001 {
            episode_fraction
        } else {
            0.0
        };
        let scan_alpha = break_alpha * (1.0 - tail_fraction - head_fraction - episode_fraction);
        if !(break_alpha <= 0.5 && scan_alpha >= 0.001) {
            return Err(TightscanError::parameter(
                "break_alpha",
                format!(
                    "must be at most 0.5, and its scan share (1 - break_tail_fraction - break_head_fraction) at least 0.001 (the shipped table); \
                     got {break_alpha}, scan share {scan_alpha}; raise alpha or give break_alpha"
                ),
            ));
        }
        let l1_alpha = config.l1.alpha.unwrap_or_else(|| d.share(DetectorKind::L1));
        // A location (the block torque rate): p = 1.
        let l1_critical_value = critical_value_any_alpha(l1_alpha, config.l1.gamma, 1).map_err(|e| match e {
            TightscanError::InvalidParameter { name, message } if name == "alpha" => {
                TightscanError::parameter("l1_alpha", message)
            }
            TightscanError::InvalidParameter { name, message } if name == "gamma" => {
                TightscanError::parameter("l1_gamma", message)
            }
            other => other,
        })?;
        // By default the threshold is the one at which the CUSUM alarms within the blocks a
        // tightening monitors with probability equal to its share of alpha (the exact
        // finite-horizon probability, `cusum_false_alarm_probabilities`), block count by block
        // count. One threshold from Siegmund's ARL for the most blocks a window can hold made
        // the CUSUM fire on 0.00-0.15 % of clean curves against a share of 0.25 %: a window of
        // 14 blocks sees a fifth of the alarms of an endless stream at that ARL.
        // The most blocks a window monitors: all `max_blocks` usable, less its training blocks.
        let most_blocks = config.blocks.max_blocks;
        let most_training = ((config.blocks.training_fraction * most_blocks as f64).ceil() as usize).max(config.blocks.min_training_blocks);
        let most_monitored = most_blocks.saturating_sub(most_training).max(1);
        let source = match (c.threshold, c.arl0) {
            (Some(h), _) if h.is_finite() && h > 0.0 => ThresholdSource::Fixed(h),
            (Some(h), _) => return Err(TightscanError::parameter("threshold", format!("must be > 0, got {h}"))),
            (None, Some(arl0)) => ThresholdSource::Fixed(cusum_threshold(arl0, c.kappa, true)?),
            (None, None) => ThresholdSource::FalseAlarm(d.share(DetectorKind::Cusum)),
        };
        let cusum_calibration = CusumCalibration::shared(source, c.kappa, config.blocks.max_blocks.max(1));
        let threshold = match source {
            ThresholdSource::Fixed(h) => h,
            // From the shared table (computed once per process); the direct call only to name
            // the error where the table could not hold one.
            ThresholdSource::FalseAlarm(alpha) => match cusum_calibration.threshold(most_monitored) {
                Some(h) => h,
                None => cusum_threshold_for_steps(alpha, c.kappa, most_monitored)?,
            },
        };
        let scan_share_to_cusum = matches!(source, ThresholdSource::FalseAlarm(_))
            && config.breaks.alpha.is_none()
            && d.detectors.contains(&DetectorKind::Break)
            && d.detectors.contains(&DetectorKind::Cusum);
        Ok(Self { config, threshold, cusum_calibration, break_alpha, scan_share_to_cusum, episode_fraction, l1_alpha, l1_critical_value, kde_alpha, pf_alpha })
    }

    /// The configuration in use.
    pub fn config(&self) -> &DetectConfig {
        &self.config
    }

    /// CUSUM threshold h in sigma units at the most blocks a tightening can monitor (30 by
    /// default: 40 blocks less 10 training); a tightening with fewer blocks gets the threshold
    /// for its own count ([`Detector::threshold_for`]) unless `threshold` or `arl0` is set.
    pub fn threshold(&self) -> f64 {
        self.threshold
    }

    /// CUSUM threshold h in sigma units for a tightening that monitors `blocks` blocks.
    pub fn threshold_for(&self, blocks: usize) -> f64 {
        self.cusum_calibration.threshold(blocks).unwrap_or(self.threshold)
    }

    /// False-alarm probability per tightening of the break detector (scan and end test).
    pub fn break_alpha(&self) -> f64 {
        self.break_alpha
    }

    /// Share of the break detector's alpha the episode scan gets (0 where the configured share
    /// would take it or the scan below the shipped tables).
    pub fn episode_fraction(&self) -> f64 {
        self.episode_fraction
    }

    /// False-alarm probability of the L1 monitoring, and its boundary's critical value c.
    pub fn l1_alpha(&self) -> (f64, f64) {
        (self.l1_alpha, self.l1_critical_value)
    }

    /// False-alarm probability of the kernel-density test.
    pub fn kde_alpha(&self) -> f64 {
        self.kde_alpha
    }

    /// Schema of the results for an input schema.
    pub fn result_schema(&self, input: &Schema, passthrough: &[String]) -> Result<SchemaRef> {
        schema::detect_layout(input)?;
        let id = match input.field_with_name(TIGHTENING_ID) {
            Ok(f) => f.clone(),
            Err(_) => Field::new(TIGHTENING_ID, DataType::Int64, false),
        };
        let pass = passthrough_fields(input, passthrough)?;
        Ok(schema::result_schema(id, &pass))
    }

    /// Analyses every tightening of `batch` (nested or long layout). `first_row` numbers the
    /// rows when the table has no `tightening_id` (row numbers continue across batches).
    /// Repeated ids are flagged within the batch ([`duplicates`]); a table given as several
    /// batches goes through [`Detector::detect_all`], which flags them across batches.
    pub fn detect(&self, batch: &RecordBatch, passthrough: &[String], first_row: i64) -> Result<RecordBatch> {
        let rows = self.detect_rows(batch, passthrough, first_row)?;
        let mut flagged = duplicates::flag_duplicate_ids(std::slice::from_ref(&rows))?;
        Ok(flagged.pop().unwrap_or(rows))
    }

    fn detect_rows(&self, batch: &RecordBatch, passthrough: &[String], first_row: i64) -> Result<RecordBatch> {
        let input_schema = batch.schema();
        let layout = schema::detect_layout(&input_schema)?;
        let out_schema = self.result_schema(&input_schema, passthrough)?;
        let nested = to_nested(batch, passthrough)?;
        let table = TighteningTable::new(&nested)?;
        let ids: ArrayRef = match nested.column_by_name(TIGHTENING_ID) {
            Some(ids) => owned_copy(ids)?,
            None => Arc::new(Int64Array::from_iter_values(first_row..first_row + nested.num_rows() as i64)),
        };
        // In the long layout a null id gathers samples of unknown tightenings: not a curve.
        let null_id_row = |i: usize| layout == Layout::Long && ids.is_null(i);

        let rows: Vec<RowResult> = (0..table.n_rows)
            .into_par_iter()
            .with_min_len(16)
            .map_init(Scratch::default, |scratch, i| {
                if null_id_row(i) {
                    return RowResult::failed(TighteningStatus::NullTightening, 0);
                }
                let mut row = self.analyse_row(&table, i, i, scratch);
                row.decision = self.decide(&row);
                self.settle_status(&mut row);
                row
            })
            .collect();

        let mut columns: Vec<ArrayRef> = Vec::with_capacity(out_schema.fields().len());
        columns.push(ids);
        columns.extend(build_columns(&rows));
        for name in passthrough {
            let col = nested
                .column_by_name(name)
                .ok_or_else(|| TightscanError::schema(name.as_str(), "pass-through column is missing"))?;
            columns.push(owned_copy(col)?);
        }
        Ok(RecordBatch::try_new(out_schema, columns)?)
    }

    /// What each detector computed along one tightening ([`traces`]), with its result row:
    /// `batch` holds exactly one tightening (nested or long layout), analysed by the very steps
    /// [`Detector::detect`] runs, with the same window, noise model, standardisation and
    /// thresholds. `row_number` is its row in the table `detect` would be given: it numbers
    /// the row when the table has no `tightening_id` and seeds the kernel-density test's
    /// permutations as `detect` does, so the trace's result row equals `detect`'s. A tightening
    /// that cannot be analysed gets its status in the row and no traces.
    /// The table may come as several batches (`input_schema` theirs).
    pub fn traces(&self, input_schema: &SchemaRef, batches: &[RecordBatch], row_number: usize) -> Result<(RecordBatch, DetectorTraces)> {
        let batch = &concat_batches(input_schema, batches)?;
        let input_schema = batch.schema();
        let layout = schema::detect_layout(&input_schema)?;
        let out_schema = self.result_schema(&input_schema, &[])?;
        let nested = to_nested(batch, &[])?;
        if nested.num_rows() != 1 {
            return Err(TightscanError::parameter(
                "tightening",
                format!("traces are of one tightening; the table holds {}", nested.num_rows()),
            ));
        }
        let table = TighteningTable::new(&nested)?;
        let ids: ArrayRef = match nested.column_by_name(TIGHTENING_ID) {
            Some(ids) => owned_copy(ids)?,
            None => Arc::new(Int64Array::from_iter_values([row_number as i64])),
        };
        let mut scratch = Scratch::default();
        scratch.trace = Some(Box::default());
        let mut row = if layout == Layout::Long && ids.is_null(0) {
            RowResult::failed(TighteningStatus::NullTightening, 0)
        } else {
            self.analyse_row(&table, 0, row_number, &mut scratch)
        };
        row.decision = self.decide(&row);
        self.settle_status(&mut row);
        let mut columns: Vec<ArrayRef> = vec![ids];
        columns.extend(build_columns(std::slice::from_ref(&row)));
        let result = RecordBatch::try_new(out_schema, columns)?;
        // A status that is not ok (too short, flat, misfit ...) keeps whatever ran before it
        // failed: its traces are what the row's statistics came from.
        Ok((result, scratch.trace.map(|t| *t).unwrap_or_default()))
    }

    /// Analyses a whole table given as batches. A long-layout table is concatenated first, so
    /// that a tightening whose samples span batches still gives exactly one row. Ids repeated
    /// anywhere in the table are flagged in every row that carries them ([`duplicates`]).
    pub fn detect_all(
        &self,
        input_schema: &SchemaRef,
        batches: &[RecordBatch],
        passthrough: &[String],
        first_row: i64,
    ) -> Result<Vec<RecordBatch>> {
        if schema::detect_layout(input_schema)? == Layout::Long && batches.len() > 1 {
            let all = concat_batches(input_schema, batches)?;
            return Ok(vec![self.detect(&all, passthrough, first_row)?]);
        }
        let mut row = first_row;
        let results = batches
            .iter()
            .map(|b| {
                let out = self.detect_rows(b, passthrough, row);
                row += b.num_rows() as i64;
                out
            })
            .collect::<Result<Vec<_>>>()?;
        duplicates::flag_duplicate_ids(&results)
    }
}

/// A copy of `column` in buffers of its own. The result's id and pass-through columns are a few
/// bytes per tightening, but a zero-copy slice of an input imported through the Arrow C data
/// interface keeps the whole input batch (every curve's samples) alive for as long as the
/// results live: 2.6 GB held by the results of a 100,000-tightening scan. (A dictionary
/// column's values are still shared: `take` copies its keys only.)
fn owned_copy(column: &ArrayRef) -> Result<ArrayRef> {
    let indices = arrow_array::UInt64Array::from_iter_values(0..column.len() as u64);
    Ok(arrow_select::take::take(column.as_ref(), &indices, None)?)
}
