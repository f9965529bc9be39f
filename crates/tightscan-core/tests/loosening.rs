//! Curves that are not tightenings with rising positive torque: loosening (unfastening) curves,
//! curves that fall, and curves whose elastic line would put the snug angle off the curve. None
//! of them may come out `ok`, `flat_signal` (they vary) or with a friction change.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::Arc;

use arrow_array::cast::AsArray;
use arrow_array::types::Float64Type;
use arrow_array::{Array, ListArray, RecordBatch};
use arrow_schema::{DataType, Field, Schema};
use tightscan_core::{DetectConfig, Detector};

const N: usize = 400;

/// Angle and torque of one curve.
type Curve = (Vec<f64>, Vec<f64>);

fn batch(curves: &[Curve]) -> RecordBatch {
    let list = |f: fn(&Curve) -> &Vec<f64>| {
        ListArray::from_iter_primitive::<Float64Type, _, _>(curves.iter().map(|c| Some(f(c).iter().map(|v| Some(*v)).collect::<Vec<_>>())))
    };
    let item = Arc::new(Field::new_list_field(DataType::Float64, true));
    let schema = Schema::new(vec![
        Field::new("angle", DataType::List(item.clone()), true),
        Field::new("torque", DataType::List(item), true),
    ]);
    RecordBatch::try_new(Arc::new(schema), vec![Arc::new(list(|c| &c.0)), Arc::new(list(|c| &c.1))]).unwrap()
}

fn angle() -> Vec<f64> {
    (0..N).map(|i| i as f64 * 0.25).collect()
}

/// A small deterministic ripple, so that no curve is exactly piecewise linear.
fn ripple(i: usize) -> f64 {
    0.004 * ((i * 7919 % 13) as f64 - 6.0) / 6.0
}

/// An unfastening curve as a cordless nutrunner records it: breakaway to -2.57 Nm within the
/// first degrees, then the torque runs out towards 0 and ends slightly positive (0.07 Nm).
fn loosening() -> Curve {
    let a = angle();
    let t = a
        .iter()
        .enumerate()
        .map(|(i, &x)| {
            let breakaway = if x < 3.0 { -2.57 * x / 3.0 } else { -2.32 * (-(x - 3.0) / 15.0).exp() - 0.25 * (1.0 - x / 100.0) };
            (breakaway + 0.07 * x / 100.0 + ripple(i)).min(0.07)
        })
        .collect();
    (a, t)
}

/// A tightening: rundown at 0.1 Nm, then a straight elastic rise to 12 Nm.
fn tightening(offset: f64) -> Curve {
    let a = angle();
    let t = a.iter().enumerate().map(|(i, &x)| offset + 0.1 + 0.3 * (x - 20.0).max(0.0) + ripple(i)).collect();
    (a, t)
}

fn run(curves: &[Curve]) -> (Vec<String>, Vec<Option<f64>>) {
    let det = Detector::new(DetectConfig::default()).unwrap();
    let out = det.detect(&batch(curves), &[], 0).unwrap();
    let status = out.column_by_name("status").unwrap().as_string::<i32>();
    let snug = out.column_by_name("snug_angle").unwrap().as_primitive::<Float64Type>();
    let statuses = (0..out.num_rows()).map(|i| status.value(i).to_string()).collect();
    let snugs = (0..out.num_rows()).map(|i| snug.is_valid(i).then(|| snug.value(i))).collect();
    (statuses, snugs)
}

#[test]
fn loosening_curves_get_their_own_status() {
    let (a, t) = loosening();
    assert!(t.iter().cloned().fold(f64::INFINITY, f64::min) < -2.5 && t.iter().cloned().fold(f64::NEG_INFINITY, f64::max) > 0.06);
    // As recorded, and with the angle counted downwards (some tools report loosening so).
    let backwards: Vec<f64> = a.iter().map(|x| -x).collect();
    let (status, snug) = run(&[(a, t.clone()), (backwards, t)]);
    for (s, snug) in status.iter().zip(&snug) {
        assert!(s.starts_with("loosening: torque falls (peak |torque| -2.5"), "{s}");
        assert!(s.contains("detection applies to tightening curves"), "{s}");
        assert_eq!(*snug, None);
    }
}

#[test]
fn a_falling_positive_curve_is_not_flat() {
    // Peak at the start, then the torque falls: it varies, so it is no flat signal, and it never
    // rises above its rundown, so there is no elastic zone.
    let a = angle();
    let t: Vec<f64> = a.iter().enumerate().map(|(i, &x)| 2.0 - 0.015 * x + ripple(i)).collect();
    let (status, _) = run(&[(a, t)]);
    assert!(status[0].starts_with("no_elastic_zone"), "{}", status[0]);
}

#[test]
fn tightenings_with_a_small_negative_offset_are_still_analysed() {
    let (status, snug) = run(&[tightening(0.0), tightening(-0.3)]);
    for (s, snug) in status.iter().zip(&snug) {
        assert_eq!(s, "ok");
        let snug = snug.unwrap();
        assert!((snug - 20.0).abs() < 1.0, "snug {snug}");
    }
}

#[test]
fn no_ok_result_has_its_snug_angle_off_the_curve() {
    // A joint already under load when the recording starts: rundown at 0 Nm for 10 deg, then
    // the torque jumps to 5 Nm and rises along a line that, extended back, meets 0 Nm at -40 deg.
    let a = angle();
    let t: Vec<f64> = a.iter().enumerate().map(|(i, &x)| if x < 10.0 { ripple(i) } else { 5.0 + 0.1 * (x - 10.0) + ripple(i) }).collect();
    let curves = vec![(a.clone(), t), tightening(0.0), loosening()];
    let (status, snug) = run(&curves);
    assert!(status[0].starts_with("no_elastic_zone") && status[0].contains("snug angle off the curve"), "{}", status[0]);
    for ((s, snug), (a, _)) in status.iter().zip(&snug).zip(&curves) {
        if s == "ok" {
            let snug = snug.unwrap();
            assert!(a[0] <= snug && snug <= a[N - 1], "{s}: snug {snug}");
        }
    }
}
