//! The physics of a tightening: thread geometry and the torque model (VDI 2230 / ISO 16047),
//! the phases of a curve (rundown, snug, elastic clamping, yield), the elastic window and its
//! torque rate (the friction signal), and the friction coefficient from clamp force or joint
//! stiffness. Uses nothing above it: no detector, no Arrow.

pub mod friction;
pub mod phases;
pub mod thread;
pub mod torque_rate;
