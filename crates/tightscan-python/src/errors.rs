//! Core errors to Python exceptions, and the one helper that releases the GIL.
//!
//! The exception classes live in `tightscan/exceptions.py` so that they can inherit from both
//! `TightscanError` and `ValueError`; each core variant maps to exactly one of them.

use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use pyo3::types::PyType;
use pyo3::sync::PyOnceLock;
use tightscan_core::TightscanError;

/// Runs `f` with the GIL released; its error becomes the matching Python exception.
pub fn detached<T, F>(py: Python<'_>, f: F) -> PyResult<T>
where
    T: Send,
    F: FnOnce() -> Result<T, DetachedError> + Send,
{
    py.detach(f).map_err(|e| match e {
        DetachedError::Core(e) => to_py_err(py, e),
        DetachedError::Arrow(e) => to_py_err(py, TightscanError::Arrow(e)),
    })
}

/// Errors that can leave a detached closure.
pub enum DetachedError {
    /// A core error.
    Core(TightscanError),
    /// An Arrow error (for example while reading the input stream).
    Arrow(arrow_schema::ArrowError),
}

impl From<TightscanError> for DetachedError {
    fn from(e: TightscanError) -> Self {
        Self::Core(e)
    }
}
impl From<arrow_schema::ArrowError> for DetachedError {
    fn from(e: arrow_schema::ArrowError) -> Self {
        Self::Arrow(e)
    }
}

fn exception_class<'py>(py: Python<'py>, cell: &'static PyOnceLock<Py<PyType>>, name: &str) -> PyResult<Bound<'py, PyType>> {
    cell.get_or_try_init(py, || {
        let module = py.import("tightscan.exceptions")?;
        Ok::<_, PyErr>(module.getattr(name)?.cast_into::<PyType>()?.unbind())
    })
    .map(|t| t.bind(py).clone())
}

static TIGHTSCAN_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();
static SCHEMA_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();
static PARAMETER_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();

/// The Python exception for a core error: `SchemaError` (with `.column`),
/// `InvalidParameterError` (with `.parameter`), else `TightscanError`.
pub fn to_py_err(py: Python<'_>, e: TightscanError) -> PyErr {
    let message = e.to_string();
    let built = (|| -> PyResult<PyErr> {
        let (class, attr) = match &e {
            TightscanError::Schema { column, .. } => {
                (exception_class(py, &SCHEMA_ERROR, "SchemaError")?, Some(("column", column.clone())))
            }
            TightscanError::InvalidParameter { name, .. } => (
                exception_class(py, &PARAMETER_ERROR, "InvalidParameterError")?,
                Some(("parameter", name.clone())),
            ),
            TightscanError::Arrow(_) => (exception_class(py, &TIGHTSCAN_ERROR, "TightscanError")?, None),
        };
        let instance = class.call1((message.clone(),))?;
        if let Some((name, value)) = attr {
            instance.setattr(name, value)?;
        }
        Ok(PyErr::from_value(instance))
    })();
    // If tightscan.exceptions cannot be imported, still raise, never panic.
    built.unwrap_or_else(|_| PyRuntimeError::new_err(message))
}
