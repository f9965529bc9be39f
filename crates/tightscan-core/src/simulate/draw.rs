//! The hidden parameters of one tightening and the ranges they are drawn from: its own
//! generator per tightening (seeded from the run seed and its id), joint, friction, tool speeds,
//! fault and yield point.


use rand::RngExt;
use rand_xoshiro::Xoshiro256PlusPlus;

use crate::physics::thread::ThreadGeometry;
use super::config::{EffectsConfig, SimulationConfig, Strategy};
use super::faults::{Fault};

/// Friction coefficient the target torque is computed for (VDI 2230 style nominal value).
pub(super) const NOMINAL_MU: f64 = 0.14;
/// Target preload stress \[MPa\]: 0.6 * 640 MPa, 60 % of the minimum lower yield strength of
/// property class 8.8 (ISO 898-1, d <= 16 mm).
pub(super) const TARGET_PRELOAD_STRESS_MPA: f64 = 0.6 * 640.0;
/// Prevailing torque as a fraction of the target torque.
pub(super) const PREVAILING_RANGE: (f64, f64) = (0.01, 0.05);
/// Rundown before the alignment zone: 1 to 3 revolutions \[deg\].
pub(super) const RUNDOWN_ANGLE_RANGE: (f64, f64) = (360.0, 1080.0);
/// Width of the alignment (seating) zone \[deg\].
pub(super) const SNUG_WIDTH_RANGE: (f64, f64) = (3.0, 10.0);
/// The rundown speed is left this many degrees before the alignment zone starts.
pub(super) const SWITCH_BEFORE_SNUG_DEG: f64 = 10.0;
/// Rundown speed \[rpm\].
pub(super) const RUNDOWN_RPM: (f64, f64) = (200.0, 400.0);
/// Time for the motor to reach rundown speed from standstill \[s\].
pub(super) const ACCELERATION_TIME_S: (f64, f64) = (0.02, 0.05);
/// Final speed of CST, also the speed of the first step of CSDT after the rundown \[rpm\].
pub(super) const FINAL_RPM: (f64, f64) = (20.0, 60.0);
/// CSDT: torque of the first step as a fraction of the target.
pub(super) const CSDT_FIRST_STEP: (f64, f64) = (0.5, 0.7);
/// CSDT: pause between the steps \[s\].
pub(super) const CSDT_PAUSE_S: (f64, f64) = (0.05, 0.2);
/// CSDT: torque relaxation during the pause, fraction of the torque at the stop.
pub(super) const CSDT_RELAXATION: (f64, f64) = (0.005, 0.02);
/// CSDT: time constant of the relaxation \[s\].
pub(super) const CSDT_RELAX_TAU_S: f64 = 0.020;
/// CSDT: angle over which the relaxed torsion is wound up again after the restart \[deg\]. The
/// bolt shank is far stiffer in torsion than the joint is in clamping, so this is a fraction of
/// a degree and the curve rejoins the torque model almost at once.
pub(super) const CSDT_RECOVERY_DEG: f64 = 0.1;
/// CSDT: speed of the second step \[rpm\].
pub(super) const CSDT_SECOND_RPM: (f64, f64) = (10.0, 40.0);
/// HDT: initial speed of the decelerating phase \[rpm\].
pub(super) const HDT_START_RPM: (f64, f64) = (150.0, 300.0);
/// HDT: floor of `1 - T/target` in the speed law, so the tool never stalls before the target.
pub(super) const HDT_MIN_REMAINING: f64 = 0.05;
/// HDT: angle the tool's inertia carries it past the shut-off \[deg\].
pub(super) const HDT_COAST_DEG: (f64, f64) = (0.2, 1.0);
/// Standard deviation of the speed measurement \[rpm\].
pub(super) const SPEED_NOISE_RPM: f64 = 0.5;
/// 1 rpm = 6 deg/s.
pub(super) const DEG_PER_S_PER_RPM: f64 = 6.0;
/// 1 rpm = 2 pi / 60 rad/s.
pub(super) const RAD_PER_S_PER_RPM: f64 = std::f64::consts::TAU / 60.0;
/// Speed friction: speed at which `mu_th` and `mu_b` hold \[rpm\] (test-bench speeds are tens
/// of rpm).
pub(super) const SPEED_FRICTION_REF_RPM: f64 = 30.0;
/// Speed friction: below this speed \[rpm\] the log law is held at its value here: it
/// diverges at rest, where sliding friction is not defined.
pub(super) const SPEED_FRICTION_MIN_RPM: f64 = 1.0;
/// Yield: the clamp-force gradient falls from the elastic to the plastic value over this
/// fraction of the elastic angle from snug to yield (a gradual yield point, as bolts with a
/// rolled thread show, not a sharp kink).
pub(super) const YIELD_TRANSITION_FRACTION: f64 = 0.1;
/// Incipient ramp length, fraction of the angle from the onset to the fault-free end.
pub(super) const INCIPIENT_RAMP: (f64, f64) = (0.2, 0.5);
/// Intermittent on/off interval length \[deg\].
pub(super) const INTERMITTENT_INTERVAL_DEG: (f64, f64) = (2.0, 6.0);
/// Safety cap on samples per tightening (never reached with validated settings: the angle
/// always advances and the torque grows without bound with it).
pub(super) const MAX_SAMPLES_PER_TIGHTENING: usize = 50_000_000;

// ---------------------------------------------------------------------------------------------

/// splitmix64 finaliser (Steele, Lea, Flood 2014): a bijective 64-bit mixer.
pub(super) fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Seed of one tightening: distinct ids give distinct seeds for a given run seed (bijection).
pub(super) fn mix(seed: u64, id: i64) -> u64 {
    splitmix64(splitmix64(seed) ^ (id as u64))
}

pub(super) fn uniform(rng: &mut Xoshiro256PlusPlus, range: (f64, f64)) -> f64 {
    // Written out instead of `random_range` so that an empty range (lo == hi) is allowed.
    range.0 + (range.1 - range.0) * rng.random::<f64>()
}

pub(super) fn pick<T: Copy>(rng: &mut Xoshiro256PlusPlus, items: &[T]) -> T {
    let i = (rng.random::<f64>() * items.len() as f64) as usize;
    items[i.min(items.len() - 1)]
}

/// Yield point of a bolt that yields (see [`SimulationConfig::with_yield`]).
#[derive(Clone, Copy, Debug)]
pub(super) struct YieldPoint {
    /// Angle where the clamp-force gradient starts to fall \[deg\].
    pub(super) angle: f64,
    /// Clamp force there \[kN\].
    pub(super) force: f64,
    /// Angle over which the gradient falls to its plastic value \[deg\].
    pub(super) width: f64,
    /// Plastic gradient over elastic gradient.
    pub(super) ratio: f64,
}

impl YieldPoint {
    /// Clamp-force travel past yield in units of the elastic stiffness \[deg\]: the integral of
    /// the normalised gradient `g(u) = 1 - (1 - r) S(u / w)` from 0 to `u`, with the smoothstep
    /// `S(s) = 3 s^2 - 2 s^3` (value and slope of the gradient continuous at both ends). Its
    /// integral is `s^3 - s^4 / 2` up to `s = 1` and `s - 1/2` beyond, where `g = r`.
    pub(super) fn travel(&self, u: f64) -> f64 {
        let s = u / self.width;
        let smoothstep_integral = if s < 1.0 { s * s * s * (1.0 - 0.5 * s) } else { s - 0.5 };
        u - (1.0 - self.ratio) * self.width * smoothstep_integral
    }
}

/// The hidden parameters of one tightening.
pub(super) struct Draw {
    pub(super) strategy: Strategy,
    pub(super) thread: &'static ThreadGeometry,
    pub(super) mu_th: f64,
    pub(super) mu_b: f64,
    pub(super) preload_target_kn: f64,
    /// `1 / preload_target_kn` \[1/kN\], for the pressure-friction law.
    pub(super) inverse_preload_target: f64,
    pub(super) target_torque: f64,
    pub(super) k_joint: f64,
    /// Total prevailing torque \[Nm\]: the thread's own plus a locking element's.
    pub(super) prevailing: f64,
    pub(super) theta0: f64,
    pub(super) snug_width: f64,
    pub(super) rundown_rpm: f64,
    pub(super) acceleration_s: f64,
    pub(super) final_rpm: f64,
    pub(super) csdt_first_step: f64,
    pub(super) csdt_pause_s: f64,
    pub(super) csdt_relaxation: f64,
    pub(super) csdt_second_rpm: f64,
    pub(super) hdt_start_rpm: f64,
    pub(super) hdt_coast_deg: f64,
    pub(super) fault: Option<Fault>,
    pub(super) yield_point: Option<YieldPoint>,
    pub(super) effects: EffectsConfig,
    /// Phase `phi` of the run-out \[rad\] (drawn even when run-out is off).
    pub(super) runout_phase: f64,
}

impl Draw {
    /// `rng` draws the basic parameters, `extras` the yield point and the effect parameters, so
    /// that switching the yield zone or an effect on never shifts the basic draws.
    pub(super) fn new(
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
    pub(super) fn clamp_force(&self, theta: f64) -> f64 {
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
