//! Labelled synthetic tightenings: reproducible, parallel and fast.
//!
//! Every tightening is a torque-controlled rundown of an ISO metric bolt (geometry from
//! [`crate::physics::thread`]) into a joint of random stiffness, recorded like a nutrunner records it
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

mod config;
mod controller;
mod draw;
mod effects;
mod faults;
mod record;
#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)] // a failed unwrap is a failed test
mod tests;


use arrow_buffer::{OffsetBuffer, ScalarBuffer};
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;

use crate::error::{Result, TightscanError};
use crate::physics::thread::{parse_thread, JointGeometry, ThreadGeometry};

pub use config::{EffectsConfig, FaultComponent, FaultKind, SimulationConfig, Strategy};
pub use record::{truth_schema, tightenings_schema, Simulated};
use self::controller::{run_controller};
use self::draw::{Draw, mix};
use self::effects::{LowPass, Measurement};
use self::faults::{FrictionPath};
use self::record::{Channels, Recorder, Truth, assemble, split_rows};

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
