use super::*;
use arrow_array::{BooleanArray, Float32Array, Float64Array, Int64Array, ListArray, RecordBatch, StringArray};

use super::draw::{DEG_PER_S_PER_RPM, SPEED_FRICTION_REF_RPM, TARGET_PRELOAD_STRESS_MPA, YIELD_TRANSITION_FRACTION};
use super::effects::sin_turns;
use arrow_array::Array;

fn small(n: usize, seed: u64) -> SimulationConfig {
    SimulationConfig { n, seed, ..SimulationConfig::default() }
}

fn f32_list(batch: &RecordBatch, column: &str, row: usize) -> Vec<f64> {
    let list =
        batch.column_by_name(column).unwrap().as_any().downcast_ref::<ListArray>().unwrap();
    let values = list.value(row);
    let values = values.as_any().downcast_ref::<Float32Array>().unwrap();
    values.values().iter().map(|v| f64::from(*v)).collect()
}

fn f64_col(batch: &RecordBatch, column: &str) -> Float64Array {
    batch
        .column_by_name(column)
        .unwrap()
        .as_any()
        .downcast_ref::<Float64Array>()
        .unwrap()
        .clone()
}

fn i64_col(batch: &RecordBatch, column: &str) -> Int64Array {
    batch.column_by_name(column).unwrap().as_any().downcast_ref::<Int64Array>().unwrap().clone()
}

fn str_col(batch: &RecordBatch, column: &str) -> StringArray {
    batch
        .column_by_name(column)
        .unwrap()
        .as_any()
        .downcast_ref::<StringArray>()
        .unwrap()
        .clone()
}

/// Least-squares slope of y over x.
fn slope(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len() as f64;
    let mx = x.iter().sum::<f64>() / n;
    let my = y.iter().sum::<f64>() / n;
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = x.iter().map(|a| (a - mx) * (a - mx)).sum();
    sxy / sxx
}

#[test]
fn same_seed_same_batches_whatever_the_thread_count() {
    let config = SimulationConfig { with_clamp_force: true, ..small(40, 7) };
    let a = simulate(&config).unwrap();
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let b = pool.install(|| simulate(&config)).unwrap();
    assert_eq!(a.tightenings, b.tightenings);
    assert_eq!(a.truth, b.truth);
    let c = simulate(&SimulationConfig { seed: 8, ..config }).unwrap();
    assert_ne!(a.tightenings, c.tightenings);
}

#[test]
fn chunks_reproduce_the_same_rows() {
    let whole = simulate(&small(10, 3)).unwrap();
    let tail = simulate(&SimulationConfig { first_id: 5, ..small(5, 3) }).unwrap();
    assert_eq!(whole.tightenings.slice(5, 5), tail.tightenings);
    assert_eq!(whole.truth.slice(5, 5), tail.truth);
    assert_eq!(i64_col(&tail.truth, "tightening_id").values().to_vec(), vec![5, 6, 7, 8, 9]);
}

#[test]
fn schemas_and_empty_batches() {
    let empty = simulate(&small(0, 1)).unwrap();
    assert_eq!(empty.tightenings.num_rows(), 0);
    assert_eq!(empty.truth.num_rows(), 0);
    assert_eq!(empty.tightenings.schema(), tightenings_schema(false));
    let s = simulate(&SimulationConfig { with_clamp_force: true, ..small(5, 1) }).unwrap();
    assert_eq!(s.tightenings.schema(), tightenings_schema(true));
    assert_eq!(s.truth.schema(), truth_schema());
    assert!(s.tightenings.column_by_name("clamp_force").is_some());
    assert!(simulate(&small(3, 1))
        .unwrap()
        .tightenings
        .column_by_name("clamp_force")
        .is_none());
}

#[test]
fn channels_are_consistent() {
    let config = SimulationConfig { with_clamp_force: true, ..small(60, 11) };
    let s = simulate(&config).unwrap();
    let n_samples = i64_col(&s.truth, "n_samples");
    for row in 0..config.n {
        let angle = f32_list(&s.tightenings, "angle", row);
        let n = angle.len();
        assert_eq!(n as i64, n_samples.value(row));
        for column in ["torque", "time", "speed", "clamp_force"] {
            assert_eq!(f32_list(&s.tightenings, column, row).len(), n, "{column} row {row}");
        }
        assert_eq!(angle[0], 0.0);
        assert!(angle.windows(2).all(|w| w[1] >= w[0]), "angle decreases in row {row}");
        let time = f32_list(&s.tightenings, "time", row);
        assert_eq!(time[0], 0.0);
        assert!(
            ((time[n - 1] - time[0]) / (n - 1) as f64 - 1.0 / config.sample_rate_hz).abs()
                < 1e-6
        );
        // Encoder quantisation: multiples of the resolution.
        assert!(angle.iter().all(|a| ((a / 0.1) - (a / 0.1).round()).abs() < 1e-3));
    }
}

#[test]
fn typical_sample_counts() {
    let s = simulate(&small(300, 5)).unwrap();
    let mut counts = i64_col(&s.truth, "n_samples").values().to_vec();
    counts.sort_unstable();
    let median = counts[counts.len() / 2];
    assert!((500..=3000).contains(&median), "median {median}");
    assert!(counts[0] >= 200, "min {}", counts[0]);
}

#[test]
fn cst_stops_at_the_target() {
    for noise in [0.0, 0.002] {
        let config = SimulationConfig {
            strategies: vec![Strategy::Cst],
            torque_noise: noise,
            ..small(300, 13)
        };
        let s = simulate(&config).unwrap();
        let targets = f64_col(&s.tightenings, "target_torque");
        let mut standardised = Vec::new();
        for row in 0..config.n {
            let torque = f32_list(&s.tightenings, "torque", row);
            let target = targets.value(row);
            let last = *torque.last().unwrap();
            if noise == 0.0 {
                assert!(last >= target * (1.0 - 1e-6), "row {row}: {last} < {target}");
                // The true torque crossed the target only at the last sample.
                assert!(torque[..torque.len() - 1].iter().all(|t| *t < target));
            } else {
                let sd = noise * target;
                standardised.push((last - target) / sd);
                assert!(last >= target - 5.0 * sd, "row {row}");
            }
        }
        if noise > 0.0 {
            let mean = standardised.iter().sum::<f64>() / standardised.len() as f64;
            assert!(mean > -1.0 / (standardised.len() as f64).sqrt() * 4.0, "mean {mean}");
        }
    }
}

#[test]
fn strategies_have_their_shape() {
    let s =
        simulate(&SimulationConfig { torque_noise: 0.0, fault_fraction: 0.0, ..small(90, 17) })
            .unwrap();
    let strategies = str_col(&s.truth, "strategy");
    let targets = f64_col(&s.tightenings, "target_torque");
    let mut seen = [0; 3];
    for row in 0..90 {
        let angle = f32_list(&s.tightenings, "angle", row);
        let torque = f32_list(&s.tightenings, "torque", row);
        let speed = f32_list(&s.tightenings, "speed", row);
        let last = torque.len() - 1;
        let stalled = (1..angle.len())
            .filter(|&k| angle[k] == angle[k - 1] && speed[k].abs() < 3.0)
            .count();
        match strategies.value(row) {
            "CST" => seen[0] += 1,
            "CSDT" => {
                seen[1] += 1;
                // A pause of at least 0.05 s at 2 kHz in which the angle holds.
                assert!(stalled >= 90, "row {row}: {stalled} stalled samples");
            }
            "HDT" => {
                seen[2] += 1;
                assert!(torque[last] > targets.value(row), "HDT overshoots");
                assert!(speed[last].abs() < 3.0, "HDT comes to rest");
            }
            other => panic!("unexpected strategy {other}"),
        }
    }
    assert!(seen.iter().all(|c| *c > 10), "{seen:?}");
}

#[test]
fn fault_fraction_is_respected() {
    for fraction in [0.0, 0.3, 1.0] {
        let n = 2000;
        let s =
            simulate(&SimulationConfig { fault_fraction: fraction, ..small(n, 21) }).unwrap();
        let flags = s.truth.column_by_name("has_change").unwrap();
        let flags = flags.as_any().downcast_ref::<BooleanArray>().unwrap();
        let count = flags.true_count() as f64;
        let sd = (n as f64 * fraction * (1.0 - fraction)).sqrt();
        assert!((count - n as f64 * fraction).abs() <= 4.0 * sd, "{fraction}: {count}");
        // Labels are null exactly when there is no change.
        for column in
            ["fault_kind", "fault_component", "magnitude", "onset_angle", "onset_index"]
        {
            let array = s.truth.column_by_name(column).unwrap();
            assert_eq!(array.null_count(), n - count as usize, "{column}");
        }
    }
}

#[test]
fn fault_labels_are_in_range() {
    let s = simulate(&SimulationConfig {
        fault_fraction: 1.0,
        angle_resolution_deg: 0.0,
        ..small(300, 23)
    })
    .unwrap();
    let magnitude = f64_col(&s.truth, "magnitude");
    let onset = f64_col(&s.truth, "onset_angle");
    let onset_index = i64_col(&s.truth, "onset_index");
    let elastic_start = f64_col(&s.truth, "elastic_start_angle");
    let snug = f64_col(&s.truth, "snug_angle");
    let final_angle = f64_col(&s.truth, "final_angle");
    for row in 0..300 {
        let m = magnitude.value(row).abs();
        assert!((0.05..=0.30).contains(&m));
        assert!(snug.value(row) < elastic_start.value(row));
        assert!(
            onset.value(row) > elastic_start.value(row)
                && onset.value(row) < final_angle.value(row)
        );
        let angle = f32_list(&s.tightenings, "angle", row);
        let k = onset_index.value(row) as usize;
        let tol = 1e-4 * onset.value(row);
        assert!(angle[k] >= onset.value(row) - tol);
        assert!(angle[k - 1] < onset.value(row) + tol);
    }
}

/// Elastic-zone torque rate expected from the truth row: k_joint (0.16 P + 0.58 d2 mu_th +
/// Dkm/2 mu_b), optionally with the faulted coefficients.
fn expected_rate(s: &Simulated, row: usize, faulted: bool) -> f64 {
    let thread = parse_thread(str_col(&s.tightenings, "thread").value(row)).unwrap();
    let k = f64_col(&s.truth, "joint_stiffness").value(row);
    let (mut mu_th, mut mu_b) =
        (f64_col(&s.truth, "mu_th").value(row), f64_col(&s.truth, "mu_b").value(row));
    if faulted {
        let factor = 1.0 + f64_col(&s.truth, "magnitude").value(row);
        match str_col(&s.truth, "fault_component").value(row) {
            "thread" => mu_th *= factor,
            "bearing" => mu_b *= factor,
            _ => {
                mu_th *= factor;
                mu_b *= factor;
            }
        }
    }
    k * thread.torque_per_force(mu_th, mu_b)
}

#[test]
fn elastic_slope_matches_the_tightening_equation() {
    let config = SimulationConfig {
        strategies: vec![Strategy::Cst],
        fault_fraction: 0.0,
        torque_noise: 0.0,
        angle_resolution_deg: 0.0,
        ..small(50, 29)
    };
    let s = simulate(&config).unwrap();
    let elastic_start = f64_col(&s.truth, "elastic_start_angle");
    for row in 0..config.n {
        let angle = f32_list(&s.tightenings, "angle", row);
        let torque = f32_list(&s.tightenings, "torque", row);
        let (x, y): (Vec<f64>, Vec<f64>) = angle
            .iter()
            .zip(&torque)
            .filter(|(a, _)| **a > elastic_start.value(row) + 0.01)
            .map(|(a, t)| (*a, *t))
            .unzip();
        assert!(x.len() > 20);
        let expected = expected_rate(&s, row, false);
        let got = slope(&x, &y);
        assert!((got / expected - 1.0).abs() < 1e-3, "row {row}: {got} vs {expected}");
    }
}

#[test]
fn abrupt_fault_changes_the_slope_by_its_factor() {
    let config = SimulationConfig {
        strategies: vec![Strategy::Cst],
        fault_fraction: 1.0,
        fault_kinds: vec![FaultKind::Abrupt],
        torque_noise: 0.0,
        angle_resolution_deg: 0.0,
        ..small(100, 31)
    };
    let s = simulate(&config).unwrap();
    let elastic_start = f64_col(&s.truth, "elastic_start_angle");
    let onset_index = i64_col(&s.truth, "onset_index");
    let mut checked = 0;
    for row in 0..config.n {
        let angle = f32_list(&s.tightenings, "angle", row);
        let torque = f32_list(&s.tightenings, "torque", row);
        let k = onset_index.value(row) as usize;
        let first = angle.iter().position(|a| *a > elastic_start.value(row) + 0.01).unwrap();
        if k - first < 10 || angle.len() - k < 10 {
            continue; // a jump to the target at the onset leaves nothing to fit
        }
        let before = slope(&angle[first..k], &torque[first..k]);
        let after = slope(&angle[k..], &torque[k..]);
        let expected = expected_rate(&s, row, true) / expected_rate(&s, row, false);
        assert!(
            (after / before / expected - 1.0).abs() < 1e-3,
            "row {row}: {} vs {expected}",
            after / before
        );
        checked += 1;
    }
    assert!(checked > 50, "only {checked} rows checked");
}

#[test]
fn noise_and_clamp_channel_leave_the_parameters_alone() {
    let a = simulate(&small(20, 37)).unwrap();
    let b = simulate(&SimulationConfig {
        torque_noise: 0.0,
        with_clamp_force: true,
        ..small(20, 37)
    })
    .unwrap();
    assert_eq!(a.truth, b.truth);
    // Speed noise is the same too.
    assert_eq!(a.tightenings.column_by_name("speed"), b.tightenings.column_by_name("speed"));
}

#[test]
fn clamp_force_follows_the_preload() {
    let s = simulate(&SimulationConfig { with_clamp_force: true, ..small(30, 41) }).unwrap();
    let preload = f64_col(&s.truth, "preload");
    for row in 0..30 {
        let force = f32_list(&s.tightenings, "clamp_force", row);
        let last = *force.last().unwrap();
        // Noise sd is 0.5 % of the target preload.
        assert!((last - preload.value(row)).abs() < 0.05 * preload.value(row), "row {row}");
        assert!(force[0].abs() < 0.05 * preload.value(row));
    }
}

#[test]
fn enum_names_round_trip() {
    for s in Strategy::ALL {
        assert_eq!(s.as_str().parse::<Strategy>().unwrap(), s);
    }
    for k in FaultKind::ALL {
        assert_eq!(k.as_str().to_uppercase().parse::<FaultKind>().unwrap(), k);
    }
    for c in FaultComponent::ALL {
        assert_eq!(format!(" {c} ").parse::<FaultComponent>().unwrap(), c);
    }
    assert_eq!("csdt".parse::<Strategy>().unwrap(), Strategy::Csdt);
    let err = "TCAM".parse::<Strategy>();
    assert!(
        matches!(err, Err(TightscanError::InvalidParameter { name, .. }) if name == "strategy")
    );
    assert!("drift".parse::<FaultKind>().is_err());
    assert!("nut".parse::<FaultComponent>().is_err());
}

#[test]
fn validate_names_the_field() {
    let cases: Vec<(&str, SimulationConfig)> = vec![
        ("fault_fraction", SimulationConfig { fault_fraction: 1.5, ..Default::default() }),
        ("fault_fraction", SimulationConfig { fault_fraction: f64::NAN, ..Default::default() }),
        ("strategies", SimulationConfig { strategies: vec![], ..Default::default() }),
        ("fault_kinds", SimulationConfig { fault_kinds: vec![], ..Default::default() }),
        (
            "fault_components",
            SimulationConfig { fault_components: vec![], ..Default::default() },
        ),
        (
            "magnitude_range",
            SimulationConfig { magnitude_range: (0.3, 0.1), ..Default::default() },
        ),
        (
            "magnitude_range",
            SimulationConfig { magnitude_range: (-0.1, 0.1), ..Default::default() },
        ),
        (
            "magnitude_range",
            SimulationConfig { magnitude_range: (0.1, 1.0), ..Default::default() },
        ),
        ("threads", SimulationConfig { threads: vec![], ..Default::default() }),
        (
            "threads",
            SimulationConfig { threads: vec!["M8".into(), "M7".into()], ..Default::default() },
        ),
        ("torque_noise", SimulationConfig { torque_noise: -0.1, ..Default::default() }),
        (
            "angle_resolution_deg",
            SimulationConfig { angle_resolution_deg: f64::INFINITY, ..Default::default() },
        ),
        ("sample_rate_hz", SimulationConfig { sample_rate_hz: 0.0, ..Default::default() }),
        ("sample_rate_hz", SimulationConfig { sample_rate_hz: -5.0, ..Default::default() }),
        ("first_id", SimulationConfig { first_id: i64::MAX, n: 2, ..Default::default() }),
        (
            "onset_fraction_range",
            SimulationConfig { onset_fraction_range: (0.5, 1.1), ..Default::default() },
        ),
        (
            "onset_fraction_range",
            SimulationConfig { onset_fraction_range: (0.6, 0.5), ..Default::default() },
        ),
        ("mu_th_range", SimulationConfig { mu_th_range: (-0.1, 0.2), ..Default::default() }),
        ("mu_b_range", SimulationConfig { mu_b_range: (0.1, f64::NAN), ..Default::default() }),
        (
            "joint_stiffness_range",
            SimulationConfig { joint_stiffness_range: Some((0.0, 1.0)), ..Default::default() },
        ),
        (
            "elastic_angle_range",
            SimulationConfig { elastic_angle_range: (50.0, 20.0), ..Default::default() },
        ),
        (
            "yield_preload_range",
            SimulationConfig { yield_preload_range: (0.0, 0.9), ..Default::default() },
        ),
        (
            "yield_gradient_ratio",
            SimulationConfig { yield_gradient_ratio: 1.0, ..Default::default() },
        ),
        (
            "clamp_force_noise",
            SimulationConfig { clamp_force_noise: -1.0, ..Default::default() },
        ),
        ("speed_friction", with_effects(EffectsConfig { speed_friction: 0.3, ..no_effects() })),
        (
            "torque_lowpass_ms",
            with_effects(EffectsConfig { torque_lowpass_ms: -1.0, ..no_effects() }),
        ),
        ("inertia", with_effects(EffectsConfig { inertia: f64::NAN, ..no_effects() })),
        (
            "pressure_friction",
            with_effects(EffectsConfig { pressure_friction: -1.0, ..no_effects() }),
        ),
        (
            "prevailing_torque_nm",
            with_effects(EffectsConfig { prevailing_torque_nm: -0.5, ..no_effects() }),
        ),
        ("runout", with_effects(EffectsConfig { runout: 1.0, ..no_effects() })),
    ];
    for (field, config) in cases {
        match config.validate() {
            Err(TightscanError::InvalidParameter { name, .. }) => assert_eq!(name, field),
            other => panic!("{field}: expected InvalidParameter, got {other:?}"),
        }
        assert!(simulate(&config).is_err());
    }
    assert!(SimulationConfig::default().validate().is_ok());
    assert!(SimulationConfig { n: 0, magnitude_range: (0.2, 0.2), ..Default::default() }
        .validate()
        .is_ok());
    assert!(with_effects(EffectsConfig::all_on()).validate().is_ok());
    assert!(SimulationConfig { onset_fraction_range: (0.0, 1.0), ..Default::default() }
        .validate()
        .is_ok());
}

fn no_effects() -> EffectsConfig {
    EffectsConfig::default()
}

fn with_effects(effects: EffectsConfig) -> SimulationConfig {
    SimulationConfig { effects, ..Default::default() }
}

/// Noise-free, unquantised, fault-free curves of one strategy, with a noise-free clamp-force
/// channel: the true trajectory as recorded.
fn clean(n: usize, seed: u64, strategy: Strategy) -> SimulationConfig {
    SimulationConfig {
        strategies: vec![strategy],
        fault_fraction: 0.0,
        torque_noise: 0.0,
        clamp_force_noise: 0.0,
        angle_resolution_deg: 0.0,
        with_clamp_force: true,
        ..small(n, seed)
    }
}

fn thread_of(s: &Simulated, row: usize) -> &'static ThreadGeometry {
    parse_thread(str_col(&s.truth, "thread").value(row)).unwrap()
}

/// Friction-dependent part of the torque per force relative to its value at the true
/// coefficients, minus 1: the relative change of both mu that the curve shows at a sample
/// with torque `t` and clamp force `f`.
fn friction_change(s: &Simulated, row: usize, t: f64, f: f64) -> f64 {
    let g = thread_of(s, row);
    let (mu_th, mu_b) =
        (f64_col(&s.truth, "mu_th").value(row), f64_col(&s.truth, "mu_b").value(row));
    let tp = f64_col(&s.truth, "prevailing_torque").value(row);
    let lead = crate::physics::thread::LEAD_FACTOR * g.pitch_mm;
    let friction_term = g.torque_per_force(mu_th, mu_b) - lead;
    ((t - tp) / f - lead) / friction_term - 1.0
}

#[test]
fn sin_turns_matches_libm() {
    let mut worst = 0.0_f64;
    for i in -200_000..200_000 {
        let u = f64::from(i) * 1.37e-4 + 0.123;
        worst = worst.max((sin_turns(u) - (std::f64::consts::TAU * u).sin()).abs());
    }
    assert!(worst < 1e-9, "worst {worst}");
    for u in [0.0, 0.25, 0.5, 0.75, 1.0, -0.25, 1e6 + 0.25] {
        assert!((sin_turns(u) - (std::f64::consts::TAU * u).sin()).abs() < 1e-9, "{u}");
    }
}

#[test]
fn defaults_switch_every_effect_and_the_yield_zone_off() {
    assert!(EffectsConfig::default().values().iter().all(|v| *v == 0.0));
    let s = simulate(&small(50, 2)).unwrap();
    assert!(str_col(&s.truth, "effects").iter().all(|e| e == Some("")));
    for column in ["runout_phase", "yield_angle"] {
        assert_eq!(s.truth.column_by_name(column).unwrap().null_count(), 50, "{column}");
    }
    assert_eq!(
        EffectsConfig { runout: 0.02, speed_friction: -0.1, ..no_effects() }.enabled_names(),
        "speed_friction,runout"
    );
    let all = EffectsConfig::all_on().enabled_names();
    assert_eq!(all, EffectsConfig::NAMES.join(","));
    let t = simulate(&SimulationConfig { effects: EffectsConfig::all_on(), ..small(5, 2) })
        .unwrap();
    assert!(str_col(&t.truth, "effects").iter().all(|e| e == Some(all.as_str())));
    let phase = f64_col(&t.truth, "runout_phase");
    assert!(phase.iter().all(|p| p.is_some_and(|p| (0.0..std::f64::consts::TAU).contains(&p))));
}

#[test]
fn effects_and_yield_are_reproducible_and_leave_the_basic_draws_alone() {
    let plain = small(60, 19);
    let rich = SimulationConfig {
        effects: EffectsConfig::all_on(),
        with_yield: true,
        with_clamp_force: true,
        ..plain.clone()
    };
    let a = simulate(&rich).unwrap();
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let b = pool.install(|| simulate(&rich)).unwrap();
    assert_eq!(a.tightenings, b.tightenings);
    assert_eq!(a.truth, b.truth);
    let tail = simulate(&SimulationConfig { first_id: 40, n: 20, ..rich.clone() }).unwrap();
    assert_eq!(a.tightenings.slice(40, 20), tail.tightenings);
    assert_eq!(a.truth.slice(40, 20), tail.truth);

    let p = simulate(&plain).unwrap();
    for column in ["strategy", "has_change", "fault_kind", "fault_component", "thread"] {
        assert_eq!(p.truth.column_by_name(column), a.truth.column_by_name(column), "{column}");
    }
    for column in ["magnitude", "mu_th", "mu_b", "mu_tot", "joint_stiffness", "snug_angle"] {
        assert_eq!(p.truth.column_by_name(column), a.truth.column_by_name(column), "{column}");
    }
    // The locking element adds its torque to the thread's own prevailing torque.
    let (tp_plain, tp_rich) =
        (f64_col(&p.truth, "prevailing_torque"), f64_col(&a.truth, "prevailing_torque"));
    for row in 0..60 {
        let added = tp_rich.value(row) - tp_plain.value(row);
        assert!((added - EffectsConfig::all_on().prevailing_torque_nm).abs() < 1e-12);
    }
    assert!(a.truth.column_by_name("yield_angle").unwrap().null_count() < 60);
    assert_ne!(p.tightenings.column_by_name("torque"), a.tightenings.column_by_name("torque"));
}

#[test]
fn drawn_friction_and_stiffness_lie_in_their_ranges() {
    let config = SimulationConfig {
        mu_th_range: (0.08, 0.12),
        mu_b_range: (0.15, 0.25),
        joint_stiffness_range: Some((0.5, 0.8)),
        ..small(400, 43)
    };
    let s = simulate(&config).unwrap();
    for (column, (lo, hi)) in [
        ("mu_th", config.mu_th_range),
        ("mu_b", config.mu_b_range),
        ("joint_stiffness", (0.5, 0.8)),
    ] {
        let values: Vec<f64> = f64_col(&s.truth, column).values().to_vec();
        let min = values.iter().copied().fold(f64::INFINITY, f64::min);
        let max = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        assert!(lo <= min && max <= hi, "{column}: [{min}, {max}] outside [{lo}, {hi}]");
        // Uniform draws fill the range: 400 draws leave less than 5 % empty at either end.
        assert!(min < lo + 0.05 * (hi - lo) && max > hi - 0.05 * (hi - lo), "{column}");
    }
    // The default derives the stiffness from the thread: F_t / k is the elastic angle.
    let d = simulate(&small(300, 43)).unwrap();
    let k = f64_col(&d.truth, "joint_stiffness");
    for row in 0..300 {
        let g = thread_of(&d, row);
        let elastic_angle =
            TARGET_PRELOAD_STRESS_MPA * g.stress_area_mm2 / 1000.0 / k.value(row);
        assert!((20.0 - 1e-9..=120.0 + 1e-9).contains(&elastic_angle), "{elastic_angle}");
    }
    // Equal ends fix a value.
    let fixed = simulate(&SimulationConfig {
        joint_stiffness_range: Some((0.6, 0.6)),
        mu_th_range: (0.12, 0.12),
        ..small(20, 43)
    })
    .unwrap();
    assert!(f64_col(&fixed.truth, "joint_stiffness").values().iter().all(|v| *v == 0.6));
    assert!(f64_col(&fixed.truth, "mu_th").values().iter().all(|v| *v == 0.12));
}

#[test]
fn onset_and_magnitude_can_be_drawn_or_fixed() {
    for fraction in [0.0, 0.5, 1.0] {
        let config = SimulationConfig {
            fault_fraction: 1.0,
            onset_fraction_range: (fraction, fraction),
            magnitude_range: (0.2, 0.2),
            ..small(100, 47)
        };
        let s = simulate(&config).unwrap();
        let onset = f64_col(&s.truth, "onset_angle");
        let (snug, start) =
            (f64_col(&s.truth, "snug_angle"), f64_col(&s.truth, "elastic_start_angle"));
        let (k, tp) =
            (f64_col(&s.truth, "joint_stiffness"), f64_col(&s.truth, "prevailing_torque"));
        let targets = f64_col(&s.tightenings, "target_torque");
        let magnitude = f64_col(&s.truth, "magnitude");
        for row in 0..config.n {
            assert_eq!(magnitude.value(row).abs(), 0.2);
            // Fault-free end of the elastic line: snug + F_needed / k.
            let g = thread_of(&s, row);
            let mu =
                (f64_col(&s.truth, "mu_th").value(row), f64_col(&s.truth, "mu_b").value(row));
            let force = (targets.value(row) - tp.value(row)) / g.torque_per_force(mu.0, mu.1);
            let end = snug.value(row) + force / k.value(row);
            let expected = start.value(row) + fraction * (end - start.value(row));
            assert!((onset.value(row) - expected).abs() < 1e-9 * expected, "row {row}");
        }
    }
    // Drawn: the onsets spread over the configured window.
    let s = simulate(&SimulationConfig {
        fault_fraction: 1.0,
        onset_fraction_range: (0.2, 0.4),
        ..small(300, 47)
    })
    .unwrap();
    let fractions: Vec<f64> = (0..300)
        .map(|row| {
            let start = f64_col(&s.truth, "elastic_start_angle").value(row);
            let onset = f64_col(&s.truth, "onset_angle").value(row);
            let snug = f64_col(&s.truth, "snug_angle").value(row);
            let k = f64_col(&s.truth, "joint_stiffness").value(row);
            let g = thread_of(&s, row);
            let mu =
                (f64_col(&s.truth, "mu_th").value(row), f64_col(&s.truth, "mu_b").value(row));
            let tp = f64_col(&s.truth, "prevailing_torque").value(row);
            let target = f64_col(&s.tightenings, "target_torque").value(row);
            let end = snug + (target - tp) / g.torque_per_force(mu.0, mu.1) / k;
            (onset - start) / (end - start)
        })
        .collect();
    assert!(fractions.iter().all(|f| (0.2 - 1e-9..=0.4 + 1e-9).contains(f)));
    assert!(fractions.iter().any(|f| *f < 0.22) && fractions.iter().any(|f| *f > 0.38));
}

#[test]
fn truth_mu_tot_is_the_iso16047_evaluation_of_the_clamp_curve() {
    let config = SimulationConfig {
        effects: EffectsConfig { prevailing_torque_nm: 3.0, ..no_effects() },
        ..clean(60, 53, Strategy::Cst)
    };
    let s = simulate(&config).unwrap();
    let start = f64_col(&s.truth, "elastic_start_angle");
    let tp = f64_col(&s.truth, "prevailing_torque");
    let mu_tot = f64_col(&s.truth, "mu_tot");
    for row in 0..config.n {
        let angle = f32_list(&s.tightenings, "angle", row);
        let torque = f32_list(&s.tightenings, "torque", row);
        let force = f32_list(&s.tightenings, "clamp_force", row);
        let elastic: Vec<usize> =
            (0..angle.len()).filter(|&k| angle[k] > start.value(row) + 0.01).collect();
        assert!(elastic.len() > 20);
        let f: Vec<f64> = elastic.iter().map(|&k| force[k]).collect();
        let t: Vec<f64> = elastic.iter().map(|&k| torque[k]).collect();
        let g = JointGeometry::from(thread_of(&s, row));
        let from_slope = g.mu_tot(slope(&f, &t));
        assert!((from_slope - mu_tot.value(row)).abs() < 1e-3, "row {row}: {from_slope}");
        // Pointwise too: (T - T_prev) / F of the last sample.
        let last = elastic[elastic.len() - 1];
        let pointwise = g.mu_tot((torque[last] - tp.value(row)) / force[last]);
        assert!((pointwise - mu_tot.value(row)).abs() < 1e-3, "row {row}: {pointwise}");
        // mu_tot lies between the two coefficients it averages.
        let (a, b) =
            (f64_col(&s.truth, "mu_th").value(row), f64_col(&s.truth, "mu_b").value(row));
        assert!(mu_tot.value(row) > a.min(b) - 2e-3 && mu_tot.value(row) < a.max(b) + 2e-3);
    }
}

#[test]
fn yield_flattens_the_torque_gradient_to_the_set_fraction() {
    let ratio = 0.15;
    let config = SimulationConfig {
        with_yield: true,
        yield_preload_range: (0.8, 0.9),
        yield_gradient_ratio: ratio,
        ..clean(40, 59, Strategy::Cst)
    };
    let s = simulate(&config).unwrap();
    let yield_angle = f64_col(&s.truth, "yield_angle");
    assert_eq!(yield_angle.null_count(), 0, "every bolt yields below its final preload");
    let start = f64_col(&s.truth, "elastic_start_angle");
    let snug = f64_col(&s.truth, "snug_angle");
    for row in 0..config.n {
        let angle = f32_list(&s.tightenings, "angle", row);
        let torque = f32_list(&s.tightenings, "torque", row);
        let elastic_rate = expected_rate(&s, row, false);
        let theta_y = yield_angle.value(row);
        let plastic_from = theta_y + YIELD_TRANSITION_FRACTION * (theta_y - snug.value(row));
        let pick_range = |lo: f64, hi: f64| -> (Vec<f64>, Vec<f64>) {
            angle
                .iter()
                .zip(&torque)
                .filter(|(a, _)| **a > lo && **a < hi)
                .map(|(a, t)| (*a, *t))
                .unzip()
        };
        let (x, y) = pick_range(start.value(row) + 0.01, theta_y);
        assert!((slope(&x, &y) / elastic_rate - 1.0).abs() < 1e-3, "row {row}: elastic");
        let (x, y) = pick_range(plastic_from + 0.01, f64::INFINITY);
        assert!(x.len() > 20, "row {row}: {} plastic samples", x.len());
        let plastic = slope(&x, &y) / elastic_rate;
        assert!(plastic <= ratio * 1.001 && plastic > ratio * 0.999, "row {row}: {plastic}");
        // In the transition the gradient falls monotonically from elastic to plastic.
        let (x, y) = pick_range(theta_y, plastic_from);
        let rates: Vec<f64> = x
            .windows(2)
            .zip(y.windows(2))
            .map(|(a, t)| (t[1] - t[0]) / (a[1] - a[0]) / elastic_rate)
            .collect();
        // (Finite differences of f32 angles: allow 1 % for their rounding.)
        assert!(rates.iter().all(|r| *r < 1.01 && *r > ratio - 0.01), "row {row}");
        assert!(rates.windows(2).all(|w| w[1] <= w[0] + 0.01), "row {row}");
    }
    // A yield point beyond the final preload is never reached: null, curves as without yield.
    let beyond = SimulationConfig { yield_preload_range: (1.5, 2.0), ..config.clone() };
    let s = simulate(&beyond).unwrap();
    assert_eq!(s.truth.column_by_name("yield_angle").unwrap().null_count(), config.n);
    let plain = simulate(&SimulationConfig { with_yield: false, ..config }).unwrap();
    assert_eq!(s.tightenings, plain.tightenings);
}

#[test]
fn prevailing_torque_raises_the_rundown_by_the_set_value() {
    let set = 2.5;
    let off = clean(60, 61, Strategy::Cst);
    let on = SimulationConfig {
        effects: EffectsConfig { prevailing_torque_nm: set, ..no_effects() },
        strategies: Strategy::ALL.to_vec(),
        ..off.clone()
    };
    let off = SimulationConfig { strategies: Strategy::ALL.to_vec(), ..off };
    let (a, b) = (simulate(&off).unwrap(), simulate(&on).unwrap());
    let snug = f64_col(&b.truth, "snug_angle");
    let tp = f64_col(&b.truth, "prevailing_torque");
    for row in 0..on.n {
        let (ta, tb) =
            (f32_list(&a.tightenings, "torque", row), f32_list(&b.tightenings, "torque", row));
        let angle = f32_list(&b.tightenings, "angle", row);
        let rundown: Vec<usize> =
            (0..angle.len()).filter(|&k| angle[k] < snug.value(row) - 6.0).collect();
        assert!(rundown.len() > 100);
        for &k in &rundown {
            assert!((tb[k] - ta[k] - set).abs() < 1e-4, "row {row} sample {k}");
            assert!((tb[k] - tp.value(row)).abs() < 1e-4, "row {row} sample {k}");
        }
        let targets = (
            f64_col(&a.tightenings, "target_torque"),
            f64_col(&b.tightenings, "target_torque"),
        );
        assert!((targets.1.value(row) - targets.0.value(row) - set).abs() < 1e-12);
        // The target is raised with it, so the preload stays (up to the last step's size).
        let preload =
            (f64_col(&a.truth, "preload").value(row), f64_col(&b.truth, "preload").value(row));
        assert!((preload.1 / preload.0 - 1.0).abs() < 0.02, "row {row}: {preload:?}");
    }
}

#[test]
fn speed_friction_follows_the_log_law_as_hdt_slows_down() {
    let a = 0.1;
    let config = SimulationConfig {
        effects: EffectsConfig { speed_friction: a, ..no_effects() },
        ..clean(40, 67, Strategy::Hdt)
    };
    let s = simulate(&config).unwrap();
    let dt = 1.0 / config.sample_rate_hz;
    let start = f64_col(&s.truth, "elastic_start_angle");
    let targets = f64_col(&s.tightenings, "target_torque");
    let (mut x, mut y) = (Vec::new(), Vec::new());
    for row in 0..config.n {
        let angle = f32_list(&s.tightenings, "angle", row);
        let torque = f32_list(&s.tightenings, "torque", row);
        let force = f32_list(&s.tightenings, "clamp_force", row);
        // Up to the shut-off: the interval speed is the angle step over dt there (the
        // coast-down records instantaneous speeds instead).
        for k in 1..angle.len() {
            if torque[k] >= targets.value(row) {
                break;
            }
            if angle[k] > start.value(row) + 0.5 {
                let rpm = (angle[k] - angle[k - 1]) / dt / DEG_PER_S_PER_RPM;
                x.push((rpm / SPEED_FRICTION_REF_RPM).ln());
                y.push(friction_change(&s, row, torque[k], force[k]));
            }
        }
    }
    let spread = x.iter().copied().fold(f64::NEG_INFINITY, f64::max)
        - x.iter().copied().fold(f64::INFINITY, f64::min);
    assert!(spread > 1.0, "speeds span only {spread} in ln");
    let got = slope(&x, &y);
    assert!((got / a - 1.0).abs() < 0.01, "a = {got}");
    // No offset: the coefficients hold at the reference speed.
    let n = x.len() as f64;
    let intercept = y.iter().sum::<f64>() / n - got * x.iter().sum::<f64>() / n;
    assert!(intercept.abs() < 1e-3, "intercept {intercept}");
    // HDT speeds stay above 30 rpm (0.22 v0 at least), so with a > 0 friction is higher
    // throughout and the target comes at a lower preload.
    let plain = simulate(&SimulationConfig { effects: no_effects(), ..config }).unwrap();
    let (on, off) = (f64_col(&s.truth, "preload"), f64_col(&plain.truth, "preload"));
    let lower = (0..40).filter(|&row| on.value(row) < off.value(row)).count();
    assert!(lower > 35, "only {lower} of 40 curves end at a lower preload with a > 0");
}

#[test]
fn pressure_friction_bends_the_torque_force_curve() {
    for c in [0.3, -0.3] {
        let config = SimulationConfig {
            effects: EffectsConfig { pressure_friction: c, ..no_effects() },
            ..clean(40, 71, Strategy::Cst)
        };
        let s = simulate(&config).unwrap();
        let start = f64_col(&s.truth, "elastic_start_angle");
        let (mut x, mut y) = (Vec::new(), Vec::new());
        for row in 0..config.n {
            let angle = f32_list(&s.tightenings, "angle", row);
            let torque = f32_list(&s.tightenings, "torque", row);
            let force = f32_list(&s.tightenings, "clamp_force", row);
            let f_target =
                TARGET_PRELOAD_STRESS_MPA * thread_of(&s, row).stress_area_mm2 / 1000.0;
            let elastic: Vec<usize> =
                (0..angle.len()).filter(|&k| angle[k] > start.value(row) + 0.5).collect();
            for &k in &elastic {
                x.push(force[k] / f_target - 1.0);
                y.push(friction_change(&s, row, torque[k], force[k]));
            }
            // dT/dF = K(mu) + F dK/dF grows with F for c > 0 and falls for c < 0.
            let half = elastic.len() / 2;
            let fit = |ks: &[usize]| {
                let f: Vec<f64> = ks.iter().map(|&k| force[k]).collect();
                let t: Vec<f64> = ks.iter().map(|&k| torque[k]).collect();
                slope(&f, &t)
            };
            let (low, high) = (fit(&elastic[..half]), fit(&elastic[half..]));
            assert!((high - low) * c > 0.0, "c {c} row {row}: {low} -> {high}");
        }
        let got = slope(&x, &y);
        assert!((got / c - 1.0).abs() < 0.01, "c = {got}, set {c}");
    }
}

#[test]
fn inertia_adds_j_alpha_at_the_csdt_restart() {
    let j = 5.0e-4;
    let off = clean(30, 73, Strategy::Csdt);
    let on = SimulationConfig {
        effects: EffectsConfig { inertia: j, ..no_effects() },
        ..off.clone()
    };
    let (a, b) = (simulate(&off).unwrap(), simulate(&on).unwrap());
    let fs = off.sample_rate_hz;
    for row in 0..off.n {
        let angle = f32_list(&a.tightenings, "angle", row);
        let (ta, tb) =
            (f32_list(&a.tightenings, "torque", row), f32_list(&b.tightenings, "torque", row));
        assert_eq!(
            angle,
            f32_list(&b.tightenings, "angle", row),
            "inertia leaves the motion alone"
        );
        // The restart: first move after at least 50 held samples.
        let mut held = 0;
        let mut restart = None;
        for k in 1..angle.len() {
            if angle[k] == angle[k - 1] {
                held += 1;
            } else {
                if held >= 50 {
                    restart = Some(k);
                    break;
                }
                held = 0;
            }
        }
        let r = restart.unwrap();
        let omega = (angle[r] - angle[r - 1]) * fs * std::f64::consts::PI / 180.0; // rad/s
        let expected = j * omega * fs; // J alpha, alpha = (omega - 0) / dt
        let step = tb[r] - ta[r];
        assert!((step / expected - 1.0).abs() < 0.01, "row {row}: {step} vs {expected}");
        // At constant speed (one sample on) the inertial torque is gone.
        assert!((tb[r + 2] - ta[r + 2]).abs() < 1e-4 * ta[r + 2], "row {row}");
    }
}

#[test]
fn lowpass_delays_the_torque_ramp_by_tau() {
    let tau_ms = 5.0;
    let off = clean(60, 79, Strategy::Cst);
    let on = SimulationConfig {
        effects: EffectsConfig { torque_lowpass_ms: tau_ms, ..no_effects() },
        ..off.clone()
    };
    let (a, b) = (simulate(&off).unwrap(), simulate(&on).unwrap());
    let start = f64_col(&a.truth, "elastic_start_angle");
    let mut checked = 0;
    for row in 0..off.n {
        let (angle, time) =
            (f32_list(&a.tightenings, "angle", row), f32_list(&a.tightenings, "time", row));
        let (ta, tb) =
            (f32_list(&a.tightenings, "torque", row), f32_list(&b.tightenings, "torque", row));
        // After 20 tau in the elastic zone the filter's transient is gone (e^-20).
        let Some(first) = angle.iter().position(|x| *x > start.value(row)) else { continue };
        let settled = first + (20.0 * tau_ms * 1e-3 * off.sample_rate_hz) as usize;
        if ta.len() < settled + 40 {
            continue;
        }
        let rate = slope(&time[settled..], &ta[settled..]); // Nm/s of the clean ramp
        let lags: Vec<f64> = (settled..ta.len()).map(|k| (ta[k] - tb[k]) / rate).collect();
        for lag in &lags {
            assert!((lag * 1e3 / tau_ms - 1.0).abs() < 0.01, "row {row}: lag {lag}");
        }
        // Before the filter settles at the start the filtered curve also lags, never leads.
        assert!((1..ta.len()).all(|k| tb[k] <= ta[k] + 1e-4), "row {row}");
        checked += 1;
    }
    assert!(checked > 30, "only {checked} rows long enough");
}

#[test]
fn runout_is_a_once_per_revolution_modulation_of_amplitude_r() {
    let r = 0.03;
    let off =
        SimulationConfig { strategies: Strategy::ALL.to_vec(), ..clean(30, 83, Strategy::Cst) };
    let on = SimulationConfig {
        effects: EffectsConfig { runout: r, ..no_effects() },
        ..off.clone()
    };
    let (a, b) = (simulate(&off).unwrap(), simulate(&on).unwrap());
    let phase = f64_col(&b.truth, "runout_phase");
    for row in 0..off.n {
        let angle = f32_list(&a.tightenings, "angle", row);
        let (ta, tb) =
            (f32_list(&a.tightenings, "torque", row), f32_list(&b.tightenings, "torque", row));
        // Least squares of the relative residual on sin and cos of the angle (1/rev).
        let (mut ss, mut cc, mut sc, mut ys, mut yc) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for k in 0..angle.len() {
            let (sn, cs) = angle[k].to_radians().sin_cos();
            let residual = tb[k] / ta[k] - 1.0;
            ss += sn * sn;
            cc += cs * cs;
            sc += sn * cs;
            ys += residual * sn;
            yc += residual * cs;
        }
        let det = ss * cc - sc * sc;
        let (p, q) = ((ys * cc - yc * sc) / det, (yc * ss - ys * sc) / det);
        // r sin(x + phi) = r cos(phi) sin(x) + r sin(phi) cos(x).
        let amplitude = p.hypot(q);
        assert!((amplitude / r - 1.0).abs() < 1e-3, "row {row}: amplitude {amplitude}");
        let fitted = q.atan2(p).rem_euclid(std::f64::consts::TAU);
        let diff = (fitted - phase.value(row)).abs();
        assert!(diff.min(std::f64::consts::TAU - diff) < 1e-3, "row {row}: phase {fitted}");
    }
}

/// Generation speed, n = 10,000, default settings and every effect on (with yield):
/// `cargo test --release -p tightscan-core --lib simulate::tests::speed -- --ignored --nocapture`
#[test]
#[ignore]
fn speed() {
    let default = SimulationConfig { n: 10_000, ..SimulationConfig::default() };
    let all_effects = SimulationConfig {
        effects: EffectsConfig::all_on(),
        with_yield: true,
        ..default.clone()
    };
    for (label, config) in [("default", default), ("all effects + yield", all_effects)] {
        simulate(&SimulationConfig { n: 500, ..config.clone() }).unwrap();
        let mut best = f64::INFINITY;
        let mut samples = 0;
        for _ in 0..5 {
            let start = std::time::Instant::now();
            let s = simulate(&config).unwrap();
            best = best.min(start.elapsed().as_secs_f64());
            samples = i64_col(&s.truth, "n_samples").values().iter().sum::<i64>();
        }
        println!(
            "{label}, n = {}: {:.3} s best of 5 on {} threads, {:.0} tightenings/s, {} samples \
             ({:.0} per tightening, {:.1} M/s)",
            config.n,
            best,
            rayon::current_num_threads(),
            config.n as f64 / best,
            samples,
            samples as f64 / config.n as f64,
            samples as f64 / best / 1e6
        );
    }
}
