//! The friction coefficient of one tightening from its torque per clamp force.
//!
//! In the elastic zone the torque model is linear in the clamp force, so its slope
//! dT/dF = 0.16 P + 0.58 d2 mu_th + Dkm/2 mu_b holds the friction (the prevailing torque, a
//! constant, drops out). dT/dF comes from clamp force where a rig measures it (the robust slope
//! of torque on force), or from a known joint stiffness k: F = k (theta - theta_snug), so
//! dT/dF = torque rate / k. ISO 16047 then gives mu_tot (METHODS.md section 1).

use crate::physics::thread::JointGeometry;

/// Where the torque per clamp force came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrictionSource {
    /// Robust slope of torque on the measured clamp force.
    ClampForce,
    /// Torque rate divided by a given joint stiffness.
    JointStiffness,
}

impl FrictionSource {
    /// Name used in the `mu_source` result column.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::ClampForce => "clamp_force",
            Self::JointStiffness => "joint_stiffness",
        }
    }
}

/// Friction coefficient and nut factor of one tightening.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrictionEstimate {
    /// Total friction coefficient (ISO 16047, mu_th = mu_b).
    pub mu_tot: f64,
    /// Nut factor K = T / (F d).
    pub nut_factor: f64,
    /// Where dT/dF came from.
    pub source: FrictionSource,
}

/// `mu_tot` and the nut factor from dT/dF \[Nm/kN\]; `None` when that does not give a finite
/// coefficient.
pub fn estimate_friction(torque_per_force: f64, geometry: &JointGeometry, source: FrictionSource) -> Option<FrictionEstimate> {
    let mu_tot = geometry.mu_tot(torque_per_force);
    mu_tot.is_finite().then(|| FrictionEstimate { mu_tot, nut_factor: geometry.nut_factor(torque_per_force), source })
}
