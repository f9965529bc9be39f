//! Friction faults: abrupt steps, incipient ramps and intermittent on/off episodes, acting
//! multiplicatively on mu_th, mu_b or both along the angle.


use rand_xoshiro::Xoshiro256PlusPlus;
use super::config::{FaultComponent, FaultKind};
use super::draw::{INTERMITTENT_INTERVAL_DEG, uniform};


#[derive(Clone, Copy, Debug)]
pub(super) struct Fault {
    pub(super) kind: FaultKind,
    pub(super) component: FaultComponent,
    /// Signed relative change of the coefficient(s).
    pub(super) magnitude: f64,
    pub(super) onset_deg: f64,
    /// Incipient only: angle over which the change builds up.
    pub(super) ramp_deg: f64,
}

/// Friction multipliers along the angle. Angles are visited in non-decreasing order, which lets
/// the intermittent pattern be drawn lazily and still be a fixed function of the angle.
pub(super) struct FrictionPath {
    pub(super) fault: Option<Fault>,
    pub(super) on: bool,
    pub(super) next_toggle: f64,
}

impl FrictionPath {
    pub(super) fn new(fault: Option<Fault>, rng: &mut Xoshiro256PlusPlus) -> Self {
        let next_toggle = match fault {
            Some(f) if f.kind == FaultKind::Intermittent => {
                f.onset_deg + uniform(rng, INTERMITTENT_INTERVAL_DEG)
            }
            _ => f64::INFINITY,
        };
        Self { fault, on: true, next_toggle }
    }

    /// (thread, bearing) multipliers of mu at `theta`.
    pub(super) fn multipliers(&mut self, theta: f64, rng: &mut Xoshiro256PlusPlus) -> (f64, f64) {
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
