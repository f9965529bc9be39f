//! Fuzzes the engine's entry point, `Detector::detect_all`, with Arrow batches built from the
//! fuzzer's bytes: nested or long layout, list or large_list, float32 or float64 channels,
//! optional `time`/`speed`/`step`, integer, string or no ids (few distinct values, so
//! duplicates are common), null lists, null samples, NaN/inf, mismatched lengths, and
//! tightening-like curves (rundown, elastic rise, a friction change, noise) so that the fuzzer
//! reaches the detectors and not only the input checks.
//!
//! It must never panic. Besides, it checks what the contract promises: a table error is a
//! `Result::Err`; one result row per nested row; every status has a documented code; slicing
//! the table into batches changes nothing.
#![no_main]

use std::sync::Arc;

use arbitrary::Arbitrary;
use arrow_array::types::{Float32Type, Float64Type, Int32Type};
use arrow_array::{Array, ArrayRef, DictionaryArray, Float32Array, Float64Array, Int32Array, Int64Array, LargeListArray, ListArray, RecordBatch, StringArray};
use arrow_schema::{DataType, Field, Schema};
use libfuzzer_sys::fuzz_target;
use tightscan_core::{DetectConfig, Detector};

/// One sample value: mostly finite and small, sometimes anything.
#[derive(Arbitrary, Debug, Clone, Copy)]
enum Value {
    Small(i16),
    Any(f64),
    Null,
}

impl Value {
    fn get(self) -> Option<f64> {
        match self {
            Self::Small(v) => Some(v as f64 / 16.0),
            Self::Any(v) => Some(v),
            Self::Null => None,
        }
    }
}

#[derive(Arbitrary, Debug)]
enum Shape {
    /// Samples straight from the bytes.
    Raw { angle: Vec<Value>, torque: Vec<Value> },
    /// A tightening-like curve.
    Curve {
        samples: u16,
        final_angle: u16,
        prevailing: u8,
        snug_at: u8,
        rate: u16,
        change_at: u8,
        change_pct: i8,
        noise: Vec<i8>,
        noise_scale: u8,
        yield_at: Option<u8>,
    },
}

#[derive(Arbitrary, Debug)]
enum Edit {
    Set { channel: u8, at: u16, value: Value },
    Truncate { channel: u8, len: u16 },
    /// Holds a channel constant over a run (a stop or a stuck sensor).
    Hold { channel: u8, at: u16, len: u16 },
    /// Reverses the channel (a decreasing angle or a loosening curve).
    Reverse { channel: u8 },
    /// Restarts the curve: appends its start again (a second curve under the same id).
    Restart { len: u16 },
}

#[derive(Arbitrary, Debug)]
struct Tightening {
    id: Option<u8>,
    shape: Shape,
    edits: Vec<Edit>,
    null_angle: bool,
    null_torque: bool,
    step_changes: Vec<u16>,
}

#[derive(Arbitrary, Debug)]
enum Ids {
    None,
    Int,
    Str,
    /// Dictionary-encoded strings (pandas categoricals).
    Dict,
}

#[derive(Arbitrary, Debug)]
struct Input {
    long: bool,
    large_list: bool,
    angle_f32: bool,
    torque_f32: bool,
    time: bool,
    speed: bool,
    step: bool,
    ids: Ids,
    slices: u8,
    kde: bool,
    tightenings: Vec<Tightening>,
}

const CHANNELS: [&str; 4] = ["angle", "torque", "time", "speed"];
const MAX_SAMPLES: usize = 3000;
const STATUS_CODES: &[&str] = &[
    "ok",
    "null_tightening",
    "empty",
    "length_mismatch",
    "null_values",
    "non_finite",
    "too_short",
    "flat_signal",
    "no_elastic_zone",
    "model_misfit",
    "unknown_thread",
    "duplicate_id",
    "loosening",
];

/// The four channels of one tightening (angle, torque, time, speed), `None` for a null list.
type Curves = [Option<Vec<Option<f64>>>; 4];

fn synthesize(t: &Tightening) -> Curves {
    let (angle, torque): (Vec<Option<f64>>, Vec<Option<f64>>) = match &t.shape {
        Shape::Raw { angle, torque } => (
            angle.iter().take(MAX_SAMPLES).map(|v| v.get()).collect(),
            torque.iter().take(MAX_SAMPLES).map(|v| v.get()).collect(),
        ),
        Shape::Curve { samples, final_angle, prevailing, snug_at, rate, change_at, change_pct, noise, noise_scale, yield_at } => {
            let n = (*samples as usize) % MAX_SAMPLES;
            let end = 1.0 + *final_angle as f64 / 50.0;
            let snug = end * (*snug_at as f64 / 255.0);
            let change = snug + (end - snug) * (*change_at as f64 / 255.0);
            let yield_angle = yield_at.map(|y| snug + (end - snug) * (y as f64 / 255.0));
            let rate = *rate as f64 / 1000.0;
            let scale = *noise_scale as f64 / 2000.0;
            let mut angle = Vec::with_capacity(n);
            let mut torque = Vec::with_capacity(n);
            for k in 0..n {
                let a = end * k as f64 / n.max(1) as f64;
                let mut tq = *prevailing as f64 / 50.0;
                if a > snug {
                    let mut gradient_span = a - snug;
                    if a > change {
                        gradient_span += (a - change) * (*change_pct as f64 / 100.0);
                    }
                    if let Some(y) = yield_angle.filter(|&y| a > y) {
                        gradient_span -= (a - y) * 0.85;
                    }
                    tq += rate * gradient_span;
                }
                if !noise.is_empty() {
                    tq += noise[k % noise.len()] as f64 * scale;
                }
                angle.push(Some(a));
                torque.push(Some(tq));
            }
            (angle, torque)
        }
    };
    let n = angle.len();
    let time = (0..n).map(|k| Some(k as f64 * 0.001)).collect();
    let speed = (0..n).map(|_| Some(30.0)).collect();
    let mut curves: [Vec<Option<f64>>; 4] = [angle, torque, time, speed];
    for edit in t.edits.iter().take(8) {
        match *edit {
            Edit::Set { channel, at, value } => {
                let c = &mut curves[channel as usize % 4];
                if !c.is_empty() {
                    let i = at as usize % c.len();
                    c[i] = value.get();
                }
            }
            Edit::Truncate { channel, len } => {
                let c = &mut curves[channel as usize % 4];
                c.truncate(len as usize);
            }
            Edit::Hold { channel, at, len } => {
                let c = &mut curves[channel as usize % 4];
                if !c.is_empty() {
                    let start = at as usize % c.len();
                    let held = c[start];
                    for v in c.iter_mut().skip(start).take(len as usize) {
                        *v = held;
                    }
                }
            }
            Edit::Reverse { channel } => curves[channel as usize % 4].reverse(),
            Edit::Restart { len } => {
                for c in curves.iter_mut() {
                    let head: Vec<Option<f64>> = c.iter().take(len as usize).copied().collect();
                    c.extend(head);
                }
            }
        }
    }
    // Restarts double a curve: cap the volume, which finds nothing but slow units.
    for c in curves.iter_mut() {
        c.truncate(4 * MAX_SAMPLES);
    }
    let [angle, torque, time, speed] = curves;
    [(!t.null_angle).then_some(angle), (!t.null_torque).then_some(torque), Some(time), Some(speed)]
}

fn float_array(values: Vec<Option<f64>>, f32: bool) -> ArrayRef {
    if f32 {
        Arc::new(values.into_iter().map(|v| v.map(|x| x as f32)).collect::<Float32Array>())
    } else {
        Arc::new(values.into_iter().collect::<Float64Array>())
    }
}

fn list_array(rows: Vec<Option<Vec<Option<f64>>>>, f32: bool, large: bool) -> ArrayRef {
    match (f32, large) {
        (false, false) => Arc::new(ListArray::from_iter_primitive::<Float64Type, _, _>(rows)),
        (false, true) => Arc::new(LargeListArray::from_iter_primitive::<Float64Type, _, _>(rows)),
        (true, false) => Arc::new(ListArray::from_iter_primitive::<Float32Type, _, _>(f32_rows(rows))),
        (true, true) => Arc::new(LargeListArray::from_iter_primitive::<Float32Type, _, _>(f32_rows(rows))),
    }
}

fn f32_rows(rows: Vec<Option<Vec<Option<f64>>>>) -> Vec<Option<Vec<Option<f32>>>> {
    rows.into_iter().map(|r| r.map(|v| v.into_iter().map(|x| x.map(|x| x as f32)).collect())).collect()
}

fn id_array(ids: &Ids, values: Vec<Option<u8>>) -> Option<ArrayRef> {
    match ids {
        Ids::None => None,
        Ids::Int => Some(Arc::new(values.into_iter().map(|v| v.map(i64::from)).collect::<Int64Array>())),
        Ids::Str => Some(Arc::new(values.into_iter().map(|v| v.map(|v| format!("t{v}é"))).collect::<StringArray>())),
        Ids::Dict => {
            let text: Vec<Option<String>> = values.into_iter().map(|v| v.map(|v| format!("t{v}"))).collect();
            Some(Arc::new(text.iter().map(|t| t.as_deref()).collect::<DictionaryArray<Int32Type>>()))
        }
    }
}

fn step_rows(input: &Input, lengths: &[usize]) -> Vec<Option<Vec<Option<i32>>>> {
    input
        .tightenings
        .iter()
        .zip(lengths)
        .map(|(t, &n)| {
            let mut step = 1;
            Some((0..n).map(|k| {
                if t.step_changes.iter().any(|&c| c as usize == k) {
                    step += 1;
                }
                Some(step)
            }).collect())
        })
        .collect()
}

fn build(input: &Input) -> Option<RecordBatch> {
    let curves: Vec<Curves> = input.tightenings.iter().take(64).map(synthesize).collect();
    let mut fields = Vec::new();
    let mut columns: Vec<ArrayRef> = Vec::new();
    let wanted = [true, true, input.time, input.speed];
    let f32_of = [input.angle_f32, input.torque_f32, false, true];
    if input.long {
        // One row per sample: a tightening's length is its angle's; other channels are cut or
        // padded with nulls to it.
        let lengths: Vec<usize> = curves.iter().map(|c| c[0].as_ref().map_or(0, Vec::len)).collect();
        let ids: Vec<Option<u8>> = input.tightenings.iter().zip(&lengths).flat_map(|(t, &n)| std::iter::repeat_n(t.id, n)).collect();
        let ids = match id_array(&input.ids, ids) {
            Some(ids) => ids,
            None => Arc::new(Int64Array::from(vec![0i64; lengths.iter().sum()])),
        };
        fields.push(Field::new("tightening_id", ids.data_type().clone(), true));
        columns.push(ids);
        for (c, name) in CHANNELS.iter().enumerate() {
            if !wanted[c] {
                continue;
            }
            let values: Vec<Option<f64>> = curves
                .iter()
                .zip(&lengths)
                .flat_map(|(cv, &n)| (0..n).map(move |k| cv[c].as_ref().and_then(|v| v.get(k).copied().flatten())))
                .collect();
            let array = float_array(values, f32_of[c]);
            fields.push(Field::new(*name, array.data_type().clone(), true));
            columns.push(array);
        }
        if input.step {
            let steps: Vec<Option<i32>> = step_rows(input, &lengths).into_iter().flat_map(|r| r.unwrap_or_default()).collect();
            let array: ArrayRef = Arc::new(Int32Array::from(steps));
            fields.push(Field::new("step", DataType::Int32, true));
            columns.push(array);
        }
    } else {
        if let Some(ids) = id_array(&input.ids, input.tightenings.iter().take(curves.len()).map(|t| t.id).collect()) {
            fields.push(Field::new("tightening_id", ids.data_type().clone(), true));
            columns.push(ids);
        }
        for (c, name) in CHANNELS.iter().enumerate() {
            if !wanted[c] {
                continue;
            }
            let rows = curves.iter().map(|cv| cv[c].clone()).collect();
            let array = list_array(rows, f32_of[c], input.large_list);
            fields.push(Field::new(*name, array.data_type().clone(), true));
            columns.push(array);
        }
        if input.step {
            let lengths: Vec<usize> = curves.iter().map(|c| c[0].as_ref().map_or(0, Vec::len)).collect();
            let array: ArrayRef = Arc::new(ListArray::from_iter_primitive::<Int32Type, _, _>(step_rows(input, &lengths)));
            fields.push(Field::new("step", array.data_type().clone(), true));
            columns.push(array);
        }
    }
    RecordBatch::try_new(Arc::new(Schema::new(fields)), columns).ok()
}

fn statuses(batches: &[RecordBatch]) -> Vec<String> {
    batches
        .iter()
        .flat_map(|b| {
            let col = b.column_by_name("status").cloned();
            let n = b.num_rows();
            (0..n).map(move |i| match &col {
                Some(c) => c.as_any().downcast_ref::<StringArray>().map_or(String::new(), |s| s.value(i).to_string()),
                None => String::new(),
            })
        })
        .collect()
}

fuzz_target!(|input: Input| {
    let Some(batch) = build(&input) else { return };
    let mut config = DetectConfig::default();
    if input.kde {
        config.residual_tests.kde = true;
        config.residual_tests.kde_permutations = 99;
    }
    let Ok(detector) = Detector::new(config) else { return };
    let schema = batch.schema();
    let whole = match detector.detect_all(&schema, std::slice::from_ref(&batch), &[], 0) {
        Ok(out) => out,
        // A table error is an answer (it becomes a SchemaError in Python), not a crash.
        Err(_) => return,
    };
    let rows: usize = whole.iter().map(RecordBatch::num_rows).sum();
    if !input.long {
        assert_eq!(rows, batch.num_rows(), "one result row per nested tightening");
    }
    let whole_status = statuses(&whole);
    for s in &whole_status {
        let code = s.split(':').next().unwrap_or_default();
        assert!(STATUS_CODES.contains(&code), "undocumented status {s:?}");
    }
    // The same table cut into slices gives the same rows.
    let parts = 1 + input.slices as usize % 4;
    if parts > 1 && batch.num_rows() > 1 {
        let step = batch.num_rows().div_ceil(parts);
        let slices: Vec<RecordBatch> = (0..batch.num_rows()).step_by(step).map(|s| batch.slice(s, step.min(batch.num_rows() - s))).collect();
        let sliced = detector.detect_all(&schema, &slices, &[], 0);
        match sliced {
            Ok(out) => assert_eq!(statuses(&out), whole_status, "slicing changed the results"),
            Err(e) => panic!("the whole table was accepted, its slices not: {e}"),
        }
    }
});
