//! The particle filter's null table (`PF_NULL_TABLE` in
//! crates/tightscan-core/src/detectors/pf.rs): for each window length, the upper quantiles of
//! the largest log Bayes factor on straight lines with white Gaussian noise
//! (`tightscan_core::detectors::pf::simulate_null_statistics`, the default 256 particles), and
//! `P(S > s) e^s` at a few s, which Ville's bound holds at or below 1.
//!
//!     cargo run --release -p tightscan-benches --example pf_null_table -- [reps] [particles]
use tightscan_core::detectors::pf::{simulate_null_statistics, PF_NULL_LEVELS, PF_NULL_SEED};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let reps: usize = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(4000);
    let particles: usize = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(256);
    for n in [30usize, 60, 120, 250, 500, 1000, 2000, 4000] {
        let t0 = std::time::Instant::now();
        let mut s = simulate_null_statistics(n, reps, particles, PF_NULL_SEED + n as u64);
        s.sort_by(f64::total_cmp);
        let quantiles: Vec<String> =
            PF_NULL_LEVELS.iter().map(|&a| format!("{:.3}", s[((1.0 - a) * reps as f64).floor() as usize])).collect();
        let tail: Vec<String> = [1.0, 2.0, 3.0, 4.0]
            .iter()
            .map(|&l| format!("{l}: {:.3}", s.iter().filter(|&&v| v > l).count() as f64 / reps as f64 * f64::exp(l)))
            .collect();
        eprintln!("n {n:5} ({:.1} s) P(S>s) e^s  {}", t0.elapsed().as_secs_f64(), tail.join("  "));
        println!("    ({n}, [{}]),", quantiles.join(", "));
    }
}
