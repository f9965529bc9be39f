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
//!   prevailing-torque level at the snug angle `theta_0 + w_s/2`. Joint stiffness `k` [kN/deg]
//!   is drawn from [`SimulationConfig::joint_stiffness_range`], or, by default, derived from the
//!   thread size: `k = F_t / A_el` with the target preload `F_t` and an elastic angle `A_el`
//!   from [`SimulationConfig::elastic_angle_range`] (20 deg hard to 120 deg soft, a
//!   hard-to-soft factor of 6 whatever the bolt size);
//! - yield zone (off by default, [`SimulationConfig::with_yield`]): the bolt yields at a clamp
//!   force `F_y`; past the yield angle the clamp-force gradient falls smoothly (smoothstep of
//!   the gradient over a transition angle) to a set fraction of the elastic gradient, so the
//!   torque gradient falls with it. Without it, the preload stays below about 80 % of the
//!   minimum yield strength of class 8.8 with mu >= 0.10 (tensile stress alone), but a friction
//!   fault of -30 % can push it towards yield, where a real curve would flatten;
//! - friction faults are multiplicative changes of `mu_th`, `mu_b` or both (abrupt step,
//!   incipient ramp, intermittent on/off), placed inside the elastic zone, where friction
//!   diagnosis belongs;
//! - the controller stops on the true torque reaching the target, so the preload varies with the
//!   real friction, as in a production torque-controlled tightening;
//! - tool: the rundown speed is reached after a short linear start-up ramp (20-50 ms); the
//!   speed recorded at a sample is the speed of the interval that ended there (instantaneous
//!   speed during the HDT coast-down); strategies as described on [`Strategy`];
//! - switchable effects the basic torque model lacks, all off by default, see [`EffectsConfig`]:
//!   speed- and pressure-dependent friction and a locking element's prevailing torque act on
//!   the true torque (the controller sees them); run-out, socket inertia and the transducer's
//!   low-pass act on the measured torque channel only.
//!
//! Reproducibility: tightening `i` draws everything from its own generator seeded with
//! `mix(seed, first_id + i)`, so a row is the same whatever the number of threads and whichever
//! chunk generates it (`simulate(n = 10, first_id = 0)` rows 5..10 equal
//! `simulate(n = 5, first_id = 5)`). Parameters, measurement noise, clamp-force noise and the
//! extras (yield point, run-out phase) come from four non-overlapping streams of that
//! generator, so changing a noise level, switching the clamp-force channel, the yield zone or an
//! effect on leaves the other draws (friction, stiffness, fault, ...) unchanged.

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
use crate::thread::{parse_thread, JointGeometry, ThreadGeometry};

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

/// Effects the basic torque model lacks, each switched off by its parameter being 0 (the
/// default). Each parameter has a physical meaning and unit; the table names of the effects
/// switched on go to the truth column `effects` in declaration order ([`EffectsConfig::NAMES`]).
///
/// Where they act: `speed_friction`, `pressure_friction` and `prevailing_torque_nm` change the
/// true torque, which the controller acts on; `runout`, `inertia` and `torque_lowpass_ms` are
/// properties of the measuring chain and change the recorded `torque` channel only. The
/// recorded torque is `LP[T (1 + r sin(2 pi theta/360 + phi)) + J alpha] + noise`: run-out
/// scales the transmitted torque, the inertial torque adds to it, the transducer's filter acts
/// on both, and the measurement noise (A/D) comes after the filter.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EffectsConfig {
    /// Speed-dependent friction, coefficient `a` (dimensionless, |a| <= 0.25): both friction
    /// coefficients follow the logarithmic rate law of boundary-lubricated contacts (the
    /// steady state of rate-and-state friction, `mu_0 + (a - b) ln(v / v_0)`, written relative
    /// to mu): `mu_eff = mu (1 + a ln(v / 30 rpm))`, with `v` the tool speed
    /// (the thread and under-head sliding speeds are both proportional to it, so one ratio
    /// serves both) and 30 rpm the reference speed at which `mu_th` and `mu_b` hold (typical of
    /// friction test benches). `a > 0`: friction rises with speed (viscous share), `a < 0`:
    /// it falls (Stribeck branch). Below 1 rpm the law is held at its 1 rpm value, and at
    /// standstill (CSDT pause) the friction keeps the value of the last sliding speed: the
    /// held torque does not jump when the tool stops. Matters for HDT, whose speed falls.
    pub speed_friction: f64,
    /// Time constant \[ms\] of a first-order low-pass on the recorded torque channel
    /// (transducer and anti-aliasing filter): `tau dy/dt = x - y`, discretised exactly for
    /// inputs linear between samples, so a torque ramp is recorded delayed by exactly `tau`.
    /// The controller shuts off on the unfiltered torque (the tool's own control loop).
    pub torque_lowpass_ms: f64,
    /// Rotational inertia `J` \[kg m^2\] between the torque transducer and the joint (socket,
    /// extension, output shaft; about 1e-4 to 1e-3): the transducer also carries the torque
    /// that accelerates it, so the recorded torque gains `J alpha` \[Nm\] with `alpha`
    /// \[rad/s^2\] the change of the interval speed between samples over the sample period.
    /// The speed steps of the idealised controller (rundown to final speed, CSDT restart)
    /// give one-sample spikes of `J dOmega / dt`, as a stiff drive would.
    pub inertia: f64,
    /// Pressure-dependent friction, coefficient `c` (dimensionless, |c| < 1): both friction
    /// coefficients scale with the clamp force, `mu_eff = mu (1 + c (F / F_t - 1))`, with
    /// `F_t` the target preload (where `mu_th` and `mu_b` hold). `c < 0`: friction falls with
    /// contact pressure (coatings, lubricant films), `c > 0`: it rises (galling). The
    /// multiplier is floored at 0. The torque-force curve then bends: `dT/dF` changes with `F`.
    pub pressure_friction: f64,
    /// Constant prevailing torque \[Nm\] of a locking element (nylon patch, deformed thread),
    /// added to the whole curve from engagement (the curve starts at engagement) on top of the
    /// thread's own small prevailing torque. As VDI 2230 prescribes for prevailing-torque
    /// screws, the programmed target torque is raised by the same amount, so the preload
    /// stays what it would be without the locking element.
    pub prevailing_torque_nm: f64,
    /// Once-per-revolution run-out amplitude `r` (dimensionless, 0 <= r < 1): the recorded
    /// torque is multiplied by `1 + r sin(2 pi theta / 360 + phi)` (eccentric socket or
    /// spindle, transducer misalignment), with the phase `phi` \[rad\] drawn uniformly per
    /// tightening (truth column `runout_phase`).
    pub runout: f64,
}

impl EffectsConfig {
    /// Table names of the effects, in declaration order (the field names).
    pub const NAMES: [&'static str; 6] = [
        "speed_friction",
        "torque_lowpass_ms",
        "inertia",
        "pressure_friction",
        "prevailing_torque_nm",
        "runout",
    ];

    /// The parameters in the order of [`EffectsConfig::NAMES`].
    pub fn values(&self) -> [f64; 6] {
        [
            self.speed_friction,
            self.torque_lowpass_ms,
            self.inertia,
            self.pressure_friction,
            self.prevailing_torque_nm,
            self.runout,
        ]
    }

    /// Comma-separated names of the effects switched on (non-zero parameter), "" if none.
    pub fn enabled_names(&self) -> String {
        Self::NAMES
            .iter()
            .zip(self.values())
            .filter(|(_, v)| *v != 0.0)
            .map(|(name, _)| *name)
            .collect::<Vec<_>>()
            .join(",")
    }

    /// Every effect on with a moderate, physically plausible value (for benchmarks and tests).
    pub fn all_on() -> Self {
        Self {
            speed_friction: 0.05,
            torque_lowpass_ms: 2.0,
            inertia: 2.0e-4,
            pressure_friction: -0.1,
            prevailing_torque_nm: 1.0,
            runout: 0.01,
        }
    }

    fn validate(&self) -> Result<()> {
        let check = |name: &str, value: f64, ok: bool, rule: &str| -> Result<()> {
            if value.is_finite() && ok {
                Ok(())
            } else {
                Err(TightscanError::parameter(name, format!("must be {rule}, got {value}")))
            }
        };
        let e = self;
        check(
            "speed_friction",
            e.speed_friction,
            e.speed_friction.abs() <= MAX_SPEED_FRICTION,
            "in [-0.25, 0.25] (keeps mu > 0 from 1 to 300 rpm)",
        )?;
        check("torque_lowpass_ms", e.torque_lowpass_ms, e.torque_lowpass_ms >= 0.0, ">= 0")?;
        check("inertia", e.inertia, e.inertia >= 0.0, ">= 0 [kg m^2]")?;
        check(
            "pressure_friction",
            e.pressure_friction,
            e.pressure_friction.abs() < 1.0,
            "in (-1, 1)",
        )?;
        check(
            "prevailing_torque_nm",
            e.prevailing_torque_nm,
            e.prevailing_torque_nm >= 0.0,
            ">= 0 [Nm]",
        )?;
        check("runout", e.runout, (0.0..1.0).contains(&e.runout), "in [0, 1)")
    }
}

/// Settings of [`simulate`]. Start from `SimulationConfig::default()` and change fields.
#[derive(Clone, Debug)]
pub struct SimulationConfig {
    /// Number of tightenings (0 gives empty batches).
    pub n: usize,
    /// Seed of the whole run; with `first_id` it fixes every row.
    pub seed: u64,
    /// Probability that a tightening has a friction fault, in [0, 1] (0: none, 1: all).
    /// Default 0.5.
    pub fault_fraction: f64,
    /// Strategies drawn uniformly from this list (repeat an entry to weight it). Default all three.
    pub strategies: Vec<Strategy>,
    /// Fault kinds drawn uniformly from this list. Default all three.
    pub fault_kinds: Vec<FaultKind>,
    /// Fault components drawn uniformly from this list. Default all three.
    pub fault_components: Vec<FaultComponent>,
    /// Range of |relative multiplicative change| of mu, `0 <= lo <= hi < 1`; the sign is + or -
    /// with equal probability. Equal ends fix the size. Default (0.05, 0.30).
    pub magnitude_range: (f64, f64),
    /// Position of the fault onset within the elastic zone, as a fraction of it (0 = elastic
    /// start, 1 = where the fault-free curve would reach the target, or the yield angle if that
    /// comes first), drawn uniformly, `0 <= lo <= hi <= 1`; equal ends fix it. A fault whose
    /// onset the curve never reaches has a null `onset_index`. Default (0.30, 0.85).
    pub onset_fraction_range: (f64, f64),
    /// Thread friction coefficient `mu_th`, drawn uniformly, `0 <= lo <= hi <= 1`.
    /// Default (0.10, 0.20), lightly oiled steel (METHODS.md section 1).
    pub mu_th_range: (f64, f64),
    /// Head (bearing) friction coefficient `mu_b`, drawn uniformly and independently of
    /// `mu_th`, `0 <= lo <= hi <= 1`. Default (0.10, 0.20).
    pub mu_b_range: (f64, f64),
    /// Joint stiffness \[kN/deg\] drawn uniformly, `0 < lo <= hi`, the same for every thread
    /// size. `None` (default): derived from the thread size through `elastic_angle_range`.
    /// For scale: an M10 joint at 22 kN target preload has 1.1 kN/deg (hard) to 0.19 (soft).
    pub joint_stiffness_range: Option<(f64, f64)>,
    /// Used when `joint_stiffness_range` is `None`: the elastic angle \[deg\] from snug to the
    /// target preload, drawn uniformly, `0 < lo <= hi`; the stiffness is then
    /// `k = F_t / angle` \[kN/deg\] with `F_t` the thread's target preload. Default (20, 120):
    /// hard (20) to soft (120) joints.
    pub elastic_angle_range: (f64, f64),
    /// Whether the bolt can yield (yield zone). Default false.
    pub with_yield: bool,
    /// With `with_yield`: the yield clamp force as a fraction of the preload the fault-free
    /// curve would reach at the target torque, drawn uniformly, `0 < lo <= hi`. Values above 1
    /// let some tightenings end before yield (null `yield_angle`, unless a fault that lowers
    /// friction raises their preload past it). Default (0.80, 0.95).
    pub yield_preload_range: (f64, f64),
    /// With `with_yield`: torque (and clamp-force) gradient after the yield transition, as a
    /// fraction of the elastic gradient, in (0, 1). Default 0.15.
    pub yield_gradient_ratio: f64,
    /// Switchable effects, all off by default; see [`EffectsConfig`].
    pub effects: EffectsConfig,
    /// Thread designations drawn uniformly (see [`crate::thread::parse_thread`]).
    /// Default M6, M8, M10, M12.
    pub threads: Vec<String>,
    /// Standard deviation of the additive Gaussian torque noise, as a fraction of the target
    /// torque. Default 0.002.
    pub torque_noise: f64,
    /// Standard deviation of the additive Gaussian clamp-force noise, as a fraction of the
    /// target preload. Default 0.005.
    pub clamp_force_noise: f64,
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
            onset_fraction_range: (0.30, 0.85),
            mu_th_range: (0.10, 0.20),
            mu_b_range: (0.10, 0.20),
            joint_stiffness_range: None,
            elastic_angle_range: (20.0, 120.0),
            with_yield: false,
            yield_preload_range: (0.80, 0.95),
            yield_gradient_ratio: 0.15,
            effects: EffectsConfig::default(),
            threads: ["M6", "M8", "M10", "M12"].iter().map(|s| (*s).to_owned()).collect(),
            torque_noise: 0.002,
            clamp_force_noise: 0.005,
            angle_resolution_deg: 0.1,
            sample_rate_hz: 2000.0,
            with_clamp_force: false,
            first_id: 0,
        }
    }
}

/// Highest sampling rate accepted: beyond it a tightening would hold millions of samples.
const MAX_SAMPLE_RATE_HZ: f64 = 1.0e6;
/// Largest |a| of the speed-friction law: keeps `1 + a ln(v / 30 rpm)` above 0.1 from 1 rpm
/// (ln = -3.4) to the highest speed under load, 300 rpm (ln = 2.3).
const MAX_SPEED_FRICTION: f64 = 0.25;

/// Checks a drawn range `(lo, hi)`: finite, `lo <= hi`, and both ends allowed by `ok`.
fn check_range(
    name: &str,
    (lo, hi): (f64, f64),
    ok: impl Fn(f64) -> bool,
    rule: &str,
) -> Result<()> {
    if lo.is_finite() && hi.is_finite() && lo <= hi && ok(lo) && ok(hi) {
        Ok(())
    } else {
        Err(TightscanError::parameter(name, format!("must satisfy {rule}, got ({lo}, {hi})")))
    }
}

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
        check_range(
            "magnitude_range",
            self.magnitude_range,
            |v| (0.0..1.0).contains(&v),
            "0 <= lo <= hi < 1 (a change of -100 % would remove friction)",
        )?;
        check_range(
            "onset_fraction_range",
            self.onset_fraction_range,
            |v| (0.0..=1.0).contains(&v),
            "0 <= lo <= hi <= 1",
        )?;
        for (name, range) in [("mu_th_range", self.mu_th_range), ("mu_b_range", self.mu_b_range)] {
            check_range(name, range, |v| (0.0..=1.0).contains(&v), "0 <= lo <= hi <= 1")?;
        }
        if let Some(range) = self.joint_stiffness_range {
            check_range("joint_stiffness_range", range, |v| v > 0.0, "0 < lo <= hi [kN/deg]")?;
        }
        check_range(
            "elastic_angle_range",
            self.elastic_angle_range,
            |v| v > 0.0,
            "0 < lo <= hi [deg]",
        )?;
        check_range("yield_preload_range", self.yield_preload_range, |v| v > 0.0, "0 < lo <= hi")?;
        if !(self.yield_gradient_ratio > 0.0 && self.yield_gradient_ratio < 1.0) {
            return Err(p(
                "yield_gradient_ratio",
                format!("must be in (0, 1), got {}", self.yield_gradient_ratio),
            ));
        }
        self.effects.validate()?;
        if self.threads.is_empty() {
            return Err(p("threads", "must not be empty"));
        }
        if let Some(bad) = self.threads.iter().find(|t| parse_thread(t).is_none()) {
            return Err(p("threads", format!("unknown ISO metric thread {bad:?}")));
        }
        for (name, value) in
            [("torque_noise", self.torque_noise), ("clamp_force_noise", self.clamp_force_noise)]
        {
            if !(value.is_finite() && value >= 0.0) {
                return Err(p(name, format!("must be finite and >= 0, got {value}")));
            }
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

/// Friction coefficient the target torque is computed for (VDI 2230 style nominal value).
const NOMINAL_MU: f64 = 0.14;
/// Target preload stress \[MPa\]: 0.6 * 640 MPa, 60 % of the minimum lower yield strength of
/// property class 8.8 (ISO 898-1, d <= 16 mm).
const TARGET_PRELOAD_STRESS_MPA: f64 = 0.6 * 640.0;
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
/// 1 rpm = 6 deg/s.
const DEG_PER_S_PER_RPM: f64 = 6.0;
/// 1 rpm = 2 pi / 60 rad/s.
const RAD_PER_S_PER_RPM: f64 = std::f64::consts::TAU / 60.0;
/// Speed friction: speed at which `mu_th` and `mu_b` hold \[rpm\] (test-bench speeds are tens
/// of rpm).
const SPEED_FRICTION_REF_RPM: f64 = 30.0;
/// Speed friction: below this speed \[rpm\] the log law is held at its value here: it
/// diverges at rest, where sliding friction is not defined.
const SPEED_FRICTION_MIN_RPM: f64 = 1.0;
/// Yield: the clamp-force gradient falls from the elastic to the plastic value over this
/// fraction of the elastic angle from snug to yield (a gradual yield point, as bolts with a
/// rolled thread show, not a sharp kink).
const YIELD_TRANSITION_FRACTION: f64 = 0.1;
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

/// Yield point of a bolt that yields (see [`SimulationConfig::with_yield`]).
#[derive(Clone, Copy, Debug)]
struct YieldPoint {
    /// Angle where the clamp-force gradient starts to fall \[deg\].
    angle: f64,
    /// Clamp force there \[kN\].
    force: f64,
    /// Angle over which the gradient falls to its plastic value \[deg\].
    width: f64,
    /// Plastic gradient over elastic gradient.
    ratio: f64,
}

impl YieldPoint {
    /// Clamp-force travel past yield in units of the elastic stiffness \[deg\]: the integral of
    /// the normalised gradient `g(u) = 1 - (1 - r) S(u / w)` from 0 to `u`, with the smoothstep
    /// `S(s) = 3 s^2 - 2 s^3` (value and slope of the gradient continuous at both ends). Its
    /// integral is `s^3 - s^4 / 2` up to `s = 1` and `s - 1/2` beyond, where `g = r`.
    fn travel(&self, u: f64) -> f64 {
        let s = u / self.width;
        let smoothstep_integral = if s < 1.0 { s * s * s * (1.0 - 0.5 * s) } else { s - 0.5 };
        u - (1.0 - self.ratio) * self.width * smoothstep_integral
    }
}

/// The hidden parameters of one tightening.
struct Draw {
    strategy: Strategy,
    thread: &'static ThreadGeometry,
    mu_th: f64,
    mu_b: f64,
    preload_target_kn: f64,
    /// `1 / preload_target_kn` \[1/kN\], for the pressure-friction law.
    inverse_preload_target: f64,
    target_torque: f64,
    k_joint: f64,
    /// Total prevailing torque \[Nm\]: the thread's own plus a locking element's.
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
    yield_point: Option<YieldPoint>,
    effects: EffectsConfig,
    /// Phase `phi` of the run-out \[rad\] (drawn even when run-out is off).
    runout_phase: f64,
}

impl Draw {
    /// `rng` draws the basic parameters, `extras` the yield point and the effect parameters, so
    /// that switching the yield zone or an effect on never shifts the basic draws.
    fn new(
        rng: &mut Xoshiro256PlusPlus,
        extras: &mut Xoshiro256PlusPlus,
        config: &SimulationConfig,
        threads: &[&'static ThreadGeometry],
    ) -> Self {
        // Every value is drawn for every tightening, in a fixed order, so that e.g. the fault
        // fraction or the strategy list never shifts the stream of the others.
        let strategy = pick(rng, &config.strategies);
        let thread = pick(rng, threads);
        let mu_th = uniform(rng, config.mu_th_range);
        let mu_b = uniform(rng, config.mu_b_range);
        // Target preload F_t [kN] = sigma * As; the target torque is what the tightening
        // equation gives at nominal friction, rounded like a programmed controller value.
        let preload_target_kn = TARGET_PRELOAD_STRESS_MPA * thread.stress_area_mm2 / 1000.0;
        let nominal_target =
            (preload_target_kn * thread.torque_per_force(NOMINAL_MU, NOMINAL_MU) * 10.0).round()
                / 10.0;
        // A locking element's prevailing torque is added to the programmed target (VDI 2230:
        // M_A = M_A,nominal + M_prevailing), so it does not eat into the preload.
        let locking = config.effects.prevailing_torque_nm;
        let target_torque = nominal_target + locking;
        // Joint stiffness [kN/deg]: from the configured range, or from the thread's target
        // preload and an elastic angle A_el (k = F_t / A_el), one uniform draw either way.
        let stiffness_u = rng.random::<f64>();
        let k_joint = match config.joint_stiffness_range {
            Some((lo, hi)) => lo + (hi - lo) * stiffness_u,
            None => {
                let (lo, hi) = config.elastic_angle_range;
                preload_target_kn / (lo + (hi - lo) * stiffness_u)
            }
        };
        let prevailing = uniform(rng, PREVAILING_RANGE) * nominal_target + locking;
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
        let onset_u = uniform(rng, config.onset_fraction_range);
        let ramp_u = uniform(rng, INCIPIENT_RAMP);

        let yield_u = uniform(extras, config.yield_preload_range);
        let runout_phase = std::f64::consts::TAU * extras.random::<f64>();

        // Where the fault-free curve of the basic model meets the target: solve
        // T_p + F(theta) K0 = target.
        let k0 = thread.torque_per_force(mu_th, mu_b);
        let force_needed = ((target_torque - prevailing) / k0).max(0.0);
        let x_end = if force_needed >= 0.5 * k_joint * snug_width {
            force_needed / k_joint + 0.5 * snug_width
        } else {
            (2.0 * snug_width * force_needed / k_joint).sqrt()
        };
        let fault_free_end = theta0 + x_end;
        let elastic_start = theta0 + snug_width;
        // Yield is a property of the bolt (a clamp force), whatever the friction: placed on the
        // elastic line F = k (x - w_s/2) at a fraction of the fault-free final preload, and not
        // before the elastic start.
        let yield_point = config.with_yield.then(|| {
            let x = (yield_u * force_needed / k_joint + 0.5 * snug_width).max(snug_width);
            YieldPoint {
                angle: theta0 + x,
                force: k_joint * (x - 0.5 * snug_width),
                width: YIELD_TRANSITION_FRACTION * (x - 0.5 * snug_width),
                ratio: config.yield_gradient_ratio,
            }
        });
        // The elastic zone ends at the fault-free end or at yield, whichever comes first.
        let elastic_end = yield_point.map_or(fault_free_end, |y| fault_free_end.min(y.angle));
        let span = (elastic_end - elastic_start).max(0.0);
        let onset_deg = elastic_start + span * onset_u;
        let fault = faulty.then_some(Fault {
            kind,
            component,
            magnitude: sign * size,
            onset_deg,
            ramp_deg: ramp_u * (elastic_end - onset_deg),
        });
        Self {
            strategy,
            thread,
            mu_th,
            mu_b,
            preload_target_kn,
            inverse_preload_target: 1.0 / preload_target_kn,
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
            yield_point,
            effects: config.effects,
            runout_phase,
        }
    }

    /// Clamp force \[kN\]: zero, then quadratic seating over `w_s`, then the elastic line, and
    /// past a yield point the falling gradient of [`YieldPoint::travel`].
    fn clamp_force(&self, theta: f64) -> f64 {
        let x = theta - self.theta0;
        let w = self.snug_width;
        if x <= 0.0 {
            0.0
        } else if x < w {
            self.k_joint * x * x / (2.0 * w)
        } else {
            match self.yield_point {
                Some(y) if theta > y.angle => y.force + self.k_joint * y.travel(theta - y.angle),
                _ => self.k_joint * (x - 0.5 * w),
            }
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
    mu_tot: f64,
    k_joint: f64,
    prevailing: f64,
    snug_angle: f64,
    elastic_start_angle: f64,
    yield_angle: Option<f64>,
    final_angle: f64,
    preload: f64,
    n_samples: usize,
    runout_phase: Option<f64>,
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

/// First-order low-pass `tau dy/dt = x - y` of the torque transducer, discretised exactly for
/// an input that is linear between samples (first-order hold): with `a = exp(-dt / tau)`,
/// `y_k = a y_{k-1} + (1 - a) x_{k-1} + (1 - tau (1 - a) / dt) (x_k - x_{k-1})`. A ramp of slope
/// `m` comes out as `x - m tau` exactly (a pure delay of `tau`), which the plain one-pole
/// recursion only approximates (`tau -+ dt/2`).
struct LowPass {
    a: f64,
    b: f64,
    previous: Option<(f64, f64)>,
}

impl LowPass {
    fn new(tau_s: f64, dt: f64) -> Self {
        let a = (-dt / tau_s).exp();
        Self { a, b: 1.0 - tau_s * (1.0 - a) / dt, previous: None }
    }

    fn filter(&mut self, x: f64) -> f64 {
        // The transducer is settled at the first sample (the curve starts at rest).
        let y = match self.previous {
            Some((x0, y0)) => self.a * y0 + (1.0 - self.a) * x0 + self.b * (x - x0),
            None => x,
        };
        self.previous = Some((x, y));
        y
    }
}

/// `sin(2 pi u)` to 1e-9 absolute, for finite `|u| < 2^53`. `u` is reduced to the fraction of
/// a turn in [-1/2, 1/2], folded into [-1/4, 1/4] by `sin(pi - x) = sin(x)`, and the odd
/// Taylor series is summed up to `x^13` (remainder at most `(pi/2)^15 / 15! = 6.7e-10`). Far
/// below the f32 resolution of the torque channel, and a libm `sin` call per sample cost as
/// much as the rest of the run-out effect.
fn sin_turns(u: f64) -> f64 {
    // Truncation toward zero leaves a fraction in (-1, 1); shift it into [-1/2, 1/2].
    let mut f = u - (u as i64) as f64;
    if f > 0.5 {
        f -= 1.0;
    } else if f < -0.5 {
        f += 1.0;
    }
    if f > 0.25 {
        f = 0.5 - f;
    } else if f < -0.25 {
        f = -0.5 - f;
    }
    let x = std::f64::consts::TAU * f;
    // sin(x)/x = 1 - y/3! + y^2/5! - y^3/7! + y^4/9! - y^5/11! + y^6/13!, y = x^2, summed in
    // Estrin's scheme: pairs first, so the dependency chain is 4 operations deep, not 7.
    let y = x * x;
    let y2 = y * y;
    // (Reciprocals are constant-folded; a division would not be.)
    let low = (1.0 - y * (1.0 / 6.0)) + (1.0 / 120.0 - y * (1.0 / 5_040.0)) * y2;
    let high = (1.0 / 362_880.0 - y * (1.0 / 39_916_800.0)) + y2 * (1.0 / 6_227_020_800.0);
    x * (low + high * (y2 * y2))
}

/// Measurement side of a [`Recorder`]: noise generators, settings and the output rows.
struct Measurement<'o> {
    noise_rng: Xoshiro256PlusPlus,
    clamp_rng: Xoshiro256PlusPlus,
    torque_sd: f64,
    clamp_sd: f64,
    resolution: f64,
    sample_rate_hz: f64,
    /// `None` when the low-pass effect is off.
    lowpass: Option<LowPass>,
    out: Channels<'o>,
}

impl Measurement<'_> {
    /// The torque the transducer reports for the true joint torque `torque` at angle `theta`,
    /// with `rpm` the speed of the interval just ended and `previous_rpm` that of the one
    /// before: run-out, inertial torque and low-pass as described on [`EffectsConfig`] (each
    /// skipped when off), noise excluded.
    fn transduce(&mut self, d: &Draw, torque: f64, theta: f64, rpm: f64, previous_rpm: f64) -> f64 {
        let e = &d.effects;
        let mut measured = torque;
        if e.runout != 0.0 {
            // sin(2 pi theta / 360 + phi), with both terms in turns.
            let turns = theta * (1.0 / 360.0) + d.runout_phase * (0.5 / std::f64::consts::PI);
            measured *= 1.0 + e.runout * sin_turns(turns);
        }
        if e.inertia != 0.0 {
            // alpha = dOmega / dt [rad/s^2] between the two intervals around the last sample.
            let alpha = (rpm - previous_rpm) * RAD_PER_S_PER_RPM * self.sample_rate_hz;
            measured += e.inertia * alpha;
        }
        match self.lowpass.as_mut() {
            Some(lowpass) => lowpass.filter(measured),
            None => measured,
        }
    }
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
    /// Speed of the interval that ended at the last sample \[rpm\].
    last_rpm: f64,
    /// Last non-zero speed \[rpm\]: friction at standstill keeps its last sliding value.
    sliding_rpm: f64,
    /// (speed \[rpm\], speed-friction factor) last computed: the speed is constant over long
    /// stretches (rundown, CST, CSDT), so the logarithm is only taken when it changes.
    speed_factor: (f64, f64),
}

impl Recorder<'_, '_> {
    /// Factor of both friction coefficients from the speed and pressure effects: 1 when both
    /// are off, or without clamp force (the friction terms are then multiplied by F = 0).
    fn condition_factor(&mut self, force: f64) -> f64 {
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
    fn record(&mut self, t: f64, theta: f64, rpm: f64, relaxation: f64) -> f64 {
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
    // A long jump (2^192 steps) keeps the extras clear of the parameter and noise streams,
    // which are at most 2 jumps (2^128 steps each) from the root.
    let mut extras_rng = root.clone();
    extras_rng.long_jump();

    let draw = Draw::new(&mut params_rng, &mut extras_rng, config, threads);
    let friction = FrictionPath::new(draw.fault, &mut params_rng);
    let measurement = out.map(|out| {
        // Jumps give 2^128-step separated streams: noise never overlaps the parameter draws.
        let mut noise_rng = root.clone();
        noise_rng.jump();
        let mut clamp_rng = noise_rng.clone();
        clamp_rng.jump();
        let tau_s = config.effects.torque_lowpass_ms / 1000.0;
        Measurement {
            noise_rng,
            clamp_rng,
            torque_sd: config.torque_noise * draw.target_torque,
            clamp_sd: config.clamp_force_noise * draw.preload_target_kn,
            resolution: config.angle_resolution_deg,
            sample_rate_hz: config.sample_rate_hz,
            lowpass: (tau_s > 0.0).then(|| LowPass::new(tau_s, 1.0 / config.sample_rate_hz)),
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
        last_rpm: 0.0,
        sliding_rpm: 0.0,
        speed_factor: (f64::NAN, 1.0),
    };
    run_controller(&mut rec, &draw, config.sample_rate_hz);
    debug_assert!(rec.measurement.as_ref().is_none_or(|m| m.out.time.len() == rec.len));
    let geometry = JointGeometry::from(draw.thread);
    Truth {
        strategy: draw.strategy,
        thread: draw.thread.designation,
        target_torque: draw.target_torque,
        fault: draw.fault,
        onset_index: rec.onset_index,
        mu_th: draw.mu_th,
        mu_b: draw.mu_b,
        mu_tot: geometry.mu_tot(geometry.torque_per_force(draw.mu_th, draw.mu_b)),
        k_joint: draw.k_joint,
        prevailing: draw.prevailing,
        snug_angle: draw.theta0 + 0.5 * draw.snug_width,
        elastic_start_angle: draw.theta0 + draw.snug_width,
        yield_angle: draw.yield_point.map(|y| y.angle).filter(|a| rec.last_theta >= *a),
        final_angle: rec.last_theta,
        preload: rec.last_force,
        n_samples: rec.len,
        runout_phase: (config.effects.runout != 0.0).then_some(draw.runout_phase),
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
            (
                "onset_fraction_range",
                SimulationConfig { onset_fraction_range: (0.5, 1.1), ..Default::default() },
            ),
            (
                "onset_fraction_range",
                SimulationConfig { onset_fraction_range: (0.6, 0.5), ..Default::default() },
            ),
            ("mu_th_range", SimulationConfig { mu_th_range: (-0.1, 0.2), ..Default::default() }),
            ("mu_b_range", SimulationConfig { mu_b_range: (0.1, f64::NAN), ..Default::default() }),
            (
                "joint_stiffness_range",
                SimulationConfig { joint_stiffness_range: Some((0.0, 1.0)), ..Default::default() },
            ),
            (
                "elastic_angle_range",
                SimulationConfig { elastic_angle_range: (50.0, 20.0), ..Default::default() },
            ),
            (
                "yield_preload_range",
                SimulationConfig { yield_preload_range: (0.0, 0.9), ..Default::default() },
            ),
            (
                "yield_gradient_ratio",
                SimulationConfig { yield_gradient_ratio: 1.0, ..Default::default() },
            ),
            (
                "clamp_force_noise",
                SimulationConfig { clamp_force_noise: -1.0, ..Default::default() },
            ),
            ("speed_friction", with_effects(EffectsConfig { speed_friction: 0.3, ..no_effects() })),
            (
                "torque_lowpass_ms",
                with_effects(EffectsConfig { torque_lowpass_ms: -1.0, ..no_effects() }),
            ),
            ("inertia", with_effects(EffectsConfig { inertia: f64::NAN, ..no_effects() })),
            (
                "pressure_friction",
                with_effects(EffectsConfig { pressure_friction: -1.0, ..no_effects() }),
            ),
            (
                "prevailing_torque_nm",
                with_effects(EffectsConfig { prevailing_torque_nm: -0.5, ..no_effects() }),
            ),
            ("runout", with_effects(EffectsConfig { runout: 1.0, ..no_effects() })),
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
        assert!(with_effects(EffectsConfig::all_on()).validate().is_ok());
        assert!(SimulationConfig { onset_fraction_range: (0.0, 1.0), ..Default::default() }
            .validate()
            .is_ok());
    }

    fn no_effects() -> EffectsConfig {
        EffectsConfig::default()
    }

    fn with_effects(effects: EffectsConfig) -> SimulationConfig {
        SimulationConfig { effects, ..Default::default() }
    }

    /// Noise-free, unquantised, fault-free curves of one strategy, with a noise-free clamp-force
    /// channel: the true trajectory as recorded.
    fn clean(n: usize, seed: u64, strategy: Strategy) -> SimulationConfig {
        SimulationConfig {
            strategies: vec![strategy],
            fault_fraction: 0.0,
            torque_noise: 0.0,
            clamp_force_noise: 0.0,
            angle_resolution_deg: 0.0,
            with_clamp_force: true,
            ..small(n, seed)
        }
    }

    fn thread_of(s: &Simulated, row: usize) -> &'static ThreadGeometry {
        parse_thread(str_col(&s.truth, "thread").value(row)).unwrap()
    }

    /// Friction-dependent part of the torque per force relative to its value at the true
    /// coefficients, minus 1: the relative change of both mu that the curve shows at a sample
    /// with torque `t` and clamp force `f`.
    fn friction_change(s: &Simulated, row: usize, t: f64, f: f64) -> f64 {
        let g = thread_of(s, row);
        let (mu_th, mu_b) =
            (f64_col(&s.truth, "mu_th").value(row), f64_col(&s.truth, "mu_b").value(row));
        let tp = f64_col(&s.truth, "prevailing_torque").value(row);
        let lead = crate::thread::LEAD_FACTOR * g.pitch_mm;
        let friction_term = g.torque_per_force(mu_th, mu_b) - lead;
        ((t - tp) / f - lead) / friction_term - 1.0
    }

    #[test]
    fn sin_turns_matches_libm() {
        let mut worst = 0.0_f64;
        for i in -200_000..200_000 {
            let u = f64::from(i) * 1.37e-4 + 0.123;
            worst = worst.max((sin_turns(u) - (std::f64::consts::TAU * u).sin()).abs());
        }
        assert!(worst < 1e-9, "worst {worst}");
        for u in [0.0, 0.25, 0.5, 0.75, 1.0, -0.25, 1e6 + 0.25] {
            assert!((sin_turns(u) - (std::f64::consts::TAU * u).sin()).abs() < 1e-9, "{u}");
        }
    }

    #[test]
    fn defaults_switch_every_effect_and_the_yield_zone_off() {
        assert!(EffectsConfig::default().values().iter().all(|v| *v == 0.0));
        let s = simulate(&small(50, 2)).unwrap();
        assert!(str_col(&s.truth, "effects").iter().all(|e| e == Some("")));
        for column in ["runout_phase", "yield_angle"] {
            assert_eq!(s.truth.column_by_name(column).unwrap().null_count(), 50, "{column}");
        }
        assert_eq!(
            EffectsConfig { runout: 0.02, speed_friction: -0.1, ..no_effects() }.enabled_names(),
            "speed_friction,runout"
        );
        let all = EffectsConfig::all_on().enabled_names();
        assert_eq!(all, EffectsConfig::NAMES.join(","));
        let t = simulate(&SimulationConfig { effects: EffectsConfig::all_on(), ..small(5, 2) })
            .unwrap();
        assert!(str_col(&t.truth, "effects").iter().all(|e| e == Some(all.as_str())));
        let phase = f64_col(&t.truth, "runout_phase");
        assert!(phase.iter().all(|p| p.is_some_and(|p| (0.0..std::f64::consts::TAU).contains(&p))));
    }

    #[test]
    fn effects_and_yield_are_reproducible_and_leave_the_basic_draws_alone() {
        let plain = small(60, 19);
        let rich = SimulationConfig {
            effects: EffectsConfig::all_on(),
            with_yield: true,
            with_clamp_force: true,
            ..plain.clone()
        };
        let a = simulate(&rich).unwrap();
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let b = pool.install(|| simulate(&rich)).unwrap();
        assert_eq!(a.tightenings, b.tightenings);
        assert_eq!(a.truth, b.truth);
        let tail = simulate(&SimulationConfig { first_id: 40, n: 20, ..rich.clone() }).unwrap();
        assert_eq!(a.tightenings.slice(40, 20), tail.tightenings);
        assert_eq!(a.truth.slice(40, 20), tail.truth);

        let p = simulate(&plain).unwrap();
        for column in ["strategy", "has_change", "fault_kind", "fault_component", "thread"] {
            assert_eq!(p.truth.column_by_name(column), a.truth.column_by_name(column), "{column}");
        }
        for column in ["magnitude", "mu_th", "mu_b", "mu_tot", "joint_stiffness", "snug_angle"] {
            assert_eq!(p.truth.column_by_name(column), a.truth.column_by_name(column), "{column}");
        }
        // The locking element adds its torque to the thread's own prevailing torque.
        let (tp_plain, tp_rich) =
            (f64_col(&p.truth, "prevailing_torque"), f64_col(&a.truth, "prevailing_torque"));
        for row in 0..60 {
            let added = tp_rich.value(row) - tp_plain.value(row);
            assert!((added - EffectsConfig::all_on().prevailing_torque_nm).abs() < 1e-12);
        }
        assert!(a.truth.column_by_name("yield_angle").unwrap().null_count() < 60);
        assert_ne!(p.tightenings.column_by_name("torque"), a.tightenings.column_by_name("torque"));
    }

    #[test]
    fn drawn_friction_and_stiffness_lie_in_their_ranges() {
        let config = SimulationConfig {
            mu_th_range: (0.08, 0.12),
            mu_b_range: (0.15, 0.25),
            joint_stiffness_range: Some((0.5, 0.8)),
            ..small(400, 43)
        };
        let s = simulate(&config).unwrap();
        for (column, (lo, hi)) in [
            ("mu_th", config.mu_th_range),
            ("mu_b", config.mu_b_range),
            ("joint_stiffness", (0.5, 0.8)),
        ] {
            let values: Vec<f64> = f64_col(&s.truth, column).values().to_vec();
            let min = values.iter().copied().fold(f64::INFINITY, f64::min);
            let max = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            assert!(lo <= min && max <= hi, "{column}: [{min}, {max}] outside [{lo}, {hi}]");
            // Uniform draws fill the range: 400 draws leave less than 5 % empty at either end.
            assert!(min < lo + 0.05 * (hi - lo) && max > hi - 0.05 * (hi - lo), "{column}");
        }
        // The default derives the stiffness from the thread: F_t / k is the elastic angle.
        let d = simulate(&small(300, 43)).unwrap();
        let k = f64_col(&d.truth, "joint_stiffness");
        for row in 0..300 {
            let g = thread_of(&d, row);
            let elastic_angle =
                TARGET_PRELOAD_STRESS_MPA * g.stress_area_mm2 / 1000.0 / k.value(row);
            assert!((20.0 - 1e-9..=120.0 + 1e-9).contains(&elastic_angle), "{elastic_angle}");
        }
        // Equal ends fix a value.
        let fixed = simulate(&SimulationConfig {
            joint_stiffness_range: Some((0.6, 0.6)),
            mu_th_range: (0.12, 0.12),
            ..small(20, 43)
        })
        .unwrap();
        assert!(f64_col(&fixed.truth, "joint_stiffness").values().iter().all(|v| *v == 0.6));
        assert!(f64_col(&fixed.truth, "mu_th").values().iter().all(|v| *v == 0.12));
    }

    #[test]
    fn onset_and_magnitude_can_be_drawn_or_fixed() {
        for fraction in [0.0, 0.5, 1.0] {
            let config = SimulationConfig {
                fault_fraction: 1.0,
                onset_fraction_range: (fraction, fraction),
                magnitude_range: (0.2, 0.2),
                ..small(100, 47)
            };
            let s = simulate(&config).unwrap();
            let onset = f64_col(&s.truth, "onset_angle");
            let (snug, start) =
                (f64_col(&s.truth, "snug_angle"), f64_col(&s.truth, "elastic_start_angle"));
            let (k, tp) =
                (f64_col(&s.truth, "joint_stiffness"), f64_col(&s.truth, "prevailing_torque"));
            let targets = f64_col(&s.tightenings, "target_torque");
            let magnitude = f64_col(&s.truth, "magnitude");
            for row in 0..config.n {
                assert_eq!(magnitude.value(row).abs(), 0.2);
                // Fault-free end of the elastic line: snug + F_needed / k.
                let g = thread_of(&s, row);
                let mu =
                    (f64_col(&s.truth, "mu_th").value(row), f64_col(&s.truth, "mu_b").value(row));
                let force = (targets.value(row) - tp.value(row)) / g.torque_per_force(mu.0, mu.1);
                let end = snug.value(row) + force / k.value(row);
                let expected = start.value(row) + fraction * (end - start.value(row));
                assert!((onset.value(row) - expected).abs() < 1e-9 * expected, "row {row}");
            }
        }
        // Drawn: the onsets spread over the configured window.
        let s = simulate(&SimulationConfig {
            fault_fraction: 1.0,
            onset_fraction_range: (0.2, 0.4),
            ..small(300, 47)
        })
        .unwrap();
        let fractions: Vec<f64> = (0..300)
            .map(|row| {
                let start = f64_col(&s.truth, "elastic_start_angle").value(row);
                let onset = f64_col(&s.truth, "onset_angle").value(row);
                let snug = f64_col(&s.truth, "snug_angle").value(row);
                let k = f64_col(&s.truth, "joint_stiffness").value(row);
                let g = thread_of(&s, row);
                let mu =
                    (f64_col(&s.truth, "mu_th").value(row), f64_col(&s.truth, "mu_b").value(row));
                let tp = f64_col(&s.truth, "prevailing_torque").value(row);
                let target = f64_col(&s.tightenings, "target_torque").value(row);
                let end = snug + (target - tp) / g.torque_per_force(mu.0, mu.1) / k;
                (onset - start) / (end - start)
            })
            .collect();
        assert!(fractions.iter().all(|f| (0.2 - 1e-9..=0.4 + 1e-9).contains(f)));
        assert!(fractions.iter().any(|f| *f < 0.22) && fractions.iter().any(|f| *f > 0.38));
    }

    #[test]
    fn truth_mu_tot_is_the_iso16047_evaluation_of_the_clamp_curve() {
        let config = SimulationConfig {
            effects: EffectsConfig { prevailing_torque_nm: 3.0, ..no_effects() },
            ..clean(60, 53, Strategy::Cst)
        };
        let s = simulate(&config).unwrap();
        let start = f64_col(&s.truth, "elastic_start_angle");
        let tp = f64_col(&s.truth, "prevailing_torque");
        let mu_tot = f64_col(&s.truth, "mu_tot");
        for row in 0..config.n {
            let angle = f32_list(&s.tightenings, "angle", row);
            let torque = f32_list(&s.tightenings, "torque", row);
            let force = f32_list(&s.tightenings, "clamp_force", row);
            let elastic: Vec<usize> =
                (0..angle.len()).filter(|&k| angle[k] > start.value(row) + 0.01).collect();
            assert!(elastic.len() > 20);
            let f: Vec<f64> = elastic.iter().map(|&k| force[k]).collect();
            let t: Vec<f64> = elastic.iter().map(|&k| torque[k]).collect();
            let g = JointGeometry::from(thread_of(&s, row));
            let from_slope = g.mu_tot(slope(&f, &t));
            assert!((from_slope - mu_tot.value(row)).abs() < 1e-3, "row {row}: {from_slope}");
            // Pointwise too: (T - T_prev) / F of the last sample.
            let last = elastic[elastic.len() - 1];
            let pointwise = g.mu_tot((torque[last] - tp.value(row)) / force[last]);
            assert!((pointwise - mu_tot.value(row)).abs() < 1e-3, "row {row}: {pointwise}");
            // mu_tot lies between the two coefficients it averages.
            let (a, b) =
                (f64_col(&s.truth, "mu_th").value(row), f64_col(&s.truth, "mu_b").value(row));
            assert!(mu_tot.value(row) > a.min(b) - 2e-3 && mu_tot.value(row) < a.max(b) + 2e-3);
        }
    }

    #[test]
    fn yield_flattens_the_torque_gradient_to_the_set_fraction() {
        let ratio = 0.15;
        let config = SimulationConfig {
            with_yield: true,
            yield_preload_range: (0.8, 0.9),
            yield_gradient_ratio: ratio,
            ..clean(40, 59, Strategy::Cst)
        };
        let s = simulate(&config).unwrap();
        let yield_angle = f64_col(&s.truth, "yield_angle");
        assert_eq!(yield_angle.null_count(), 0, "every bolt yields below its final preload");
        let start = f64_col(&s.truth, "elastic_start_angle");
        let snug = f64_col(&s.truth, "snug_angle");
        for row in 0..config.n {
            let angle = f32_list(&s.tightenings, "angle", row);
            let torque = f32_list(&s.tightenings, "torque", row);
            let elastic_rate = expected_rate(&s, row, false);
            let theta_y = yield_angle.value(row);
            let plastic_from = theta_y + YIELD_TRANSITION_FRACTION * (theta_y - snug.value(row));
            let pick_range = |lo: f64, hi: f64| -> (Vec<f64>, Vec<f64>) {
                angle
                    .iter()
                    .zip(&torque)
                    .filter(|(a, _)| **a > lo && **a < hi)
                    .map(|(a, t)| (*a, *t))
                    .unzip()
            };
            let (x, y) = pick_range(start.value(row) + 0.01, theta_y);
            assert!((slope(&x, &y) / elastic_rate - 1.0).abs() < 1e-3, "row {row}: elastic");
            let (x, y) = pick_range(plastic_from + 0.01, f64::INFINITY);
            assert!(x.len() > 20, "row {row}: {} plastic samples", x.len());
            let plastic = slope(&x, &y) / elastic_rate;
            assert!(plastic <= ratio * 1.001 && plastic > ratio * 0.999, "row {row}: {plastic}");
            // In the transition the gradient falls monotonically from elastic to plastic.
            let (x, y) = pick_range(theta_y, plastic_from);
            let rates: Vec<f64> = x
                .windows(2)
                .zip(y.windows(2))
                .map(|(a, t)| (t[1] - t[0]) / (a[1] - a[0]) / elastic_rate)
                .collect();
            // (Finite differences of f32 angles: allow 1 % for their rounding.)
            assert!(rates.iter().all(|r| *r < 1.01 && *r > ratio - 0.01), "row {row}");
            assert!(rates.windows(2).all(|w| w[1] <= w[0] + 0.01), "row {row}");
        }
        // A yield point beyond the final preload is never reached: null, curves as without yield.
        let beyond = SimulationConfig { yield_preload_range: (1.5, 2.0), ..config.clone() };
        let s = simulate(&beyond).unwrap();
        assert_eq!(s.truth.column_by_name("yield_angle").unwrap().null_count(), config.n);
        let plain = simulate(&SimulationConfig { with_yield: false, ..config }).unwrap();
        assert_eq!(s.tightenings, plain.tightenings);
    }

    #[test]
    fn prevailing_torque_raises_the_rundown_by_the_set_value() {
        let set = 2.5;
        let off = clean(60, 61, Strategy::Cst);
        let on = SimulationConfig {
            effects: EffectsConfig { prevailing_torque_nm: set, ..no_effects() },
            strategies: Strategy::ALL.to_vec(),
            ..off.clone()
        };
        let off = SimulationConfig { strategies: Strategy::ALL.to_vec(), ..off };
        let (a, b) = (simulate(&off).unwrap(), simulate(&on).unwrap());
        let snug = f64_col(&b.truth, "snug_angle");
        let tp = f64_col(&b.truth, "prevailing_torque");
        for row in 0..on.n {
            let (ta, tb) =
                (f32_list(&a.tightenings, "torque", row), f32_list(&b.tightenings, "torque", row));
            let angle = f32_list(&b.tightenings, "angle", row);
            let rundown: Vec<usize> =
                (0..angle.len()).filter(|&k| angle[k] < snug.value(row) - 6.0).collect();
            assert!(rundown.len() > 100);
            for &k in &rundown {
                assert!((tb[k] - ta[k] - set).abs() < 1e-4, "row {row} sample {k}");
                assert!((tb[k] - tp.value(row)).abs() < 1e-4, "row {row} sample {k}");
            }
            let targets = (
                f64_col(&a.tightenings, "target_torque"),
                f64_col(&b.tightenings, "target_torque"),
            );
            assert!((targets.1.value(row) - targets.0.value(row) - set).abs() < 1e-12);
            // The target is raised with it, so the preload stays (up to the last step's size).
            let preload =
                (f64_col(&a.truth, "preload").value(row), f64_col(&b.truth, "preload").value(row));
            assert!((preload.1 / preload.0 - 1.0).abs() < 0.02, "row {row}: {preload:?}");
        }
    }

    #[test]
    fn speed_friction_follows_the_log_law_as_hdt_slows_down() {
        let a = 0.1;
        let config = SimulationConfig {
            effects: EffectsConfig { speed_friction: a, ..no_effects() },
            ..clean(40, 67, Strategy::Hdt)
        };
        let s = simulate(&config).unwrap();
        let dt = 1.0 / config.sample_rate_hz;
        let start = f64_col(&s.truth, "elastic_start_angle");
        let targets = f64_col(&s.tightenings, "target_torque");
        let (mut x, mut y) = (Vec::new(), Vec::new());
        for row in 0..config.n {
            let angle = f32_list(&s.tightenings, "angle", row);
            let torque = f32_list(&s.tightenings, "torque", row);
            let force = f32_list(&s.tightenings, "clamp_force", row);
            // Up to the shut-off: the interval speed is the angle step over dt there (the
            // coast-down records instantaneous speeds instead).
            for k in 1..angle.len() {
                if torque[k] >= targets.value(row) {
                    break;
                }
                if angle[k] > start.value(row) + 0.5 {
                    let rpm = (angle[k] - angle[k - 1]) / dt / DEG_PER_S_PER_RPM;
                    x.push((rpm / SPEED_FRICTION_REF_RPM).ln());
                    y.push(friction_change(&s, row, torque[k], force[k]));
                }
            }
        }
        let spread = x.iter().copied().fold(f64::NEG_INFINITY, f64::max)
            - x.iter().copied().fold(f64::INFINITY, f64::min);
        assert!(spread > 1.0, "speeds span only {spread} in ln");
        let got = slope(&x, &y);
        assert!((got / a - 1.0).abs() < 0.01, "a = {got}");
        // No offset: the coefficients hold at the reference speed.
        let n = x.len() as f64;
        let intercept = y.iter().sum::<f64>() / n - got * x.iter().sum::<f64>() / n;
        assert!(intercept.abs() < 1e-3, "intercept {intercept}");
        // HDT speeds stay above 30 rpm (0.22 v0 at least), so with a > 0 friction is higher
        // throughout and the target comes at a lower preload.
        let plain = simulate(&SimulationConfig { effects: no_effects(), ..config }).unwrap();
        let (on, off) = (f64_col(&s.truth, "preload"), f64_col(&plain.truth, "preload"));
        let lower = (0..40).filter(|&row| on.value(row) < off.value(row)).count();
        assert!(lower > 35, "only {lower} of 40 curves end at a lower preload with a > 0");
    }

    #[test]
    fn pressure_friction_bends_the_torque_force_curve() {
        for c in [0.3, -0.3] {
            let config = SimulationConfig {
                effects: EffectsConfig { pressure_friction: c, ..no_effects() },
                ..clean(40, 71, Strategy::Cst)
            };
            let s = simulate(&config).unwrap();
            let start = f64_col(&s.truth, "elastic_start_angle");
            let (mut x, mut y) = (Vec::new(), Vec::new());
            for row in 0..config.n {
                let angle = f32_list(&s.tightenings, "angle", row);
                let torque = f32_list(&s.tightenings, "torque", row);
                let force = f32_list(&s.tightenings, "clamp_force", row);
                let f_target =
                    TARGET_PRELOAD_STRESS_MPA * thread_of(&s, row).stress_area_mm2 / 1000.0;
                let elastic: Vec<usize> =
                    (0..angle.len()).filter(|&k| angle[k] > start.value(row) + 0.5).collect();
                for &k in &elastic {
                    x.push(force[k] / f_target - 1.0);
                    y.push(friction_change(&s, row, torque[k], force[k]));
                }
                // dT/dF = K(mu) + F dK/dF grows with F for c > 0 and falls for c < 0.
                let half = elastic.len() / 2;
                let fit = |ks: &[usize]| {
                    let f: Vec<f64> = ks.iter().map(|&k| force[k]).collect();
                    let t: Vec<f64> = ks.iter().map(|&k| torque[k]).collect();
                    slope(&f, &t)
                };
                let (low, high) = (fit(&elastic[..half]), fit(&elastic[half..]));
                assert!((high - low) * c > 0.0, "c {c} row {row}: {low} -> {high}");
            }
            let got = slope(&x, &y);
            assert!((got / c - 1.0).abs() < 0.01, "c = {got}, set {c}");
        }
    }

    #[test]
    fn inertia_adds_j_alpha_at_the_csdt_restart() {
        let j = 5.0e-4;
        let off = clean(30, 73, Strategy::Csdt);
        let on = SimulationConfig {
            effects: EffectsConfig { inertia: j, ..no_effects() },
            ..off.clone()
        };
        let (a, b) = (simulate(&off).unwrap(), simulate(&on).unwrap());
        let fs = off.sample_rate_hz;
        for row in 0..off.n {
            let angle = f32_list(&a.tightenings, "angle", row);
            let (ta, tb) =
                (f32_list(&a.tightenings, "torque", row), f32_list(&b.tightenings, "torque", row));
            assert_eq!(
                angle,
                f32_list(&b.tightenings, "angle", row),
                "inertia leaves the motion alone"
            );
            // The restart: first move after at least 50 held samples.
            let mut held = 0;
            let mut restart = None;
            for k in 1..angle.len() {
                if angle[k] == angle[k - 1] {
                    held += 1;
                } else {
                    if held >= 50 {
                        restart = Some(k);
                        break;
                    }
                    held = 0;
                }
            }
            let r = restart.unwrap();
            let omega = (angle[r] - angle[r - 1]) * fs * std::f64::consts::PI / 180.0; // rad/s
            let expected = j * omega * fs; // J alpha, alpha = (omega - 0) / dt
            let step = tb[r] - ta[r];
            assert!((step / expected - 1.0).abs() < 0.01, "row {row}: {step} vs {expected}");
            // At constant speed (one sample on) the inertial torque is gone.
            assert!((tb[r + 2] - ta[r + 2]).abs() < 1e-4 * ta[r + 2], "row {row}");
        }
    }

    #[test]
    fn lowpass_delays_the_torque_ramp_by_tau() {
        let tau_ms = 5.0;
        let off = clean(60, 79, Strategy::Cst);
        let on = SimulationConfig {
            effects: EffectsConfig { torque_lowpass_ms: tau_ms, ..no_effects() },
            ..off.clone()
        };
        let (a, b) = (simulate(&off).unwrap(), simulate(&on).unwrap());
        let start = f64_col(&a.truth, "elastic_start_angle");
        let mut checked = 0;
        for row in 0..off.n {
            let (angle, time) =
                (f32_list(&a.tightenings, "angle", row), f32_list(&a.tightenings, "time", row));
            let (ta, tb) =
                (f32_list(&a.tightenings, "torque", row), f32_list(&b.tightenings, "torque", row));
            // After 20 tau in the elastic zone the filter's transient is gone (e^-20).
            let Some(first) = angle.iter().position(|x| *x > start.value(row)) else { continue };
            let settled = first + (20.0 * tau_ms * 1e-3 * off.sample_rate_hz) as usize;
            if ta.len() < settled + 40 {
                continue;
            }
            let rate = slope(&time[settled..], &ta[settled..]); // Nm/s of the clean ramp
            let lags: Vec<f64> = (settled..ta.len()).map(|k| (ta[k] - tb[k]) / rate).collect();
            for lag in &lags {
                assert!((lag * 1e3 / tau_ms - 1.0).abs() < 0.01, "row {row}: lag {lag}");
            }
            // Before the filter settles at the start the filtered curve also lags, never leads.
            assert!((1..ta.len()).all(|k| tb[k] <= ta[k] + 1e-4), "row {row}");
            checked += 1;
        }
        assert!(checked > 30, "only {checked} rows long enough");
    }

    #[test]
    fn runout_is_a_once_per_revolution_modulation_of_amplitude_r() {
        let r = 0.03;
        let off =
            SimulationConfig { strategies: Strategy::ALL.to_vec(), ..clean(30, 83, Strategy::Cst) };
        let on = SimulationConfig {
            effects: EffectsConfig { runout: r, ..no_effects() },
            ..off.clone()
        };
        let (a, b) = (simulate(&off).unwrap(), simulate(&on).unwrap());
        let phase = f64_col(&b.truth, "runout_phase");
        for row in 0..off.n {
            let angle = f32_list(&a.tightenings, "angle", row);
            let (ta, tb) =
                (f32_list(&a.tightenings, "torque", row), f32_list(&b.tightenings, "torque", row));
            // Least squares of the relative residual on sin and cos of the angle (1/rev).
            let (mut ss, mut cc, mut sc, mut ys, mut yc) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for k in 0..angle.len() {
                let (sn, cs) = angle[k].to_radians().sin_cos();
                let residual = tb[k] / ta[k] - 1.0;
                ss += sn * sn;
                cc += cs * cs;
                sc += sn * cs;
                ys += residual * sn;
                yc += residual * cs;
            }
            let det = ss * cc - sc * sc;
            let (p, q) = ((ys * cc - yc * sc) / det, (yc * ss - ys * sc) / det);
            // r sin(x + phi) = r cos(phi) sin(x) + r sin(phi) cos(x).
            let amplitude = p.hypot(q);
            assert!((amplitude / r - 1.0).abs() < 1e-3, "row {row}: amplitude {amplitude}");
            let fitted = q.atan2(p).rem_euclid(std::f64::consts::TAU);
            let diff = (fitted - phase.value(row)).abs();
            assert!(diff.min(std::f64::consts::TAU - diff) < 1e-3, "row {row}: phase {fitted}");
        }
    }

    /// Generation speed, n = 10,000, default settings and every effect on (with yield):
    /// `cargo test --release -p tightscan-core --lib simulate::tests::speed -- --ignored --nocapture`
    #[test]
    #[ignore]
    fn speed() {
        let default = SimulationConfig { n: 10_000, ..SimulationConfig::default() };
        let all_effects = SimulationConfig {
            effects: EffectsConfig::all_on(),
            with_yield: true,
            ..default.clone()
        };
        for (label, config) in [("default", default), ("all effects + yield", all_effects)] {
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
                "{label}, n = {}: {:.3} s best of 5 on {} threads, {:.0} tightenings/s, {} samples \
                 ({:.0} per tightening, {:.1} M/s)",
                config.n,
                best,
                rayon::current_num_threads(),
                config.n as f64 / best,
                samples,
                samples as f64 / config.n as f64,
                samples as f64 / best / 1e6
            );
        }
    }
}
