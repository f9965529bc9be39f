//! One `Detector::detect` (default rule) over `simulate(n, seed = 7)` on one thread: a small
//! binary for `valgrind --tool=callgrind` and `perf` (instruction counts are stable on a busy
//! machine, timings are not).
//!
//! `cargo build --profile profiling -p tightscan-benches --example detect_once`, then
//! `valgrind --tool=callgrind target/profiling/examples/detect_once 200`. Arguments: tightenings
//! (default 200), repetitions (default 1), sample rate in Hz (default the simulator's, 2 kHz;
//! samples per tightening grow with it, for the cost per sample at several lengths).
#![allow(clippy::expect_used)]

use std::time::Instant;

use arrow_array::cast::AsArray;
use tightscan_core::simulate::{simulate, SimulationConfig};
use tightscan_core::{DetectConfig, Detector};

fn main() {
    let mut args = std::env::args().skip(1);
    let n: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(200);
    let repeat: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(1);
    let defaults = SimulationConfig::default();
    let sample_rate_hz: f64 = args.next().and_then(|a| a.parse().ok()).unwrap_or(defaults.sample_rate_hz);
    let batch = simulate(&SimulationConfig { n, seed: 7, sample_rate_hz, ..defaults }).expect("simulate").tightenings;
    let offsets = batch.column_by_name("angle").expect("angle").as_list::<i32>().value_offsets().to_vec();
    let samples = (offsets[offsets.len() - 1] - offsets[0]) as f64;
    let detector = Detector::new(DetectConfig::default()).expect("detector");
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("pool");
    let start = Instant::now();
    let mut rows = 0;
    for _ in 0..repeat {
        rows += pool.install(|| detector.detect(&batch, &[], 0)).expect("detect").num_rows();
    }
    let seconds = start.elapsed().as_secs_f64();
    println!(
        "{n} tightenings at {sample_rate_hz} Hz x {repeat}, {samples} samples each pass ({:.0} per tightening), {rows} rows, {:.2} M samples/s on one thread",
        samples / n as f64,
        samples * repeat as f64 / seconds / 1e6
    );
}
