//! The data contract: names, units and types of the tightening table and of the result table.
//!
//! One source of truth: `docs/data-contract.md` is checked against these constants by a test.

use std::sync::Arc;

use arrow_schema::{DataType, Field, Schema, SchemaRef};

use crate::error::{Result, TightscanError};

/// Identifier of a tightening: string or integer, returned unchanged.
pub const TIGHTENING_ID: &str = "tightening_id";
/// Rotation angle [deg]. Required.
pub const ANGLE: &str = "angle";
/// Torque [Nm]. Required.
pub const TORQUE: &str = "torque";
/// Time [s]. Optional.
pub const TIME: &str = "time";
/// Tool speed [rpm]. Optional.
pub const SPEED: &str = "speed";
/// Clamp force [kN] (test rigs). Optional.
pub const CLAMP_FORCE: &str = "clamp_force";
/// Controller step of each sample (integer; tool programs of several steps, e.g. the Rexroth
/// import). Optional. A change of step is a controller event, not friction: the detectors test
/// the last step of the elastic window, after the torque has regained its level.
pub const STEP: &str = "step";
/// Tightening strategy: CST, CSDT or HDT. Optional metadata.
pub const STRATEGY: &str = "strategy";
/// ISO thread designation, e.g. "M8x1.25"; "M8" means coarse pitch. Optional metadata.
pub const THREAD: &str = "thread";
/// Target torque [Nm]. Optional metadata.
pub const TARGET_TORQUE: &str = "target_torque";
/// Thread pitch P \[mm\]; overrides the thread table. Optional metadata.
pub const PITCH_MM: &str = "pitch_mm";
/// Pitch diameter d2 \[mm\]; overrides the thread table. Optional metadata.
pub const D2_MM: &str = "d2_mm";
/// Effective bearing diameter Dkm \[mm\]; overrides the thread table. Optional metadata.
pub const DKM_MM: &str = "dkm_mm";
/// Joint stiffness in the elastic zone \[kN/deg\]: gives `mu_tot` without a clamp-force
/// channel. Optional metadata.
pub const JOINT_STIFFNESS: &str = "joint_stiffness";

/// Per-tightening numeric metadata the analysis reads (one value per tightening; in the long
/// layout the value of the tightening's first sample). Float or integer columns.
pub const NUMERIC_METADATA: [(&str, &str); 4] =
    [(PITCH_MM, "mm"), (D2_MM, "mm"), (DKM_MM, "mm"), (JOINT_STIFFNESS, "kN/deg")];

/// A measured channel of the contract.
#[derive(Clone, Copy, Debug)]
pub struct ChannelSpec {
    /// Column name.
    pub name: &'static str,
    /// Unit of its samples.
    pub unit: &'static str,
    /// Whether every table must have it.
    pub required: bool,
}

/// All channels, required first. Every channel of a tightening has the same length.
pub const CHANNELS: [ChannelSpec; 5] = [
    ChannelSpec { name: ANGLE, unit: "deg", required: true },
    ChannelSpec { name: TORQUE, unit: "Nm", required: true },
    ChannelSpec { name: TIME, unit: "s", required: false },
    ChannelSpec { name: SPEED, unit: "rpm", required: false },
    ChannelSpec { name: CLAMP_FORCE, unit: "kN", required: false },
];

/// How samples are laid out in the table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// One row per tightening, channels as list<float>.
    Nested,
    /// One row per sample, `tightening_id` plus scalar channel columns.
    Long,
}

/// Decides the layout from the type of `angle`, and checks every channel's type.
pub fn detect_layout(schema: &Schema) -> Result<Layout> {
    let angle = schema
        .field_with_name(ANGLE)
        .map_err(|_| missing_column(schema, ANGLE))?;
    let layout = match angle.data_type() {
        DataType::List(_) | DataType::LargeList(_) => Layout::Nested,
        DataType::Float32 | DataType::Float64 => Layout::Long,
        other => {
            return Err(TightscanError::schema(
                ANGLE,
                format!(
                    "expected list<float32|float64> (one row per tightening) or float32/float64 \
                     (one row per sample), got {other}"
                ),
            ))
        }
    };
    for spec in CHANNELS {
        let field = match schema.field_with_name(spec.name) {
            Ok(f) => f,
            Err(_) if spec.required => return Err(missing_column(schema, spec.name)),
            Err(_) => continue,
        };
        check_channel_type(spec.name, field.data_type(), layout)?;
    }
    if layout == Layout::Long && schema.field_with_name(TIGHTENING_ID).is_err() {
        return Err(TightscanError::schema(
            TIGHTENING_ID,
            "missing: the long layout (one row per sample) needs it to group samples into tightenings",
        ));
    }
    if let Ok(f) = schema.field_with_name(THREAD) {
        if !matches!(f.data_type(), DataType::Utf8 | DataType::LargeUtf8 | DataType::Utf8View) {
            return Err(TightscanError::schema(
                THREAD,
                format!("expected a string column such as \"M8\" or \"M10x1.25\", got {}", f.data_type()),
            ));
        }
    }
    for (name, unit) in NUMERIC_METADATA {
        if let Ok(f) = schema.field_with_name(name) {
            if !(f.data_type().is_floating() || f.data_type().is_integer()) {
                return Err(TightscanError::schema(
                    name,
                    format!("expected one number per tightening [{unit}], got {}", f.data_type()),
                ));
            }
        }
    }
    if let Ok(id) = schema.field_with_name(TIGHTENING_ID) {
        if !is_id_type(id.data_type()) {
            return Err(TightscanError::schema(
                TIGHTENING_ID,
                format!("expected a string or integer column, got {}", id.data_type()),
            ));
        }
    }
    Ok(layout)
}

/// True for the integer and string types accepted as `tightening_id`, plain or
/// dictionary-encoded (pandas categoricals, Parquet dictionary pages read as such).
pub fn is_id_type(dt: &DataType) -> bool {
    if let DataType::Dictionary(_, values) = dt {
        return is_id_type(values);
    }
    matches!(
        dt,
        DataType::Int8
            | DataType::Int16
            | DataType::Int32
            | DataType::Int64
            | DataType::UInt8
            | DataType::UInt16
            | DataType::UInt32
            | DataType::UInt64
            | DataType::Utf8
            | DataType::LargeUtf8
            | DataType::Utf8View
    )
}

fn check_channel_type(name: &str, dt: &DataType, layout: Layout) -> Result<()> {
    let value_type = match (layout, dt) {
        (Layout::Nested, DataType::List(item) | DataType::LargeList(item)) => item.data_type(),
        (Layout::Long, DataType::Float32 | DataType::Float64) => return Ok(()),
        (Layout::Nested, other) => {
            return Err(TightscanError::schema(
                name,
                format!("expected list<float32|float64> like 'angle', got {other}"),
            ))
        }
        (Layout::Long, other) => {
            return Err(TightscanError::schema(
                name,
                format!("expected float32 or float64 samples like 'angle', got {other}"),
            ))
        }
    };
    match value_type {
        DataType::Float32 | DataType::Float64 => Ok(()),
        other => Err(TightscanError::schema(
            name,
            format!(
                "expected float32 or float64 samples, got {other}; cast the channel to float64 first"
            ),
        )),
    }
}

fn missing_column(schema: &Schema, name: &str) -> TightscanError {
    let have: Vec<&str> = schema.fields().iter().map(|f| f.name().as_str()).collect();
    TightscanError::schema(name, format!("required column is missing (table has: {})", have.join(", ")))
}

/// Result columns: name, type, unit, meaning. `detect` builds its arrays in this order, and the
/// data-contract document lists the same names.
pub const RESULT_COLUMNS: &[(&str, ResultType, &str, &str)] = &[
    ("status", ResultType::Utf8, "", "'ok', or 'code: detail' saying what is wrong with the tightening"),
    ("n_samples", ResultType::Int64, "", "samples in the tightening"),
    ("change_detected", ResultType::Boolean, "", "the decision rule found a friction change (null when none of its detectors could run)"),
    ("change_angle", ResultType::Float64, "deg", "estimated start of the change (null when none)"),
    ("change_index", ResultType::Int64, "", "sample index of the estimated start: the first changed sample (null when none)"),
    ("detectors_fired", ResultType::Utf8, "", "comma-separated detectors that fired: break, l1, kde, cusum (empty when none)"),
    ("prevailing_torque", ResultType::Float64, "Nm", "median rundown torque before the final rise"),
    ("snug_angle", ResultType::Float64, "deg", "where the elastic line meets the prevailing torque (tangent method)"),
    ("elastic_start_angle", ResultType::Float64, "deg", "start of the analysed elastic window"),
    ("elastic_end_angle", ResultType::Float64, "deg", "end of the analysed elastic window"),
    ("tested_start_angle", ResultType::Float64, "deg", "where the samples the detectors test start: the window's start, or later, after the last controller step change, unsampled pause or relaxation dip inside it"),
    ("tested_end_angle", ResultType::Float64, "deg", "where the samples the detectors test end: the window's end, or earlier, before a pause or relaxation dip too late in the window to test after"),
    ("yield_angle", ResultType::Float64, "deg", "where the torque gradient falls below half the elastic one (null when it does not)"),
    ("peak_torque", ResultType::Float64, "Nm", "highest torque of the curve"),
    ("peak_angle", ResultType::Float64, "deg", "angle at the highest torque"),
    ("torque_rate", ResultType::Float64, "Nm/deg", "robust (Huber) torque rate over the elastic window"),
    ("mu_tot", ResultType::Float64, "", "total friction coefficient, ISO 16047 (null without clamp force or joint stiffness, or without thread geometry)"),
    ("nut_factor", ResultType::Float64, "", "nut factor K = T / (F d) from the elastic torque-force slope"),
    ("mu_tot_source", ResultType::Utf8, "", "'clamp_force' or 'joint_stiffness': what mu_tot was computed from"),
    ("noise_lag1", ResultType::Float64, "", "lag-1 autocorrelation of the window's torque noise (AR model of local residuals); the detectors test the window whitened with it"),
    ("cusum_alarm", ResultType::Boolean, "", "CUSUM crossed its threshold"),
    ("cusum_alarm_index", ResultType::Int64, "", "sample index where it crossed"),
    ("cusum_alarm_angle", ResultType::Float64, "deg", "angle where it crossed"),
    ("cusum_side", ResultType::Utf8, "", "'increase' or 'decrease' of the torque rate"),
    ("cusum_change_index", ResultType::Int64, "", "sample index of the change-start estimate"),
    ("cusum_change_angle", ResultType::Float64, "deg", "angle of the change-start estimate"),
    ("cusum_max_statistic", ResultType::Float64, "sigma", "largest CUSUM statistic over the window"),
    ("cusum_threshold", ResultType::Float64, "sigma", "threshold h in use: by default the one at which the CUSUM alarms within cusum_blocks blocks with probability equal to its share of alpha (lower for fewer blocks); arl0 or threshold in the config set one h for every tightening"),
    ("cusum_alpha", ResultType::Float64, "", "false-alarm probability the CUSUM is held to in this tightening: its share of alpha, plus the share of the break scan that the scan's encoder-step check leaves unspent on a clean window (a coarse encoder against the noise); null where threshold or arl0 sets the threshold"),
    ("cusum_reference_rate", ResultType::Float64, "Nm/deg", "torque rate of the training window"),
    ("cusum_noise_sd", ResultType::Float64, "Nm", "torque noise scale of the whitened window (innovation sd), from the block residuals, widened for the AR fit's uncertainty (and narrowed by the threshold's scale where cusum_alpha is above the CUSUM's share); each block's rate is standardised by it with the variance the angle's quantisation error adds to that block's slope"),
    ("cusum_noise_df", ResultType::Float64, "", "degrees of freedom behind cusum_noise_sd"),
    ("cusum_dispersion", ResultType::Float64, "", "spread of standardised training blocks (1 for white noise)"),
    ("cusum_blocks", ResultType::Int64, "", "blocks monitored after the training window"),
    ("cusum_block_angle", ResultType::Float64, "deg", "angle width of one block"),
    ("break_alarm", ResultType::Boolean, "", "the sup-LR scan, the end test, the start test or the episode scan found a break (or an episode) of the elastic line at break_alpha"),
    ("break_statistic", ResultType::Float64, "", "sup-LR statistic (largest likelihood ratio over split points)"),
    ("break_critical_value", ResultType::Float64, "", "critical value of break_statistic at its share of break_alpha, for this window's sample count and noise model (the GLS scan's null table by AR gain)"),
    ("break_p_value", ResultType::Float64, "", "p-value of the statistic from the shipped null table (0.001 to 0.5), averaged over the AR fit's uncertainty where the window is whitened"),
    ("break_tail_p_value", ResultType::Float64, "", "Bonferroni-adjusted p-value of the end test (Chow predictive test of the last samples up to the peak)"),
    ("break_head_p_value", ResultType::Float64, "", "Bonferroni-adjusted p-value of the start test (the end test read backwards: the window's first samples against the line after them); null where the tested window starts after a controller step or a pause"),
    ("break_episode_p_value", ResultType::Float64, "", "p-value of the episode scan (up to three stretches of the window off the line that the line before and after them shares, as an intermittent friction fault leaves; averaged over the whitening's uncertainty, clamped to [0.001, 0.5]); null where no episode is admissible (a short window) or the scan is off (break_episode_fraction 0)"),
    ("break_change_index", ResultType::Int64, "", "sample index of the most likely break"),
    ("break_change_angle", ResultType::Float64, "deg", "angle of the most likely break: halfway between break_change_index (the first changed sample) and the sample before it, on the angle with the encoder's quantisation interpolated"),
    ("break_jump", ResultType::Float64, "Nm", "torque jump of the two fitted lines at the break"),
    ("l1_alarm", ResultType::Boolean, "", "L1 sign-residual monitoring of the elastic line crossed its boundary"),
    ("l1_alarm_index", ResultType::Int64, "", "sample index where it crossed"),
    ("l1_alarm_angle", ResultType::Float64, "deg", "angle where it crossed"),
    ("l1_max_ratio", ResultType::Float64, "", "largest sqrt(statistic) / boundary, on the critical value's scale (above 1: alarm)"),
    ("l1_statistic_at_alarm", ResultType::Float64, "", "detector at the alarm (quadratic form of the sign residuals)"),
    ("l1_boundary_at_alarm", ResultType::Float64, "", "boundary at the alarm, c^2 (1 + k/m)^2 (k/(m+k))^(2 gamma)"),
    ("l1_gamma", ResultType::Float64, "", "boundary exponent gamma used"),
    ("l1_alpha", ResultType::Float64, "", "false-alarm probability per tightening used"),
    ("kde_alarm", ResultType::Boolean, "", "kernel-density change test of the line residuals fired at kde_alpha (null unless enabled)"),
    ("kde_statistic", ResultType::Float64, "", "largest standardised L2 distance (biased squared MMD) between reference and window"),
    ("kde_p_value", ResultType::Float64, "", "block-permutation p-value of kde_statistic"),
    ("kde_change_index", ResultType::Int64, "", "sample index where the residual distribution changes"),
    ("kde_change_angle", ResultType::Float64, "deg", "angle where the residual distribution changes"),
    ("shewhart_alarm", ResultType::Boolean, "", "classical baseline: a line residual beyond shewhart_k training sigmas"),
    ("shewhart_max_abs_z", ResultType::Float64, "sigma", "largest standardised line residual after the reference"),
    ("shewhart_alarm_index", ResultType::Int64, "", "sample index of the first residual beyond the limit"),
    ("shewhart_alarm_angle", ResultType::Float64, "deg", "angle of the first residual beyond the limit"),
    ("pf_alarm", ResultType::Boolean, "", "particle-filter fault test fired: pf_p_value at or below pf_alpha, and the kink beyond 1.5 encoder steps of torque by the window's end where one step exceeds the noise's sd (or pf_p_value at a hundredth of pf_alpha) (null unless enabled)"),
    ("pf_statistic", ResultType::Float64, "", "largest log Bayes factor over the window, ln BF (fault model against no fault)"),
    ("pf_p_value", ResultType::Float64, "", "p-value of pf_statistic from the shipped null table (white Gaussian noise, by window length), averaged over the whitening's uncertainty (the noise model's log-gain standard error); exp(-pf_statistic) is Ville's bound, valid but conservative"),
    ("pf_fault_probability", ResultType::Float64, "", "posterior probability of the fault mode (the torque rate has jumped) after the window's last sample"),
    ("pf_change_angle", ResultType::Float64, "deg", "posterior median of where the torque rate jumped: on an alarm from the exact posterior of the change's sample (the line turning about the snug), else from the filter's particles (null when no particle jumped)"),
    ("pf_change_lo", ResultType::Float64, "deg", "5 % posterior quantile of the jump's angle (90 % credible interval, on the interpolated angle, plus the half encoder step by which an average of floor-quantised counts lags the shaft; a jump at a sample happened after the sample before, so on an alarm each sample's posterior mass is spread evenly over the advance since the sample before, and from the particles the interval starts at the sample before their 5 % sample)"),
    ("pf_change_hi", ResultType::Float64, "deg", "95 % posterior quantile of the jump's angle (90 % credible interval)"),
    ("pf_friction", ResultType::ListFloat64, "Nm/deg", "posterior mean torque rate (the friction proxy) after each tested sample from the filter's 11th on, on the whitened window (null unless pf_friction is asked)"),
];

/// Arrow type of a result column.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResultType {
    /// Utf8.
    Utf8,
    /// Int64.
    Int64,
    /// Float64.
    Float64,
    /// Boolean.
    Boolean,
    /// List of Float64 (one list per tightening).
    ListFloat64,
}

impl ResultType {
    /// The Arrow data type.
    pub fn data_type(self) -> DataType {
        match self {
            Self::Utf8 => DataType::Utf8,
            Self::Int64 => DataType::Int64,
            Self::Float64 => DataType::Float64,
            Self::Boolean => DataType::Boolean,
            Self::ListFloat64 => DataType::List(Arc::new(Field::new_list_field(DataType::Float64, true))),
        }
    }
}

/// Result schema: `tightening_id` (type as given), [`RESULT_COLUMNS`], then pass-through fields.
pub fn result_schema(id_field: Field, passthrough: &[Field]) -> SchemaRef {
    let mut fields = Vec::with_capacity(1 + RESULT_COLUMNS.len() + passthrough.len());
    fields.push(id_field.with_name(TIGHTENING_ID));
    for (name, ty, _, _) in RESULT_COLUMNS {
        let nullable = *name != "status" && *name != "n_samples";
        fields.push(Field::new(*name, ty.data_type(), nullable));
    }
    fields.extend(passthrough.iter().cloned());
    Arc::new(Schema::new(fields))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn list(dt: DataType) -> DataType {
        DataType::List(Arc::new(Field::new_list_field(dt, true)))
    }

    #[test]
    fn layouts() {
        let nested = Schema::new(vec![
            Field::new(ANGLE, list(DataType::Float32), true),
            Field::new(TORQUE, list(DataType::Float64), true),
        ]);
        assert_eq!(detect_layout(&nested).ok(), Some(Layout::Nested));
        let long = Schema::new(vec![
            Field::new(TIGHTENING_ID, DataType::Utf8, true),
            Field::new(ANGLE, DataType::Float64, true),
            Field::new(TORQUE, DataType::Float32, true),
        ]);
        assert_eq!(detect_layout(&long).ok(), Some(Layout::Long));
    }

    #[test]
    fn errors_name_the_column() {
        let no_torque = Schema::new(vec![Field::new(ANGLE, list(DataType::Float32), true)]);
        let e = detect_layout(&no_torque).err().map(|e| e.to_string()).unwrap_or_default();
        assert!(e.contains("'torque'") && e.contains("missing"), "{e}");

        let text_torque = Schema::new(vec![
            Field::new(ANGLE, list(DataType::Float32), true),
            Field::new(TORQUE, list(DataType::Utf8), true),
        ]);
        let e = detect_layout(&text_torque).err().map(|e| e.to_string()).unwrap_or_default();
        assert!(e.contains("'torque'"), "{e}");

        let mixed = Schema::new(vec![
            Field::new(ANGLE, list(DataType::Float32), true),
            Field::new(TORQUE, DataType::Float32, true),
        ]);
        let e = detect_layout(&mixed).err().map(|e| e.to_string()).unwrap_or_default();
        assert!(e.contains("'torque'"), "{e}");

        let long_no_id = Schema::new(vec![
            Field::new(ANGLE, DataType::Float64, true),
            Field::new(TORQUE, DataType::Float64, true),
        ]);
        let e = detect_layout(&long_no_id).err().map(|e| e.to_string()).unwrap_or_default();
        assert!(e.contains("'tightening_id'"), "{e}");

        let float_id = Schema::new(vec![
            Field::new(TIGHTENING_ID, DataType::Float64, true),
            Field::new(ANGLE, list(DataType::Float64), true),
            Field::new(TORQUE, list(DataType::Float64), true),
        ]);
        let e = detect_layout(&float_id).err().map(|e| e.to_string()).unwrap_or_default();
        assert!(e.contains("'tightening_id'"), "{e}");
    }
}
