//! Zero-copy views of the tightening table, and nesting of the long layout.
//!
//! A channel stays in the buffers Arrow (and so Python) handed over: a tightening is a pair of
//! offsets into the channel's value buffer, read as `f32` or `f64` where it lies.

use std::sync::Arc;

use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Float64Type, Int32Type, Int64Type};
use arrow_array::{
    Array, ArrayRef, GenericListArray, LargeListArray, OffsetSizeTrait, RecordBatch, UInt32Array,
};
use arrow_buffer::{NullBuffer, OffsetBuffer, ScalarBuffer};
use arrow_schema::{DataType, Field, Schema};
use arrow_select::take::take;

use crate::error::{Result, TightscanError};
use crate::engine::schema::{self, Layout, CHANNELS, TIGHTENING_ID};
pub use crate::sample::Sample;

/// Samples of one channel of one tightening, borrowed from the Arrow buffer.
#[derive(Clone, Copy, Debug)]
pub enum Samples<'a> {
    /// float32 channel.
    F32(&'a [f32]),
    /// float64 channel.
    F64(&'a [f64]),
}

impl Samples<'_> {
    /// Number of samples.
    pub fn len(&self) -> usize {
        match self {
            Self::F32(s) => s.len(),
            Self::F64(s) => s.len(),
        }
    }
    /// True when there are no samples.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Count of NaN and infinite samples.
    pub fn non_finite_count(&self) -> usize {
        match self {
            Self::F32(s) => s.iter().filter(|v| !v.is_finite()).count(),
            Self::F64(s) => s.iter().filter(|v| !v.is_finite()).count(),
        }
    }
}

#[derive(Clone, Copy, Debug)]
enum Offsets<'a> {
    I32(&'a [i32]),
    I64(&'a [i64]),
}

#[derive(Clone, Copy, Debug)]
enum Values<'a> {
    F32(&'a [f32]),
    F64(&'a [f64]),
}

/// One channel column of a nested batch.
#[derive(Clone, Debug)]
pub struct ChannelColumn<'a> {
    /// Channel name.
    pub name: &'static str,
    offsets: Offsets<'a>,
    list_nulls: Option<&'a NullBuffer>,
    values: Values<'a>,
    value_nulls: Option<&'a NullBuffer>,
}

/// One tightening's view of a channel.
#[derive(Clone, Copy, Debug)]
pub enum ChannelRow<'a> {
    /// The list entry is null.
    Null,
    /// The samples, and how many of them are null.
    Present {
        /// The samples (null ones hold arbitrary values).
        samples: Samples<'a>,
        /// Null samples among them.
        null_count: usize,
    },
}

impl<'a> ChannelColumn<'a> {
    fn from_array(name: &'static str, array: &'a dyn Array) -> Result<Self> {
        match array.data_type() {
            DataType::List(_) => Self::from_list(name, array.as_list::<i32>(), Offsets::I32),
            DataType::LargeList(_) => Self::from_list(name, array.as_list::<i64>(), Offsets::I64),
            other => Err(TightscanError::schema(name, format!("expected a list column, got {other}"))),
        }
    }

    fn from_list<O: OffsetSizeTrait>(
        name: &'static str,
        list: &'a GenericListArray<O>,
        wrap: impl Fn(&'a [O]) -> Offsets<'a>,
    ) -> Result<Self> {
        let child = list.values();
        let values = match child.data_type() {
            DataType::Float32 => Values::F32(child.as_primitive::<Float32Type>().values()),
            DataType::Float64 => Values::F64(child.as_primitive::<Float64Type>().values()),
            other => {
                return Err(TightscanError::schema(
                    name,
                    format!("expected float32 or float64 samples, got {other}"),
                ))
            }
        };
        let value_nulls = child.nulls().filter(|n| n.null_count() > 0);
        Ok(Self {
            name,
            offsets: wrap(list.value_offsets()),
            list_nulls: list.nulls().filter(|n| n.null_count() > 0),
            values,
            value_nulls,
        })
    }

    /// The samples of row `i`.
    pub fn row(&self, i: usize) -> ChannelRow<'a> {
        if self.list_nulls.is_some_and(|n| n.is_null(i)) {
            return ChannelRow::Null;
        }
        let (start, end) = match self.offsets {
            Offsets::I32(o) => (o[i] as usize, o[i + 1] as usize),
            Offsets::I64(o) => (o[i] as usize, o[i + 1] as usize),
        };
        let samples = match self.values {
            Values::F32(v) => Samples::F32(&v[start..end]),
            Values::F64(v) => Samples::F64(&v[start..end]),
        };
        let null_count = match self.value_nulls {
            Some(n) if end > start => n.slice(start, end - start).null_count(),
            _ => 0,
        };
        ChannelRow::Present { samples, null_count }
    }
}

/// The controller-step channel of a nested batch (list of int32 or int64).
#[derive(Clone, Debug)]
pub struct StepColumn<'a> {
    offsets: Offsets<'a>,
    list_nulls: Option<&'a NullBuffer>,
    values: StepValues<'a>,
}

#[derive(Clone, Copy, Debug)]
enum StepValues<'a> {
    I32(&'a [i32]),
    I64(&'a [i64]),
}

impl<'a> StepColumn<'a> {
    fn from_array(array: &'a dyn Array) -> Result<Self> {
        let (offsets, list_nulls, child) = match array.data_type() {
            DataType::List(_) => {
                let l = array.as_list::<i32>();
                (Offsets::I32(l.value_offsets()), l.nulls(), l.values())
            }
            DataType::LargeList(_) => {
                let l = array.as_list::<i64>();
                (Offsets::I64(l.value_offsets()), l.nulls(), l.values())
            }
            other => return Err(TightscanError::schema(schema::STEP, format!("expected a list column, got {other}"))),
        };
        let values = match child.data_type() {
            DataType::Int32 => StepValues::I32(child.as_primitive::<Int32Type>().values()),
            DataType::Int64 => StepValues::I64(child.as_primitive::<Int64Type>().values()),
            other => {
                return Err(TightscanError::schema(schema::STEP, format!("expected int32 or int64 step numbers, got {other}")))
            }
        };
        Ok(Self { offsets, list_nulls: list_nulls.filter(|n| n.null_count() > 0), values })
    }

    /// Length of row `i`'s step list, and the samples where the step number changes (the first
    /// sample of every step but the first) into `changes`. `None` for a null row.
    pub fn step_changes(&self, i: usize, changes: &mut Vec<usize>) -> Option<usize> {
        changes.clear();
        if self.list_nulls.is_some_and(|n| n.is_null(i)) {
            return None;
        }
        let (start, end) = match self.offsets {
            Offsets::I32(o) => (o[i] as usize, o[i + 1] as usize),
            Offsets::I64(o) => (o[i] as usize, o[i + 1] as usize),
        };
        fn collect<T: PartialEq>(v: &[T], out: &mut Vec<usize>) {
            out.extend((1..v.len()).filter(|&k| v[k] != v[k - 1]));
        }
        match self.values {
            StepValues::I32(v) => collect(&v[start..end], changes),
            StepValues::I64(v) => collect(&v[start..end], changes),
        }
        Some(end - start)
    }
}

/// Zero-copy view of a nested tightening batch.
#[derive(Debug)]
pub struct TighteningTable<'a> {
    /// Number of tightenings (rows).
    pub n_rows: usize,
    /// Required channels, `angle` first.
    pub angle: ChannelColumn<'a>,
    /// `torque`.
    pub torque: ChannelColumn<'a>,
    /// Optional channels present in the table.
    pub optional: Vec<ChannelColumn<'a>>,
    /// `thread` designations, when the table has them.
    pub thread: Option<&'a dyn Array>,
    /// Numeric metadata columns present, by name (see [`schema::NUMERIC_METADATA`]).
    pub numeric: Vec<(&'static str, &'a dyn Array)>,
    /// Controller steps, when the table has them ([`schema::STEP`]).
    pub step: Option<StepColumn<'a>>,
}

/// Columns carried from the first sample of each tightening when the long layout is nested:
/// the per-tightening metadata the analysis reads.
fn metadata_columns() -> impl Iterator<Item = &'static str> {
    std::iter::once(schema::THREAD).chain(schema::NUMERIC_METADATA.iter().map(|(n, _)| *n))
}

impl<'a> TighteningTable<'a> {
    /// Views a nested-layout batch (see [`schema::detect_layout`]).
    pub fn new(batch: &'a RecordBatch) -> Result<Self> {
        let column = |name: &'static str| -> Result<Option<ChannelColumn<'a>>> {
            match batch.column_by_name(name) {
                Some(a) => ChannelColumn::from_array(name, a.as_ref()).map(Some),
                None => Ok(None),
            }
        };
        let required = |name: &'static str| -> Result<ChannelColumn<'a>> {
            column(name)?.ok_or_else(|| TightscanError::schema(name, "required column is missing"))
        };
        let angle = required(schema::ANGLE)?;
        let torque = required(schema::TORQUE)?;
        let mut optional = Vec::new();
        for spec in CHANNELS.iter().filter(|s| !s.required) {
            if let Some(c) = column(spec.name)? {
                optional.push(c);
            }
        }
        let thread = batch.column_by_name(schema::THREAD).map(|a| a.as_ref());
        let numeric = schema::NUMERIC_METADATA
            .iter()
            .filter_map(|(name, _)| batch.column_by_name(name).map(|a| (*name, a.as_ref())))
            .collect();
        let step = batch.column_by_name(schema::STEP).map(|a| StepColumn::from_array(a.as_ref())).transpose()?;
        Ok(Self { n_rows: batch.num_rows(), angle, torque, optional, thread, numeric, step })
    }

    /// The optional channel `name`, if the table has it.
    pub fn channel(&self, name: &str) -> Option<&ChannelColumn<'a>> {
        self.optional.iter().find(|c| c.name == name)
    }

    /// Thread designation of row `i` (None when absent or null).
    pub fn thread_of(&self, i: usize) -> Option<&'a str> {
        let a = self.thread?;
        if a.is_null(i) {
            return None;
        }
        match a.data_type() {
            DataType::Utf8 => Some(a.as_string::<i32>().value(i)),
            DataType::LargeUtf8 => Some(a.as_string::<i64>().value(i)),
            DataType::Utf8View => Some(a.as_string_view().value(i)),
            _ => None,
        }
    }

    /// Numeric metadata `name` of row `i` as f64 (None when absent, null or not finite).
    pub fn number_of(&self, name: &str, i: usize) -> Option<f64> {
        use arrow_array::types::*;
        let (_, a) = self.numeric.iter().find(|(n, _)| *n == name)?;
        if a.is_null(i) {
            return None;
        }
        let v = match a.data_type() {
            DataType::Float64 => a.as_primitive::<Float64Type>().value(i),
            DataType::Float32 => a.as_primitive::<Float32Type>().value(i) as f64,
            DataType::Float16 => a.as_primitive::<Float16Type>().value(i).to_f64(),
            DataType::Int8 => a.as_primitive::<Int8Type>().value(i) as f64,
            DataType::Int16 => a.as_primitive::<Int16Type>().value(i) as f64,
            DataType::Int32 => a.as_primitive::<Int32Type>().value(i) as f64,
            DataType::Int64 => a.as_primitive::<Int64Type>().value(i) as f64,
            DataType::UInt8 => a.as_primitive::<UInt8Type>().value(i) as f64,
            DataType::UInt16 => a.as_primitive::<UInt16Type>().value(i) as f64,
            DataType::UInt32 => a.as_primitive::<UInt32Type>().value(i) as f64,
            DataType::UInt64 => a.as_primitive::<UInt64Type>().value(i) as f64,
            _ => return None,
        };
        v.is_finite().then_some(v)
    }
}

/// Key of a tightening id, for finding where long-layout tightenings start and which ids repeat.
#[derive(Clone, Copy, PartialEq, Eq, Hash, Debug)]
pub(crate) enum IdKey<'a> {
    Null,
    Int(i128),
    Str(&'a str),
}

impl std::fmt::Display for IdKey<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Null => write!(f, "null"),
            Self::Int(v) => write!(f, "{v}"),
            Self::Str(s) => write!(f, "{s:?}"),
        }
    }
}

/// The id of every row as a key. Integer, string and dictionary-encoded ids of either.
pub(crate) fn id_keys(ids: &dyn Array) -> Result<Vec<IdKey<'_>>> {
    use arrow_array::types::*;
    macro_rules! ints {
        ($t:ty) => {{
            let a = ids.as_primitive::<$t>();
            (0..a.len())
                .map(|i| if a.is_null(i) { IdKey::Null } else { IdKey::Int(a.value(i) as i128) })
                .collect()
        }};
    }
    let keys = match ids.data_type() {
        DataType::Int8 => ints!(Int8Type),
        DataType::Int16 => ints!(Int16Type),
        DataType::Int32 => ints!(Int32Type),
        DataType::Int64 => ints!(Int64Type),
        DataType::UInt8 => ints!(UInt8Type),
        DataType::UInt16 => ints!(UInt16Type),
        DataType::UInt32 => ints!(UInt32Type),
        DataType::UInt64 => ints!(UInt64Type),
        DataType::Utf8 => ids.as_string::<i32>().iter().map(|s| s.map_or(IdKey::Null, IdKey::Str)).collect(),
        DataType::LargeUtf8 => ids.as_string::<i64>().iter().map(|s| s.map_or(IdKey::Null, IdKey::Str)).collect(),
        DataType::Utf8View => ids.as_string_view().iter().map(|s| s.map_or(IdKey::Null, IdKey::Str)).collect(),
        DataType::Dictionary(_, _) => {
            let dict = ids.as_any_dictionary();
            let values = id_keys(dict.values().as_ref())?;
            if values.is_empty() {
                // No values (an empty or all-null column): `normalized_keys` would panic.
                return Ok(vec![IdKey::Null; ids.len()]);
            }
            let nulls = ids.logical_nulls();
            dict.normalized_keys()
                .into_iter()
                .enumerate()
                .map(|(i, k)| match values.get(k) {
                    Some(v) if !nulls.as_ref().is_some_and(|n| n.is_null(i)) => *v,
                    _ => IdKey::Null,
                })
                .collect()
        }
        other => {
            return Err(TightscanError::schema(
                TIGHTENING_ID,
                format!("expected a string or integer column, got {other}"),
            ))
        }
    };
    Ok(keys)
}

/// A scalar float channel of the long layout, read as f64.
fn float_at(array: &dyn Array) -> Option<impl Fn(usize) -> f64 + '_> {
    let (f32s, f64s) = match array.data_type() {
        DataType::Float32 => (Some(array.as_primitive::<Float32Type>()), None),
        DataType::Float64 => (None, Some(array.as_primitive::<Float64Type>())),
        _ => return None,
    };
    Some(move |i: usize| {
        if array.is_null(i) {
            return f64::NAN;
        }
        match (f32s, f64s) {
            (Some(a), _) => a.value(i) as f64,
            (_, Some(a)) => a.value(i),
            _ => f64::NAN,
        }
    })
}

/// Where a second curve starts inside the samples `[start, end)` of one id: the clock (`time`,
/// else `angle`) falls back, in one sample, by more than half its span over the run to within
/// 5 % of the span of the run's first value. A tightening's own clock never does that: time
/// only grows, and the angle's backlash or a loosening's fall are a small or gradual part of
/// its span; a second recording under the same id starts over from the beginning.
fn restarts(clock: &dyn Fn(usize) -> f64, start: usize, end: usize, out: &mut Vec<usize>) {
    if end - start < 2 {
        return;
    }
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for i in start..end {
        let v = clock(i);
        if v.is_finite() {
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    let span = hi - lo;
    let first = clock(start);
    if !(span > 0.0 && span.is_finite() && first.is_finite()) {
        return;
    }
    for i in start + 1..end {
        let (before, now) = (clock(i - 1), clock(i));
        if before - now > 0.5 * span && now - first <= 0.05 * span {
            out.push(i);
        }
    }
}

/// Turns a long-layout batch (one row per sample) into the nested layout (one row per
/// tightening), in input order, without copying a sample: the new lists point into the
/// original value buffers.
///
/// A tightening is a run of consecutive samples with the same id, so its samples must be
/// contiguous. An id that comes back after other ids is a second tightening under that id, and
/// so is a run whose clock starts over (see [`restarts`]): each becomes its own row, and
/// [`super::duplicates`] reports the repeated id in every row that carries it. Nothing is
/// merged. Samples with a null id form a tightening with a null id (its status says so).
/// `passthrough` columns take the value of each tightening's first sample.
pub fn nest_long(batch: &RecordBatch, passthrough: &[String]) -> Result<RecordBatch> {
    let ids = batch
        .column_by_name(TIGHTENING_ID)
        .ok_or_else(|| TightscanError::schema(TIGHTENING_ID, "required column is missing"))?;
    let keys = id_keys(ids.as_ref())?;
    let n = keys.len();
    let clock = [schema::TIME, schema::ANGLE]
        .iter()
        .find_map(|name| batch.column_by_name(name).and_then(|c| float_at(c.as_ref())));

    let mut starts: Vec<usize> = Vec::new();
    let mut run_start = 0;
    for i in 1..=n {
        if i == n || keys[i] != keys[run_start] {
            starts.push(run_start);
            if let (Some(clock), false) = (&clock, keys[run_start] == IdKey::Null) {
                restarts(clock, run_start, i, &mut starts);
            }
            run_start = i;
        }
    }
    let mut offsets: Vec<i64> = starts.iter().map(|&s| s as i64).collect();
    offsets.push(n as i64);
    let first_rows = UInt32Array::from(starts.iter().map(|&s| s as u32).collect::<Vec<_>>());
    let offsets = OffsetBuffer::new(ScalarBuffer::from(offsets));

    let mut fields: Vec<Field> = Vec::new();
    let mut columns: Vec<ArrayRef> = Vec::new();
    fields.push(batch.schema().field_with_name(TIGHTENING_ID)?.clone());
    columns.push(take(ids.as_ref(), &first_rows, None)?);
    for name in CHANNELS.iter().map(|c| c.name).chain([schema::STEP]) {
        let Some(values) = batch.column_by_name(name) else { continue };
        let item = Arc::new(Field::new_list_field(values.data_type().clone(), true));
        let list = LargeListArray::try_new(item.clone(), offsets.clone(), values.clone(), None)?;
        fields.push(Field::new(name, DataType::LargeList(item), true));
        columns.push(Arc::new(list));
    }
    let carried = metadata_columns().filter(|m| !passthrough.iter().any(|p| p == m)).map(str::to_string);
    for name in passthrough.iter().cloned().chain(carried) {
        let Some(col) = batch.column_by_name(&name) else {
            if passthrough.contains(&name) {
                return Err(TightscanError::schema(name.as_str(), "pass-through column is missing"));
            }
            continue;
        };
        fields.push(batch.schema().field_with_name(&name)?.clone());
        columns.push(take(col.as_ref(), &first_rows, None)?);
    }
    Ok(RecordBatch::try_new(Arc::new(Schema::new(fields)), columns)?)
}

/// Nested view of any contract batch: the batch itself, or its long layout nested.
pub fn to_nested(batch: &RecordBatch, passthrough: &[String]) -> Result<RecordBatch> {
    match schema::detect_layout(batch.schema().as_ref())? {
        Layout::Nested => Ok(batch.clone()),
        Layout::Long => nest_long(batch, passthrough),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use arrow_array::{Float32Array, Float64Array, Int64Array, StringArray};

    fn long_batch(ids: Vec<&str>, angle: Vec<f64>) -> RecordBatch {
        let torque: Vec<f32> = angle.iter().map(|a| (*a as f32) * 2.0).collect();
        let schema = Schema::new(vec![
            Field::new(TIGHTENING_ID, DataType::Utf8, true),
            Field::new("angle", DataType::Float64, true),
            Field::new("torque", DataType::Float32, true),
            Field::new("station", DataType::Int64, true),
        ]);
        let n = ids.len() as i64;
        RecordBatch::try_new(
            Arc::new(schema),
            vec![
                Arc::new(StringArray::from(ids)),
                Arc::new(Float64Array::from(angle)),
                Arc::new(Float32Array::from(torque)),
                Arc::new(Int64Array::from((0..n).collect::<Vec<_>>())),
            ],
        )
        .unwrap_or_else(|e| panic!("{e}"))
    }

    fn angles(nested: &RecordBatch, row: usize) -> Vec<f64> {
        let t = TighteningTable::new(nested).unwrap_or_else(|e| panic!("{e}"));
        match t.angle.row(row) {
            ChannelRow::Present { samples: Samples::F64(s), .. } => s.to_vec(),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn grouped_long_layout_nests_in_place() {
        let b = long_batch(vec!["a", "a", "b", "b", "b"], vec![1.0, 2.0, 3.0, 4.0, 5.0]);
        let nested = nest_long(&b, &["station".to_string()]).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(nested.num_rows(), 2);
        assert_eq!(angles(&nested, 0), vec![1.0, 2.0]);
        assert_eq!(angles(&nested, 1), vec![3.0, 4.0, 5.0]);
        let station = nested.column_by_name("station").map(|c| c.as_primitive::<arrow_array::types::Int64Type>().values().to_vec());
        assert_eq!(station, Some(vec![0, 2]));
    }

    #[test]
    fn a_reappearing_id_is_a_second_tightening_not_merged() {
        let b = long_batch(vec!["b", "a", "b", "a", "c"], vec![1.0, 2.0, 3.0, 4.0, 5.0]);
        let nested = nest_long(&b, &[]).unwrap_or_else(|e| panic!("{e}"));
        let ids: Vec<Option<&str>> = nested.column(0).as_string::<i32>().iter().collect();
        assert_eq!(ids, vec![Some("b"), Some("a"), Some("b"), Some("a"), Some("c")]);
        assert_eq!(angles(&nested, 0), vec![1.0]);
        assert_eq!(angles(&nested, 2), vec![3.0]);
    }

    #[test]
    fn a_curve_that_starts_over_under_its_id_is_split() {
        // Two recordings under "a": the angle climbs to 40, then starts again from 0.
        let first: Vec<f64> = (0..=40).map(f64::from).collect();
        let second: Vec<f64> = (0..=30).map(f64::from).collect();
        let angle: Vec<f64> = first.iter().chain(&second).copied().chain([7.0, 8.0]).collect();
        let mut ids = vec!["a"; first.len() + second.len()];
        ids.extend(["z", "z"]);
        let nested = nest_long(&long_batch(ids, angle), &[]).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(nested.num_rows(), 3);
        assert_eq!(angles(&nested, 0), first);
        assert_eq!(angles(&nested, 1), second);
        assert_eq!(angles(&nested, 2), vec![7.0, 8.0]);
    }

    #[test]
    fn backlash_and_a_falling_angle_are_not_restarts() {
        // 1 deg of backlash at the start of a 60 deg curve, then a loosening-like fall.
        let mut angle: Vec<f64> = vec![0.0, 0.5, 1.0, 0.0];
        angle.extend((1..=60).map(f64::from));
        angle.extend((0..60).rev().map(f64::from));
        let nested = nest_long(&long_batch(vec!["a"; angle.len()], angle.clone()), &[]).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(nested.num_rows(), 1);
        assert_eq!(angles(&nested, 0), angle);
    }

    #[test]
    fn dictionary_ids_key_by_value() {
        use arrow_array::types::Int8Type;
        use arrow_array::DictionaryArray;
        let ids: DictionaryArray<Int8Type> = vec![Some("x"), Some("x"), None, Some("y"), Some("x")].into_iter().collect();
        let keys = id_keys(&ids).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(keys, vec![IdKey::Str("x"), IdKey::Str("x"), IdKey::Null, IdKey::Str("y"), IdKey::Str("x")]);
        // Found by tests/test_properties.py: a dictionary without values (all ids null).
        let empty: DictionaryArray<Int8Type> = vec![None::<&str>, None].into_iter().collect();
        assert_eq!(id_keys(&empty).unwrap_or_else(|e| panic!("{e}")), vec![IdKey::Null, IdKey::Null]);
    }
}
