//! Change detectors and their critical values. Each works on plain slices (a series, a line's
//! residuals, block torque rates) and knows nothing of Arrow or of tightenings: the engine
//! feeds them. A new detector goes here, with its size and power tests beside it, and joins
//! the decision rule in [`crate::engine::decision`].

pub mod breakpoint;
pub mod critical_values;
pub mod cusum;
pub mod kde;
pub mod monitor;
pub mod noise;
pub mod sequence;
pub mod shewhart;
