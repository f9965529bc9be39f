use super::*;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

fn normals(rng: &mut Xoshiro256PlusPlus, n: usize, mean: f64, sd: f64) -> Vec<f64> {
    (0..n)
        .map(|_| {
            let z: f64 = StandardNormal.sample(rng);
            mean + sd * z
        })
        .collect()
}

fn exact(x: &[f64], y: &[f64], h: f64, e: MmdEstimator) -> f64 {
    kde_statistic(x, y, h, e, KdeEvaluation::Exact)
}

#[test]
fn silverman_matches_hand_computation() {
    let x: Vec<f64> = (1..=10).map(f64::from).collect();
    // sd = sqrt(110/12) = 3.0277 < IQR/1.34 = (7.75 - 3.25)/1.34 = 3.358.
    let sd = (110.0f64 / 12.0).sqrt();
    let h = silverman_bandwidth(&x).unwrap();
    assert!((h - 0.9 * sd * 10f64.powf(-0.2)).abs() < 1e-12, "{h}");
    // An outlier inflates the sd; the IQR (type 7: 2.25 .. 4.75) takes over.
    let x = [5.0, 1.0, 3.0, 100.0, 2.0, 4.0];
    let h = silverman_bandwidth(&x).unwrap();
    assert!((h - 0.9 * 2.5 / 1.34 * 6f64.powf(-0.2)).abs() < 1e-12, "{h}");
    // IQR 0 (ties): the sd alone.
    let x = [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 5.0];
    let sd = (16.0f64 * 7.0 / 8.0 / 7.0).sqrt();
    let h = silverman_bandwidth(&x).unwrap();
    assert!((h - 0.9 * sd * 8f64.powf(-0.2)).abs() < 1e-12, "{h}");
    assert!(silverman_bandwidth(&[1.0]).is_err());
    assert!(silverman_bandwidth(&[1.0, 1.0, 1.0]).is_err());
    assert!(silverman_bandwidth(&[1.0, f64::NAN, 2.0]).is_err());
}

/// T is the L2 distance between the KDEs: compare with int (f_X - f_Y)^2 dx by composite
/// Simpson on a fine grid (error ~ (step/h)^4, far below 1e-9 here), and the unbiased
/// estimator with the i != j double sums written out.
#[test]
fn l2_identity_by_quadrature() {
    let x = [-0.7, 0.1, 0.25, 1.3, 2.0];
    let y = [-1.9, -0.4, 0.0, 0.6, 0.65, 1.1, 3.2];
    let h = 0.4;
    let kde = |s: &[f64], t: f64| {
        s.iter().map(|&v| normal_density(t - v, h)).sum::<f64>() / s.len() as f64
    };
    let (a, b) = (-1.9 - 12.0 * h, 3.2 + 12.0 * h);
    let intervals = 20_000;
    let step = (b - a) / intervals as f64;
    let mut integral = 0.0;
    for i in 0..=intervals {
        let t = a + i as f64 * step;
        let d = kde(&x, t) - kde(&y, t);
        let w = if i == 0 || i == intervals {
            1.0
        } else if i % 2 == 1 {
            4.0
        } else {
            2.0
        };
        integral += w * d * d;
    }
    integral *= step / 3.0;
    let t = exact(&x, &y, h, MmdEstimator::Biased);
    assert!((t / integral - 1.0).abs() < 1e-6, "T = {t}, integral = {integral}");

    let sigma = std::f64::consts::SQRT_2 * h;
    let k = |a: f64, b: f64| normal_density(a - b, sigma);
    let (n, m) = (x.len() as f64, y.len() as f64);
    let mut sxx = 0.0;
    for (i, &a) in x.iter().enumerate() {
        for (j, &b) in x.iter().enumerate() {
            if i != j {
                sxx += k(a, b);
            }
        }
    }
    let mut syy = 0.0;
    for (i, &a) in y.iter().enumerate() {
        for (j, &b) in y.iter().enumerate() {
            if i != j {
                syy += k(a, b);
            }
        }
    }
    let sxy: f64 = x.iter().map(|&a| y.iter().map(|&b| k(a, b)).sum::<f64>()).sum();
    let u = sxx / (n * (n - 1.0)) + syy / (m * (m - 1.0)) - 2.0 * sxy / (n * m);
    let got = exact(&x, &y, h, MmdEstimator::Unbiased);
    assert!((got - u).abs() < 1e-14, "{got} vs {u}");
    assert!(got < t);
    // Degenerate inputs.
    assert!(kde_l2_distance(&[], &y, h).is_nan());
    assert!(kde_l2_distance(&x, &y, 0.0).is_nan());
    assert!(kde_l2_distance(&x, &[f64::NAN], h).is_nan());
    assert!(exact(&x, &[1.0], h, MmdEstimator::Unbiased).is_nan());
}

/// Cases for the fast evaluations: (n, m, shift, scale of Y), X ~ N(0, 1).
const CASES: [(usize, usize, f64, f64); 6] = [
    (300, 300, 0.0, 1.0),
    (1000, 500, 0.0, 1.0),
    (2000, 2000, 0.0, 1.0),
    (5000, 1000, 0.0, 1.0),
    (1000, 1000, 0.5, 1.0),
    (500, 2000, 0.0, 1.5),
];

/// Worst relative error of `evaluation` against the exact sums over CASES. The unbiased
/// estimator has mean 0 under H0, so its error is taken relative to the biased T of the
/// same samples (the scale of both).
fn worst_error(evaluation: KdeEvaluation) -> (f64, f64) {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
    let (mut worst_b, mut worst_u) = (0.0f64, 0.0f64);
    for (n, m, shift, scale) in CASES {
        let x = normals(&mut rng, n, 0.0, 1.0);
        let y = normals(&mut rng, m, shift, scale);
        let h = silverman_bandwidth(&x).unwrap();
        let tb = exact(&x, &y, h, MmdEstimator::Biased);
        let tu = exact(&x, &y, h, MmdEstimator::Unbiased);
        let fb = kde_statistic(&x, &y, h, MmdEstimator::Biased, evaluation);
        let fu = kde_statistic(&x, &y, h, MmdEstimator::Unbiased, evaluation);
        worst_b = worst_b.max((fb / tb - 1.0).abs());
        worst_u = worst_u.max(((fu - tu) / tb).abs());
    }
    (worst_b, worst_u)
}

#[test]
fn binned_matches_exact() {
    let (b, u) = worst_error(KdeEvaluation::Binned);
    eprintln!("binned: worst relative error biased {b:.2e}, unbiased {u:.2e}");
    assert!(b < 1e-3 && u < 1e-3, "{b} {u}");
    // Auto picks the exact sums for small samples.
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
    let x = normals(&mut rng, 100, 0.0, 1.0);
    let y = normals(&mut rng, 120, 0.0, 1.0);
    assert_eq!(kde_l2_distance(&x, &y, 0.3), exact(&x, &y, 0.3, MmdEstimator::Biased));
}

#[test]
fn spectral_matches_exact() {
    let (b, u) = worst_error(KdeEvaluation::Spectral);
    eprintln!("spectral: worst relative error biased {b:.2e}, unbiased {u:.2e}");
    assert!(b < 1e-6 && u < 1e-6, "{b} {u}");
    // An outlier 40 sd out stretches the range and the node count, not the error.
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
    let mut x = normals(&mut rng, 200, 0.0, 1.0);
    x[17] = 40.0;
    let y = normals(&mut rng, 300, 0.2, 1.0);
    let h = silverman_bandwidth(&x).unwrap();
    let tb = exact(&x, &y, h, MmdEstimator::Biased);
    let fb = kde_statistic(&x, &y, h, MmdEstimator::Biased, KdeEvaluation::Spectral);
    let fbin = kde_statistic(&x, &y, h, MmdEstimator::Biased, KdeEvaluation::Binned);
    assert!((fb / tb - 1.0).abs() < 1e-6, "{fb} vs {tb}");
    assert!((fbin / tb - 1.0).abs() < 1e-3, "{fbin} vs {tb}");
}

#[test]
fn pvalue_and_critical_value_agree() {
    let null: Vec<f64> = (1..=199).map(f64::from).collect();
    assert_eq!(permutation_pvalue(200.0, &null), 1.0 / 200.0);
    assert_eq!(permutation_pvalue(190.0, &null), 11.0 / 200.0);
    assert_eq!(permutation_pvalue(190.5, &null), 10.0 / 200.0);
    assert_eq!(permutation_pvalue(0.0, &null), 1.0);
    assert!(permutation_pvalue(f64::NAN, &null).is_nan());
    assert_eq!(allowed_exceedances(199, 0.05), 10);
    assert_eq!(allowed_exceedances(499, 0.05), 25);
    assert_eq!(allowed_exceedances(99, 0.01), 1);
    assert_eq!(allowed_exceedances(98, 0.01), 0);
    // 10th largest of 1..=199 is 190: p <= 0.05 iff T > 190.
    assert_eq!(permutation_critical_value(&null, 0.05), 190.0);
    assert_eq!(permutation_critical_value(&null[..50], 0.01), f64::INFINITY);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(2);
    let null = normals(&mut rng, 199, 0.0, 1.0);
    for alpha in [0.01, 0.05, 0.1, 0.5] {
        let c = permutation_critical_value(&null, alpha);
        for t in normals(&mut rng, 2000, 1.0, 1.5) {
            assert_eq!(permutation_pvalue(t, &null) <= alpha, t > c, "alpha {alpha}, t {t}");
        }
    }
}

#[test]
fn block_permutation_moves_whole_blocks() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(9);
    let (n, l) = (23, 5);
    let mut seen_first = [false; 4];
    for _ in 0..200 {
        let order = block_permutation(n, l, &mut rng);
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..n).collect::<Vec<_>>());
        // n mod L = 3 leading indices stay; then 4 runs of 5 consecutive indices starting at
        // 3 + 5 b.
        assert_eq!(&order[..3], &[0, 1, 2]);
        for run in order[3..].chunks(l) {
            assert_eq!((run[0] - 3) % l, 0);
            assert!(run.windows(2).all(|w| w[1] == w[0] + 1));
        }
        seen_first[(order[3] - 3) / l] = true;
    }
    assert!(seen_first.iter().all(|&s| s), "every block reaches the front");
    // L = 1 is an ordinary permutation.
    let order = block_permutation(10, 1, &mut rng);
    assert_ne!(order, (0..10).collect::<Vec<_>>());
}

/// The scan's incremental spectral statistics equal the exact statistic of each window.
#[test]
fn scan_profile_matches_exact_statistics() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(21);
    let mut r = normals(&mut rng, 300, 0.0, 1.0);
    r.extend(normals(&mut rng, 100, 0.8, 1.3));
    let training = 120;
    let h = silverman_bandwidth(&r[..training]).unwrap();
    let (lo, hi) = min_max(r.iter()).unwrap();
    let grid = SpectralGrid::new(lo, hi, h).unwrap();
    let prefix = grid.prefix_sums(&r);
    for window in
        [KdeWindow::Growing { min_len: 15 }, KdeWindow::Sliding { width: 60 }, KdeWindow::Whole]
    {
        for (stride, block_len) in [(1, 1), (7, 8)] {
            let plan = plan_windows(r.len(), training, window, stride, 0.25).unwrap();
            assert_eq!(plan.ends.last(), Some(&r.len()));
            let mut scan = SpectralScan::new(&prefix, &grid.weights, training, &plan);
            let mut profile = vec![0.0; plan.ends.len()];
            let identity = BlockOrder::identity(r.len(), block_len);
            let max = scan.run(&identity, Some(&mut profile));
            for j in 0..plan.ends.len() {
                let y = &r[plan.starts[j]..plan.ends[j]];
                let want = plan.scale[j] * exact(&r[..training], y, h, MmdEstimator::Biased);
                assert!((profile[j] / want - 1.0).abs() < 1e-6, "{window:?} window {j}");
            }
            assert_eq!(max, profile.iter().cloned().fold(f64::NEG_INFINITY, f64::max));
            // Scanning through a block order equals scanning the permuted series.
            let mut order = BlockOrder::identity(r.len(), block_len);
            order.shuffle(&mut rng);
            let a = scan.run(&order, None);
            let mut indices = Vec::new();
            order.pieces(0, r.len(), |lo, hi| indices.extend(lo..hi));
            let permuted: Vec<f64> = indices.iter().map(|&i| r[i]).collect();
            let prefix_p = grid.prefix_sums(&permuted);
            let mut scan_p = SpectralScan::new(&prefix_p, &grid.weights, training, &plan);
            let b = scan_p.run(&BlockOrder::identity(r.len(), 1), None);
            assert!((a / b - 1.0).abs() < 1e-9, "{a} vs {b}");
        }
    }
}

#[test]
fn change_test_rejects_bad_configuration() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
    let r = normals(&mut rng, 200, 0.0, 1.0);
    let ok = KdeTestConfig::default();
    assert!(kde_change_test(&r, 100, &ok).is_ok());
    let bad = |c: KdeTestConfig, training: usize| kde_change_test(&r, training, &c).is_err();
    assert!(bad(ok, 1));
    assert!(bad(ok, 199));
    assert!(bad(KdeTestConfig { alpha: 0.0, ..ok }, 100));
    assert!(bad(KdeTestConfig { alpha: 1.0, ..ok }, 100));
    assert!(bad(KdeTestConfig { permutations: 10, ..ok }, 100));
    assert!(bad(KdeTestConfig { block_len: Some(0), ..ok }, 100));
    assert!(bad(KdeTestConfig { block_len: Some(101), ..ok }, 100));
    assert!(bad(KdeTestConfig { stride: Some(0), ..ok }, 100));
    assert!(bad(KdeTestConfig { window: KdeWindow::Growing { min_len: 1 }, ..ok }, 100));
    assert!(bad(KdeTestConfig { window: KdeWindow::Growing { min_len: 101 }, ..ok }, 100));
    assert!(bad(KdeTestConfig { window: KdeWindow::Sliding { width: 101 }, ..ok }, 100));
    let mut nan = r.clone();
    nan[150] = f64::NAN;
    assert!(kde_change_test(&nan, 100, &ok).is_err());
    let mut flat = r.clone();
    flat[..100].fill(0.5);
    assert!(kde_change_test(&flat, 100, &ok).is_err());
    let mut wild = r.clone();
    wild[150] = 1e9;
    assert!(kde_change_test(&wild, 100, &ok).is_err());
}

/// A 1.5 sd mean shift at 300 of 600 (training 150): found, located, and the same seed gives
/// the same answer.
#[test]
fn detects_and_locates_a_step() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(8);
    let mut r = normals(&mut rng, 300, 0.0, 1.0);
    r.extend(normals(&mut rng, 300, 1.5, 1.0));
    for window in [KdeWindow::Growing { min_len: 20 }, KdeWindow::Sliding { width: 50 }] {
        for block_len in [None, Some(1)] {
            let config = KdeTestConfig { window, block_len, seed: 4, ..Default::default() };
            let res = kde_change_test(&r, 150, &config).unwrap();
            eprintln!("{res:?}");
            assert!(res.alarm && res.p_value == 1.0 / 200.0, "{res:?}");
            assert!(res.statistic > res.critical_value);
            let end = res.alarm_end.unwrap();
            assert!(end > 300 && end < 460, "{window:?}: alarm at {end}");
            let c = res.change_start.unwrap();
            assert!(c.abs_diff(300) <= 10, "{window:?}: change start {c}");
            assert_eq!(res, kde_change_test(&r, 150, &config).unwrap());
        }
    }
    // In control: no alarm, no location.
    let r = normals(&mut rng, 600, 0.0, 1.0);
    let res = kde_change_test(&r, 150, &KdeTestConfig::default()).unwrap();
    assert!(!res.alarm && res.alarm_end.is_none() && res.change_start.is_none(), "{res:?}");
}

/// Wall time per series (best of 5 rounds of 20, to see through other load); run with
/// `cargo test -p tightscan-core kde_timing -- --ignored --nocapture` (the test profile is
/// opt-level 3).
#[test]
#[ignore]
fn kde_timing() {
    let best_ms = |f: &mut dyn FnMut()| {
        (0..5)
            .map(|_| {
                let t0 = std::time::Instant::now();
                for _ in 0..20 {
                    f();
                }
                t0.elapsed().as_secs_f64() * 1e3 / 20.0
            })
            .fold(f64::INFINITY, f64::min)
    };
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(77);
    for (n, training) in [(400, 100), (1000, 250), (4000, 500)] {
        let r = normals(&mut rng, n, 0.0, 1.0);
        for (window, stride) in [
            (KdeWindow::Growing { min_len: 20 }, None),
            (KdeWindow::Sliding { width: 100 }, None),
            (KdeWindow::Whole, None),
            (KdeWindow::Growing { min_len: 20 }, Some(1)),
            (KdeWindow::Sliding { width: 100 }, Some(1)),
        ] {
            let config = KdeTestConfig { window, stride, ..KdeTestConfig::default() };
            let res = kde_change_test(&r, training, &config).unwrap();
            let ms = best_ms(&mut || {
                let _ = kde_change_test(&r, training, &config);
            });
            eprintln!(
                "scan N={n} m={training} {window:?} stride {}: {ms:.2} ms ({} windows, Q={}, \
                 B=199)",
                res.stride, res.windows_evaluated, res.spectral_nodes
            );
        }
    }
    for size in [500, 2000, 10_000] {
        let x = normals(&mut rng, size, 0.0, 1.0);
        let y = normals(&mut rng, size, 0.3, 1.0);
        let h = silverman_bandwidth(&x).unwrap();
        for evaluation in [KdeEvaluation::Exact, KdeEvaluation::Binned, KdeEvaluation::Spectral]
        {
            if evaluation == KdeEvaluation::Exact && size > 2000 {
                continue;
            }
            let ms = best_ms(&mut || {
                let _ = kde_statistic(&x, &y, h, MmdEstimator::Biased, evaluation);
            });
            eprintln!("T with n = m = {size}, {evaluation:?}: {ms:.3} ms");
        }
    }
}

/// Worst relative error of the binned evaluation against the exact sums by grid density,
/// with and without the grid-variance correction: the figures behind BINS_PER_SIGMA.
/// Run with `-- --ignored --nocapture`.
#[test]
#[ignore]
fn binned_experiment() {
    for correct in [false, true] {
        for bins_per_sigma in [4.0, 8.0, 16.0, 32.0] {
            let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
            let (mut worst_b, mut worst_u) = (0.0f64, 0.0f64);
            for (n, m, shift, scale) in CASES {
                let x = normals(&mut rng, n, 0.0, 1.0);
                let y = normals(&mut rng, m, shift, scale);
                let h = silverman_bandwidth(&x).unwrap();
                let tb = exact(&x, &y, h, MmdEstimator::Biased);
                let tu = exact(&x, &y, h, MmdEstimator::Unbiased);
                let pb = binned_parts_with(&x, &y, h, bins_per_sigma, false, correct).unwrap();
                let pu = binned_parts_with(&x, &y, h, bins_per_sigma, true, correct).unwrap();
                worst_b = worst_b.max((pb.biased / tb - 1.0).abs());
                let fu = pu.estimate(MmdEstimator::Unbiased, n, m);
                worst_u = worst_u.max(((fu - tu) / tb).abs());
            }
            eprintln!(
                "variance correction {correct}, {bins_per_sigma} points per sigma: worst \
                 relative error biased {worst_b:.2e}, unbiased {worst_u:.2e}"
            );
        }
    }
}

/// AR(1) series x_t = phi x_(t-1) + e_t with a stationary start, unit innovation variance.
fn ar1(rng: &mut Xoshiro256PlusPlus, n: usize, phi: f64) -> Vec<f64> {
    let mut x: f64 = StandardNormal.sample(rng);
    x /= (1.0 - phi * phi).sqrt();
    (0..n)
        .map(|_| {
            let e: f64 = StandardNormal.sample(rng);
            x = phi * x + e;
            x
        })
        .collect()
}

/// Fraction of `series` simulated series on which `kde_change_test` alarms; series s uses
/// generator seed (seed, s) and permutation seed s.
fn alarm_rate(
    seed: u64,
    series: usize,
    training: usize,
    config: KdeTestConfig,
    make: impl Fn(&mut Xoshiro256PlusPlus) -> Vec<f64> + Sync,
) -> f64 {
    let alarms: usize = (0..series)
        .into_par_iter()
        .map(|s| {
            let mut rng =
                Xoshiro256PlusPlus::seed_from_u64(seed.wrapping_mul(1_000_003) ^ s as u64);
            let r = make(&mut rng);
            let c = KdeTestConfig { seed: s as u64, ..config };
            usize::from(kde_change_test(&r, training, &c).unwrap().alarm)
        })
        .sum();
    alarms as f64 / series as f64
}

/// Two-sample Kolmogorov-Smirnov statistic sup |F_a - F_b|.
fn ks_statistic(a: &[f64], b: &[f64]) -> f64 {
    let mut a = a.to_vec();
    let mut b = b.to_vec();
    a.sort_by(f64::total_cmp);
    b.sort_by(f64::total_cmp);
    let (mut i, mut j, mut d) = (0, 0, 0.0f64);
    while i < a.len() && j < b.len() {
        let v = a[i].min(b[j]);
        while i < a.len() && a[i] <= v {
            i += 1;
        }
        while j < b.len() && b[j] <= v {
            j += 1;
        }
        d = d.max((i as f64 / a.len() as f64 - j as f64 / b.len() as f64).abs());
    }
    d
}

fn mean_var(x: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    (m, x.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (n - 1.0))
}

/// Oracle tests at alpha = 0.05 that know the change point c: KS (asymptotic critical
/// value 1.358 sqrt((n1 + n2) / (n1 n2))), pooled t (|t| > 1.966, t_398) and the variance
/// ratio (|ln F| / sqrt(2/(n1-1) + 2/(n2-1)) > 1.96, normal approximation of ln F).
fn oracles(r: &[f64], c: usize) -> [bool; 3] {
    let (a, b) = r.split_at(c);
    let (n1, n2) = (a.len() as f64, b.len() as f64);
    let ks = ks_statistic(a, b) > 1.358 * ((n1 + n2) / (n1 * n2)).sqrt();
    let ((ma, va), (mb, vb)) = (mean_var(a), mean_var(b));
    let pooled = ((n1 - 1.0) * va + (n2 - 1.0) * vb) / (n1 + n2 - 2.0);
    let t = (mb - ma) / (pooled * (1.0 / n1 + 1.0 / n2)).sqrt();
    let lnf = (vb / va).ln() / (2.0 / (n1 - 1.0) + 2.0 / (n2 - 1.0)).sqrt();
    [ks, t.abs() > 1.966, lnf.abs() > 1.96]
}

/// The standardisation puts all window sizes on the same footing: S_k = (n k / (n + k)) T
/// has the same null mean, sd and 95 % point for k = 20 and k = 300 (n = 100, X and Y
/// i.i.d. N(0, 1); 4,000 replicates, standard errors ~0.007 for the mean and sd).
#[test]
fn standardised_statistic_has_one_null_law() {
    let (n, reps) = (100, 4000);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
    let mut summary = Vec::new();
    for k in [20usize, 300] {
        let mut v: Vec<f64> = (0..reps)
            .map(|_| {
                let x = normals(&mut rng, n, 0.0, 1.0);
                let y = normals(&mut rng, k, 0.0, 1.0);
                let h = silverman_bandwidth(&x).unwrap();
                let scale = (n * k) as f64 / (n + k) as f64;
                scale * kde_statistic(&x, &y, h, MmdEstimator::Biased, KdeEvaluation::Spectral)
            })
            .collect();
        let m = v.iter().sum::<f64>() / reps as f64;
        let sd = (v.iter().map(|a| (a - m) * (a - m)).sum::<f64>() / reps as f64).sqrt();
        v.sort_by(f64::total_cmp);
        summary.push((m, sd, v[reps * 95 / 100]));
    }
    eprintln!("null of S_k (mean, sd, q95): k = 20 {:?}, k = 300 {:?}", summary[0], summary[1]);
    let ((m1, s1, q1), (m2, s2, q2)) = (summary[0], summary[1]);
    assert!((m1 - m2).abs() < 0.03 && (s1 - s2).abs() < 0.04 && (q1 - q2).abs() < 0.1);
}

/// P(chi2_1 > x) = 2 (1 - Phi(sqrt x)), by Simpson's rule on the normal density.
fn chi2_1_tail(x: f64) -> f64 {
    let (a, b, steps) = (x.sqrt(), 12.0, 20_000);
    let dt = (b - a) / steps as f64;
    let f = |t: f64| (-0.5 * t * t).exp() * INV_SQRT_2PI;
    let mut sum = f(a) + f(b);
    for i in 1..steps {
        sum += f(a + i as f64 * dt) * if i % 2 == 1 { 4.0 } else { 2.0 };
    }
    2.0 * sum * dt / 3.0
}

/// B = 99 in the size tests: alpha (B + 1) = 5 is an integer, so the test is as exact as
/// with 199 or 499, at half the cost.
const SIZE_CONFIG: KdeTestConfig = KdeTestConfig {
    alpha: 0.05,
    permutations: 99,
    block_len: None,
    window: KdeWindow::Growing { min_len: 20 },
    stride: None,
    gamma: 0.25,
    seed: 0,
};

/// Size on i.i.d. series: the permutation test is exact for exchangeable data, so the
/// false-alarm rate over 4,000 series (standard error 0.34 pp) must be 5 % +- 1 pp, both
/// with blocks (growing windows, default L) and without (sliding windows, L = 1).
#[test]
fn size_iid_is_nominal() {
    let series = 4000;
    let growing = alarm_rate(1, series, 100, SIZE_CONFIG, |rng| normals(rng, 400, 0.0, 1.0));
    let config = KdeTestConfig {
        block_len: Some(1),
        window: KdeWindow::Sliding { width: 50 },
        ..SIZE_CONFIG
    };
    let sliding = alarm_rate(2, series, 100, config, |rng| normals(rng, 400, 0.0, 1.0));
    eprintln!("size iid N = 400: growing (L = 7) {growing:.4}, sliding (L = 1) {sliding:.4}");
    assert!((growing - 0.05).abs() < 0.01, "{growing}");
    assert!((sliding - 0.05).abs() < 0.01, "{sliding}");
}

/// Size on AR(1) series (phi = 0.5, N = 1,000, training 250, growing windows), 4,000
/// series each. Block permutation keeps lags inside blocks only, so the long-run variance
/// of the statistic's leading (mean-like) component, sum_h rho(h) = (1 + phi)/(1 - phi), is
/// seen as sum_h (1 - |h|/L) rho(h): a relative shortfall of 2 phi / (L (1 - phi^2)). With a
/// chi2_1-like leading term the size is then P(chi2_1 > 3.84 (1 - 2 phi / (L (1 - phi^2)))):
/// 6.8 % at the default L = round(N^(1/3)) = 10, 5.4 % at L = 40. L = 10 cannot reach
/// 5 % +- 1 pp, so it is held to the prediction +- 1.2 pp (2.6 standard errors plus the
/// approximation); L = 40 is held to 5 % +- 1 pp.
#[test]
fn size_ar1_block_permutation() {
    let (n, training, phi) = (1000, 250, 0.5);
    let predicted = |l: f64| {
        chi2_1_tail(3.841_458_820_694_124 * (1.0 - 2.0 * phi / (l * (1.0 - phi * phi))))
    };
    let mut rates = Vec::new();
    // L = 10: 3,000 series (standard error 0.46 pp); L = 40: 4,000 (0.35 pp).
    for (l, series) in [(10, 3000), (40, 4000)] {
        let config = KdeTestConfig { block_len: Some(l), ..SIZE_CONFIG };
        let rate = alarm_rate(3, series, training, config, |rng| ar1(rng, n, phi));
        let p = predicted(l as f64);
        eprintln!("size AR(1) phi = {phi}, L = {l}: {rate:.4} (predicted {p:.4})");
        rates.push((rate, p));
    }
    let ((r10, p10), (r40, _)) = (rates[0], rates[1]);
    assert!((p10 - 0.068).abs() < 0.001, "{p10}");
    assert!((r10 - p10).abs() < 0.012, "{r10} vs {p10}");
    assert!((r40 - 0.05).abs() < 0.01, "{r40}");
    // Without blocks the dependence is lost and the test is far too liberal.
    let config = KdeTestConfig { block_len: Some(1), ..SIZE_CONFIG };
    let naive = alarm_rate(3, 400, training, config, |rng| ar1(rng, n, phi));
    eprintln!("size AR(1) phi = {phi}, L = 1: {naive:.4}");
    assert!(naive > 0.15, "{naive}");
}

/// Power against a change at the middle of N = 400 (training 100, change at 200), 1,000
/// series each: a mean shift of 0.5 sd and an sd ratio of 1.5. Oracles that know the split
/// compare r[0..200) with r[200..400): KS, t (mean), ln F (variance), and the KDE test itself
/// on that split (Whole window, L = 1). The scans know neither where the change is nor
/// more than the 100 training samples: growing windows dilute the change with the 100
/// in-control samples between training and change, sliding windows (100) see pure
/// post-change windows but only 100 at a time, and both pay for the maximum over windows
/// and for block permutation (a change inflates the block-permutation null, as it would a
/// long-run variance estimate).
#[test]
fn power_against_mean_and_variance_changes() {
    let (n, training, change, series) = (400, 100, 200, 1000);
    // (label, shift, sd, floors for growing, sliding, KDE oracle): the measured powers
    // (seed 5) less 3 binomial standard errors (~0.015 at these values), rounded down.
    let cases = [
        ("mean +0.5 sd", 0.5, 1.0, [0.33, 0.62, 0.92]),
        ("sd x1.5", 0.0, 1.5, [0.25, 0.55, 0.91]),
    ];
    for (label, shift, scale, floors) in cases {
        let make = |rng: &mut Xoshiro256PlusPlus| {
            let mut r = normals(rng, change, 0.0, 1.0);
            r.extend(normals(rng, n - change, shift, scale));
            r
        };
        let base = KdeTestConfig::default();
        let growing = alarm_rate(5, series, training, base, make);
        let sliding = KdeTestConfig { window: KdeWindow::Sliding { width: 100 }, ..base };
        let sliding = alarm_rate(5, series, training, sliding, make);
        let oracle = KdeTestConfig { window: KdeWindow::Whole, block_len: Some(1), ..base };
        let kde_oracle = alarm_rate(5, series, change, oracle, make);
        let mut hits = [0usize; 3];
        for s in 0..series {
            let mut rng =
                Xoshiro256PlusPlus::seed_from_u64(5u64.wrapping_mul(1_000_003) ^ s as u64);
            let r = make(&mut rng);
            for (h, hit) in hits.iter_mut().zip(oracles(&r, change)) {
                *h += usize::from(hit);
            }
        }
        let [ks, t, f] = hits.map(|v| v as f64 / series as f64);
        eprintln!(
            "power {label}: growing {growing:.3}, sliding {sliding:.3} | oracles on the true \
             split: KDE {kde_oracle:.3}, KS {ks:.3}, t {t:.3}, ln F {f:.3}"
        );
        assert!(growing >= floors[0], "{label}: growing {growing}");
        assert!(sliding >= floors[1], "{label}: sliding {sliding}");
        assert!(kde_oracle >= floors[2], "{label}: KDE oracle {kde_oracle}");
        // Knowing the split is worth more than any scan can recover.
        assert!(kde_oracle > sliding && sliding > growing);
        if shift > 0.0 {
            // For a pure location shift of normal data the t-test is optimal; the KDE
            // statistic on the same split is close behind.
            assert!(t >= kde_oracle && kde_oracle > 0.9 * t, "{t} {kde_oracle}");
        } else {
            // KS is weak against a scale change (the cdfs cross at the centre); the L2
            // distance of the densities is not.
            assert!(kde_oracle > ks + 0.25, "{kde_oracle} vs KS {ks}");
        }
    }
}
