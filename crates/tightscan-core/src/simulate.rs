//! Labelled synthetic tightenings: reproducible, parallel and fast.
//!
//! Every tightening is a torque-controlled rundown of an ISO metric bolt (geometry from
//! [`crate::thread`]) into a joint of random stiffness, recorded like a nutrunner records it
//! (time, quantised angle, noisy torque, speed, optionally clamp force), with or without a
//! friction fault of known kind, component, size and onset. The physics follows METHODS.md
//! section 1:
//!
//! - torque model (VDI 2230 Part 1, R13/1), F in kN, lengths in mm, T in Nm:
//!   `T(theta) = T_p + F(theta) * (0.16 P + 0.58 d2 mu_th(theta) + (Dkm/2) mu_b(theta))`,
//!   with a constant prevailing torque `T_p` (thread engagement, locking elements);
//! - clamp force over angle: zero during the rundown, quadratic in the alignment zone of width
//!   `w_s` that starts at `theta_0` (`F = k x^2 / (2 w_s)`, `x = theta - theta_0`: the joint
//!   surfaces seat progressively), then linear in the elastic zone (`F = k (x - w_s/2)`), the
//!   two pieces meeting with equal value and slope at `x = w_s`. The elastic line meets the
//!   prevailing-torque level at the snug angle `theta_0 + w_s/2`. No yield zone is modelled:
//!   with mu >= 0.10 the preload stays below about 80 % of the minimum yield strength of class
//!   8.8 (tensile stress alone), but a friction fault of -30 % can push it towards yield, where
//!   a real curve would flatten;
//! - friction faults are multiplicative changes of `mu_th`, `mu_b` or both (abrupt step,
//!   incipient ramp, intermittent on/off), placed inside the elastic zone, where friction
//!   diagnosis belongs;
//! - the controller stops on the true torque reaching the target, so the preload varies with the
//!   real friction, as in a production torque-controlled tightening;
//! - tool: the rundown speed is reached after a short linear start-up ramp (20-50 ms); the
//!   speed recorded at a sample is the speed of the interval that ended there (instantaneous
//!   speed during the HDT coast-down); strategies as described on [`Strategy`].
//!
//! Reproducibility: tightening `i` draws everything from its own generator seeded with
//! `mix(seed, first_id + i)`, so a row is the same whatever the number of threads and whichever
//! chunk generates it (`simulate(n = 10, first_id = 0)` rows 5..10 equal
//! `simulate(n = 5, first_id = 5)`). Parameters, measurement noise and clamp-force noise come from
//! three non-overlapping streams of that generator, so changing a noise level or switching the
//! clamp-force channel on leaves the curves' parameters unchanged.

use std::fmt;
use std::str::FromStr;
use std::sync::Arc;

use arrow_array::{
    ArrayRef, BooleanArray, Float32Array, Float64Array, Int64Array, ListArray, RecordBatch,
    StringArray,
};
use arrow_buffer::{OffsetBuffer, ScalarBuffer};
use arrow_schema::{DataType, Field, Schema, SchemaRef};
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;

use crate::error::{Result, TightscanError};
use crate::thread::{parse_thread, ThreadGeometry};

/// Tightening strategy of the simulated nutrunner.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Strategy {
    /// Constant speed: rundown at 200-400 rpm until 10 deg before the seating zone, then one
    /// constant final speed (20-60 rpm) up to the target torque.
    Cst,
    /// Constant speed, double step: as CST, but the first step stops at 50-70 % of the target;
    /// a pause of 0.05-0.2 s follows (angle held, speed 0, torque relaxing by 0.5-2 % with a
    /// 20 ms time constant), then a second step at 10-40 rpm to the target.
    Csdt,
    /// Decelerating: rundown as CST, then the speed falls as the torque nears the target,
    /// `v = v0 sqrt(max(0.05, 1 - T/target))` with `v0` 150-300 rpm; at the target the tool's
    /// inertia carries it 0.2-1.0 deg further, so the final torque overshoots a little.
    Hdt,
}

impl Strategy {
    /// Every strategy, in declaration order.
    pub const ALL: [Strategy; 3] = [Strategy::Cst, Strategy::Csdt, Strategy::Hdt];

    /// Name used in tables: "CST", "CSDT" or "HDT".
    pub fn as_str(self) -> &'static str {
        match self {
            Strategy::Cst => "CST",
            Strategy::Csdt => "CSDT",
            Strategy::Hdt => "HDT",
        }
    }
}

/// Time course of a friction fault.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultKind {
    /// Step change of the coefficient at the onset angle.
    Abrupt,
    /// Linear drift from the onset, reaching the full change after a ramp angle.
    Incipient,
    /// Alternating on/off intervals of 2-6 deg each after the onset, starting "on".
    Intermittent,
}

impl FaultKind {
    /// Every fault kind, in declaration order.
    pub const ALL: [FaultKind; 3] =
        [FaultKind::Abrupt, FaultKind::Incipient, FaultKind::Intermittent];

    /// Name used in tables: "abrupt", "incipient" or "intermittent".
    pub fn as_str(self) -> &'static str {
        match self {
            FaultKind::Abrupt => "abrupt",
            FaultKind::Incipient => "incipient",
            FaultKind::Intermittent => "intermittent",
        }
    }
}

/// Which friction coefficient a fault changes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultComponent {
    /// Thread friction `mu_th` only.
    Thread,
    /// Head (bearing) friction `mu_b` only.
    Bearing,
    /// Both coefficients by the same factor.
    Both,
}

impl FaultComponent {
    /// Every component, in declaration order.
    pub const ALL: [FaultComponent; 3] =
        [FaultComponent::Thread, FaultComponent::Bearing, FaultComponent::Both];

    /// Name used in tables: "thread", "bearing" or "both".
    pub fn as_str(self) -> &'static str {
        match self {
            FaultComponent::Thread => "thread",
            FaultComponent::Bearing => "bearing",
            FaultComponent::Both => "both",
        }
    }
}

/// Case-insensitive lookup of a name among the `as_str` spellings of `all`.
fn parse_named<T: Copy>(
    text: &str,
    all: &[T],
    name: fn(T) -> &'static str,
    parameter: &str,
) -> Result<T> {
    let wanted = text.trim();
    all.iter().copied().find(|v| name(*v).eq_ignore_ascii_case(wanted)).ok_or_else(|| {
        let expected: Vec<_> = all.iter().map(|v| name(*v)).collect();
        TightscanError::parameter(
            parameter,
            format!("unknown value {text:?}, expected one of {}", expected.join(", ")),
        )
    })
}

macro_rules! named_enum_traits {
    ($ty:ty, $parameter:literal) => {
        impl FromStr for $ty {
            type Err = TightscanError;
            /// Parses the `as_str` spelling, ignoring case and surrounding spaces.
            fn from_str(s: &str) -> Result<Self> {
                parse_named(s, &<$ty>::ALL, <$ty>::as_str, $parameter)
            }
        }
        impl fmt::Display for $ty {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(self.as_str())
            }
        }
    };
}
named_enum_traits!(Strategy, "strategy");
named_enum_traits!(FaultKind, "fault_kind");
named_enum_traits!(FaultComponent, "fault_component");

/// Settings of [`simulate`]. Start from `SimulationConfig::default()` and change fields.
#[derive(Clone, Debug)]
pub struct SimulationConfig {
    /// Number of tightenings (0 gives empty batches).
    pub n: usize,
    /// Seed of the whole run; with `first_id` it fixes every row.
    pub seed: u64,
    /// Probability that a tightening has a friction fault, in [0, 1]. Default 0.5.
    pub fault_fraction: f64,
    /// Strategies drawn uniformly from this list (repeat an entry to weight it). Default all three.
    pub strategies: Vec<Strategy>,
    /// Fault kinds drawn uniformly from this list. Default all three.
    pub fault_kinds: Vec<FaultKind>,
    /// Fault components drawn uniformly from this list. Default all three.
    pub fault_components: Vec<FaultComponent>,
    /// Range of |relative multiplicative change| of mu, `0 <= lo <= hi < 1`; the sign is + or -
    /// with equal probability. Default (0.05, 0.30).
    pub magnitude_range: (f64, f64),
    /// Thread designations drawn uniformly (see [`crate::thread::parse_thread`]).
    /// Default M6, M8, M10, M12.
    pub threads: Vec<String>,
    /// Standard deviation of the additive Gaussian torque noise, as a fraction of the target
    /// torque. Default 0.002.
    pub torque_noise: f64,
    /// Encoder resolution \[deg\]: the angle channel is quantised down to multiples of it
    /// (0 = no quantisation). Default 0.1.
    pub angle_resolution_deg: f64,
    /// Sampling rate \[Hz\], in (0, 1e6]. Default 2000.
    pub sample_rate_hz: f64,
    /// Whether to add the `clamp_force` channel (test-rig data). Default false.
    pub with_clamp_force: bool,
    /// `tightening_id` of the first row, so that chunks can be concatenated. Default 0.
    pub first_id: i64,
}

impl Default for SimulationConfig {
    fn default() -> Self {
        Self {
            n: 1000,
            seed: 0,
            fault_fraction: 0.5,
            strategies: Strategy::ALL.to_vec(),
            fault_kinds: FaultKind::ALL.to_vec(),
            fault_components: FaultComponent::ALL.to_vec(),
            magnitude_range: (0.05, 0.30),
            threads: ["M6", "M8", "M10", "M12"].iter().map(|s| (*s).to_owned()).collect(),
            torque_noise: 0.002,
            angle_resolution_deg: 0.1,
            sample_rate_hz: 2000.0,
            with_clamp_force: false,
            first_id: 0,
        }
    }
}

/// Highest sampling rate accepted: beyond it a tightening would hold millions of samples.
const MAX_SAMPLE_RATE_HZ: f64 = 1.0e6;

impl SimulationConfig {
    /// Checks every field; the error names the offending field.
    pub fn validate(&self) -> Result<()> {
        fn p(name: &str, message: impl Into<String>) -> TightscanError {
            TightscanError::parameter(name, message)
        }
        if !(self.fault_fraction.is_finite() && (0.0..=1.0).contains(&self.fault_fraction)) {
            return Err(p(
                "fault_fraction",
                format!("must be in [0, 1], got {}", self.fault_fraction),
            ));
        }
        if self.strategies.is_empty() {
            return Err(p("strategies", "must not be empty"));
        }
        if self.fault_kinds.is_empty() {
            return Err(p("fault_kinds", "must not be empty"));
        }
        if self.fault_components.is_empty() {
            return Err(p("fault_components", "must not be empty"));
        }
        let (lo, hi) = self.magnitude_range;
        if !(lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo <= hi && hi < 1.0) {
            return Err(p(
                "magnitude_range",
                format!(
                    "must satisfy 0 <= lo <= hi < 1 (a change of -100 % would remove \
                     friction), got ({lo}, {hi})"
                ),
            ));
        }
        if self.threads.is_empty() {
            return Err(p("threads", "must not be empty"));
        }
        if let Some(bad) = self.threads.iter().find(|t| parse_thread(t).is_none()) {
            return Err(p("threads", format!("unknown ISO metric thread {bad:?}")));
        }
        if !(self.torque_noise.is_finite() && self.torque_noise >= 0.0) {
            return Err(p(
                "torque_noise",
                format!("must be finite and >= 0, got {}", self.torque_noise),
            ));
        }
        if !(self.angle_resolution_deg.is_finite() && self.angle_resolution_deg >= 0.0) {
            return Err(p(
                "angle_resolution_deg",
                format!("must be finite and >= 0, got {}", self.angle_resolution_deg),
            ));
        }
        if !(self.sample_rate_hz.is_finite()
            && self.sample_rate_hz > 0.0
            && self.sample_rate_hz <= MAX_SAMPLE_RATE_HZ)
        {
            return Err(p(
                "sample_rate_hz",
                format!("must be in (0, {MAX_SAMPLE_RATE_HZ}], got {}", self.sample_rate_hz),
            ));
        }
        let fits = i64::try_from(self.n).ok().and_then(|n| self.first_id.checked_add(n)).is_some();
        if !fits {
            return Err(p("first_id", "first_id + n overflows a 64-bit tightening_id"));
        }
        Ok(())
    }
}

/// Output of [`simulate`]: the curves and their ground truth, row `i` of both describing the
/// same tightening.
#[derive(Clone, Debug)]
pub struct Simulated {
    /// One row per tightening, channels as lists; schema [`tightenings_schema`].
    pub tightenings: RecordBatch,
    /// One row per tightening with the labels and the hidden parameters; schema [`truth_schema`].
    pub truth: RecordBatch,
}

fn list_of_f32() -> DataType {
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
    ]))
}

// ---------------------------------------------------------------------------------------------
// Physical and tool constants (METHODS.md section 1; tool values typical of EC nutrunners).

/// Friction coefficient the target torque is computed for (VDI 2230 style nominal value).
const NOMINAL_MU: f64 = 0.14;
/// Target preload stress \[MPa\]: 0.6 * 640 MPa, 60 % of the minimum lower yield strength of
/// property class 8.8 (ISO 898-1, d <= 16 mm).
const TARGET_PRELOAD_STRESS_MPA: f64 = 0.6 * 640.0;
/// Range of the real friction coefficients, lightly oiled steel (METHODS.md section 1).
const MU_RANGE: (f64, f64) = (0.10, 0.20);
/// Elastic angle from snug to the target preload \[deg\]: hard (20) to soft (120) joints.
const ELASTIC_ANGLE_RANGE: (f64, f64) = (20.0, 120.0);
/// Prevailing torque as a fraction of the target torque.
const PREVAILING_RANGE: (f64, f64) = (0.01, 0.05);
/// Rundown before the alignment zone: 1 to 3 revolutions \[deg\].
const RUNDOWN_ANGLE_RANGE: (f64, f64) = (360.0, 1080.0);
/// Width of the alignment (seating) zone \[deg\].
const SNUG_WIDTH_RANGE: (f64, f64) = (3.0, 10.0);
/// The rundown speed is left this many degrees before the alignment zone starts.
const SWITCH_BEFORE_SNUG_DEG: f64 = 10.0;
/// Rundown speed \[rpm\].
const RUNDOWN_RPM: (f64, f64) = (200.0, 400.0);
/// Time for the motor to reach rundown speed from standstill \[s\].
const ACCELERATION_TIME_S: (f64, f64) = (0.02, 0.05);
/// Final speed of CST, also the speed of the first step of CSDT after the rundown \[rpm\].
const FINAL_RPM: (f64, f64) = (20.0, 60.0);
/// CSDT: torque of the first step as a fraction of the target.
const CSDT_FIRST_STEP: (f64, f64) = (0.5, 0.7);
/// CSDT: pause between the steps \[s\].
const CSDT_PAUSE_S: (f64, f64) = (0.05, 0.2);
/// CSDT: torque relaxation during the pause, fraction of the torque at the stop.
const CSDT_RELAXATION: (f64, f64) = (0.005, 0.02);
/// CSDT: time constant of the relaxation \[s\].
const CSDT_RELAX_TAU_S: f64 = 0.020;
/// CSDT: angle over which the relaxed torsion is wound up again after the restart \[deg\]. The
/// bolt shank is far stiffer in torsion than the joint is in clamping, so this is a fraction of
/// a degree and the curve rejoins the torque model almost at once.
const CSDT_RECOVERY_DEG: f64 = 0.1;
/// CSDT: speed of the second step \[rpm\].
const CSDT_SECOND_RPM: (f64, f64) = (10.0, 40.0);
/// HDT: initial speed of the decelerating phase \[rpm\].
const HDT_START_RPM: (f64, f64) = (150.0, 300.0);
/// HDT: floor of `1 - T/target` in the speed law, so the tool never stalls before the target.
const HDT_MIN_REMAINING: f64 = 0.05;
/// HDT: angle the tool's inertia carries it past the shut-off \[deg\].
const HDT_COAST_DEG: (f64, f64) = (0.2, 1.0);
/// Standard deviation of the speed measurement \[rpm\].
const SPEED_NOISE_RPM: f64 = 0.5;
/// Standard deviation of the clamp-force measurement, fraction of the target preload.
const CLAMP_NOISE_FRACTION: f64 = 0.005;
/// 1 rpm = 6 deg/s.
const DEG_PER_S_PER_RPM: f64 = 6.0;
/// Fault onset window, fractions of the elastic span (elastic start to fault-free end).
const ONSET_WINDOW: (f64, f64) = (0.30, 0.85);
/// Incipient ramp length, fraction of the angle from the onset to the fault-free end.
const INCIPIENT_RAMP: (f64, f64) = (0.2, 0.5);
/// Intermittent on/off interval length \[deg\].
const INTERMITTENT_INTERVAL_DEG: (f64, f64) = (2.0, 6.0);
/// Safety cap on samples per tightening (never reached with validated settings: the angle
/// always advances and the torque grows without bound with it).
const MAX_SAMPLES_PER_TIGHTENING: usize = 50_000_000;

// ---------------------------------------------------------------------------------------------

/// splitmix64 finaliser (Steele, Lea, Flood 2014): a bijective 64-bit mixer.
fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Seed of one tightening: distinct ids give distinct seeds for a given run seed (bijection).
fn mix(seed: u64, id: i64) -> u64 {
    splitmix64(splitmix64(seed) ^ (id as u64))
}

fn uniform(rng: &mut Xoshiro256PlusPlus, range: (f64, f64)) -> f64 {
    // Written out instead of `random_range` so that an empty range (lo == hi) is allowed.
    range.0 + (range.1 - range.0) * rng.random::<f64>()
}

fn pick<T: Copy>(rng: &mut Xoshiro256PlusPlus, items: &[T]) -> T {
    let i = (rng.random::<f64>() * items.len() as f64) as usize;
    items[i.min(items.len() - 1)]
}

#[derive(Clone, Copy, Debug)]
struct Fault {
    kind: FaultKind,
    component: FaultComponent,
    /// Signed relative change of the coefficient(s).
    magnitude: f64,
    onset_deg: f64,
    /// Incipient only: angle over which the change builds up.
    ramp_deg: f64,
}

/// The hidden parameters of one tightening.
struct Draw {
    strategy: Strategy,
    thread: &'static ThreadGeometry,
    mu_th: f64,
    mu_b: f64,
    preload_target_kn: f64,
    target_torque: f64,
    k_joint: f64,
    prevailing: f64,
    theta0: f64,
    snug_width: f64,
    rundown_rpm: f64,
    acceleration_s: f64,
    final_rpm: f64,
    csdt_first_step: f64,
    csdt_pause_s: f64,
    csdt_relaxation: f64,
    csdt_second_rpm: f64,
    hdt_start_rpm: f64,
    hdt_coast_deg: f64,
    fault: Option<Fault>,
}

impl Draw {
    fn new(
        rng: &mut Xoshiro256PlusPlus,
        config: &SimulationConfig,
        threads: &[&'static ThreadGeometry],
    ) -> Self {
        // Every value is drawn for every tightening, in a fixed order, so that e.g. the fault
        // fraction or the strategy list never shifts the stream of the others.
        let strategy = pick(rng, &config.strategies);
        let thread = pick(rng, threads);
        let mu_th = uniform(rng, MU_RANGE);
        let mu_b = uniform(rng, MU_RANGE);
        // Target preload F_t [kN] = sigma * As; the target torque is what the tightening
        // equation gives at nominal friction, rounded like a programmed controller value.
        let preload_target_kn = TARGET_PRELOAD_STRESS_MPA * thread.stress_area_mm2 / 1000.0;
        let target_torque =
            (preload_target_kn * thread.torque_per_force(NOMINAL_MU, NOMINAL_MU) * 10.0).round()
                / 10.0;
        // Joint stiffness from a target elastic angle: k = F_t / A_el [kN/deg].
        let elastic_angle = uniform(rng, ELASTIC_ANGLE_RANGE);
        let k_joint = preload_target_kn / elastic_angle;
        let prevailing = uniform(rng, PREVAILING_RANGE) * target_torque;
        let theta0 = uniform(rng, RUNDOWN_ANGLE_RANGE);
        let snug_width = uniform(rng, SNUG_WIDTH_RANGE);
        let rundown_rpm = uniform(rng, RUNDOWN_RPM);
        let acceleration_s = uniform(rng, ACCELERATION_TIME_S);
        let final_rpm = uniform(rng, FINAL_RPM);
        let csdt_first_step = uniform(rng, CSDT_FIRST_STEP);
        let csdt_pause_s = uniform(rng, CSDT_PAUSE_S);
        let csdt_relaxation = uniform(rng, CSDT_RELAXATION);
        let csdt_second_rpm = uniform(rng, CSDT_SECOND_RPM);
        let hdt_start_rpm = uniform(rng, HDT_START_RPM);
        let hdt_coast_deg = uniform(rng, HDT_COAST_DEG);

        let faulty = rng.random::<f64>() < config.fault_fraction;
        let kind = pick(rng, &config.fault_kinds);
        let component = pick(rng, &config.fault_components);
        let size = uniform(rng, config.magnitude_range);
        let sign = if rng.random::<bool>() { 1.0 } else { -1.0 };
        let onset_u = rng.random::<f64>();
        let ramp_u = uniform(rng, INCIPIENT_RAMP);

        // Where the fault-free curve meets the target: solve T_p + F(theta) K0 = target.
        let k0 = thread.torque_per_force(mu_th, mu_b);
        let force_needed = ((target_torque - prevailing) / k0).max(0.0);
        let x_end = if force_needed >= 0.5 * k_joint * snug_width {
            force_needed / k_joint + 0.5 * snug_width
        } else {
            (2.0 * snug_width * force_needed / k_joint).sqrt()
        };
        let fault_free_end = theta0 + x_end;
        let elastic_start = theta0 + snug_width;
        let span = (fault_free_end - elastic_start).max(0.0);
        let onset_deg =
            elastic_start + span * (ONSET_WINDOW.0 + (ONSET_WINDOW.1 - ONSET_WINDOW.0) * onset_u);
        let fault = faulty.then_some(Fault {
            kind,
            component,
            magnitude: sign * size,
            onset_deg,
            ramp_deg: ramp_u * (fault_free_end - onset_deg),
        });
        Self {
            strategy,
            thread,
            mu_th,
            mu_b,
            preload_target_kn,
            target_torque,
            k_joint,
            prevailing,
            theta0,
            snug_width,
            rundown_rpm,
            acceleration_s,
            final_rpm,
            csdt_first_step,
            csdt_pause_s,
            csdt_relaxation,
            csdt_second_rpm,
            hdt_start_rpm,
            hdt_coast_deg,
            fault,
        }
    }

    /// Clamp force \[kN\]: zero, then quadratic seating over `w_s`, then the elastic line.
    fn clamp_force(&self, theta: f64) -> f64 {
        let x = theta - self.theta0;
        let w = self.snug_width;
        if x <= 0.0 {
            0.0
        } else if x < w {
            self.k_joint * x * x / (2.0 * w)
        } else {
            self.k_joint * (x - 0.5 * w)
        }
    }
}

/// Friction multipliers along the angle. Angles are visited in non-decreasing order, which lets
/// the intermittent pattern be drawn lazily and still be a fixed function of the angle.
struct FrictionPath {
    fault: Option<Fault>,
    on: bool,
    next_toggle: f64,
}

impl FrictionPath {
    fn new(fault: Option<Fault>, rng: &mut Xoshiro256PlusPlus) -> Self {
        let next_toggle = match fault {
            Some(f) if f.kind == FaultKind::Intermittent => {
                f.onset_deg + uniform(rng, INTERMITTENT_INTERVAL_DEG)
            }
            _ => f64::INFINITY,
        };
        Self { fault, on: true, next_toggle }
    }

    /// (thread, bearing) multipliers of mu at `theta`.
    fn multipliers(&mut self, theta: f64, rng: &mut Xoshiro256PlusPlus) -> (f64, f64) {
        let Some(f) = self.fault else { return (1.0, 1.0) };
        if theta < f.onset_deg {
            return (1.0, 1.0);
        }
        let m = match f.kind {
            FaultKind::Abrupt => 1.0 + f.magnitude,
            FaultKind::Incipient => {
                let progress = if f.ramp_deg > 0.0 {
                    ((theta - f.onset_deg) / f.ramp_deg).min(1.0)
                } else {
                    1.0
                };
                1.0 + f.magnitude * progress
            }
            FaultKind::Intermittent => {
                while theta >= self.next_toggle {
                    self.on = !self.on;
                    self.next_toggle += uniform(rng, INTERMITTENT_INTERVAL_DEG);
                }
                if self.on {
                    1.0 + f.magnitude
                } else {
                    1.0
                }
            }
        };
        match f.component {
            FaultComponent::Thread => (m, 1.0),
            FaultComponent::Bearing => (1.0, m),
            FaultComponent::Both => (m, m),
        }
    }
}

/// The truth row of one tightening. Everything in it follows from the true trajectory, which
/// does not depend on the measurement noise.
struct Truth {
    strategy: Strategy,
    thread: &'static str,
    target_torque: f64,
    fault: Option<Fault>,
    onset_index: Option<usize>,
    mu_th: f64,
    mu_b: f64,
    k_joint: f64,
    snug_angle: f64,
    elastic_start_angle: f64,
    final_angle: f64,
    preload: f64,
    n_samples: usize,
}

/// Where one tightening's measured samples go: its rows of the final channel buffers.
struct Channels<'o> {
    time: &'o mut [f32],
    angle: &'o mut [f32],
    torque: &'o mut [f32],
    speed: &'o mut [f32],
    /// Empty when the clamp-force channel is off.
    clamp_force: &'o mut [f32],
}

/// Measurement side of a [`Recorder`]: noise generators, settings and the output rows.
struct Measurement<'o> {
    noise_rng: Xoshiro256PlusPlus,
    clamp_rng: Xoshiro256PlusPlus,
    torque_sd: f64,
    clamp_sd: f64,
    resolution: f64,
    out: Channels<'o>,
}

/// Evaluates the model at an angle and records one sample. Without a [`Measurement`] it only
/// follows the true trajectory (to count samples and fill the truth row).
struct Recorder<'a, 'o> {
    draw: &'a Draw,
    friction: FrictionPath,
    params_rng: Xoshiro256PlusPlus,
    measurement: Option<Measurement<'o>>,
    len: usize,
    onset_index: Option<usize>,
    last_theta: f64,
    last_force: f64,
}

impl Recorder<'_, '_> {
    /// Records the sample at time `t`, true angle `theta`, speed `rpm`; `relaxation` is
    /// subtracted from the model torque. Returns the true torque, which is what the controller
    /// acts on.
    fn record(&mut self, t: f64, theta: f64, rpm: f64, relaxation: f64) -> f64 {
        let d = self.draw;
        let (m_th, m_b) = self.friction.multipliers(theta, &mut self.params_rng);
        let force = d.clamp_force(theta);
        let torque = d.prevailing + force * d.thread.torque_per_force(d.mu_th * m_th, d.mu_b * m_b)
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
                *v = (torque + m.torque_sd * z_torque) as f32;
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
        torque
    }
}

#[derive(Clone, Copy)]
enum Phase {
    /// Fast rundown at (ramped-up) rundown speed.
    Rundown,
    /// Constant speed until the target torque (CST final step, CSDT second step).
    Final { rpm: f64 },
    /// CSDT first step, at the final speed, until the first-step torque.
    FirstStep,
    /// CSDT pause: the angle holds, the torque relaxes.
    Pause { start: f64, level: f64 },
    /// HDT: the speed falls with the remaining torque.
    Decelerating,
}

/// Simulates tightening `index` of the run. Without `out` only the true trajectory is followed
/// (first pass: sample count and truth); with `out` the measured channels are written into it
/// (second pass). Both passes take the same path: the controller acts on the true torque only.
fn simulate_one(
    config: &SimulationConfig,
    threads: &[&'static ThreadGeometry],
    index: usize,
    out: Option<Channels<'_>>,
) -> Truth {
    let id = config.first_id.wrapping_add(index as i64);
    let mut params_rng = Xoshiro256PlusPlus::seed_from_u64(mix(config.seed, id));
    let root = params_rng.clone();

    let draw = Draw::new(&mut params_rng, config, threads);
    let friction = FrictionPath::new(draw.fault, &mut params_rng);
    let measurement = out.map(|out| {
        // Jumps give 2^128-step separated streams: noise never overlaps the parameter draws.
        let mut noise_rng = root.clone();
        noise_rng.jump();
        let mut clamp_rng = noise_rng.clone();
        clamp_rng.jump();
        Measurement {
            noise_rng,
            clamp_rng,
            torque_sd: config.torque_noise * draw.target_torque,
            clamp_sd: CLAMP_NOISE_FRACTION * draw.preload_target_kn,
            resolution: config.angle_resolution_deg,
            out,
        }
    });
    let mut rec = Recorder {
        draw: &draw,
        friction,
        params_rng,
        measurement,
        len: 0,
        onset_index: None,
        last_theta: 0.0,
        last_force: 0.0,
    };
    run_controller(&mut rec, &draw, config.sample_rate_hz);
    debug_assert!(rec.measurement.as_ref().is_none_or(|m| m.out.time.len() == rec.len));
    Truth {
        strategy: draw.strategy,
        thread: draw.thread.designation,
        target_torque: draw.target_torque,
        fault: draw.fault,
        onset_index: rec.onset_index,
        mu_th: draw.mu_th,
        mu_b: draw.mu_b,
        k_joint: draw.k_joint,
        snug_angle: draw.theta0 + 0.5 * draw.snug_width,
        elastic_start_angle: draw.theta0 + draw.snug_width,
        final_angle: rec.last_theta,
        preload: rec.last_force,
        n_samples: rec.len,
    }
}

/// Time-steps the nutrunner: each sample is recorded, then the controller picks the speed of
/// the next interval from the true torque, and the angle is integrated with it. The speed
/// recorded at a sample is the speed of the interval that ended there.
fn run_controller(rec: &mut Recorder<'_, '_>, d: &Draw, sample_rate_hz: f64) {
    let dt = 1.0 / sample_rate_hz;
    let target = d.target_torque;
    let switch_angle = d.theta0 - SWITCH_BEFORE_SNUG_DEG;
    let mut phase = Phase::Rundown;
    let mut theta = 0.0_f64;
    let mut rpm_in = 0.0_f64;
    // Torsion relaxed during the CSDT pause, wound up again after the restart.
    let mut recovery: Option<(f64, f64)> = None; // (angle at restart, deficit [Nm])
    let mut step = 0_usize;
    loop {
        let t = step as f64 * dt;
        let relaxation = match (phase, recovery) {
            (Phase::Pause { start, level }, _) => {
                level * (1.0 - (-(t - start) / CSDT_RELAX_TAU_S).exp())
            }
            (_, Some((from, deficit))) => {
                let wound = (theta - from) / CSDT_RECOVERY_DEG;
                if wound > 40.0 {
                    recovery = None;
                    0.0
                } else {
                    deficit * (-wound).exp()
                }
            }
            _ => 0.0,
        };
        let torque = rec.record(t, theta, rpm_in, relaxation);
        step += 1;
        if step >= MAX_SAMPLES_PER_TIGHTENING {
            return;
        }
        // Resolve phase changes until a speed for the next interval is decided (None = stop).
        let next_rpm = loop {
            match phase {
                Phase::Rundown => {
                    if theta < switch_angle {
                        break Some(d.rundown_rpm * ((t + dt) / d.acceleration_s).min(1.0));
                    }
                    phase = match d.strategy {
                        Strategy::Cst => Phase::Final { rpm: d.final_rpm },
                        Strategy::Csdt => Phase::FirstStep,
                        Strategy::Hdt => Phase::Decelerating,
                    };
                }
                Phase::Final { rpm } => break (torque < target).then_some(rpm),
                Phase::FirstStep => {
                    if torque < d.csdt_first_step * target {
                        break Some(d.final_rpm);
                    }
                    phase = Phase::Pause { start: t, level: d.csdt_relaxation * torque };
                }
                Phase::Pause { start, .. } => {
                    if t - start + 0.5 * dt < d.csdt_pause_s {
                        break Some(0.0);
                    }
                    recovery = Some((theta, relaxation));
                    phase = Phase::Final { rpm: d.csdt_second_rpm };
                }
                Phase::Decelerating => {
                    if torque >= target {
                        coast(rec, theta, rpm_in, t, dt, d.hdt_coast_deg);
                        break None;
                    }
                    let remaining = (1.0 - torque / target).max(HDT_MIN_REMAINING);
                    break Some(d.hdt_start_rpm * remaining.sqrt());
                }
            }
        };
        match next_rpm {
            Some(rpm) => {
                theta += DEG_PER_S_PER_RPM * rpm * dt;
                rpm_in = rpm;
            }
            None => return,
        }
    }
}

/// HDT shut-off: the tool decelerates uniformly from `rpm` to rest over `coast_deg`, the torque
/// following the model all the way (hence the small overshoot of HDT curves).
fn coast(rec: &mut Recorder<'_, '_>, theta: f64, rpm: f64, t: f64, dt: f64, coast_deg: f64) {
    let omega = DEG_PER_S_PER_RPM * rpm;
    if omega <= 0.0 || coast_deg <= 0.0 {
        return;
    }
    let decel = omega * omega / (2.0 * coast_deg);
    let stop_after = 2.0 * coast_deg / omega;
    let samples = (stop_after / dt).ceil() as usize;
    for j in 1..=samples {
        // The last sample falls at or just after the stop: it shows the tool at rest.
        let tau = (j as f64 * dt).min(stop_after);
        let angle = theta + omega * tau - 0.5 * decel * tau * tau;
        let rpm_now = (omega - decel * tau).max(0.0) / DEG_PER_S_PER_RPM;
        rec.record(t + j as f64 * dt, angle, rpm_now, 0.0);
    }
}

/// Generates `config.n` labelled tightenings (in parallel with rayon).
///
/// The batches take about 16 bytes per sample (20 with clamp force), about 25 MB per 1,000
/// tightenings at the default settings: generate large sets in chunks with `first_id`.
///
/// Fails with [`TightscanError::InvalidParameter`] naming the field when `config` is invalid, or
/// naming `n` when the batch would hold more than `i32::MAX` samples per channel (generate it in
/// chunks with `first_id`).
pub fn simulate(config: &SimulationConfig) -> Result<Simulated> {
    config.validate()?;
    let threads: Vec<&'static ThreadGeometry> =
        config.threads.iter().filter_map(|t| parse_thread(t)).collect();

    // Pass 1: the true trajectories, for the sample counts and the truth rows. It is cheap next
    // to pass 2, and lets pass 2 write every sample once, straight into the final buffers:
    // collecting per-tightening vectors and concatenating them doubled the memory traffic,
    // which dominated the run time.
    let truths: Vec<Truth> =
        (0..config.n).into_par_iter().map(|i| simulate_one(config, &threads, i, None)).collect();
    let lengths: Vec<usize> = truths.iter().map(|t| t.n_samples).collect();
    let mut offsets = Vec::with_capacity(lengths.len() + 1);
    offsets.push(0_i32);
    let mut total = 0_usize;
    for len in &lengths {
        total += len;
        let end = i32::try_from(total).map_err(|_| {
            TightscanError::parameter(
                "n",
                "more than i32::MAX samples per channel in one batch; generate it in chunks with \
                 first_id",
            )
        })?;
        offsets.push(end);
    }

    // Pass 2: measured channels, each tightening into its own rows of the shared buffers.
    let clamp_total = if config.with_clamp_force { total } else { 0 };
    let (mut time, mut angle, mut torque, mut speed, mut clamp) = (
        vec![0.0_f32; total],
        vec![0.0_f32; total],
        vec![0.0_f32; total],
        vec![0.0_f32; total],
        vec![0.0_f32; clamp_total],
    );
    let clamp_lengths: Vec<usize> =
        if config.with_clamp_force { lengths.clone() } else { vec![0; lengths.len()] };
    let rows: Vec<Channels<'_>> = split_rows(&mut time, &lengths)
        .into_iter()
        .zip(split_rows(&mut angle, &lengths))
        .zip(split_rows(&mut torque, &lengths))
        .zip(split_rows(&mut speed, &lengths))
        .zip(split_rows(&mut clamp, &clamp_lengths))
        .map(|((((time, angle), torque), speed), clamp_force)| Channels {
            time,
            angle,
            torque,
            speed,
            clamp_force,
        })
        .collect();
    rows.into_par_iter().enumerate().for_each(|(i, out)| {
        simulate_one(config, &threads, i, Some(out));
    });

    let offsets = OffsetBuffer::new(ScalarBuffer::from(offsets));
    let channels = [time, angle, torque, speed];
    assemble(config, &truths, &offsets, channels, clamp)
}

/// Cuts `buffer` into consecutive rows of the given lengths.
fn split_rows<'a>(mut buffer: &'a mut [f32], lengths: &[usize]) -> Vec<&'a mut [f32]> {
    let mut rows = Vec::with_capacity(lengths.len());
    for &len in lengths {
        let len = len.min(buffer.len());
        let (row, rest) = std::mem::take(&mut buffer).split_at_mut(len);
        rows.push(row);
        buffer = rest;
    }
    rows
}

fn list_column(offsets: &OffsetBuffer<i32>, values: Vec<f32>) -> Result<ArrayRef> {
    let field = Arc::new(Field::new_list_field(DataType::Float32, true));
    let values = Arc::new(Float32Array::new(ScalarBuffer::from(values), None));
    Ok(Arc::new(ListArray::try_new(field, offsets.clone(), values, None)?))
}

fn assemble(
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
    ];
    let truth = RecordBatch::try_new(truth_schema(), truth_columns)?;
    Ok(Simulated { tightenings, truth })
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)] // a failed unwrap is a failed test
mod tests {
    use super::*;
    use arrow_array::Array;

    fn small(n: usize, seed: u64) -> SimulationConfig {
        SimulationConfig { n, seed, ..SimulationConfig::default() }
    }

    fn f32_list(batch: &RecordBatch, column: &str, row: usize) -> Vec<f64> {
        let list =
            batch.column_by_name(column).unwrap().as_any().downcast_ref::<ListArray>().unwrap();
        let values = list.value(row);
        let values = values.as_any().downcast_ref::<Float32Array>().unwrap();
        values.values().iter().map(|v| f64::from(*v)).collect()
    }

    fn f64_col(batch: &RecordBatch, column: &str) -> Float64Array {
        batch
            .column_by_name(column)
            .unwrap()
            .as_any()
            .downcast_ref::<Float64Array>()
            .unwrap()
            .clone()
    }

    fn i64_col(batch: &RecordBatch, column: &str) -> Int64Array {
        batch.column_by_name(column).unwrap().as_any().downcast_ref::<Int64Array>().unwrap().clone()
    }

    fn str_col(batch: &RecordBatch, column: &str) -> StringArray {
        batch
            .column_by_name(column)
            .unwrap()
            .as_any()
            .downcast_ref::<StringArray>()
            .unwrap()
            .clone()
    }

    /// Least-squares slope of y over x.
    fn slope(x: &[f64], y: &[f64]) -> f64 {
        let n = x.len() as f64;
        let mx = x.iter().sum::<f64>() / n;
        let my = y.iter().sum::<f64>() / n;
        let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
        let sxx: f64 = x.iter().map(|a| (a - mx) * (a - mx)).sum();
        sxy / sxx
    }

    #[test]
    fn same_seed_same_batches_whatever_the_thread_count() {
        let config = SimulationConfig { with_clamp_force: true, ..small(40, 7) };
        let a = simulate(&config).unwrap();
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let b = pool.install(|| simulate(&config)).unwrap();
        assert_eq!(a.tightenings, b.tightenings);
        assert_eq!(a.truth, b.truth);
        let c = simulate(&SimulationConfig { seed: 8, ..config }).unwrap();
        assert_ne!(a.tightenings, c.tightenings);
    }

    #[test]
    fn chunks_reproduce_the_same_rows() {
        let whole = simulate(&small(10, 3)).unwrap();
        let tail = simulate(&SimulationConfig { first_id: 5, ..small(5, 3) }).unwrap();
        assert_eq!(whole.tightenings.slice(5, 5), tail.tightenings);
        assert_eq!(whole.truth.slice(5, 5), tail.truth);
        assert_eq!(i64_col(&tail.truth, "tightening_id").values().to_vec(), vec![5, 6, 7, 8, 9]);
    }

    #[test]
    fn schemas_and_empty_batches() {
        let empty = simulate(&small(0, 1)).unwrap();
        assert_eq!(empty.tightenings.num_rows(), 0);
        assert_eq!(empty.truth.num_rows(), 0);
        assert_eq!(empty.tightenings.schema(), tightenings_schema(false));
        let s = simulate(&SimulationConfig { with_clamp_force: true, ..small(5, 1) }).unwrap();
        assert_eq!(s.tightenings.schema(), tightenings_schema(true));
        assert_eq!(s.truth.schema(), truth_schema());
        assert!(s.tightenings.column_by_name("clamp_force").is_some());
        assert!(simulate(&small(3, 1))
            .unwrap()
            .tightenings
            .column_by_name("clamp_force")
            .is_none());
    }

    #[test]
    fn channels_are_consistent() {
        let config = SimulationConfig { with_clamp_force: true, ..small(60, 11) };
        let s = simulate(&config).unwrap();
        let n_samples = i64_col(&s.truth, "n_samples");
        for row in 0..config.n {
            let angle = f32_list(&s.tightenings, "angle", row);
            let n = angle.len();
            assert_eq!(n as i64, n_samples.value(row));
            for column in ["torque", "time", "speed", "clamp_force"] {
                assert_eq!(f32_list(&s.tightenings, column, row).len(), n, "{column} row {row}");
            }
            assert_eq!(angle[0], 0.0);
            assert!(angle.windows(2).all(|w| w[1] >= w[0]), "angle decreases in row {row}");
            let time = f32_list(&s.tightenings, "time", row);
            assert_eq!(time[0], 0.0);
            assert!(
                ((time[n - 1] - time[0]) / (n - 1) as f64 - 1.0 / config.sample_rate_hz).abs()
                    < 1e-6
            );
            // Encoder quantisation: multiples of the resolution.
            assert!(angle.iter().all(|a| ((a / 0.1) - (a / 0.1).round()).abs() < 1e-3));
        }
    }

    #[test]
    fn typical_sample_counts() {
        let s = simulate(&small(300, 5)).unwrap();
        let mut counts = i64_col(&s.truth, "n_samples").values().to_vec();
        counts.sort_unstable();
        let median = counts[counts.len() / 2];
        assert!((500..=3000).contains(&median), "median {median}");
        assert!(counts[0] >= 200, "min {}", counts[0]);
    }

    #[test]
    fn cst_stops_at_the_target() {
        for noise in [0.0, 0.002] {
            let config = SimulationConfig {
                strategies: vec![Strategy::Cst],
                torque_noise: noise,
                ..small(300, 13)
            };
            let s = simulate(&config).unwrap();
            let targets = f64_col(&s.tightenings, "target_torque");
            let mut standardised = Vec::new();
            for row in 0..config.n {
                let torque = f32_list(&s.tightenings, "torque", row);
                let target = targets.value(row);
                let last = *torque.last().unwrap();
                if noise == 0.0 {
                    assert!(last >= target * (1.0 - 1e-6), "row {row}: {last} < {target}");
                    // The true torque crossed the target only at the last sample.
                    assert!(torque[..torque.len() - 1].iter().all(|t| *t < target));
                } else {
                    let sd = noise * target;
                    standardised.push((last - target) / sd);
                    assert!(last >= target - 5.0 * sd, "row {row}");
                }
            }
            if noise > 0.0 {
                let mean = standardised.iter().sum::<f64>() / standardised.len() as f64;
                assert!(mean > -1.0 / (standardised.len() as f64).sqrt() * 4.0, "mean {mean}");
            }
        }
    }

    #[test]
    fn strategies_have_their_shape() {
        let s =
            simulate(&SimulationConfig { torque_noise: 0.0, fault_fraction: 0.0, ..small(90, 17) })
                .unwrap();
        let strategies = str_col(&s.truth, "strategy");
        let targets = f64_col(&s.tightenings, "target_torque");
        let mut seen = [0; 3];
        for row in 0..90 {
            let angle = f32_list(&s.tightenings, "angle", row);
            let torque = f32_list(&s.tightenings, "torque", row);
            let speed = f32_list(&s.tightenings, "speed", row);
            let last = torque.len() - 1;
            let stalled = (1..angle.len())
                .filter(|&k| angle[k] == angle[k - 1] && speed[k].abs() < 3.0)
                .count();
            match strategies.value(row) {
                "CST" => seen[0] += 1,
                "CSDT" => {
                    seen[1] += 1;
                    // A pause of at least 0.05 s at 2 kHz in which the angle holds.
                    assert!(stalled >= 90, "row {row}: {stalled} stalled samples");
                }
                "HDT" => {
                    seen[2] += 1;
                    assert!(torque[last] > targets.value(row), "HDT overshoots");
                    assert!(speed[last].abs() < 3.0, "HDT comes to rest");
                }
                other => panic!("unexpected strategy {other}"),
            }
        }
        assert!(seen.iter().all(|c| *c > 10), "{seen:?}");
    }

    #[test]
    fn fault_fraction_is_respected() {
        for fraction in [0.0, 0.3, 1.0] {
            let n = 2000;
            let s =
                simulate(&SimulationConfig { fault_fraction: fraction, ..small(n, 21) }).unwrap();
            let flags = s.truth.column_by_name("has_change").unwrap();
            let flags = flags.as_any().downcast_ref::<BooleanArray>().unwrap();
            let count = flags.true_count() as f64;
            let sd = (n as f64 * fraction * (1.0 - fraction)).sqrt();
            assert!((count - n as f64 * fraction).abs() <= 4.0 * sd, "{fraction}: {count}");
            // Labels are null exactly when there is no change.
            for column in
                ["fault_kind", "fault_component", "magnitude", "onset_angle", "onset_index"]
            {
                let array = s.truth.column_by_name(column).unwrap();
                assert_eq!(array.null_count(), n - count as usize, "{column}");
            }
        }
    }

    #[test]
    fn fault_labels_are_in_range() {
        let s = simulate(&SimulationConfig {
            fault_fraction: 1.0,
            angle_resolution_deg: 0.0,
            ..small(300, 23)
        })
        .unwrap();
        let magnitude = f64_col(&s.truth, "magnitude");
        let onset = f64_col(&s.truth, "onset_angle");
        let onset_index = i64_col(&s.truth, "onset_index");
        let elastic_start = f64_col(&s.truth, "elastic_start_angle");
        let snug = f64_col(&s.truth, "snug_angle");
        let final_angle = f64_col(&s.truth, "final_angle");
        for row in 0..300 {
            let m = magnitude.value(row).abs();
            assert!((0.05..=0.30).contains(&m));
            assert!(snug.value(row) < elastic_start.value(row));
            assert!(
                onset.value(row) > elastic_start.value(row)
                    && onset.value(row) < final_angle.value(row)
            );
            let angle = f32_list(&s.tightenings, "angle", row);
            let k = onset_index.value(row) as usize;
            let tol = 1e-4 * onset.value(row);
            assert!(angle[k] >= onset.value(row) - tol);
            assert!(angle[k - 1] < onset.value(row) + tol);
        }
    }

    /// Elastic-zone torque rate expected from the truth row: k_joint (0.16 P + 0.58 d2 mu_th +
    /// Dkm/2 mu_b), optionally with the faulted coefficients.
    fn expected_rate(s: &Simulated, row: usize, faulted: bool) -> f64 {
        let thread = parse_thread(str_col(&s.tightenings, "thread").value(row)).unwrap();
        let k = f64_col(&s.truth, "joint_stiffness").value(row);
        let (mut mu_th, mut mu_b) =
            (f64_col(&s.truth, "mu_th").value(row), f64_col(&s.truth, "mu_b").value(row));
        if faulted {
            let factor = 1.0 + f64_col(&s.truth, "magnitude").value(row);
            match str_col(&s.truth, "fault_component").value(row) {
                "thread" => mu_th *= factor,
                "bearing" => mu_b *= factor,
                _ => {
                    mu_th *= factor;
                    mu_b *= factor;
                }
            }
        }
        k * thread.torque_per_force(mu_th, mu_b)
    }

    #[test]
    fn elastic_slope_matches_the_tightening_equation() {
        let config = SimulationConfig {
            strategies: vec![Strategy::Cst],
            fault_fraction: 0.0,
            torque_noise: 0.0,
            angle_resolution_deg: 0.0,
            ..small(50, 29)
        };
        let s = simulate(&config).unwrap();
        let elastic_start = f64_col(&s.truth, "elastic_start_angle");
        for row in 0..config.n {
            let angle = f32_list(&s.tightenings, "angle", row);
            let torque = f32_list(&s.tightenings, "torque", row);
            let (x, y): (Vec<f64>, Vec<f64>) = angle
                .iter()
                .zip(&torque)
                .filter(|(a, _)| **a > elastic_start.value(row) + 0.01)
                .map(|(a, t)| (*a, *t))
                .unzip();
            assert!(x.len() > 20);
            let expected = expected_rate(&s, row, false);
            let got = slope(&x, &y);
            assert!((got / expected - 1.0).abs() < 1e-3, "row {row}: {got} vs {expected}");
        }
    }

    #[test]
    fn abrupt_fault_changes_the_slope_by_its_factor() {
        let config = SimulationConfig {
            strategies: vec![Strategy::Cst],
            fault_fraction: 1.0,
            fault_kinds: vec![FaultKind::Abrupt],
            torque_noise: 0.0,
            angle_resolution_deg: 0.0,
            ..small(100, 31)
        };
        let s = simulate(&config).unwrap();
        let elastic_start = f64_col(&s.truth, "elastic_start_angle");
        let onset_index = i64_col(&s.truth, "onset_index");
        let mut checked = 0;
        for row in 0..config.n {
            let angle = f32_list(&s.tightenings, "angle", row);
            let torque = f32_list(&s.tightenings, "torque", row);
            let k = onset_index.value(row) as usize;
            let first = angle.iter().position(|a| *a > elastic_start.value(row) + 0.01).unwrap();
            if k - first < 10 || angle.len() - k < 10 {
                continue; // a jump to the target at the onset leaves nothing to fit
            }
            let before = slope(&angle[first..k], &torque[first..k]);
            let after = slope(&angle[k..], &torque[k..]);
            let expected = expected_rate(&s, row, true) / expected_rate(&s, row, false);
            assert!(
                (after / before / expected - 1.0).abs() < 1e-3,
                "row {row}: {} vs {expected}",
                after / before
            );
            checked += 1;
        }
        assert!(checked > 50, "only {checked} rows checked");
    }

    #[test]
    fn noise_and_clamp_channel_leave_the_parameters_alone() {
        let a = simulate(&small(20, 37)).unwrap();
        let b = simulate(&SimulationConfig {
            torque_noise: 0.0,
            with_clamp_force: true,
            ..small(20, 37)
        })
        .unwrap();
        assert_eq!(a.truth, b.truth);
        // Speed noise is the same too.
        assert_eq!(a.tightenings.column_by_name("speed"), b.tightenings.column_by_name("speed"));
    }

    #[test]
    fn clamp_force_follows_the_preload() {
        let s = simulate(&SimulationConfig { with_clamp_force: true, ..small(30, 41) }).unwrap();
        let preload = f64_col(&s.truth, "preload");
        for row in 0..30 {
            let force = f32_list(&s.tightenings, "clamp_force", row);
            let last = *force.last().unwrap();
            // Noise sd is 0.5 % of the target preload.
            assert!((last - preload.value(row)).abs() < 0.05 * preload.value(row), "row {row}");
            assert!(force[0].abs() < 0.05 * preload.value(row));
        }
    }

    #[test]
    fn enum_names_round_trip() {
        for s in Strategy::ALL {
            assert_eq!(s.as_str().parse::<Strategy>().unwrap(), s);
        }
        for k in FaultKind::ALL {
            assert_eq!(k.as_str().to_uppercase().parse::<FaultKind>().unwrap(), k);
        }
        for c in FaultComponent::ALL {
            assert_eq!(format!(" {c} ").parse::<FaultComponent>().unwrap(), c);
        }
        assert_eq!("csdt".parse::<Strategy>().unwrap(), Strategy::Csdt);
        let err = "TCAM".parse::<Strategy>();
        assert!(
            matches!(err, Err(TightscanError::InvalidParameter { name, .. }) if name == "strategy")
        );
        assert!("drift".parse::<FaultKind>().is_err());
        assert!("nut".parse::<FaultComponent>().is_err());
    }

    #[test]
    fn validate_names_the_field() {
        let cases: Vec<(&str, SimulationConfig)> = vec![
            ("fault_fraction", SimulationConfig { fault_fraction: 1.5, ..Default::default() }),
            ("fault_fraction", SimulationConfig { fault_fraction: f64::NAN, ..Default::default() }),
            ("strategies", SimulationConfig { strategies: vec![], ..Default::default() }),
            ("fault_kinds", SimulationConfig { fault_kinds: vec![], ..Default::default() }),
            (
                "fault_components",
                SimulationConfig { fault_components: vec![], ..Default::default() },
            ),
            (
                "magnitude_range",
                SimulationConfig { magnitude_range: (0.3, 0.1), ..Default::default() },
            ),
            (
                "magnitude_range",
                SimulationConfig { magnitude_range: (-0.1, 0.1), ..Default::default() },
            ),
            (
                "magnitude_range",
                SimulationConfig { magnitude_range: (0.1, 1.0), ..Default::default() },
            ),
            ("threads", SimulationConfig { threads: vec![], ..Default::default() }),
            (
                "threads",
                SimulationConfig { threads: vec!["M8".into(), "M7".into()], ..Default::default() },
            ),
            ("torque_noise", SimulationConfig { torque_noise: -0.1, ..Default::default() }),
            (
                "angle_resolution_deg",
                SimulationConfig { angle_resolution_deg: f64::INFINITY, ..Default::default() },
            ),
            ("sample_rate_hz", SimulationConfig { sample_rate_hz: 0.0, ..Default::default() }),
            ("sample_rate_hz", SimulationConfig { sample_rate_hz: -5.0, ..Default::default() }),
            ("first_id", SimulationConfig { first_id: i64::MAX, n: 2, ..Default::default() }),
        ];
        for (field, config) in cases {
            match config.validate() {
                Err(TightscanError::InvalidParameter { name, .. }) => assert_eq!(name, field),
                other => panic!("{field}: expected InvalidParameter, got {other:?}"),
            }
            assert!(simulate(&config).is_err());
        }
        assert!(SimulationConfig::default().validate().is_ok());
        assert!(SimulationConfig { n: 0, magnitude_range: (0.2, 0.2), ..Default::default() }
            .validate()
            .is_ok());
    }

    /// Generation speed, n = 10,000 with default settings:
    /// `cargo test --release -p tightscan-core --lib simulate::tests::speed -- --ignored --nocapture`
    #[test]
    #[ignore]
    fn speed() {
        let config = SimulationConfig { n: 10_000, ..SimulationConfig::default() };
        simulate(&SimulationConfig { n: 500, ..config.clone() }).unwrap();
        let mut best = f64::INFINITY;
        let mut samples = 0;
        for _ in 0..5 {
            let start = std::time::Instant::now();
            let s = simulate(&config).unwrap();
            best = best.min(start.elapsed().as_secs_f64());
            samples = i64_col(&s.truth, "n_samples").values().iter().sum::<i64>();
        }
        println!(
            "n = {}: {:.3} s best of 5 on {} threads, {} samples ({:.0} per tightening, {:.1} M/s)",
            config.n,
            best,
            rayon::current_num_threads(),
            samples,
            samples as f64 / config.n as f64,
            samples as f64 / best / 1e6
        );
    }
}
