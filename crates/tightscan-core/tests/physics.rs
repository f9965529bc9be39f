//! Accuracy of the physics layer on simulated tightenings whose truth is known: the friction
//! coefficient, the snug angle and the prevailing torque, without friction change and with the
//! simulator's default (realistic) noise and angle quantisation.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::Arc;

use arrow_array::cast::AsArray;
use arrow_array::types::Float64Type;
use arrow_array::{Array, ArrayRef, Float64Array, RecordBatch, StringArray};
use arrow_schema::{DataType, Field, Schema};
use tightscan_core::simulate::{simulate, SimulationConfig};
use tightscan_core::physics::thread::{parse_thread, JointGeometry};
use tightscan_core::{DetectConfig, Detector};

fn f64_col<'a>(b: &'a RecordBatch, name: &str) -> &'a Float64Array {
    b.column_by_name(name).unwrap_or_else(|| panic!("no column {name}")).as_primitive::<Float64Type>()
}

fn str_col<'a>(b: &'a RecordBatch, name: &str) -> &'a StringArray {
    b.column_by_name(name).unwrap_or_else(|| panic!("no column {name}")).as_string::<i32>()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn clean(n: usize, seed: u64, with_clamp_force: bool) -> (RecordBatch, RecordBatch) {
    let cfg = SimulationConfig { n, seed, fault_fraction: 0.0, with_clamp_force, ..SimulationConfig::default() };
    let s = simulate(&cfg).unwrap();
    (s.tightenings, s.truth)
}

/// The ISO 16047 value of the simulated joint: the evaluation applied to the true torque per
/// clamp force (so the constants' rounding, below 1e-3, is not counted as estimation error).
fn true_mu_tot(thread: &str, mu_th: f64, mu_b: f64) -> f64 {
    let g = JointGeometry::from(parse_thread(thread).unwrap());
    g.mu_tot(g.torque_per_force(mu_th, mu_b))
}

fn with_column(b: &RecordBatch, name: &str, values: ArrayRef) -> RecordBatch {
    let mut fields: Vec<Field> = b.schema().fields().iter().map(|f| f.as_ref().clone()).collect();
    fields.push(Field::new(name, values.data_type().clone(), true));
    let mut cols = b.columns().to_vec();
    cols.push(values);
    RecordBatch::try_new(Arc::new(Schema::new(fields)), cols).unwrap()
}

#[test]
fn mu_tot_from_clamp_force_and_snug_angle_are_accurate() {
    let (curves, truth) = clean(2_000, 11, true);
    let det = Detector::new(DetectConfig::default()).unwrap();
    let out = det.detect(&curves, &[], 0).unwrap();
    let status = str_col(&out, "status");
    let threads = str_col(&curves, "thread");
    let (mu_th, mu_b) = (f64_col(&truth, "mu_th"), f64_col(&truth, "mu_b"));
    let (mu, source) = (f64_col(&out, "mu_tot"), str_col(&out, "mu_tot_source"));
    let (snug, snug_true) = (f64_col(&out, "snug_angle"), f64_col(&truth, "snug_angle"));
    let (mut mu_err, mut snug_err) = (Vec::new(), Vec::new());
    for i in 0..out.num_rows() {
        if status.value(i) != "ok" {
            continue;
        }
        assert_eq!(source.value(i), "clamp_force");
        mu_err.push((mu.value(i) - true_mu_tot(threads.value(i), mu_th.value(i), mu_b.value(i))).abs());
        snug_err.push((snug.value(i) - snug_true.value(i)).abs());
    }
    assert!(mu_err.len() > 1_700, "{} of 2000 analysed", mu_err.len());
    let (m_mu, m_snug) = (median(mu_err.clone()), median(snug_err.clone()));
    // Issue 3 asks 0.003 and 2 deg (medians).
    assert!(m_mu < 0.003, "median |mu_tot error| {m_mu}");
    assert!(m_snug < 2.0, "median |snug error| {m_snug} deg");
    eprintln!("median |mu_tot err| {m_mu:.5}, median |snug err| {m_snug:.3} deg, n {}", mu_err.len());
}

#[test]
fn mu_tot_from_joint_stiffness_column() {
    let (curves, truth) = clean(1_000, 12, false);
    let stiffness = truth.column_by_name("joint_stiffness").unwrap().clone();
    let curves = with_column(&curves, "joint_stiffness", stiffness);
    let out = Detector::new(DetectConfig::default()).unwrap().detect(&curves, &[], 0).unwrap();
    let status = str_col(&out, "status");
    let threads = str_col(&curves, "thread");
    let (mu_th, mu_b) = (f64_col(&truth, "mu_th"), f64_col(&truth, "mu_b"));
    let mu = f64_col(&out, "mu_tot");
    let source = str_col(&out, "mu_tot_source");
    let errs: Vec<f64> = (0..out.num_rows())
        .filter(|&i| status.value(i) == "ok")
        .map(|i| {
            assert_eq!(source.value(i), "joint_stiffness");
            (mu.value(i) - true_mu_tot(threads.value(i), mu_th.value(i), mu_b.value(i))).abs()
        })
        .collect();
    let m = median(errs);
    assert!(m < 0.003, "median |mu_tot error| {m} from stiffness");
}

#[test]
fn prevailing_torque_is_the_rundown_level() {
    let (curves, _) = clean(500, 13, false);
    let out = Detector::new(DetectConfig::default()).unwrap().detect(&curves, &[], 0).unwrap();
    let status = str_col(&out, "status");
    let target = f64_col(&curves, "target_torque");
    let prevailing = f64_col(&out, "prevailing_torque");
    // The simulator draws the prevailing torque from 1-5 % of the target.
    for i in 0..out.num_rows() {
        if status.value(i) == "ok" {
            let r = prevailing.value(i) / target.value(i);
            assert!((0.005..0.06).contains(&r), "row {i}: prevailing {r} of target");
        }
    }
    // No friction input: mu_tot stays null, nothing made up.
    assert_eq!(out.column_by_name("mu_tot").unwrap().null_count(), out.num_rows());
}

#[test]
fn unknown_thread_gets_a_status_only_when_mu_tot_is_asked_for() {
    let (curves, _) = clean(4, 14, true);
    let n = curves.num_rows();
    let bad: ArrayRef = Arc::new(StringArray::from(vec![Some("M7"), Some("M8"), None, Some("M7")]));
    let idx = curves.schema().index_of("thread").unwrap();
    let mut cols = curves.columns().to_vec();
    cols[idx] = bad;
    let mut fields: Vec<Field> = curves.schema().fields().iter().map(|f| f.as_ref().clone()).collect();
    fields[idx] = Field::new("thread", DataType::Utf8, true);
    let with_bad = RecordBatch::try_new(Arc::new(Schema::new(fields)), cols).unwrap();
    let out = Detector::new(DetectConfig::default()).unwrap().detect(&with_bad, &[], 0).unwrap();
    let status = str_col(&out, "status");
    assert!(status.value(0).starts_with("unknown_thread: \"M7\""), "{}", status.value(0));
    assert!(status.value(3).starts_with("unknown_thread"));
    assert!(!status.value(1).starts_with("unknown_thread"));
    // Overriding geometry columns make the unknown designation usable.
    let pitch: ArrayRef = Arc::new(Float64Array::from(vec![1.0; n]));
    let d2: ArrayRef = Arc::new(Float64Array::from(vec![6.35; n]));
    let dkm: ArrayRef = Arc::new(Float64Array::from(vec![9.0; n]));
    let fixed = with_column(&with_column(&with_column(&with_bad, "pitch_mm", pitch), "d2_mm", d2), "dkm_mm", dkm);
    let out = Detector::new(DetectConfig::default()).unwrap().detect(&fixed, &[], 0).unwrap();
    let status = str_col(&out, "status");
    assert!(!status.value(0).starts_with("unknown_thread"), "{}", status.value(0));
    // Without clamp force or stiffness the thread is not needed and not checked.
    let no_force = {
        let keep: Vec<usize> = (0..with_bad.num_columns())
            .filter(|&c| with_bad.schema().field(c).name() != "clamp_force")
            .collect();
        with_bad.project(&keep).unwrap()
    };
    let out = Detector::new(DetectConfig::default()).unwrap().detect(&no_force, &[], 0).unwrap();
    assert!(!str_col(&out, "status").value(0).starts_with("unknown_thread"));
}
