//! Regenerates `CRITICAL_VALUES` in `src/detectors/critical_values.rs` (method in that module's docs).
//!
//! `cargo run --release -p tightscan-core --example critical_values [scale]`
//!
//! Two runs: the rows gamma <= 0.35 (short paths, TABLE_REPETITIONS_LOW_GAMMA of them) and the
//! rows gamma >= 0.45 (long paths, TABLE_REPETITIONS_HIGH_GAMMA), each with extra gammas at
//! the grid midpoints to judge interpolation. `scale` (default 1) divides both path counts,
//! for a quick look. Prints, per (p, gamma, alpha), the raw and continuity-corrected quantiles
//! on nested grids, the Richardson cross-check and the shipped estimate; then how far linear
//! interpolation in gamma would be off at the midpoints; then the Rust source of the table.

use std::time::Instant;

use tightscan_core::detectors::critical_values::{
    simulate_suprema, SupremumSample, SupremumSimulation, ALPHA_GRID, GAMMA_GRID, MAX_DIMENSION,
    TABLE_FINEST_STEP_LOG2, TABLE_REPETITIONS_HIGH_GAMMA, TABLE_REPETITIONS_LOW_GAMMA, TABLE_SEED,
};

/// Midpoints of the gamma grid and their neighbours' indices in GAMMA_GRID.
const MIDPOINTS: [(f64, usize, usize); 5] = [(0.05, 0, 1), (0.2, 2, 3), (0.3, 3, 4), (0.4, 4, 5), (0.47, 5, 6)];

/// Estimate for every simulated gamma: `[p - 1][alpha index]`.
type Estimates = Vec<(f64, Vec<[f64; 4]>)>;

fn run(gammas: Vec<f64>, repetitions: usize, seed: u64, grids: usize) -> Result<Estimates, Box<dyn std::error::Error>> {
    let settings = SupremumSimulation {
        gammas,
        max_dimension: MAX_DIMENSION,
        horizon_ratio: None,
        finest_step_log2: TABLE_FINEST_STEP_LOG2,
        grids,
        repetitions,
        seed,
    };
    let started = Instant::now();
    let sample = simulate_suprema(&settings)?;
    println!(
        "# gammas {:?}: {repetitions} paths, seed {seed}, finest step 2^-{TABLE_FINEST_STEP_LOG2}, \
         {} threads, {:.1} s wall",
        settings.gammas,
        rayon::current_num_threads(),
        started.elapsed().as_secs_f64()
    );
    Ok(report(&sample))
}

fn report(sample: &SupremumSample) -> Estimates {
    let settings = &sample.settings;
    println!("# p gamma alpha | raw q(d), d = 2^-8, 2^-7, ... | corrected q(d), same grids | Richardson | shipped");
    let (mut worst_grid, mut worst_richardson) = (0.0_f64, 0.0_f64);
    let mut out = Vec::new();
    for (g, &gamma) in settings.gammas.iter().enumerate() {
        let mut by_p = vec![[0.0_f64; 4]; MAX_DIMENSION];
        for (p, row) in by_p.iter_mut().enumerate().map(|(i, r)| (i + 1, r)) {
            for (a, &alpha) in ALPHA_GRID.iter().enumerate() {
                let raw: Vec<String> =
                    (0..settings.grids).map(|l| format!("{:.4}", sample.raw_quantile(alpha, p, g, l))).collect();
                let corrected: Vec<f64> =
                    (0..settings.grids).map(|l| sample.corrected_quantile(alpha, p, g, l)).collect();
                let shown: Vec<String> = corrected.iter().map(|v| format!("{v:.4}")).collect();
                let rich = sample.richardson_quantile(alpha, p, g);
                let shipped = sample.continuous_quantile(alpha, p, g);
                println!(
                    "{p} {gamma:.2} {alpha:.3} | {} | {} | {rich:.4} | {shipped:.4}",
                    raw.join(" "),
                    shown.join(" ")
                );
                row[a] = shipped;
                worst_grid = worst_grid.max((shipped - corrected[0]).abs());
                worst_richardson = worst_richardson.max((shipped - rich).abs());
            }
        }
        out.push((gamma, by_p));
    }
    println!("# max |shipped - corrected(2^-8)| = {worst_grid:.4}; max |shipped - Richardson| = {worst_richardson:.4}");
    out
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let scale: usize = match std::env::args().nth(1) {
        Some(s) => s.parse()?,
        None => 1,
    };
    let started = Instant::now();
    let low =
        run(vec![0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35], TABLE_REPETITIONS_LOW_GAMMA / scale, TABLE_SEED, 3)?;
    let high = run(vec![0.4, 0.45, 0.47, 0.49], TABLE_REPETITIONS_HIGH_GAMMA / scale, TABLE_SEED + 1, 5)?;
    println!("# total {:.1} s wall", started.elapsed().as_secs_f64());
    let all: Estimates = low.into_iter().chain(high).collect();
    let lookup =
        |gamma: f64| all.iter().find(|(g, _)| (g - gamma).abs() < 1e-9).map(|(_, v)| v.clone()).ok_or("gamma missing");

    println!("# interpolation error at midpoints (linear in gamma minus simulated), worst over alpha");
    for p in 1..=MAX_DIMENSION {
        for (gamma, lo, hi) in MIDPOINTS {
            let (a, b, mid) = (lookup(GAMMA_GRID[lo])?, lookup(GAMMA_GRID[hi])?, lookup(gamma)?);
            let w = (gamma - GAMMA_GRID[lo]) / (GAMMA_GRID[hi] - GAMMA_GRID[lo]);
            let worst = (0..ALPHA_GRID.len())
                .map(|k| (1.0 - w) * a[p - 1][k] + w * b[p - 1][k] - mid[p - 1][k])
                .fold(0.0_f64, |acc, e| if e.abs() > acc.abs() { e } else { acc });
            println!("p {p} gamma {gamma:.2}: {worst:+.4}");
        }
    }

    println!("pub static CRITICAL_VALUES: [[[f64; 4]; 7]; 4] = [");
    for p in 1..=MAX_DIMENSION {
        println!("    // p = {p}");
        println!("    [");
        for gamma in GAMMA_GRID {
            let row = lookup(gamma)?;
            let cells: Vec<String> = row[p - 1].iter().map(|v| format!("{v:.4}")).collect();
            println!("        [{}], // gamma = {gamma}", cells.join(", "));
        }
        println!("    ],");
    }
    println!("];");
    Ok(())
}
