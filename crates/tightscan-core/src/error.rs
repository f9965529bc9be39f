//! Typed errors of the core. The binding maps each variant to one Python exception class.

use thiserror::Error;

/// Everything that can go wrong in the core that is not a per-tightening problem.
///
/// Per-tightening problems (too short, NaN, ...) never become an error: they become a result
/// row with a status (see [`crate::engine::status::TighteningStatus`]).
#[derive(Debug, Error)]
pub enum TightscanError {
    /// The table does not follow the data contract; names the column.
    #[error("column '{column}': {message}")]
    Schema {
        /// Column that violates the contract.
        column: String,
        /// What is wrong with it.
        message: String,
    },
    /// A configuration value is out of its domain; names the parameter.
    #[error("parameter '{name}': {message}")]
    InvalidParameter {
        /// Parameter name as the user spells it.
        name: String,
        /// What is wrong with it.
        message: String,
    },
    /// An Arrow compute or construction step failed.
    #[error("arrow: {0}")]
    Arrow(#[from] arrow_schema::ArrowError),
}

impl TightscanError {
    /// Shorthand for a [`TightscanError::Schema`] error.
    pub fn schema(column: impl Into<String>, message: impl Into<String>) -> Self {
        Self::Schema { column: column.into(), message: message.into() }
    }
    /// Shorthand for a [`TightscanError::InvalidParameter`] error.
    pub fn parameter(name: impl Into<String>, message: impl Into<String>) -> Self {
        Self::InvalidParameter { name: name.into(), message: message.into() }
    }
}

/// Result alias of the core.
pub type Result<T> = std::result::Result<T, TightscanError>;
