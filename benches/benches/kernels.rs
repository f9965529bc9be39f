//! Criterion benchmarks of the tightscan kernels.
//!
//! Size grid (every input is seeded, so every run measures the same data):
//!
//! | group       | bench                 | input                                             | throughput unit     |
//! |-------------|-----------------------|---------------------------------------------------|---------------------|
//! | `cusum`     | `update/10000`        | 1e4 N(0, 1) increments, Xoshiro256++ seed 42      | increments          |
//! | `cusum`     | `update/100000`       | 1e5 N(0, 1) increments, Xoshiro256++ seed 42      | increments          |
//! | `break_scan`| `two_lines/500`       | 500-sample AR(1) 0.85 window, whitened, seed 42   | window samples      |
//! | `break_scan`| `gls/500`             | the same window, GLS break regression (AR(1))     | window samples      |
//! | `detect`    | `tightenings/1000`    | `simulate(n = 1000, seed = 7)`, default config    | samples (all rows)  |
//! | `detect`    | `tightenings/10000`   | `simulate(n = 10000, seed = 7)`, default config   | samples (all rows)  |
//! | `simulate`  | `tightenings/1000`    | `SimulationConfig { n: 1000, seed: 7, .. }`       | tightenings         |
//! | `simulate`  | `tightenings/10000`   | `SimulationConfig { n: 10000, seed: 7, .. }`      | tightenings + bytes |
//! | `simulate`  | `all_effects/10000`   | as above, `EffectsConfig::all_on()`, `with_yield` | tightenings + bytes |
//! | `stages`    | see below             | `simulate(n = 1000, seed = 7)`, one thread        | samples (all rows)  |
//!
//! `stages` splits one tightening's analysis into the public building blocks `Detector::detect`
//! runs, each over all 1,000 tightenings on the calling thread, so that their costs per sample
//! add up against `stages/detect_1_thread` (the whole detector in a one-thread rayon pool):
//! `validate` (the NaN/inf scan of all four channels, as `detect` does it), `find_phases` (the
//! phases and the elastic window),
//! `block_stats` and `stop_ranges` (on the windows found), `torque_max` (one plain pass of
//! max over the torque, the cost of each extra whole-curve pass), `noise_model` (the AR noise
//! model of each window from local quadratics over the window and up to 1,024 samples of
//! rundown before it, as the detector fits it: the bias-corrected moments solved by Newton's
//! method, the order by BIC, the jackknife of the gain) and `heavy_tail_fit` (the rundown's
//! whitened local-quadratic noise, `block_noise`, and the Student t fitted to it over the grid
//! of degrees of freedom, the heavy-tail check every window gets). The last two were 20 % and
//! 40-50 % of a warm detect's instructions before issue 15's work (callgrind).
//!
//! `break_scan` compares the two-line sup-LR scan with the GLS break regression the engine runs
//! under AR noise (`detectors/gls_breakpoint.rs`): the price of the whitened step's edge rows.
//!
//! The CUSUM uses kappa = 0.5 and the threshold of the default detector (two-sided ARL0 = 3,000
//! blocks, h ~ 6.4). The recursion keeps running after the first alarm, so every increment
//! costs the same whether or not the series alarms.
//!
//! The two `simulate` cases at n = 10,000 also report bytes/s: the bytes are those of the four
//! float32 channels generated (16 per sample), so samples/s = bytes/s / 16; the setup prints the
//! samples per tightening of each case. `all_effects` switches on every effect of
//! `EffectsConfig::all_on()` (speed and pressure friction, 2 ms low-pass, 2e-4 kg m^2 inertia,
//! 1 Nm prevailing torque, 1 % run-out) and the yield zone.
//!
//! `detect` and `simulate` run on rayon's global pool (all cores; set `RAYON_NUM_THREADS` to
//! pin it). A detect sample is one (angle, torque) pair; the throughput counts every sample of
//! every tightening (from the `angle` list offsets), not only the elastic window.
//!
//! Run: `cargo bench -p tightscan-benches` (full), `cargo bench -p tightscan-benches -- --quick`
//! (short), `cargo test -p tightscan-benches --benches` (each bench once, as a smoke test).
#![allow(clippy::expect_used)]

use std::hint::black_box;
use std::time::Duration;

use arrow_array::cast::AsArray;
use arrow_array::RecordBatch;
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;
use tightscan_core::detectors::breakpoint::sup_lr_scan;
use tightscan_core::detectors::cusum::TwoSidedCusum;
use tightscan_core::detectors::gls_breakpoint::{gls_sup_lr_scan, GlsScratch};
use tightscan_core::engine::input::{ChannelRow, Samples, TighteningTable};
use tightscan_core::detectors::noise::{block_noise, estimate_noise_in, fit_student_t_groups, NoiseScratch};
use tightscan_core::physics::phases::{find_phases, PhaseScratch};
use tightscan_core::physics::torque_rate::{block_count, block_stats, stop_ranges, Blocks, ElasticWindow};
use tightscan_core::simulate::{simulate, EffectsConfig, SimulationConfig};
use tightscan_core::{DetectConfig, Detector};

/// CUSUM series lengths.
const CUSUM_SIZES: [usize; 2] = [10_000, 100_000];
/// Seed of the CUSUM increments.
const CUSUM_SEED: u64 = 42;
/// Tightenings per detect batch.
const DETECT_SIZES: [usize; 2] = [1_000, 10_000];
/// Tightenings per simulate call.
const SIMULATE_SIZE: usize = 1_000;
/// Tightenings per simulate call of the default / all-effects comparison.
const SIMULATE_LARGE: usize = 10_000;
/// Bytes generated per sample: four float32 channels (angle, torque, time, speed).
const SIMULATE_BYTES_PER_SAMPLE: u64 = 16;
/// Seed of the simulated tightenings.
const SIM_SEED: u64 = 7;

fn normal_increments(n: usize, seed: u64) -> Vec<f64> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    (0..n).map(|_| StandardNormal.sample(&mut rng)).collect()
}

fn simulated_batch(n: usize) -> RecordBatch {
    let cfg = SimulationConfig { n, seed: SIM_SEED, ..SimulationConfig::default() };
    simulate(&cfg).expect("bench setup: simulate failed").tightenings
}

/// Total samples of a nested batch: span of the `angle` list offsets.
fn total_samples(batch: &RecordBatch) -> u64 {
    let angle = batch.column_by_name("angle").expect("bench setup: no angle column");
    let offsets = angle.as_list::<i32>().value_offsets();
    let (first, last) = (offsets.first().copied().unwrap_or(0), offsets.last().copied().unwrap_or(0));
    u64::try_from(last - first).expect("bench setup: negative offsets")
}

fn bench_cusum(c: &mut Criterion) {
    let kappa = 0.5;
    // The threshold detect_batch uses by default (from the CUSUM's share of the decision alpha).
    let h = Detector::new(DetectConfig::default()).expect("bench setup: detector").threshold();
    let mut group = c.benchmark_group("cusum");
    for &n in &CUSUM_SIZES {
        let zs = normal_increments(n, CUSUM_SEED);
        group.throughput(Throughput::Elements(n as u64));
        group.bench_with_input(BenchmarkId::new("update", n), &zs, |b, zs| {
            b.iter(|| {
                let mut cusum = TwoSidedCusum::new(kappa, h);
                for &z in black_box(zs.as_slice()) {
                    black_box(cusum.update(z));
                }
                (cusum.alarm(), cusum.max_statistic())
            });
        });
    }
    group.finish();
}

/// One 500-sample window of a line under AR(1) 0.85 noise, whitened with that coefficient: the
/// two-line scan and the GLS scan on it (`Throughput::Elements(500)`).
fn bench_break_scan(c: &mut Criterion) {
    let (n, phi) = (500, 0.85);
    let e = normal_increments(n + 1, CUSUM_SEED);
    let x: Vec<f64> = (0..=n).map(|i| i as f64 * 0.1).collect();
    let mut noise = 0.0;
    let y: Vec<f64> = x.iter().zip(&e).map(|(xi, ei)| {
        noise = phi * noise + 0.05 * ei;
        2.0 + 1.5 * xi + noise
    }).collect();
    let wx: Vec<f64> = x.windows(2).map(|w| w[1] - phi * w[0]).collect();
    let wy: Vec<f64> = y.windows(2).map(|w| w[1] - phi * w[0]).collect();
    let seg = tightscan_core::detectors::breakpoint::min_segment(n);
    let mut group = c.benchmark_group("break_scan");
    group.throughput(Throughput::Elements(n as u64));
    group.bench_function(BenchmarkId::new("two_lines", n), |b| {
        let mut prefix = Vec::new();
        b.iter(|| sup_lr_scan(black_box(&wx), black_box(&wy), seg, &mut prefix).map(|s| s.statistic));
    });
    group.bench_function(BenchmarkId::new("gls", n), |b| {
        let mut scratch = GlsScratch::default();
        b.iter(|| gls_sup_lr_scan(black_box(&wx), black_box(&wy), &x, &[phi], &[], seg, &mut scratch, None).map(|s| s.statistic));
    });
    group.finish();
}

/// The particle filter's cost per sample and particle (`Throughput::Elements(n * particles)`):
/// one 1,000-sample white-noise line, 64 to 1,024 particles.
fn bench_pf(c: &mut Criterion) {
    use tightscan_core::detectors::pf::{pf_fault_test, PfConfig};
    let n = 1000;
    let noise = normal_increments(n, CUSUM_SEED);
    let x: Vec<f64> = (0..n).map(|i| i as f64).collect();
    let y: Vec<f64> = x.iter().zip(&noise).map(|(xi, e)| xi + e).collect();
    let mut group = c.benchmark_group("pf");
    for particles in [64usize, 256, 1024] {
        group.throughput(Throughput::Elements((n * particles) as u64));
        let config = PfConfig { particles, ..PfConfig::default() };
        group.bench_with_input(BenchmarkId::new("sample_particle", particles), &config, |b, config| {
            b.iter(|| pf_fault_test(black_box(&x), black_box(&y), 0.01, config).map(|r| r.statistic));
        });
    }
    group.finish();
}

fn bench_detect(c: &mut Criterion) {
    let detector = Detector::new(DetectConfig::default()).expect("bench setup: detector");
    let mut group = c.benchmark_group("detect");
    group.sample_size(20).measurement_time(Duration::from_secs(8));
    for &n in &DETECT_SIZES {
        let batch = simulated_batch(n);
        group.throughput(Throughput::Elements(total_samples(&batch)));
        group.bench_with_input(BenchmarkId::new("tightenings", n), &batch, |b, batch| {
            b.iter(|| detector.detect(black_box(batch), &[], 0));
        });
    }
    group.finish();
}

fn bench_simulate(c: &mut Criterion) {
    let cfg = SimulationConfig { n: SIMULATE_SIZE, seed: SIM_SEED, ..SimulationConfig::default() };
    let mut group = c.benchmark_group("simulate");
    group.sample_size(20).measurement_time(Duration::from_secs(8));
    group.throughput(Throughput::Elements(SIMULATE_SIZE as u64));
    group.bench_with_input(BenchmarkId::new("tightenings", SIMULATE_SIZE), &cfg, |b, cfg| {
        b.iter(|| simulate(black_box(cfg)));
    });
    group.sample_size(10).measurement_time(Duration::from_secs(10));
    let large = SimulationConfig { n: SIMULATE_LARGE, ..cfg };
    let all_effects = SimulationConfig { effects: EffectsConfig::all_on(), with_yield: true, ..large.clone() };
    for (name, config) in [("tightenings", large), ("all_effects", all_effects)] {
        let samples = total_samples(&simulate(&config).expect("bench setup: simulate failed").tightenings);
        eprintln!(
            "simulate/{name}/{SIMULATE_LARGE}: {samples} samples, {:.0} per tightening",
            samples as f64 / SIMULATE_LARGE as f64
        );
        group.throughput(Throughput::ElementsAndBytes {
            elements: SIMULATE_LARGE as u64,
            bytes: samples * SIMULATE_BYTES_PER_SAMPLE,
        });
        group.bench_with_input(BenchmarkId::new(name, SIMULATE_LARGE), &config, |b, cfg| {
            b.iter(|| simulate(black_box(cfg)));
        });
    }
    group.finish();
}

/// The f32 samples of `row` of `column`, or `None` for a null row.
fn f32_row<'a>(column: &tightscan_core::engine::input::ChannelColumn<'a>, row: usize) -> Option<Samples<'a>> {
    match column.row(row) {
        ChannelRow::Present { samples, .. } => Some(samples),
        ChannelRow::Null => None,
    }
}

fn as_f32<'a>(s: Samples<'a>) -> &'a [f32] {
    match s {
        Samples::F32(v) => v,
        Samples::F64(_) => panic!("bench setup: simulate gives float32 channels"),
    }
}

/// Sample numbers, torque and the two segments (rundown, window) of one noise-model input.
type NoiseInput = (Vec<f64>, Vec<f64>, [std::ops::Range<usize>; 2]);

fn bench_stages(c: &mut Criterion) {
    let batch = simulated_batch(DETECT_SIZES[0]);
    let samples = total_samples(&batch);
    let table = TighteningTable::new(&batch).expect("bench setup: table view");
    let config = DetectConfig::default();
    // Every channel of every row (angle, torque, then the optional ones), as detect checks them.
    let rows: Vec<Vec<Samples<'_>>> = (0..table.n_rows)
        .map(|i| {
            std::iter::once(&table.angle)
                .chain(std::iter::once(&table.torque))
                .chain(table.optional.iter())
                .filter_map(|col| f32_row(col, i))
                .collect()
        })
        .collect();
    let curves: Vec<(&[f32], &[f32])> = rows.iter().map(|r| (as_f32(r[0]), as_f32(r[1]))).collect();
    let windows: Vec<(usize, ElasticWindow, usize)> = curves
        .iter()
        .enumerate()
        .filter_map(|(i, (a, t))| {
            let w = find_phases(a, t, &config.zone, &config.yield_zone, &mut PhaseScratch::default()).ok()?.window;
            let nb = block_count(w.end - w.start, &config.blocks);
            (nb >= config.blocks.min_training_blocks + 2).then_some((i, w, nb))
        })
        .collect();
    let detector = Detector::new(config.clone()).expect("bench setup: detector");
    let one_thread = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("bench setup: thread pool");

    let mut group = c.benchmark_group("stages");
    group.throughput(Throughput::Elements(samples));
    group.bench_function("validate", |b| {
        b.iter(|| rows.iter().map(|r| r.iter().map(|s| s.non_finite_count()).sum::<usize>()).sum::<usize>());
    });
    group.bench_function("find_phases", |b| {
        let mut scratch = PhaseScratch::default();
        b.iter(|| {
            curves
                .iter()
                .filter(|(a, t)| find_phases(a, t, black_box(&config.zone), &config.yield_zone, &mut scratch).is_ok())
                .count()
        });
    });
    group.bench_function("torque_max", |b| {
        b.iter(|| {
            curves.iter().map(|(_, t)| t.iter().fold(f64::NEG_INFINITY, |m, &x| m.max(f64::from(x)))).sum::<f64>()
        });
    });
    group.bench_function("block_stats", |b| {
        let mut blocks = Blocks::default();
        b.iter(|| {
            let mut n = 0;
            for &(i, w, nb) in &windows {
                let (a, t) = curves[i];
                block_stats(a, t, w, nb, &mut blocks);
                n += blocks.stats.len();
            }
            n
        });
    });
    group.bench_function("stop_ranges", |b| {
        let mut stops = Vec::new();
        b.iter(|| {
            let mut n = 0;
            for &(i, w, _) in &windows {
                let (a, t) = curves[i];
                stop_ranges(a, t, w, &mut stops);
                n += stops.len();
            }
            n
        });
    });
    // The noise model's inputs: torque on sample number over the window and up to 1,024
    // samples before it (the detector's NOISE_HISTORY), in two segments (rundown, window).
    let noise_inputs: Vec<NoiseInput> = windows
        .iter()
        .map(|&(i, w, _)| {
            let first = w.start.saturating_sub(1024);
            let y: Vec<f64> = curves[i].1[first..w.end].iter().map(|&t| f64::from(t)).collect();
            let t: Vec<f64> = (0..y.len()).map(|k| k as f64).collect();
            (t, y, [0..w.start - first, w.start - first..w.end - first])
        })
        .collect();
    group.bench_function("noise_model", |b| {
        let mut scratch = NoiseScratch::default();
        b.iter(|| {
            noise_inputs
                .iter()
                .map(|(t, y, segments)| estimate_noise_in(t, y, segments, 64, &mut scratch).coefficients.len())
                .sum::<usize>()
        });
    });
    group.bench_function("heavy_tail_fit", |b| {
        let mut noise = Vec::new();
        b.iter(|| {
            noise_inputs
                .iter()
                .filter(|(t, y, segments)| {
                    noise.clear();
                    block_noise(t, y, segments[0].clone(), 64, &[0.5], 0.0, &mut noise);
                    fit_student_t_groups(&[&noise]).is_some_and(|fit| fit.lr > 5.41)
                })
                .count()
        });
    });
    group.bench_function("detect_1_thread", |b| {
        b.iter(|| one_thread.install(|| detector.detect(black_box(&batch), &[], 0)));
    });
    group.finish();
}

criterion_group!(benches, bench_cusum, bench_break_scan, bench_pf, bench_detect, bench_simulate, bench_stages);
criterion_main!(benches);
