//! [`Detector::traces`] is the batch analysis of one tightening: its result row is `detect`'s,
//! and its traces cross their limits exactly where the row says the detectors fired.

use super::*;
use arrow_array::cast::AsArray;
use arrow_array::types::Float64Type;
use arrow_array::ListArray;
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;

/// `n` tightenings of 400 samples over 100 deg: rundown at 0.1 Nm to 20 deg, then a torque rate
/// of 0.3 Nm/deg, white noise of sd 0.05; every third is clean, the others change their rate by
/// +-10 % to 40 % (both signs) at 40-80 % of the rise.
fn curves(n: usize, seed: u64) -> RecordBatch {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let uniform = |rng: &mut Xoshiro256PlusPlus| rng.random::<f64>();
    let (mut angles, mut torques) = (Vec::new(), Vec::new());
    for i in 0..n {
        let change = (i % 3 != 0).then(|| {
            let at = 20.0 + 80.0 * (0.4 + 0.4 * uniform(&mut rng));
            let m = (0.1 + 0.3 * uniform(&mut rng)) * if i % 3 == 1 { 1.0 } else { -1.0 };
            (at, m)
        });
        let a: Vec<f64> = (0..400).map(|k| 100.0 * k as f64 / 399.0).collect();
        let t: Vec<Option<f64>> = a
            .iter()
            .map(|&x| {
                let ideal = match change {
                    Some((at, m)) if x > at => 0.1 + 0.3 * (at - 20.0) + 0.3 * (1.0 + m) * (x - at),
                    _ if x < 20.0 => 0.1,
                    _ => 0.1 + 0.3 * (x - 20.0),
                };
                let e: f64 = StandardNormal.sample(&mut rng);
                Some(ideal + 0.05 * e)
            })
            .collect();
        angles.push(Some(a.into_iter().map(Some).collect::<Vec<_>>()));
        torques.push(Some(t));
    }
    let a: ArrayRef = Arc::new(ListArray::from_iter_primitive::<Float64Type, _, _>(angles));
    let t: ArrayRef = Arc::new(ListArray::from_iter_primitive::<Float64Type, _, _>(torques));
    let schema = Schema::new(vec![Field::new("angle", a.data_type().clone(), true), Field::new("torque", t.data_type().clone(), true)]);
    RecordBatch::try_new(Arc::new(schema), vec![a, t]).unwrap_or_else(|e| panic!("{e}"))
}

fn float(row: &RecordBatch, name: &str) -> Option<f64> {
    let c = row.column_by_name(name).unwrap_or_else(|| panic!("no column {name}"));
    let c = c.as_primitive::<Float64Type>();
    c.is_valid(0).then(|| c.value(0))
}

fn flag(row: &RecordBatch, name: &str) -> Option<bool> {
    let c = row.column_by_name(name).unwrap_or_else(|| panic!("no column {name}"));
    let c = c.as_boolean();
    c.is_valid(0).then(|| c.value(0))
}

#[test]
fn traces_give_the_batch_row_and_cross_where_the_detectors_fired() {
    let mut config = DetectConfig::default();
    config.residual_tests.kde = true;
    config.residual_tests.kde_permutations = 199;
    let detector = Detector::new(config).unwrap_or_else(|e| panic!("{e}"));
    let batch = curves(30, 5);
    let batch_rows = detector.detect(&batch, &[], 0).unwrap_or_else(|e| panic!("{e}"));
    let (mut cusum_alarms, mut break_alarms, mut traced) = (0, 0, 0);
    for i in 0..batch.num_rows() {
        let (row, traces) = detector.traces(&batch.schema(), &[batch.slice(i, 1)], i).unwrap_or_else(|e| panic!("{e}"));
        let expected = batch_rows.slice(i, 1);
        for (name, (a, b)) in row.schema().fields().iter().map(|f| f.name()).zip(row.columns().iter().zip(expected.columns())) {
            assert_eq!(a.to_data(), b.to_data(), "row {i}, column {name}");
        }
        if let Some(c) = &traces.cusum {
            traced += 1;
            let top = c.upper.iter().chain(&c.lower).copied().fold(0.0, f64::max);
            let fired = flag(&row, "cusum_alarm").unwrap_or(false);
            assert_eq!(top > c.threshold, fired, "row {i}: CUSUM");
            assert_eq!(Some(top), float(&row, "cusum_max_statistic"), "row {i}");
            if fired {
                let first = c.upper.iter().zip(&c.lower).position(|(u, l)| u.max(*l) > c.threshold).unwrap_or(usize::MAX);
                assert_eq!(Some(c.angle[first]), float(&row, "cusum_alarm_angle"), "row {i}");
                cusum_alarms += 1;
            }
        }
        if let Some(l) = &traces.l1 {
            let first = l.statistic.iter().zip(&l.boundary).position(|(q, g)| q >= g);
            assert_eq!(first.map(|j| l.angle[j]), float(&row, "l1_alarm_angle"), "row {i}: L1");
        }
        if let Some(b) = &traces.breaks {
            let top = b.lr.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            assert!((top - float(&row, "break_statistic").unwrap_or(f64::NAN)).abs() <= 1e-12 * top.abs(), "row {i}");
            assert_eq!(b.scan_alarm || b.tail_alarm || b.head_alarm || b.episode_alarm, flag(&row, "break_alarm").unwrap_or(false), "row {i}: break");
            if b.scan_alarm {
                let argmax = b.lr.iter().enumerate().fold(0, |best, (k, &v)| if v > b.lr[best] { k } else { best });
                assert_eq!(Some(b.angle[argmax]), float(&row, "break_change_angle"), "row {i}");
                break_alarms += 1;
            }
        }
    }
    assert!(traced >= 25 && cusum_alarms > 0 && cusum_alarms < traced && break_alarms > 5 && break_alarms < traced, "{traced} traced, {cusum_alarms} CUSUM and {break_alarms} break alarms");
}

#[test]
fn traces_are_of_one_tightening() {
    let detector = Detector::new(DetectConfig::default()).unwrap_or_else(|e| panic!("{e}"));
    let batch = curves(3, 1);
    assert!(detector.traces(&batch.schema(), std::slice::from_ref(&batch), 0).is_err());
    assert!(detector.traces(&batch.schema(), &[], 0).is_err());
}
