//! Python bindings of tightscan-core (`tightscan._core`): type and error conversion only.
//!
//! Every call that computes extracts its Python inputs first, then runs in
//! [`errors::detached`] with the GIL released.

mod config;
mod errors;

use arrow_array::RecordBatch;
use arrow_schema::SchemaRef;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use pyo3_arrow::input::AnyRecordBatch;
use pyo3_arrow::{PySchema, PyTable};
use tightscan_core::detectors::cusum;
use tightscan_core::{simulate as sim, Detector};

use crate::errors::{detached, to_py_err};

/// Analyses every tightening of `data` (anything with the Arrow PyCapsule interface) and
/// returns a pyarrow Table with one row per input tightening, in input order.
#[pyfunction]
#[pyo3(signature = (data, config=None, passthrough=None, first_row=0))]
fn detect<'py>(
    py: Python<'py>,
    data: AnyRecordBatch,
    config: Option<&Bound<'py, PyDict>>,
    passthrough: Option<Vec<String>>,
    first_row: i64,
) -> PyResult<Bound<'py, PyAny>> {
    let detector = Detector::new(config::detect_config(config)?).map_err(|e| to_py_err(py, e))?;
    let passthrough = passthrough.unwrap_or_default();
    let reader = data.into_reader()?;
    let input_schema = reader.schema();
    let schema = detector.result_schema(&input_schema, &passthrough).map_err(|e| to_py_err(py, e))?;
    let batches = detached(py, move || {
        let batches = reader.collect::<Result<Vec<RecordBatch>, _>>()?;
        Ok(detector.detect_all(&input_schema, &batches, &passthrough, first_row)?)
    })?;
    PyTable::try_new(batches, schema)?.into_pyarrow(py)
}

/// What each detector computed along the one tightening of `data` (`Detector::traces`): its
/// result row as a pyarrow Table and a dict of the traces (`cusum`, `l1`, `breaks`, `kde`;
/// None for a detector that did not run), each a dict of lists and numbers. `row_number` is
/// the tightening's row in the table `detect` is given.
#[pyfunction]
#[pyo3(signature = (data, row_number=0, config=None))]
fn detector_traces<'py>(
    py: Python<'py>,
    data: AnyRecordBatch,
    row_number: usize,
    config: Option<&Bound<'py, PyDict>>,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyDict>)> {
    let detector = Detector::new(config::detect_config(config)?).map_err(|e| to_py_err(py, e))?;
    let reader = data.into_reader()?;
    let input_schema = reader.schema();
    let (row, traces) = detached(py, move || {
        let batches = reader.collect::<Result<Vec<RecordBatch>, _>>()?;
        Ok(detector.traces(&input_schema, &batches, row_number)?)
    })?;
    let schema = row.schema();
    let table = PyTable::try_new(vec![row], schema)?.into_pyarrow(py)?;
    let d = PyDict::new(py);
    let cusum = traces.cusum.map(|t| -> PyResult<_> {
        let c = PyDict::new(py);
        c.set_item("angle", t.angle)?;
        c.set_item("z", t.z)?;
        c.set_item("upper", t.upper)?;
        c.set_item("lower", t.lower)?;
        c.set_item("threshold", t.threshold)?;
        c.set_item("kappa", t.kappa)?;
        Ok(c)
    });
    d.set_item("cusum", cusum.transpose()?)?;
    let l1 = traces.l1.map(|t| -> PyResult<_> {
        let c = PyDict::new(py);
        c.set_item("angle", t.angle)?;
        c.set_item("statistic", t.statistic)?;
        c.set_item("boundary", t.boundary)?;
        c.set_item("critical_value", t.critical_value)?;
        c.set_item("gamma", t.gamma)?;
        c.set_item("training", t.training)?;
        Ok(c)
    });
    d.set_item("l1", l1.transpose()?)?;
    let breaks = traces.breaks.map(|t| -> PyResult<_> {
        let c = PyDict::new(py);
        c.set_item("angle", t.angle)?;
        c.set_item("lr", t.lr)?;
        c.set_item("critical_value", t.critical_value)?;
        c.set_item("decision_value", t.decision_value)?;
        c.set_item("significant", t.significant)?;
        c.set_item("scan_alarm", t.scan_alarm)?;
        c.set_item("tail_alarm", t.tail_alarm)?;
        c.set_item("head_alarm", t.head_alarm)?;
        c.set_item("episode", t.episode)?;
        c.set_item("episode_alarm", t.episode_alarm)?;
        Ok(c)
    });
    d.set_item("breaks", breaks.transpose()?)?;
    let kde = traces.kde.map(|t| -> PyResult<_> {
        let c = PyDict::new(py);
        c.set_item("grid", t.grid)?;
        c.set_item("before", t.before)?;
        c.set_item("after", t.after)?;
        c.set_item("bandwidth", t.bandwidth)?;
        c.set_item("before_angles", t.before_angles)?;
        c.set_item("after_angles", t.after_angles)?;
        c.set_item("tested", t.tested)?;
        Ok(c)
    });
    d.set_item("kde", kde.transpose()?)?;
    Ok((table, d))
}

/// The configuration `detect` runs with for `config`: every parameter (defaults filled in) as
/// the flat dict `detect` reads, and what the engine derives from them: the CUSUM threshold,
/// each detector's false-alarm probability (its share of the rule's alpha unless set), the L1
/// boundary's critical value. Raises as `detect` would for an invalid config.
#[pyfunction]
#[pyo3(signature = (config=None))]
fn effective_config<'py>(py: Python<'py>, config: Option<&Bound<'py, PyDict>>) -> PyResult<Bound<'py, PyDict>> {
    let detector = Detector::new(config::detect_config(config)?).map_err(|e| to_py_err(py, e))?;
    let d = PyDict::new(py);
    d.set_item("config", config::detect_config_to_dict(py, detector.config())?)?;
    let derived = PyDict::new(py);
    derived.set_item("cusum_threshold", detector.threshold())?;
    derived.set_item("break_alpha", detector.break_alpha())?;
    let (l1_alpha, l1_critical_value) = detector.l1_alpha();
    derived.set_item("l1_alpha", l1_alpha)?;
    derived.set_item("l1_critical_value", l1_critical_value)?;
    derived.set_item("kde_alpha", detector.kde_alpha())?;
    d.set_item("derived", derived)?;
    let decision = &detector.config().decision;
    let shares = PyDict::new(py);
    for kind in &decision.detectors {
        shares.set_item(kind.as_str(), decision.share(*kind))?;
    }
    d.set_item("shares", shares)?;
    Ok(d)
}

/// Flags repeated `tightening_id`s across all rows of a results table (`detect` flags within
/// the table it is given; a table analysed in pieces is flagged whole here).
#[pyfunction]
fn flag_duplicate_ids<'py>(py: Python<'py>, results: AnyRecordBatch) -> PyResult<Bound<'py, PyAny>> {
    let reader = results.into_reader()?;
    let schema = reader.schema();
    let batches = detached(py, move || {
        let batches = reader.collect::<Result<Vec<RecordBatch>, _>>()?;
        Ok(tightscan_core::engine::duplicates::flag_duplicate_ids(&batches)?)
    })?;
    PyTable::try_new(batches, schema)?.into_pyarrow(py)
}

/// Schema of `detect`'s result for an input schema.
#[pyfunction]
#[pyo3(signature = (schema, config=None, passthrough=None))]
fn result_schema<'py>(
    py: Python<'py>,
    schema: PySchema,
    config: Option<&Bound<'py, PyDict>>,
    passthrough: Option<Vec<String>>,
) -> PyResult<Bound<'py, PyAny>> {
    let detector = Detector::new(config::detect_config(config)?).map_err(|e| to_py_err(py, e))?;
    let input: SchemaRef = schema.into_inner();
    let out = detector
        .result_schema(&input, &passthrough.unwrap_or_default())
        .map_err(|e| to_py_err(py, e))?;
    PySchema::new(out).into_pyarrow(py)
}

/// The default detection parameters, as a flat dict (the one source of the defaults).
#[pyfunction]
fn default_config<'py>(py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
    config::detect_config_to_dict(py, &tightscan_core::DetectConfig::default())
}

/// `(pitch_mm, d2_mm, dkm_mm)` of an ISO metric thread designation ("M10", "m10 x 1,25") from
/// the engine's thread table (the one source; `diagnose` reads designations through it), or
/// None when the table does not hold it.
#[pyfunction]
fn thread_geometry(designation: &str) -> Option<(f64, f64, f64)> {
    tightscan_core::physics::thread::parse_thread(designation).map(|t| (t.pitch_mm, t.d2_mm, t.dkm_mm))
}

/// Labelled synthetic tightenings: (tightenings, truth) as pyarrow Tables.
#[pyfunction]
#[pyo3(signature = (config=None))]
fn simulate<'py>(
    py: Python<'py>,
    config: Option<&Bound<'py, PyDict>>,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    let cfg = config::simulation_config(config)?;
    let out = detached(py, move || Ok(sim::simulate(&cfg)?))?;
    let table = |b: RecordBatch| -> PyResult<Bound<'py, PyAny>> {
        let schema = b.schema();
        PyTable::try_new(vec![b], schema)?.into_pyarrow(py)
    };
    Ok((table(out.tightenings)?, table(out.truth)?))
}

/// Threshold h whose in-control ARL is `arl0` (Siegmund's approximation).
#[pyfunction]
#[pyo3(signature = (arl0, kappa, two_sided=true))]
fn cusum_threshold(py: Python<'_>, arl0: f64, kappa: f64, two_sided: bool) -> PyResult<f64> {
    cusum::cusum_threshold(arl0, kappa, two_sided).map_err(|e| to_py_err(py, e))
}

/// ARL of the CUSUM for a mean shift (Siegmund's approximation).
#[pyfunction]
#[pyo3(signature = (h, kappa, shift=0.0, two_sided=true))]
fn cusum_arl(h: f64, kappa: f64, shift: f64, two_sided: bool) -> f64 {
    cusum::cusum_arl(h, kappa, shift, two_sided)
}

/// Monitors one series of per-tightening values in production order (see
/// `tightscan_core::detectors::sequence`): self-starting CUSUM and L1 sign monitoring after `training`
/// reference values, each at `alpha` per series.
#[pyfunction]
#[pyo3(signature = (values, training=10, alpha=0.05, kappa=0.5, gamma=0.25))]
fn monitor_series<'py>(
    py: Python<'py>,
    values: Vec<f64>,
    training: usize,
    alpha: f64,
    kappa: f64,
    gamma: f64,
) -> PyResult<Bound<'py, PyDict>> {
    let cfg = tightscan_core::detectors::sequence::SequenceConfig { training, alpha, kappa, gamma };
    let m = detached(py, move || Ok(tightscan_core::detectors::sequence::monitor_series(&values, &cfg)?))?;
    let d = PyDict::new(py);
    d.set_item("z", m.z)?;
    d.set_item("cusum", m.cusum)?;
    d.set_item("threshold", m.threshold)?;
    d.set_item("cusum_alarm", m.cusum_alarm)?;
    d.set_item("cusum_side", m.cusum_side.map(|s| s.as_str()))?;
    d.set_item("cusum_change", m.cusum_change)?;
    d.set_item("l1_alarm", m.l1_alarm)?;
    d.set_item("reference_median", m.reference.0)?;
    d.set_item("reference_sd", m.reference.1)?;
    d.set_item("monitored", m.monitored)?;
    Ok(d)
}

/// Sequential monitoring of a linear regression (`tightscan_core::detectors::monitor`): L1 sign residuals
/// (`method="l1"`) or OLS-CUSUM (`method="ols_cusum"`, Horvath et al. 2004), trained on the first
/// `training` observations, with the boundary c (1 + k/m) (k/(m+k))^gamma. `regressors` are
/// columns besides the intercept. With `keep_path` the detector and boundary of every monitored
/// k are returned, for plots.
#[pyfunction]
#[pyo3(signature = (response, regressors=Vec::new(), training=20, gamma=0.25, alpha=0.05, method="l1", keep_path=true, long_run_variance=false, critical_value=None))]
#[allow(clippy::too_many_arguments)]
fn monitor_regression<'py>(
    py: Python<'py>,
    response: Vec<f64>,
    regressors: Vec<Vec<f64>>,
    training: usize,
    gamma: f64,
    alpha: f64,
    method: &str,
    keep_path: bool,
    long_run_variance: bool,
    critical_value: Option<f64>,
) -> PyResult<Bound<'py, PyDict>> {
    use tightscan_core::detectors::monitor::{monitor_l1, monitor_ols_cusum, L1MonitorConfig, OlsCusumConfig};
    let l1 = match method {
        "l1" => true,
        "ols_cusum" => false,
        other => {
            return Err(to_py_err(
                py,
                tightscan_core::TightscanError::parameter("method", format!("expected 'l1' or 'ols_cusum', got '{other}'")),
            ))
        }
    };
    let m = detached(py, move || {
        let columns: Vec<&[f64]> = regressors.iter().map(|c| c.as_slice()).collect();
        Ok(if l1 {
            let cfg = L1MonitorConfig { gamma, alpha, keep_path, long_run_variance, critical_value, ..L1MonitorConfig::new(training) };
            monitor_l1(&columns, &response, &cfg)?
        } else {
            let cfg = OlsCusumConfig { gamma, alpha, keep_path, critical_value, ..OlsCusumConfig::new(training) };
            monitor_ols_cusum(&columns, &response, &cfg)?
        })
    })?;
    let d = PyDict::new(py);
    d.set_item("method", method)?;
    d.set_item("alarm", m.alarm)?;
    d.set_item("alarm_index", m.alarm_index)?;
    d.set_item("statistic_at_alarm", m.statistic_at_alarm)?;
    d.set_item("boundary_at_alarm", m.boundary_at_alarm)?;
    d.set_item("max_ratio", m.max_ratio)?;
    d.set_item("gamma", m.gamma)?;
    d.set_item("alpha", m.alpha)?;
    d.set_item("critical_value", m.critical_value)?;
    d.set_item("training", m.training)?;
    d.set_item("monitored", m.monitored)?;
    d.set_item("coefficients", m.coefficients)?;
    d.set_item("scale", m.scale)?;
    let (statistic, boundary) = m.path.map_or((None, None), |p| (Some(p.statistic), Some(p.boundary)));
    d.set_item("statistic", statistic)?;
    d.set_item("boundary", boundary)?;
    Ok(d)
}

/// Critical value c(alpha, gamma, p) of the monitoring boundary: the shipped table, or with
/// `simulate` a fresh Monte Carlo value for any (alpha, gamma, p), optionally for a finite
/// horizon of `horizon_ratio` training lengths (`tightscan_core::detectors::critical_values`).
#[pyfunction]
#[pyo3(signature = (alpha, gamma, p=1, simulate=false, repetitions=10_000, grid=256, seed=0, horizon_ratio=None))]
#[allow(clippy::too_many_arguments)]
fn monitoring_critical_value(
    py: Python<'_>,
    alpha: f64,
    gamma: f64,
    p: usize,
    simulate: bool,
    repetitions: usize,
    grid: usize,
    seed: u64,
    horizon_ratio: Option<f64>,
) -> PyResult<f64> {
    use tightscan_core::detectors::critical_values as cv;
    if !simulate {
        if horizon_ratio.is_some() {
            return Err(to_py_err(
                py,
                tightscan_core::TightscanError::parameter("horizon_ratio", "the table is open-ended; a finite horizon needs simulate=True"),
            ));
        }
        return cv::critical_value(alpha, gamma, p).map_err(|e| to_py_err(py, e));
    }
    detached(py, move || {
        Ok(match horizon_ratio {
            Some(t) => cv::simulate_critical_value_horizon(alpha, gamma, p, t, repetitions, grid, seed)?,
            None => cv::simulate_critical_value(alpha, gamma, p, repetitions, grid, seed)?,
        })
    })
}

/// Column names, types, units and meanings of the result table.
#[pyfunction]
fn result_columns() -> Vec<(&'static str, String, &'static str, &'static str)> {
    tightscan_core::engine::schema::RESULT_COLUMNS
        .iter()
        .map(|(n, t, u, d)| (*n, t.data_type().to_string(), *u, *d))
        .collect()
}

#[pymodule(gil_used = false)]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(detect, m)?)?;
    m.add_function(wrap_pyfunction!(result_schema, m)?)?;
    m.add_function(wrap_pyfunction!(detector_traces, m)?)?;
    m.add_function(wrap_pyfunction!(effective_config, m)?)?;
    m.add_function(wrap_pyfunction!(flag_duplicate_ids, m)?)?;
    m.add_function(wrap_pyfunction!(default_config, m)?)?;
    m.add_function(wrap_pyfunction!(thread_geometry, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(cusum_threshold, m)?)?;
    m.add_function(wrap_pyfunction!(cusum_arl, m)?)?;
    m.add_function(wrap_pyfunction!(monitor_regression, m)?)?;
    m.add_function(wrap_pyfunction!(monitoring_critical_value, m)?)?;
    m.add_function(wrap_pyfunction!(result_columns, m)?)?;
    m.add_function(wrap_pyfunction!(monitor_series, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("DEBUG_BUILD", cfg!(debug_assertions))?;
    Ok(())
}
