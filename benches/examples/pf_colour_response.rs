//! How the particle filter's fault statistic responds to colour the whitening leaves: null
//! lines whose noise is AR(1) of a small psi (long-run over marginal variance
//! `lambda = (1 + psi) / (1 - psi)`), upper quantiles against the white ones, and the offset
//! `C` of the scaling `S_lambda + C = lambda (S_1 + C)` each quantile implies.
//!
//!     cargo run --release -p tightscan-benches --example pf_colour_response -- [reps]
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;
use tightscan_core::detectors::pf::{pf_fault_test, PfConfig};

fn statistics(n: usize, psi: f64, reps: usize, seed: u64) -> Vec<f64> {
    let mut s: Vec<f64> = (0..reps)
        .into_par_iter()
        .map(|r| {
            let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed + r as u64);
            let x: Vec<f64> = (0..n).map(|i| i as f64).collect();
            let mut e: f64 = Distribution::<f64>::sample(&StandardNormal, &mut rng) / (1.0 - psi * psi).sqrt();
            let y: Vec<f64> = (0..n)
                .map(|i| {
                    e = psi * e + Distribution::<f64>::sample(&StandardNormal, &mut rng);
                    i as f64 + e
                })
                .collect();
            let config = PfConfig { seed: seed + r as u64, ..PfConfig::default() };
            pf_fault_test(&x, &y, 0.0, &config).map_or(0.0, |res| res.statistic)
        })
        .collect();
    s.sort_by(f64::total_cmp);
    s
}

fn main() {
    let reps: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(2000);
    for n in [60usize, 250, 1000] {
        let white = statistics(n, 0.0, reps, 1);
        for psi in [0.1, 0.2] {
            let lambda = (1.0 + psi) / (1.0 - psi);
            let coloured = statistics(n, psi, reps, 1_000_000);
            let cells: Vec<String> = [0.5, 0.2, 0.1, 0.05, 0.01]
                .iter()
                .map(|&a| {
                    let k = ((1.0 - a) * reps as f64) as usize;
                    let (q1, ql) = (white[k], coloured[k]);
                    format!("{a}: {q1:.2} -> {ql:.2} (C {:.2})", (ql - lambda * q1) / (lambda - 1.0))
                })
                .collect();
            println!("n {n:5} psi {psi} lambda {lambda:.2}  {}", cells.join("  "));
        }
    }
}
