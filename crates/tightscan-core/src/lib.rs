//! tightscan-core: detects friction changes in bolted-joint tightening curves.
//!
//! Pure Rust, no Python: the `tightscan-python` crate only converts types and errors.
#![doc = include_str!("../README.md")]

// Layers, each using only those listed after it: engine -> detectors -> physics; simulate
// uses physics only; error and sample serve every layer (docs/architecture.md).
pub mod engine;
pub mod detectors;
pub mod physics;
pub mod simulate;
pub mod error;
pub mod sample;

pub use engine::{CusumConfig, DetectConfig, Detector};
pub use error::{Result, TightscanError};
