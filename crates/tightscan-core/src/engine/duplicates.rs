//! Repeated tightening ids, reported in every row that carries one.
//!
//! Two result rows with the same `tightening_id` are two curves that cannot be told apart
//! downstream: a controller counter reset, two stations numbering alike, a file read twice. Each
//! row keeps the analysis of its own curve (nothing is merged or dropped: either curve may be
//! the one wanted, and both are worth looking at), but its status becomes
//! `duplicate_id: tightening_id <id> appears <n> times; as a curve: <its own status>`, so that
//! no repeated id passes as `ok`. Null ids are unknown, not equal: they are never flagged.
//!
//! The pass runs over all result rows of a table at once, since the repeat of an id may come
//! many batches after its first row. It is idempotent: a row flagged before is re-flagged with
//! the count over the rows it is given now.

use std::collections::HashMap;
use std::sync::Arc;

use arrow_array::cast::AsArray;
use arrow_array::{Array, ArrayRef, RecordBatch, StringArray};
use arrow_schema::DataType;

use crate::engine::input::{id_keys, IdKey};
use crate::engine::schema::TIGHTENING_ID;
use crate::engine::status::TighteningStatus;
use crate::error::Result;

const STATUS: &str = "status";
const CURVE_STATUS: &str = "; as a curve: ";

/// Rewrites the `status` of every row whose `tightening_id` appears in more than one row of
/// `results` (result batches of one table, in order). Batches without repeats come back as
/// they are (cheap clones).
pub fn flag_duplicate_ids(results: &[RecordBatch]) -> Result<Vec<RecordBatch>> {
    let mut keys: Vec<Vec<IdKey<'_>>> = Vec::with_capacity(results.len());
    for batch in results {
        match batch.column_by_name(TIGHTENING_ID) {
            Some(ids) => keys.push(id_keys(ids.as_ref())?),
            None => return Ok(results.to_vec()),
        }
    }
    let mut counts: HashMap<IdKey<'_>, usize> = HashMap::new();
    for key in keys.iter().flatten().filter(|k| **k != IdKey::Null) {
        *counts.entry(*key).or_insert(0) += 1;
    }
    if counts.values().all(|&c| c < 2) {
        return Ok(results.to_vec());
    }
    results
        .iter()
        .zip(&keys)
        .map(|(batch, keys)| {
            let count_of = |i: usize| counts.get(&keys[i]).copied().unwrap_or(0);
            if !(0..batch.num_rows()).any(|i| count_of(i) > 1) {
                return Ok(batch.clone());
            }
            let Some((index, _)) = batch.schema().column_with_name(STATUS) else { return Ok(batch.clone()) };
            let status = batch.column(index);
            if !matches!(status.data_type(), DataType::Utf8) {
                return Ok(batch.clone());
            }
            let status = status.as_string::<i32>();
            let flagged: StringArray = (0..batch.num_rows())
                .map(|i| {
                    let own = status.is_valid(i).then(|| status.value(i));
                    let count = count_of(i);
                    if count < 2 {
                        return own.map(str::to_string);
                    }
                    // A row flagged by an earlier pass: keep only its curve's own status.
                    let own = own.map(|s| match s.split_once(CURVE_STATUS) {
                        Some((_, curve)) if s.starts_with("duplicate_id") => curve,
                        _ => s,
                    });
                    let duplicate = TighteningStatus::DuplicateId { id: keys[i].to_string(), count };
                    Some(format!("{duplicate}{CURVE_STATUS}{}", own.unwrap_or("null")))
                })
                .collect();
            let mut columns: Vec<ArrayRef> = batch.columns().to_vec();
            columns[index] = Arc::new(flagged);
            Ok(RecordBatch::try_new(batch.schema(), columns)?)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use arrow_array::Int64Array;
    use arrow_schema::{Field, Schema};

    fn results(ids: Vec<Option<i64>>, status: Vec<&str>) -> RecordBatch {
        let schema = Schema::new(vec![
            Field::new(TIGHTENING_ID, DataType::Int64, true),
            Field::new(STATUS, DataType::Utf8, false),
        ]);
        RecordBatch::try_new(Arc::new(schema), vec![Arc::new(Int64Array::from(ids)), Arc::new(StringArray::from(status))])
            .unwrap_or_else(|e| panic!("{e}"))
    }

    fn statuses(batches: &[RecordBatch]) -> Vec<String> {
        batches
            .iter()
            .flat_map(|b| b.column(1).as_string::<i32>().iter().map(|s| s.unwrap_or_default().to_string()).collect::<Vec<_>>())
            .collect()
    }

    #[test]
    fn repeats_across_batches_are_flagged_in_every_row_and_nulls_never() {
        let a = results(vec![Some(1), Some(2), None], vec!["ok", "ok", "ok"]);
        let b = results(vec![Some(3), Some(1), None, Some(1)], vec!["ok", "too_short: x", "ok", "ok"]);
        let out = flag_duplicate_ids(&[a, b]).unwrap_or_else(|e| panic!("{e}"));
        let once = "duplicate_id: tightening_id 1 appears 3 times; as a curve: ";
        assert_eq!(
            statuses(&out),
            vec![format!("{once}ok"), "ok".into(), "ok".into(), "ok".into(), format!("{once}too_short: x"), "ok".into(), format!("{once}ok")]
        );
        // Flagging again changes nothing.
        let again = flag_duplicate_ids(&out).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(statuses(&again), statuses(&out));
    }

    #[test]
    fn unique_ids_pass_unchanged() {
        let a = results(vec![Some(1), Some(2)], vec!["ok", "empty: no samples"]);
        let out = flag_duplicate_ids(std::slice::from_ref(&a)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(out, vec![a]);
    }
}
