//! tightscan-core: detects friction changes in bolted-joint tightening curves.
//!
//! Pure Rust, no Python: the `tightscan-python` crate only converts types and errors.
#![doc = include_str!("../README.md")]

pub mod breakpoint;
pub mod critical_values;
pub mod cusum;
pub mod detect;
pub mod error;
pub mod input;
pub mod kde;
pub mod monitor;
pub mod phases;
pub mod schema;
pub mod sequence;
pub mod shewhart;
pub mod signal;
pub mod simulate;
pub mod status;
pub mod thread;

pub use detect::{CusumConfig, DetectConfig, Detector};
pub use error::{Result, TightscanError};
