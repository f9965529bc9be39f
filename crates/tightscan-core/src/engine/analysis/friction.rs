//! The friction step: which signal gives dT/dF for this tightening (clamp force, or a joint
//! stiffness) with which joint geometry (columns, then configuration, then the ISO thread
//! table), and the estimate itself ([`crate::physics::friction`]).

use crate::engine::input::{ChannelRow, Sample, Samples, TighteningTable};
use crate::engine::schema;
use crate::engine::status::TighteningStatus;
use crate::engine::Detector;
use crate::physics::friction::{estimate_friction, FrictionEstimate, FrictionSource};
use crate::physics::phases::Phases;
use crate::physics::thread::{parse_thread, JointGeometry, D2_PITCH_FACTOR};

use super::Scratch;

/// What the friction estimate can use for one tightening.
pub(super) enum FrictionInput {
    /// Neither clamp force nor joint stiffness: torque rate only.
    None,
    /// Clamp force samples \[kN\] (copied to `Scratch::force`) and the joint geometry.
    ClampForce(JointGeometry),
    /// Joint stiffness \[kN/deg\] and the joint geometry.
    JointStiffness(f64, JointGeometry),
}

impl Detector {
    /// Clamp force (copied into `scratch.force`) or joint stiffness, with the joint geometry:
    /// columns first, then the configuration, then the thread table. Without either signal the
    /// thread does not matter and is not checked.
    pub(super) fn friction_input(
        &self,
        table: &TighteningTable<'_>,
        i: usize,
        scratch: &mut Scratch,
    ) -> std::result::Result<FrictionInput, TighteningStatus> {
        scratch.has_force = false;
        let cfg = &self.config.friction;
        let number = |name: &str, fallback: Option<f64>| table.number_of(name, i).filter(|v| *v > 0.0).or(fallback);
        let force = table.channel(schema::CLAMP_FORCE).and_then(|c| match c.row(i) {
            ChannelRow::Present { samples, .. } => Some(samples),
            ChannelRow::Null => None,
        });
        let stiffness = number(schema::JOINT_STIFFNESS, cfg.joint_stiffness);
        if force.is_none() && stiffness.is_none() {
            return Ok(FrictionInput::None);
        }
        let designation = table.thread_of(i).or(cfg.thread.as_deref());
        let tabled = designation.and_then(parse_thread).map(JointGeometry::from);
        let pitch = number(schema::PITCH_MM, cfg.pitch_mm).or(tabled.map(|g| g.pitch_mm));
        let d2 = number(schema::D2_MM, cfg.d2_mm).or(tabled.map(|g| g.d2_mm));
        let dkm = number(schema::DKM_MM, cfg.dkm_mm).or(tabled.map(|g| g.dkm_mm));
        let geometry = match (pitch, d2, dkm) {
            (Some(p), Some(d2), Some(dkm)) => JointGeometry {
                pitch_mm: p,
                d2_mm: d2,
                dkm_mm: dkm,
                // d from the table when the designation is known, else from ISO 724 d2 = d - 0.6495 P.
                nominal_diameter_mm: tabled.map_or(d2 + D2_PITCH_FACTOR * p, |g| g.nominal_diameter_mm),
            },
            _ => {
                return match designation {
                    Some(d) => Err(TighteningStatus::UnknownThread { designation: d.to_string() }),
                    // No thread at all: mu_tot stays null, the rest is analysed.
                    None => Ok(FrictionInput::None),
                }
            }
        };
        match (force, stiffness) {
            (Some(f), _) => {
                scratch.force.clear();
                match f {
                    Samples::F32(v) => scratch.force.extend(v.iter().map(|x| *x as f64)),
                    Samples::F64(v) => scratch.force.extend_from_slice(v),
                }
                scratch.has_force = true;
                Ok(FrictionInput::ClampForce(geometry))
            }
            (None, Some(k)) => Ok(FrictionInput::JointStiffness(k, geometry)),
            (None, None) => Ok(FrictionInput::None),
        }
    }

    /// Friction coefficient and nut factor over the elastic window. With clamp force: the robust
    /// slope of torque on force, dT/dF = 0.16 P + 0.58 d2 mu_th + Dkm/2 mu_b (the prevailing
    /// torque, a constant, drops out of the slope); with a joint stiffness k: F = k (theta -
    /// theta_snug) in the elastic zone, so dT/dF = torque rate / k. Then ISO 16047 for mu_tot.
    pub(super) fn friction_row<T: Sample>(
        &self,
        torque: &[T],
        phases: &Phases,
        friction: FrictionInput,
        s: &mut Scratch,
    ) -> Option<FrictionEstimate> {
        let (torque_per_force, geometry, source) = match friction {
            FrictionInput::None => return None,
            FrictionInput::JointStiffness(k, g) => (phases.torque_rate / k, g, FrictionSource::JointStiffness),
            FrictionInput::ClampForce(g) => {
                let w = phases.window;
                let force = s.force.get(w.start..w.end)?;
                let line = s.phases.robust_line_of(force, &torque[w.start..w.end])?;
                (line.slope, g, FrictionSource::ClampForce)
            }
        };
        estimate_friction(torque_per_force, &geometry, source)
    }
}
