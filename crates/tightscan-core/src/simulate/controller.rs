//! The nutrunner's speed controller for the three strategies (CST, CSDT with its pause, HDT
//! with its falling speed), time-stepped sample by sample.


use super::config::{Strategy};
use super::draw::{CSDT_RECOVERY_DEG, CSDT_RELAX_TAU_S, DEG_PER_S_PER_RPM, Draw, HDT_MIN_REMAINING, MAX_SAMPLES_PER_TIGHTENING, SWITCH_BEFORE_SNUG_DEG};
use super::record::{Recorder};


#[derive(Clone, Copy)]
pub(super) enum Phase {
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

/// Time-steps the nutrunner: each sample is recorded, then the controller picks the speed of
/// the next interval from the true torque, and the angle is integrated with it. The speed
/// recorded at a sample is the speed of the interval that ended there.
pub(super) fn run_controller(rec: &mut Recorder<'_, '_>, d: &Draw, sample_rate_hz: f64) {
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
pub(super) fn coast(rec: &mut Recorder<'_, '_>, theta: f64, rpm: f64, t: f64, dt: f64, coast_deg: f64) {
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
