//! Effects on the measured torque channel (transducer low-pass, run-out, socket inertia) and
//! the measurement itself (noise, quantisation).


use rand_xoshiro::Xoshiro256PlusPlus;
use super::draw::{Draw, RAD_PER_S_PER_RPM};
use super::record::{Channels};


/// First-order low-pass `tau dy/dt = x - y` of the torque transducer, discretised exactly for
/// an input that is linear between samples (first-order hold): with `a = exp(-dt / tau)`,
/// `y_k = a y_{k-1} + (1 - a) x_{k-1} + (1 - tau (1 - a) / dt) (x_k - x_{k-1})`. A ramp of slope
/// `m` comes out as `x - m tau` exactly (a pure delay of `tau`), which the plain one-pole
/// recursion only approximates (`tau -+ dt/2`).
pub(super) struct LowPass {
    pub(super) a: f64,
    pub(super) b: f64,
    pub(super) previous: Option<(f64, f64)>,
}

impl LowPass {
    pub(super) fn new(tau_s: f64, dt: f64) -> Self {
        let a = (-dt / tau_s).exp();
        Self { a, b: 1.0 - tau_s * (1.0 - a) / dt, previous: None }
    }

    pub(super) fn filter(&mut self, x: f64) -> f64 {
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
pub(super) fn sin_turns(u: f64) -> f64 {
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
pub(super) struct Measurement<'o> {
    pub(super) noise_rng: Xoshiro256PlusPlus,
    pub(super) clamp_rng: Xoshiro256PlusPlus,
    pub(super) torque_sd: f64,
    pub(super) clamp_sd: f64,
    pub(super) resolution: f64,
    pub(super) sample_rate_hz: f64,
    /// `None` when the low-pass effect is off.
    pub(super) lowpass: Option<LowPass>,
    pub(super) out: Channels<'o>,
}

impl Measurement<'_> {
    /// The torque the transducer reports for the true joint torque `torque` at angle `theta`,
    /// with `rpm` the speed of the interval just ended and `previous_rpm` that of the one
    /// before: run-out, inertial torque and low-pass as described on [`EffectsConfig`] (each
    /// skipped when off), noise excluded.
    pub(super) fn transduce(&mut self, d: &Draw, torque: f64, theta: f64, rpm: f64, previous_rpm: f64) -> f64 {
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
