//! Settings of the simulator: strategies, fault kinds and components, the switchable effects
//! and [`SimulationConfig`] with its validation.

use std::fmt;
use std::str::FromStr;


use crate::error::{Result, TightscanError};
use crate::physics::thread::parse_thread;

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
    /// Thread designations drawn uniformly (see [`crate::physics::thread::parse_thread`]).
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
