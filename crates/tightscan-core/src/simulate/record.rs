//! Recording: the model evaluated and written sample by sample, the truth row, and the Arrow
//! batches of curves and truth with their schemas.

use std::sync::Arc;

use arrow_array::{
    ArrayRef, BooleanArray, Float32Array, Float64Array, Int64Array, ListArray, RecordBatch,
    StringArray,
};
use arrow_buffer::{OffsetBuffer, ScalarBuffer};
use arrow_schema::{DataType, Field, Schema, SchemaRef};
use rand::RngExt;
use rand_distr::StandardNormal;
use rand_xoshiro::Xoshiro256PlusPlus;

use crate::error::Result;
use super::config::{SimulationConfig, Strategy};
use super::draw::{Draw, SPEED_FRICTION_MIN_RPM, SPEED_FRICTION_REF_RPM, SPEED_NOISE_RPM};
use super::effects::{Measurement};
use super::faults::{Fault, FrictionPath};

/// Output of [`simulate`]: the curves and their ground truth, row `i` of both describing the
/// same tightening.
#[derive(Clone, Debug)]
pub struct Simulated {
    /// One row per tightening, channels as lists; schema [`tightenings_schema`].
    pub tightenings: RecordBatch,
    /// One row per tightening with the labels and the hidden parameters; schema [`truth_schema`].
    pub truth: RecordBatch,
}

pub(super) fn list_of_f32() -> DataType {
    // Nullable items: the default of pyarrow's list type, so round trips keep the schema equal.
    DataType::List(Arc::new(Field::new_list_field(DataType::Float32, true)))
}

/// Schema of [`Simulated::tightenings`] (nested layout, one row per tightening):
/// `tightening_id` Int64, `strategy` Utf8, `thread` Utf8, `target_torque` Float64 \[Nm\],
/// then `angle` \[deg, cumulative from 0\], `torque` \[Nm\], `time` \[s\], `speed` \[rpm\]
/// and, only with `with_clamp_force`, `clamp_force` \[kN\], each `List<Float32>`.
pub fn tightenings_schema(with_clamp_force: bool) -> SchemaRef {
    let mut fields = vec![
        Field::new("tightening_id", DataType::Int64, false),
        Field::new("strategy", DataType::Utf8, false),
        Field::new("thread", DataType::Utf8, false),
        Field::new("target_torque", DataType::Float64, false),
        Field::new("angle", list_of_f32(), false),
        Field::new("torque", list_of_f32(), false),
        Field::new("time", list_of_f32(), false),
        Field::new("speed", list_of_f32(), false),
    ];
    if with_clamp_force {
        fields.push(Field::new("clamp_force", list_of_f32(), false));
    }
    Arc::new(Schema::new(fields))
}

/// Schema of [`Simulated::truth`]. Fault columns are null for tightenings without a fault.
/// Angles are true (unquantised) angles on the same axis as the `angle` channel.
///
/// Columns: `tightening_id`, `strategy`, `has_change`, `fault_kind`, `fault_component`,
/// `magnitude` (signed relative change of mu), `onset_angle` \[deg\], `onset_index` (first
/// sample at or past the onset; null if the curve ends before it), `mu_th`, `mu_b` (true
/// coefficients before any fault; with speed or pressure friction on, their values at 30 rpm
/// and at the target preload), `joint_stiffness` \[kN/deg\], `snug_angle`,
/// `elastic_start_angle`, `final_angle` \[deg\], `preload` \[kN\], `n_samples`, then
/// `thread` (designation), `mu_tot` (what the ISO 16047 evaluation
/// [`JointGeometry::mu_tot`] gives for the fault-free torque per clamp force of the true
/// `mu_th`, `mu_b`), `prevailing_torque` \[Nm\] (thread's own plus the locking element's),
/// `yield_angle` \[deg\] (where the clamp-force gradient starts to fall; null without
/// `with_yield` or when the curve ends before it), `effects` (comma-separated names of the
/// effects switched on, "" if none) and `runout_phase` \[rad\] (the drawn `phi` of the run-out;
/// null when run-out is off).
pub fn truth_schema() -> SchemaRef {
    Arc::new(Schema::new(vec![
        Field::new("tightening_id", DataType::Int64, false),
        Field::new("strategy", DataType::Utf8, false),
        Field::new("has_change", DataType::Boolean, false),
        Field::new("fault_kind", DataType::Utf8, true),
        Field::new("fault_component", DataType::Utf8, true),
        Field::new("magnitude", DataType::Float64, true),
        Field::new("onset_angle", DataType::Float64, true),
        Field::new("onset_index", DataType::Int64, true),
        Field::new("mu_th", DataType::Float64, false),
        Field::new("mu_b", DataType::Float64, false),
        Field::new("joint_stiffness", DataType::Float64, false),
        Field::new("snug_angle", DataType::Float64, false),
        Field::new("elastic_start_angle", DataType::Float64, false),
        Field::new("final_angle", DataType::Float64, false),
        Field::new("preload", DataType::Float64, false),
        Field::new("n_samples", DataType::Int64, false),
        Field::new("thread", DataType::Utf8, false),
        Field::new("mu_tot", DataType::Float64, false),
        Field::new("prevailing_torque", DataType::Float64, false),
        Field::new("yield_angle", DataType::Float64, true),
        Field::new("effects", DataType::Utf8, false),
        Field::new("runout_phase", DataType::Float64, true),
    ]))
}

// ---------------------------------------------------------------------------------------------
// Physical and tool constants (METHODS.md section 1; tool values typical of EC nutrunners).

/// The truth row of one tightening. Everything in it follows from the true trajectory, which
/// does not depend on the measurement noise.
pub(super) struct Truth {
    pub(super) strategy: Strategy,
    pub(super) thread: &'static str,
    pub(super) target_torque: f64,
    pub(super) fault: Option<Fault>,
    pub(super) onset_index: Option<usize>,
    pub(super) mu_th: f64,
    pub(super) mu_b: f64,
    pub(super) mu_tot: f64,
    pub(super) k_joint: f64,
    pub(super) prevailing: f64,
    pub(super) snug_angle: f64,
    pub(super) elastic_start_angle: f64,
    pub(super) yield_angle: Option<f64>,
    pub(super) final_angle: f64,
    pub(super) preload: f64,
    pub(super) n_samples: usize,
    pub(super) runout_phase: Option<f64>,
}

/// Where one tightening's measured samples go: its rows of the final channel buffers.
pub(super) struct Channels<'o> {
    pub(super) time: &'o mut [f32],
    pub(super) angle: &'o mut [f32],
    pub(super) torque: &'o mut [f32],
    pub(super) speed: &'o mut [f32],
    /// Empty when the clamp-force channel is off.
    pub(super) clamp_force: &'o mut [f32],
}

/// Evaluates the model at an angle and records one sample. Without a [`Measurement`] it only
/// follows the true trajectory (to count samples and fill the truth row).
pub(super) struct Recorder<'a, 'o> {
    pub(super) draw: &'a Draw,
    pub(super) friction: FrictionPath,
    pub(super) params_rng: Xoshiro256PlusPlus,
    pub(super) measurement: Option<Measurement<'o>>,
    pub(super) len: usize,
    pub(super) onset_index: Option<usize>,
    pub(super) last_theta: f64,
    pub(super) last_force: f64,
    /// Speed of the interval that ended at the last sample \[rpm\].
    pub(super) last_rpm: f64,
    /// Last non-zero speed \[rpm\]: friction at standstill keeps its last sliding value.
    pub(super) sliding_rpm: f64,
    /// (speed \[rpm\], speed-friction factor) last computed: the speed is constant over long
    /// stretches (rundown, CST, CSDT), so the logarithm is only taken when it changes.
    pub(super) speed_factor: (f64, f64),
}

impl Recorder<'_, '_> {
    /// Factor of both friction coefficients from the speed and pressure effects: 1 when both
    /// are off, or without clamp force (the friction terms are then multiplied by F = 0).
    pub(super) fn condition_factor(&mut self, force: f64) -> f64 {
        let d = self.draw;
        let e = &d.effects;
        if force <= 0.0 || (e.speed_friction == 0.0 && e.pressure_friction == 0.0) {
            return 1.0;
        }
        let mut factor = 1.0;
        if e.speed_friction != 0.0 {
            if self.speed_factor.0 != self.sliding_rpm {
                // mu_eff = mu (1 + a ln(v / v_ref)), held below v_min (EffectsConfig docs).
                let v = self.sliding_rpm.max(SPEED_FRICTION_MIN_RPM);
                let value = (1.0 + e.speed_friction * (v / SPEED_FRICTION_REF_RPM).ln()).max(0.0);
                self.speed_factor = (self.sliding_rpm, value);
            }
            factor *= self.speed_factor.1;
        }
        if e.pressure_friction != 0.0 {
            // mu_eff = mu (1 + c (F / F_t - 1)): mu holds at the target preload.
            let relative = force * d.inverse_preload_target - 1.0;
            factor *= (1.0 + e.pressure_friction * relative).max(0.0);
        }
        factor
    }

    /// Records the sample at time `t`, true angle `theta`, speed `rpm`; `relaxation` is
    /// subtracted from the model torque. Returns the true torque, which is what the controller
    /// acts on.
    pub(super) fn record(&mut self, t: f64, theta: f64, rpm: f64, relaxation: f64) -> f64 {
        let d = self.draw;
        let (m_th, m_b) = self.friction.multipliers(theta, &mut self.params_rng);
        let force = d.clamp_force(theta);
        if rpm > 0.0 {
            self.sliding_rpm = rpm;
        }
        let condition = self.condition_factor(force);
        let torque = d.prevailing
            + force
                * d.thread.torque_per_force(d.mu_th * m_th * condition, d.mu_b * m_b * condition)
            - relaxation;
        if self.onset_index.is_none() {
            if let Some(f) = d.fault {
                if theta >= f.onset_deg {
                    self.onset_index = Some(self.len);
                }
            }
        }
        if let Some(m) = self.measurement.as_mut() {
            let measured_angle = if m.resolution > 0.0 {
                // theta >= 0, so truncation is the floor (and avoids a libm call per sample).
                ((theta / m.resolution) as i64) as f64 * m.resolution
            } else {
                theta
            };
            let measured_torque = m.transduce(d, torque, theta, rpm, self.last_rpm);
            // Both normals are always drawn so the speed noise does not depend on torque_noise.
            let z_torque: f64 = m.noise_rng.sample(StandardNormal);
            let z_speed: f64 = m.noise_rng.sample(StandardNormal);
            let k = self.len;
            // The counting pass sized the rows; `get_mut` only guards against a mismatch.
            if let Some(v) = m.out.time.get_mut(k) {
                *v = t as f32;
            }
            if let Some(v) = m.out.angle.get_mut(k) {
                *v = measured_angle as f32;
            }
            if let Some(v) = m.out.torque.get_mut(k) {
                *v = (measured_torque + m.torque_sd * z_torque) as f32;
            }
            if let Some(v) = m.out.speed.get_mut(k) {
                *v = (rpm + SPEED_NOISE_RPM * z_speed) as f32;
            }
            if let Some(v) = m.out.clamp_force.get_mut(k) {
                let z: f64 = m.clamp_rng.sample(StandardNormal);
                *v = (force + m.clamp_sd * z) as f32;
            }
        }
        self.len += 1;
        self.last_theta = theta;
        self.last_force = force;
        self.last_rpm = rpm;
        torque
    }
}

/// Cuts `buffer` into consecutive rows of the given lengths.
pub(super) fn split_rows<'a>(mut buffer: &'a mut [f32], lengths: &[usize]) -> Vec<&'a mut [f32]> {
    let mut rows = Vec::with_capacity(lengths.len());
    for &len in lengths {
        let len = len.min(buffer.len());
        let (row, rest) = std::mem::take(&mut buffer).split_at_mut(len);
        rows.push(row);
        buffer = rest;
    }
    rows
}

pub(super) fn list_column(offsets: &OffsetBuffer<i32>, values: Vec<f32>) -> Result<ArrayRef> {
    let field = Arc::new(Field::new_list_field(DataType::Float32, true));
    let values = Arc::new(Float32Array::new(ScalarBuffer::from(values), None));
    Ok(Arc::new(ListArray::try_new(field, offsets.clone(), values, None)?))
}

pub(super) fn assemble(
    config: &SimulationConfig,
    truths: &[Truth],
    offsets: &OffsetBuffer<i32>,
    channels: [Vec<f32>; 4],
    clamp: Vec<f32>,
) -> Result<Simulated> {
    let n = truths.len();
    let ids: ArrayRef =
        Arc::new(Int64Array::from_iter_values((0..n).map(|i| config.first_id + i as i64)));
    let strategies: ArrayRef =
        Arc::new(StringArray::from_iter_values(truths.iter().map(|t| t.strategy.as_str())));
    let f64s = |get: fn(&Truth) -> f64| -> ArrayRef {
        Arc::new(Float64Array::from_iter_values(truths.iter().map(get)))
    };
    let [time, angle, torque, speed] = channels;
    let mut columns: Vec<ArrayRef> = vec![
        ids.clone(),
        strategies.clone(),
        Arc::new(StringArray::from_iter_values(truths.iter().map(|t| t.thread))),
        f64s(|t| t.target_torque),
        list_column(offsets, angle)?,
        list_column(offsets, torque)?,
        list_column(offsets, time)?,
        list_column(offsets, speed)?,
    ];
    if config.with_clamp_force {
        columns.push(list_column(offsets, clamp)?);
    }
    let tightenings = RecordBatch::try_new(tightenings_schema(config.with_clamp_force), columns)?;

    let truth_columns: Vec<ArrayRef> = vec![
        ids,
        strategies,
        Arc::new(BooleanArray::from(truths.iter().map(|t| t.fault.is_some()).collect::<Vec<_>>())),
        Arc::new(StringArray::from(
            truths.iter().map(|t| t.fault.map(|f| f.kind.as_str())).collect::<Vec<_>>(),
        )),
        Arc::new(StringArray::from(
            truths.iter().map(|t| t.fault.map(|f| f.component.as_str())).collect::<Vec<_>>(),
        )),
        Arc::new(Float64Array::from(
            truths.iter().map(|t| t.fault.map(|f| f.magnitude)).collect::<Vec<_>>(),
        )),
        Arc::new(Float64Array::from(
            truths.iter().map(|t| t.fault.map(|f| f.onset_deg)).collect::<Vec<_>>(),
        )),
        Arc::new(Int64Array::from(
            truths.iter().map(|t| t.onset_index.map(|k| k as i64)).collect::<Vec<_>>(),
        )),
        f64s(|t| t.mu_th),
        f64s(|t| t.mu_b),
        f64s(|t| t.k_joint),
        f64s(|t| t.snug_angle),
        f64s(|t| t.elastic_start_angle),
        f64s(|t| t.final_angle),
        f64s(|t| t.preload),
        Arc::new(Int64Array::from_iter_values(truths.iter().map(|t| t.n_samples as i64))),
        Arc::new(StringArray::from_iter_values(truths.iter().map(|t| t.thread))),
        f64s(|t| t.mu_tot),
        f64s(|t| t.prevailing),
        Arc::new(Float64Array::from(truths.iter().map(|t| t.yield_angle).collect::<Vec<_>>())),
        Arc::new(StringArray::from_iter_values(std::iter::repeat_n(
            config.effects.enabled_names(),
            n,
        ))),
        Arc::new(Float64Array::from(truths.iter().map(|t| t.runout_phase).collect::<Vec<_>>())),
    ];
    let truth = RecordBatch::try_new(truth_schema(), truth_columns)?;
    Ok(Simulated { tightenings, truth })
}
