//! The result table: pass-through fields, and the result arrays built from the per-tightening
//! rows in the order of [`RESULT_COLUMNS`], the one table of result columns.

use std::sync::Arc;

use arrow_array::builder::{Float64Builder, ListBuilder};
use arrow_array::{ArrayRef, BooleanArray, Float64Array, Int64Array, StringArray};
use arrow_schema::{Field, Schema};

use crate::engine::rows::RowResult;
use crate::engine::schema::{RESULT_COLUMNS, TIGHTENING_ID};
use crate::error::{Result, TightscanError};

pub(super) fn passthrough_fields(input: &Schema, passthrough: &[String]) -> Result<Vec<Field>> {
    passthrough
        .iter()
        .map(|name| {
            if name == TIGHTENING_ID || RESULT_COLUMNS.iter().any(|(r, ..)| r == name) {
                return Err(TightscanError::schema(name.as_str(), "cannot pass through: the results have a column of that name"));
            }
            input
                .field_with_name(name)
                .cloned()
                .map_err(|_| TightscanError::schema(name.as_str(), "pass-through column is missing"))
        })
        .collect()
}

/// Builds the result arrays in the order of [`RESULT_COLUMNS`] (a test checks the order).
pub(super) fn build_columns(rows: &[RowResult]) -> Vec<ArrayRef> {
    let f = |get: fn(&RowResult) -> Option<f64>| -> ArrayRef {
        Arc::new(rows.iter().map(get).collect::<Float64Array>())
    };
    let i = |get: fn(&RowResult) -> Option<i64>| -> ArrayRef {
        Arc::new(rows.iter().map(get).collect::<Int64Array>())
    };
    let b = |get: fn(&RowResult) -> Option<bool>| -> ArrayRef {
        Arc::new(rows.iter().map(get).collect::<BooleanArray>())
    };
    let status: ArrayRef = Arc::new(rows.iter().map(|r| Some(r.status.to_string())).collect::<StringArray>());
    let side: ArrayRef = Arc::new(rows.iter().map(|r| r.alarm().map(|a| a.side.as_str())).collect::<StringArray>());
    let mu_source: ArrayRef = Arc::new(
        rows.iter()
            .map(|r| {
                r.friction.map(|f| f.source.as_str())
            })
            .collect::<StringArray>(),
    );
    let fired: ArrayRef = Arc::new(rows.iter().map(|r| r.decision.as_ref().map(|d| d.fired.as_str())).collect::<StringArray>());
    let mut track = ListBuilder::new(Float64Builder::new());
    for r in rows {
        match r.pf.as_ref().filter(|p| !p.friction.is_empty()) {
            Some(p) => {
                track.values().append_slice(&p.friction);
                track.append(true);
            }
            None => track.append(false),
        }
    }
    let pf_friction: ArrayRef = Arc::new(track.finish());
    vec![
        status,
        i(|r| Some(r.n_samples as i64)),
        b(|r| r.decision.as_ref().map(|d| d.detected)),
        f(|r| r.decision.as_ref().and_then(|d| d.change).map(|c| c.1)),
        i(|r| r.decision.as_ref().and_then(|d| d.change).map(|c| c.0 as i64)),
        fired,
        f(|r| r.phases.map(|p| p.prevailing_torque)),
        f(|r| r.phases.map(|p| p.snug_angle)),
        f(|r| r.window.map(|w| w.0)),
        f(|r| r.window.map(|w| w.1)),
        f(|r| r.tested_start),
        f(|r| r.tested_end),
        f(|r| r.phases.and_then(|p| p.yield_angle)),
        f(|r| r.phases.map(|p| p.peak_torque)),
        f(|r| r.phases.map(|p| p.peak_angle)),
        f(|r| r.phases.map(|p| p.torque_rate)),
        f(|r| r.friction.map(|p| p.mu_tot)),
        f(|r| r.friction.map(|p| p.nut_factor)),
        mu_source,
        f(|r| r.noise_lag1),
        b(|r| r.cusum.as_ref().map(|c| c.alarm.is_some())),
        i(|r| r.alarm().map(|a| a.alarm_index as i64)),
        f(|r| r.alarm().map(|a| a.alarm_angle)),
        side,
        i(|r| r.alarm().map(|a| a.change_index as i64)),
        f(|r| r.alarm().map(|a| a.change_angle)),
        f(|r| r.cusum.as_ref().map(|c| c.max_statistic)),
        f(|r| r.cusum.as_ref().map(|c| c.threshold)),
        f(|r| r.cusum.as_ref().and_then(|c| c.alpha)),
        f(|r| r.cusum.as_ref().map(|c| c.reference_rate)),
        f(|r| r.cusum.as_ref().map(|c| c.noise_sd)),
        f(|r| r.cusum.as_ref().map(|c| c.noise_df)),
        f(|r| r.cusum.as_ref().map(|c| c.dispersion)),
        i(|r| r.cusum.as_ref().map(|c| c.blocks as i64)),
        f(|r| r.cusum.as_ref().map(|c| c.block_angle)),
        b(|r| r.breaks.map(|b| b.alarm)),
        f(|r| r.breaks.map(|b| b.statistic)),
        f(|r| r.breaks.map(|b| b.critical_value)),
        f(|r| r.breaks.map(|b| b.p_value)),
        f(|r| r.breaks.and_then(|b| b.tail_p_value)),
        f(|r| r.breaks.and_then(|b| b.head_p_value)),
        f(|r| r.breaks.and_then(|b| b.episode_p_value)),
        i(|r| r.breaks.map(|b| b.change_index as i64)),
        f(|r| r.breaks.map(|b| b.change_angle)),
        f(|r| r.breaks.map(|b| b.jump)),
        b(|r| r.l1.map(|l| l.alarm_index.is_some())),
        i(|r| r.l1.and_then(|l| l.alarm_index).map(|v| v as i64)),
        f(|r| r.l1.and_then(|l| l.alarm_angle)),
        f(|r| r.l1.map(|l| l.max_ratio)),
        f(|r| r.l1.and_then(|l| l.statistic_at_alarm)),
        f(|r| r.l1.and_then(|l| l.boundary_at_alarm)),
        f(|r| r.l1.map(|l| l.gamma)),
        f(|r| r.l1.map(|l| l.alpha)),
        b(|r| r.residual.and_then(|k| k.kde).map(|k| k.alarm)),
        f(|r| r.residual.and_then(|k| k.kde).map(|k| k.statistic)),
        f(|r| r.residual.and_then(|k| k.kde).map(|k| k.p_value)),
        i(|r| r.residual.and_then(|k| k.kde).and_then(|k| k.change_index).map(|v| v as i64)),
        f(|r| r.residual.and_then(|k| k.kde).and_then(|k| k.change_angle)),
        b(|r| r.residual.map(|k| k.shewhart_alarm)),
        f(|r| r.residual.map(|k| k.shewhart_max_abs_z)),
        i(|r| r.residual.and_then(|k| k.shewhart_alarm_index).map(|v| v as i64)),
        f(|r| r.residual.and_then(|k| k.shewhart_alarm_angle)),
        b(|r| r.pf.as_ref().map(|p| p.alarm)),
        f(|r| r.pf.as_ref().map(|p| p.statistic)),
        f(|r| r.pf.as_ref().map(|p| p.p_value)),
        f(|r| r.pf.as_ref().map(|p| p.fault_probability)),
        f(|r| r.pf.as_ref().and_then(|p| p.onset).map(|o| o.angle)),
        f(|r| r.pf.as_ref().and_then(|p| p.onset).map(|o| o.lo_angle)),
        f(|r| r.pf.as_ref().and_then(|p| p.onset).map(|o| o.hi_angle)),
        pf_friction,
    ]
}
