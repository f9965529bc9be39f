//! Python dicts to core configurations. Unknown keys and wrong types raise
//! `InvalidParameterError` naming the key.

use pyo3::prelude::*;
use pyo3::types::{PyDict, PyDictMethods};
use tightscan_core::simulate::{FaultComponent, FaultKind, SimulationConfig, Strategy};
use tightscan_core::engine::{DecisionRule, DetectorKind};
use tightscan_core::{DetectConfig, TightscanError};

use crate::errors::to_py_err;

fn bad(py: Python<'_>, key: &str, message: impl Into<String>) -> PyErr {
    to_py_err(py, TightscanError::parameter(key, message))
}

fn get<'py, T: for<'a> FromPyObject<'a, 'py>>(py: Python<'py>, key: &str, value: &Bound<'py, PyAny>) -> PyResult<T> {
    value.extract::<T>().map_err(|_| {
        let ty = value.get_type().name().map(|n| n.to_string()).unwrap_or_default();
        bad(py, key, format!("has the wrong type ({ty})"))
    })
}

/// Flat dict of detection parameters to [`DetectConfig`] (absent keys keep their defaults).
pub fn detect_config(dict: Option<&Bound<'_, PyDict>>) -> PyResult<DetectConfig> {
    let mut c = DetectConfig::default();
    let Some(dict) = dict else { return Ok(c) };
    let py = dict.py();
    for (k, v) in dict.iter() {
        let key: String = k.extract()?;
        // None keeps a default, except where None itself is a setting (derive from alpha).
        if v.is_none() && !matches!(key.as_str(), "threshold" | "arl0" | "break_alpha" | "kde_alpha" | "l1_alpha" | "pf_alpha") {
            continue;
        }
        match key.as_str() {
            "zone_start_fraction" => c.zone.start_fraction = get(py, &key, &v)?,
            "zone_end_fraction" => c.zone.end_fraction = get(py, &key, &v)?,
            "zone_trim_fraction" => c.zone.trim_fraction = get(py, &key, &v)?,
            "zone_min_samples" => c.zone.min_samples = get(py, &key, &v)?,
            "yield_gradient_fraction" => c.yield_zone.gradient_fraction = get(py, &key, &v)?,
            "thread" => c.friction.thread = Some(get(py, &key, &v)?),
            "pitch_mm" => c.friction.pitch_mm = Some(get(py, &key, &v)?),
            "d2_mm" => c.friction.d2_mm = Some(get(py, &key, &v)?),
            "dkm_mm" => c.friction.dkm_mm = Some(get(py, &key, &v)?),
            "joint_stiffness" => c.friction.joint_stiffness = Some(get(py, &key, &v)?),
            "break_alpha" => c.breaks.alpha = get(py, &key, &v)?,
            "break_min_jump_steps" => c.breaks.min_jump_steps = get(py, &key, &v)?,
            "break_tail_fraction" => c.breaks.tail_fraction = get(py, &key, &v)?,
            "break_episode_fraction" => c.breaks.episode_fraction = get(py, &key, &v)?,
            "break_head_fraction" => c.breaks.head_fraction = get(py, &key, &v)?,
            "l1_alpha" => c.l1.alpha = get(py, &key, &v)?,
            "l1_gamma" => c.l1.gamma = get(py, &key, &v)?,
            "alpha" => c.decision.alpha = get(py, &key, &v)?,
            "rule" => c.decision.rule = parse_rule(py, &v)?,
            "detectors" => {
                let names: Vec<String> = get(py, &key, &v)?;
                c.decision.detectors = names
                    .iter()
                    .map(|n| {
                        DetectorKind::parse(n)
                            .ok_or_else(|| bad(py, "detectors", format!("unknown detector '{n}' (break, l1, cusum, kde, pf)")))
                    })
                    .collect::<PyResult<_>>()?;
            }
            "residual_training_fraction" => c.residual_tests.training_fraction = get(py, &key, &v)?,
            "kde" => c.residual_tests.kde = get(py, &key, &v)?,
            "kde_alpha" => c.residual_tests.kde_alpha = get(py, &key, &v)?,
            "kde_permutations" => c.residual_tests.kde_permutations = get(py, &key, &v)?,
            "kde_seed" => c.residual_tests.kde_seed = get(py, &key, &v)?,
            "shewhart_k" => c.residual_tests.shewhart_k = get(py, &key, &v)?,
            "pf" => c.pf.enabled = get(py, &key, &v)?,
            "pf_particles" => c.pf.particles = get(py, &key, &v)?,
            "pf_alpha" => c.pf.alpha = get(py, &key, &v)?,
            "pf_seed" => c.pf.seed = get(py, &key, &v)?,
            "pf_friction" => c.pf.friction_track = get(py, &key, &v)?,
            "max_blocks" => c.blocks.max_blocks = get(py, &key, &v)?,
            "min_block_samples" => c.blocks.min_block_samples = get(py, &key, &v)?,
            "training_fraction" => c.blocks.training_fraction = get(py, &key, &v)?,
            "min_training_blocks" => c.blocks.min_training_blocks = get(py, &key, &v)?,
            "kappa" => c.cusum.kappa = get(py, &key, &v)?,
            "arl0" => c.cusum.arl0 = get(py, &key, &v)?,
            "threshold" => c.cusum.threshold = get(py, &key, &v)?,
            _ => return Err(bad(py, &key, "unknown detection parameter")),
        }
    }
    Ok(c)
}

/// [`DetectConfig`] to the flat dict [`detect_config`] reads.
pub fn detect_config_to_dict<'py>(py: Python<'py>, c: &DetectConfig) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("zone_start_fraction", c.zone.start_fraction)?;
    d.set_item("zone_end_fraction", c.zone.end_fraction)?;
    d.set_item("zone_trim_fraction", c.zone.trim_fraction)?;
    d.set_item("zone_min_samples", c.zone.min_samples)?;
    d.set_item("yield_gradient_fraction", c.yield_zone.gradient_fraction)?;
    d.set_item("thread", c.friction.thread.clone())?;
    d.set_item("pitch_mm", c.friction.pitch_mm)?;
    d.set_item("d2_mm", c.friction.d2_mm)?;
    d.set_item("dkm_mm", c.friction.dkm_mm)?;
    d.set_item("joint_stiffness", c.friction.joint_stiffness)?;
    d.set_item("break_alpha", c.breaks.alpha)?;
    d.set_item("break_min_jump_steps", c.breaks.min_jump_steps)?;
    d.set_item("break_tail_fraction", c.breaks.tail_fraction)?;
    d.set_item("break_episode_fraction", c.breaks.episode_fraction)?;
    d.set_item("break_head_fraction", c.breaks.head_fraction)?;
    d.set_item("l1_alpha", c.l1.alpha)?;
    d.set_item("l1_gamma", c.l1.gamma)?;
    d.set_item("alpha", c.decision.alpha)?;
    match &c.decision.rule {
        DecisionRule::Any => d.set_item("rule", "any")?,
        DecisionRule::AtLeast(k) => d.set_item("rule", format!("{k}-of-n"))?,
        DecisionRule::Table(rows) => {
            let table = rows
                .iter()
                .map(|row| {
                    let r = PyDict::new(py);
                    row.iter().try_for_each(|&(kind, fires)| r.set_item(kind.as_str(), fires))?;
                    Ok(r)
                })
                .collect::<PyResult<Vec<_>>>()?;
            d.set_item("rule", table)?
        }
    }
    d.set_item("detectors", c.decision.detectors.iter().map(|k| k.as_str()).collect::<Vec<_>>())?;
    d.set_item("residual_training_fraction", c.residual_tests.training_fraction)?;
    d.set_item("kde", c.residual_tests.kde)?;
    d.set_item("kde_alpha", c.residual_tests.kde_alpha)?;
    d.set_item("kde_permutations", c.residual_tests.kde_permutations)?;
    d.set_item("kde_seed", c.residual_tests.kde_seed)?;
    d.set_item("shewhart_k", c.residual_tests.shewhart_k)?;
    d.set_item("pf", c.pf.enabled)?;
    d.set_item("pf_particles", c.pf.particles)?;
    d.set_item("pf_alpha", c.pf.alpha)?;
    d.set_item("pf_seed", c.pf.seed)?;
    d.set_item("pf_friction", c.pf.friction_track)?;
    d.set_item("max_blocks", c.blocks.max_blocks)?;
    d.set_item("min_block_samples", c.blocks.min_block_samples)?;
    d.set_item("training_fraction", c.blocks.training_fraction)?;
    d.set_item("min_training_blocks", c.blocks.min_training_blocks)?;
    d.set_item("kappa", c.cusum.kappa)?;
    d.set_item("arl0", c.cusum.arl0)?;
    d.set_item("threshold", c.cusum.threshold)?;
    Ok(d)
}

/// "any", "K-of-n" (at least K detectors of the rule), or a response table: a list of dicts,
/// one per row, detector name -> must fire (True) or stay silent (False).
fn parse_rule(py: Python<'_>, value: &Bound<'_, PyAny>) -> PyResult<DecisionRule> {
    if let Ok(text) = value.extract::<String>() {
        if text == "any" {
            return Ok(DecisionRule::Any);
        }
        return text
            .strip_suffix("-of-n")
            .and_then(|k| k.parse::<usize>().ok())
            .map(DecisionRule::AtLeast)
            .ok_or_else(|| bad(py, "rule", format!("expected 'any', 'K-of-n' (e.g. '2-of-n') or a list of dicts, got '{text}'")));
    }
    let rows: Vec<Bound<'_, PyDict>> = value
        .extract()
        .map_err(|_| bad(py, "rule", "expected 'any', 'K-of-n' or a response table (a list of dicts detector -> bool)"))?;
    rows.iter()
        .map(|row| {
            row.iter()
                .map(|(name, fires)| {
                    let name: String = get(py, "rule", &name)?;
                    let kind = DetectorKind::parse(&name)
                        .ok_or_else(|| bad(py, "rule", format!("unknown detector '{name}' in the response table (break, l1, cusum, kde, pf)")))?;
                    Ok((kind, get::<bool>(py, "rule", &fires)?))
                })
                .collect::<PyResult<Vec<_>>>()
        })
        .collect::<PyResult<Vec<_>>>()
        .map(DecisionRule::Table)
}

fn parse_list<T: std::str::FromStr>(py: Python<'_>, key: &str, names: Vec<String>) -> PyResult<Vec<T>> {
    names
        .iter()
        .map(|n| n.parse::<T>().map_err(|_| bad(py, key, format!("unknown value '{n}'"))))
        .collect()
}

/// Dict of simulation parameters to [`SimulationConfig`], validated. Keys are the field names;
/// the effects are flat keys named as the fields of `EffectsConfig` (`speed_friction`,
/// `torque_lowpass_ms`, `inertia`, `pressure_friction`, `prevailing_torque_nm`, `runout`).
/// `None` values keep the default (for `joint_stiffness_range`: derived from the thread).
pub fn simulation_config(dict: Option<&Bound<'_, PyDict>>) -> PyResult<SimulationConfig> {
    let mut c = SimulationConfig::default();
    if let Some(dict) = dict {
        let py = dict.py();
        for (k, v) in dict.iter() {
            let key: String = k.extract()?;
            if v.is_none() {
                continue;
            }
            match key.as_str() {
                "n" => c.n = get(py, &key, &v)?,
                "seed" => c.seed = get(py, &key, &v)?,
                "first_id" => c.first_id = get(py, &key, &v)?,
                "fault_fraction" => c.fault_fraction = get(py, &key, &v)?,
                "strategies" => c.strategies = parse_list::<Strategy>(py, &key, get(py, &key, &v)?)?,
                "fault_kinds" => c.fault_kinds = parse_list::<FaultKind>(py, &key, get(py, &key, &v)?)?,
                "fault_components" => {
                    c.fault_components = parse_list::<FaultComponent>(py, &key, get(py, &key, &v)?)?
                }
                "magnitude_range" => c.magnitude_range = get(py, &key, &v)?,
                "onset_fraction_range" => c.onset_fraction_range = get(py, &key, &v)?,
                "mu_th_range" => c.mu_th_range = get(py, &key, &v)?,
                "mu_b_range" => c.mu_b_range = get(py, &key, &v)?,
                "joint_stiffness_range" => c.joint_stiffness_range = Some(get(py, &key, &v)?),
                "elastic_angle_range" => c.elastic_angle_range = get(py, &key, &v)?,
                "with_yield" => c.with_yield = get(py, &key, &v)?,
                "yield_preload_range" => c.yield_preload_range = get(py, &key, &v)?,
                "yield_gradient_ratio" => c.yield_gradient_ratio = get(py, &key, &v)?,
                // Effects: flat keys named as the EffectsConfig fields; 0 switches one off.
                "speed_friction" => c.effects.speed_friction = get(py, &key, &v)?,
                "torque_lowpass_ms" => c.effects.torque_lowpass_ms = get(py, &key, &v)?,
                "inertia" => c.effects.inertia = get(py, &key, &v)?,
                "pressure_friction" => c.effects.pressure_friction = get(py, &key, &v)?,
                "prevailing_torque_nm" => c.effects.prevailing_torque_nm = get(py, &key, &v)?,
                "runout" => c.effects.runout = get(py, &key, &v)?,
                "threads" => c.threads = get(py, &key, &v)?,
                "torque_noise" => c.torque_noise = get(py, &key, &v)?,
                "clamp_force_noise" => c.clamp_force_noise = get(py, &key, &v)?,
                "angle_resolution_deg" => c.angle_resolution_deg = get(py, &key, &v)?,
                "sample_rate_hz" => c.sample_rate_hz = get(py, &key, &v)?,
                "with_clamp_force" => c.with_clamp_force = get(py, &key, &v)?,
                _ => return Err(bad(py, &key, "unknown simulation parameter")),
            }
        }
        c.validate().map_err(|e| to_py_err(py, e))?;
    }
    Ok(c)
}
