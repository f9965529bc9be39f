//! Per-tightening status: what is wrong with one tightening, reported in its result row.
//!
//! A malformed tightening never raises: it gets a row whose `status` column is this value's
//! text. The text is `code` or `code: detail`; the codes are stable, the details are for people.

use std::fmt;

/// Outcome of checking and analysing one tightening.
#[derive(Clone, Debug, PartialEq)]
pub enum TighteningStatus {
    /// Analysed.
    Ok,
    /// The row itself is null (null list, or long-layout samples with a null id).
    NullTightening,
    /// No samples at all.
    Empty,
    /// A channel's length differs from `angle`'s.
    LengthMismatch {
        /// Channel whose length differs.
        channel: &'static str,
        /// Its length.
        len: usize,
        /// Length of `angle`.
        expected: usize,
    },
    /// Null samples inside a channel.
    NullValues {
        /// Channel holding nulls.
        channel: &'static str,
        /// How many.
        count: usize,
    },
    /// NaN or infinite samples inside a channel.
    NonFinite {
        /// Channel holding them.
        channel: &'static str,
        /// How many.
        count: usize,
    },
    /// Fewer samples than the analysis needs.
    TooShort {
        /// Samples available where they were counted (whole curve or elastic window).
        samples: usize,
        /// Samples needed.
        minimum: usize,
        /// Where they were counted.
        what: &'static str,
    },
    /// A channel does not vary at all.
    FlatSignal {
        /// Channel that is constant.
        channel: &'static str,
    },
    /// The largest torque in magnitude is negative: an unfastening (loosening) curve, or a
    /// tightening recorded with the opposite sign convention. Detection assumes a tightening
    /// whose torque rises with angle, so none is attempted.
    Loosening {
        /// The most negative torque [Nm].
        peak_torque: f64,
        /// Angle at that torque [deg].
        peak_angle: f64,
    },
    /// The null model of the window (a straight elastic line) does not fit, and a smooth curve
    /// explains the window better than any break: a change cannot be told from the misfit.
    ModelMisfit {
        /// Two-sided p-value of the curvature (quadratic term) of the whitened window.
        curvature_p_value: f64,
    },
    /// Clamp force or joint stiffness is given, so `mu_tot` is asked for, but the thread is not
    /// in the table and no `pitch_mm`/`d2_mm`/`dkm_mm` replace it.
    UnknownThread {
        /// The designation as given.
        designation: String,
    },
    /// No usable elastic clamping zone was found.
    NoElasticZone {
        /// Why not.
        reason: &'static str,
    },
    /// Several result rows carry this tightening id (a repeated id in the nested layout; in the
    /// long layout an id that reappears after other ids, or a curve that restarts under it).
    /// Set after the analysis, by [`super::duplicates`]: the row keeps what its curve gave, and
    /// the text goes on with `; as a curve: <that status>`.
    DuplicateId {
        /// The id as text (strings quoted).
        id: String,
        /// Rows carrying it.
        count: usize,
    },
}

impl TighteningStatus {
    /// Stable machine-readable code (the text before the colon).
    pub fn code(&self) -> &'static str {
        match self {
            Self::Ok => "ok",
            Self::NullTightening => "null_tightening",
            Self::Empty => "empty",
            Self::LengthMismatch { .. } => "length_mismatch",
            Self::NullValues { .. } => "null_values",
            Self::NonFinite { .. } => "non_finite",
            Self::TooShort { .. } => "too_short",
            Self::FlatSignal { .. } => "flat_signal",
            Self::Loosening { .. } => "loosening",
            Self::NoElasticZone { .. } => "no_elastic_zone",
            Self::ModelMisfit { .. } => "model_misfit",
            Self::UnknownThread { .. } => "unknown_thread",
            Self::DuplicateId { .. } => "duplicate_id",
        }
    }

    /// True for [`TighteningStatus::Ok`].
    pub fn is_ok(&self) -> bool {
        matches!(self, Self::Ok)
    }
}

impl fmt::Display for TighteningStatus {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let code = self.code();
        match self {
            Self::Ok => write!(f, "{code}"),
            Self::NullTightening => write!(f, "{code}: the tightening is null"),
            Self::Empty => write!(f, "{code}: no samples"),
            Self::LengthMismatch { channel, len, expected } => write!(
                f,
                "{code}: {channel} has {len} samples, angle has {expected}"
            ),
            Self::NullValues { channel, count } => {
                write!(f, "{code}: {channel} has {count} null samples")
            }
            Self::NonFinite { channel, count } => {
                write!(f, "{code}: {channel} has {count} NaN or infinite samples")
            }
            Self::TooShort { samples, minimum, what } => {
                write!(f, "{code}: {samples} samples in the {what}, at least {minimum} needed")
            }
            Self::FlatSignal { channel } => write!(f, "{code}: {channel} does not vary"),
            Self::Loosening { peak_torque, peak_angle } => write!(
                f,
                "{code}: torque falls (peak |torque| {peak_torque:.3} Nm at {peak_angle:.2} deg is negative); detection applies \
                 to tightening curves (a tightening recorded with negative torque: negate torque to analyse it)"
            ),
            Self::NoElasticZone { reason } => write!(f, "{code}: {reason}"),
            Self::ModelMisfit { curvature_p_value } => write!(
                f,
                "{code}: the elastic window is curved (curvature p = {curvature_p_value:.1e}) and a smooth curve fits it \
                 better than any break; no change is claimed"
            ),
            Self::DuplicateId { id, count } => write!(f, "{code}: tightening_id {id} appears {count} times"),
            Self::UnknownThread { designation } => write!(
                f,
                "{code}: {designation:?} is not an ISO metric thread of the table (M3-M24, coarse and \
                 common fine pitches); give pitch_mm, d2_mm and dkm_mm to compute mu_tot"
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_starts_with_code() {
        let all = [
            TighteningStatus::Ok,
            TighteningStatus::NullTightening,
            TighteningStatus::Empty,
            TighteningStatus::LengthMismatch { channel: "torque", len: 3, expected: 4 },
            TighteningStatus::NullValues { channel: "angle", count: 1 },
            TighteningStatus::NonFinite { channel: "torque", count: 2 },
            TighteningStatus::TooShort { samples: 3, minimum: 30, what: "curve" },
            TighteningStatus::FlatSignal { channel: "torque" },
            TighteningStatus::Loosening { peak_torque: -2.57, peak_angle: 3.5 },
            TighteningStatus::NoElasticZone { reason: "x" },
            TighteningStatus::DuplicateId { id: "7".into(), count: 2 },
        ];
        for s in all {
            assert!(s.to_string().starts_with(s.code()), "{s}");
        }
        assert_eq!(
            TighteningStatus::LengthMismatch { channel: "torque", len: 3, expected: 4 }.to_string(),
            "length_mismatch: torque has 3 samples, angle has 4"
        );
    }
}
