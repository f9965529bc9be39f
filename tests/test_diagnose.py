"""The diagnosis loop: nothing claimed on clean data, the right effect named first (with its
parameter and an out-of-sample error near the noise floor) when one of the simulator's effects
is switched on without any column saying so, the real Rexroth runs, and the CLI.

Noise floor: the simulator's torque noise is ``torque_noise * target_torque`` (sd, per
tightening); the floor of the pooled RMSE weights it by each tightening's samples in the model.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

import tightscan
from tightscan.cli import main
from tightscan.diagnose import EFFECT_NAMES, Diagnosis, load_table

TORQUE_NOISE = 0.002
N = 600

# ISO metric coarse threads of the simulator's default set: pitch, d2, Dkm [mm]
# (crates/tightscan-core/src/physics/thread.rs: d2 = d - 0.6495 P, Dkm = (dw + dh) / 2)
THREADS = {
    "M6": (1.0, 6.0 - 0.6495 * 1.0, (8.88 + 6.6) / 2),
    "M8": (1.25, 8.0 - 0.6495 * 1.25, (11.63 + 9.0) / 2),
    "M10": (1.5, 10.0 - 0.6495 * 1.5, (14.63 + 11.0) / 2),
    "M12": (1.75, 12.0 - 0.6495 * 1.75, (16.63 + 13.5) / 2),
}


def _friction_share(truth: pa.Table) -> float:
    """Median share of the friction terms in the torque per clamp force (speed and pressure
    friction scale mu, not the lead 0.16 P): what a_eff / a and c_eff / c should be."""
    shares = []
    for thread, mu_th, mu_b in zip(truth.column("thread").to_pylist(), truth.column("mu_th").to_pylist(), truth.column("mu_b").to_pylist()):
        p, d2, dkm = THREADS[thread]
        friction = 0.58 * d2 * mu_th + 0.5 * dkm * mu_b
        shares.append(friction / (0.16 * p + friction))
    return float(np.median(shares))


def _noise_floor(curves: pa.Table, d: Diagnosis) -> float:
    assert d.per_tightening is not None
    target = dict(zip(curves.column("tightening_id").to_pylist(), curves.column("target_torque").to_pylist()))
    ids = d.per_tightening.column("tightening_id").to_pylist()
    n = d.per_tightening.column("n_samples").to_numpy().astype(float)
    sd = np.array([TORQUE_NOISE * target[i] for i in ids])
    return float(np.sqrt(np.sum(n * sd**2) / np.sum(n)))


def _hidden(curves: pa.Table) -> pa.Table:
    """Nothing in the columns says how the data was made."""
    return curves.drop_columns([c for c in ("strategy", "thread") if c in curves.column_names])


def _level1(d: Diagnosis) -> list[Any]:
    return [e for e in d.effects if e.level == "within_tightening"]


# ---------------------------------------------------------------------------------------------
# Clean data: nothing claimed


@pytest.mark.parametrize("clamp", [False, True])
def test_clean_data_claims_nothing(clamp: bool) -> None:
    curves, _ = tightscan.simulate(N, seed=101, fault_fraction=0.0, with_clamp_force=clamp)
    d = tightscan.diagnose(_hidden(curves))
    assert d.effects == [], [e.name for e in d.effects]
    assert not d.unexplained_structure
    # the declared model is right: its out-of-sample error is the noise (within a few %)
    floor = _noise_floor(curves, d)
    assert d.rmse_before == d.rmse_after
    assert d.rmse_before / floor < 1.05
    # whiteness is reported, and clean data passes it (quantised angle included)
    white = d.details["whiteness"]
    assert white["ar_r2"] < 0.02
    assert abs(white["lag_autocorrelation"][0]) < 0.1
    # every candidate was tried, and none passed
    tried = {c["name"] for c in d.details["rounds"][0]["candidates"]}
    assert {"speed_dependent_friction", "channel_delay", "inertia", "runout"} <= tried
    assert not any(c["significant"] for c in d.details["rounds"][0]["candidates"])


# ---------------------------------------------------------------------------------------------
# One undeclared effect at a time: named first, its parameter, error near the noise floor

EFFECT_CASES = {
    # name first expected, simulate() settings
    "speed": ("speed_dependent_friction", {"speed_friction": 0.1, "strategies": ["HDT", "CSDT"]}),
    "lowpass": ("channel_delay", {"torque_lowpass_ms": 5.0}),
    "inertia": ("inertia", {"inertia": 1e-3, "strategies": ["HDT", "CSDT"]}),
    "pressure": ("pressure_dependent_friction", {"pressure_friction": 0.3, "with_clamp_force": True}),
    "runout": ("runout", {"runout": 0.02}),
}


@pytest.mark.parametrize("case", sorted(EFFECT_CASES))
def test_undeclared_effect_is_named_first(case: str) -> None:
    expected, settings = EFFECT_CASES[case]
    curves, truth = tightscan.simulate(N, seed=202, fault_fraction=0.0, **settings)
    d = tightscan.diagnose(_hidden(curves))
    names = [e.name for e in _level1(d)]
    assert names and names[0] == expected, names
    first = _level1(d)[0]
    assert first.significant and first.description == EFFECT_NAMES[expected]
    assert first.evidence["p_value"] < first.evidence["bonferroni_alpha"]
    assert first.evidence["rmse_gain"] >= 0.01
    # nothing else is claimed
    assert len(names) == 1, names
    assert not d.unexplained_structure
    # out of sample, the error drops to near the noise floor
    floor = _noise_floor(curves, d)
    assert d.rmse_before > 1.05 * floor
    assert d.rmse_after / floor < 1.12, (d.rmse_before, d.rmse_after, floor)
    # the parameter, where the data identify it
    p = first.parameters
    share = _friction_share(truth)
    if case == "speed":
        # a_eff = a * friction share (the lead term does not depend on speed)
        assert p["a_eff"]["value"] == pytest.approx(0.1 * share, rel=0.08)
    elif case == "lowpass":
        assert p["tau_ms"]["value"] == pytest.approx(5.0, rel=0.05)
    elif case == "inertia":
        assert p["J_kg_m2"]["value"] == pytest.approx(1e-3, rel=0.03)
    elif case == "pressure":
        assert p["pressure_coefficient"]["value"] == pytest.approx(0.3 * share, rel=0.08)
    elif case == "runout":
        assert p["period_deg"] == 360.0
        assert p["amplitude"]["value"] == pytest.approx(0.02, rel=0.15)


def test_low_pass_is_told_from_inertia_and_estimated_per_strategy() -> None:
    """HDT (continuous deceleration) and CSDT (pause and restart) each identify the delay;
    the exact low-pass path keeps the estimate right where the first-order form is not."""
    for strategy in ("HDT", "CSDT"):
        curves, _ = tightscan.simulate(300, seed=303, fault_fraction=0.0, strategies=[strategy], torque_lowpass_ms=2.0)
        d = tightscan.diagnose(_hidden(curves))
        first = _level1(d)[0]
        assert first.name == "channel_delay"
        assert first.parameters["tau_ms"]["value"] == pytest.approx(2.0, rel=0.06)
    # at constant speed (CST) a delay is a shift of the elastic line: not identifiable
    curves, _ = tightscan.simulate(300, seed=303, fault_fraction=0.0, strategies=["CST"], torque_lowpass_ms=5.0)
    assert tightscan.diagnose(_hidden(curves)).effects == []


def test_prevailing_torque_of_a_locking_element_is_not_identifiable_within_a_curve() -> None:
    """A locking element's torque acts from engagement on, like the thread's own prevailing
    torque, which clean data already has: the declared model absorbs it (c_j, a_j), so no
    within-tightening effect may be claimed. What the data do show is the level itself."""
    clean, _ = tightscan.simulate(N, seed=404, fault_fraction=0.0, with_clamp_force=True)
    locked, _ = tightscan.simulate(N, seed=404, fault_fraction=0.0, with_clamp_force=True, prevailing_torque_nm=1.0)
    d0 = tightscan.diagnose(_hidden(clean))
    d1 = tightscan.diagnose(_hidden(locked))
    assert d1.effects == []
    assert d1.rmse_after / _noise_floor(locked, d1) < 1.05
    assert d0.per_tightening is not None and d1.per_tightening is not None
    p0 = dict(zip(d0.per_tightening.column("tightening_id").to_pylist(), d0.per_tightening.column("prevailing_torque").to_pylist()))
    p1 = dict(zip(d1.per_tightening.column("tightening_id").to_pylist(), d1.per_tightening.column("prevailing_torque").to_pylist()))
    rise = [p1[i] - p0[i] for i in p0 if i in p1 and p0[i] is not None and p1[i] is not None and math.isfinite(p0[i]) and math.isfinite(p1[i])]
    assert len(rise) > 0.8 * N
    assert np.median(rise) == pytest.approx(1.0, abs=0.05)


# ---------------------------------------------------------------------------------------------
# Input forms


def test_long_layout_and_polars_give_the_same_diagnosis() -> None:
    curves, _ = tightscan.simulate(120, seed=505, fault_fraction=0.0, torque_lowpass_ms=5.0, strategies=["CSDT"])
    curves = _hidden(curves)
    nested = tightscan.diagnose(curves)
    flat = curves.select(["tightening_id", "angle", "torque", "time", "speed"])
    lengths = pc.list_value_length(flat.column("angle"))
    long = pa.table(
        {
            "tightening_id": pa.array(np.repeat(flat.column("tightening_id").to_numpy(), lengths.to_numpy())),
            **{c: pc.list_flatten(flat.column(c)) for c in ("angle", "torque", "time", "speed")},
            "target_torque": pa.array(np.repeat(curves.column("target_torque").to_numpy(), lengths.to_numpy())),
        }
    )
    from_long = tightscan.diagnose(long)
    assert [e.name for e in from_long.effects] == [e.name for e in nested.effects] == ["channel_delay"]
    assert from_long.rmse_after == pytest.approx(nested.rmse_after, rel=1e-9)
    import polars as pl

    assert tightscan.diagnose(pl.from_arrow(curves)).rmse_after == pytest.approx(nested.rmse_after, rel=1e-12)
    with pytest.raises(TypeError):
        tightscan.diagnose([1, 2, 3])


# ---------------------------------------------------------------------------------------------
# The real runs

JSON_TYPES = {"model": str, "rmse_before": float, "rmse_after": float, "effects": list, "unexplained_structure": bool}
EFFECT_TYPES = {"name": str, "description": str, "significant": bool, "parameters": dict, "rmse_after": float, "evidence": dict, "level": str}


def _check_document(doc: dict[str, Any]) -> None:
    for key, kind in JSON_TYPES.items():
        assert isinstance(doc[key], kind), key
    for e in doc["effects"]:
        for key, kind in EFFECT_TYPES.items():
            assert isinstance(e[key], kind), (e["name"], key)
        assert e["level"] in ("within_tightening", "between_tightenings")
    json.dumps(doc, allow_nan=False)


def test_real_rexroth_runs(rexroth_s01: pa.Table) -> None:
    d = tightscan.diagnose(rexroth_s01)
    doc = d.to_dict()
    _check_document(doc)
    assert d.details["tightenings"] > 4500  # nearly every run has phases
    assert d.details["group_by"] == ["workpiece_id", "workpiece_location"]
    assert d.rmse_after < 0.85 * d.rmse_before
    level1 = _level1(d)
    assert level1 and all(e.significant for e in level1)
    # the program's 200 -> 40 rpm step inside the elastic window is the largest structure
    assert level1[0].name in ("program_step", "speed_dependent_friction")
    # errors out of sample fall from effect to effect
    rmses = [d.rmse_before] + [e.rmse_after for e in level1]
    assert all(b < a for a, b in zip(rmses, rmses[1:]))
    # thread wear with re-use: the prevailing torque falls from ~0.7 Nm (new thread) to ~0.2
    wear = {e.name: e for e in d.effects if e.level == "between_tightenings"}
    prev = wear["prevailing_torque_vs_workpiece_usage"]
    assert prev.significant and prev.rmse_unit == "Nm"
    assert prev.evidence["p_value"] < 1e-10
    levels = prev.parameters["levels"]
    first, last = levels[next(iter(levels))]["mean"], levels[list(levels)[-1]]["mean"]
    assert first > 0.6 and last < 0.3
    # what is left is not white: the report must say so
    assert d.unexplained_structure
    assert d.details["whiteness"]["ar_r2"] > 0.05


# ---------------------------------------------------------------------------------------------
# CLI


def test_cli_writes_json_and_figures(tmp_path: Path, rexroth_s01: pa.Table) -> None:
    subset = tmp_path / "subset.parquet"
    pq.write_table(rexroth_s01.slice(0, 400), subset)
    out = tmp_path / "out" / "diagnose.json"
    assert main(["diagnose", str(subset), "--json", str(out), "--report", str(tmp_path / "report")]) == 0
    doc = json.loads(out.read_text())
    _check_document(doc)
    figures = sorted(p.name for p in (tmp_path / "report" / "figures").glob("diagnose-*.png"))
    assert figures == ["diagnose-evidence.png", "diagnose-residual-after.png", "diagnose-residual-before.png"]
    assert all((tmp_path / "report" / "figures" / f).stat().st_size > 10_000 for f in figures)


def test_cli_reads_a_rexroth_directory(tmp_path: Path, rexroth_dir: Path) -> None:
    runs = tmp_path / "s01" / "runs"
    runs.mkdir(parents=True)
    for path in sorted((rexroth_dir / "runs").glob("*.json"))[:60]:
        shutil.copy(path, runs / path.name)
    shutil.copy(rexroth_dir / "labels.csv", tmp_path / "s01" / "labels.csv")
    table = load_table(tmp_path / "s01")
    assert table.num_rows == 60 and "workpiece_usage" in table.column_names
    out = tmp_path / "d.json"
    assert main(["diagnose", str(tmp_path / "s01"), "--json", str(out), "--limit", "50"]) == 0
    doc = json.loads(out.read_text())
    _check_document(doc)
    assert doc["tightenings_in_table"] == 50
    assert main(["diagnose", str(tmp_path / "nowhere"), "--json", str(out)]) == 3  # a data error



def test_a_nested_export_with_upper_case_names_is_found(tmp_path: Path, rexroth_dir: Path) -> None:
    """diagnose searches an export as `import rexroth` does: below the directory, any case."""
    for k, path in enumerate(sorted((rexroth_dir / "runs").glob("*.json"))[:6]):
        day = tmp_path / "export" / f"day{k % 2}"
        day.mkdir(parents=True, exist_ok=True)
        shutil.copy(path, day / (path.stem + ".JSON"))
    assert load_table(tmp_path / "export").num_rows == 6

# ---------------------------------------------------------------------------------------------
# The statistics come from scipy and statsmodels, each used as its textbook says


def test_improvement_tests_are_student_t_and_the_exact_sign_test() -> None:
    from scipy import stats

    from tightscan.diagnose.fit import _one_sided_tests

    # five tightenings: the sd comes from the same five values, so the reference is t with 4
    # degrees of freedom, whose tail is several times the normal's at t = 2.4
    u = np.array([0.3, -0.1, 0.5, 0.2, 0.4])
    got = _one_sided_tests(u)
    ref = stats.ttest_1samp(u, 0.0, alternative="greater")
    t = got["t_statistic"]
    assert t == pytest.approx(float(ref.statistic), rel=1e-12)
    assert got["p_value"] == pytest.approx(float(ref.pvalue), rel=1e-12)
    # Student's t with 4 degrees of freedom in closed form (a wrong df fails here)
    cdf4 = 0.5 + 0.375 * (t / math.sqrt(1 + t * t / 4)) * (1 - t * t / (12 * (1 + t * t / 4)))
    assert got["p_value"] == pytest.approx(1 - cdf4, rel=1e-9)
    normal_tail = 0.5 * math.erfc(t / math.sqrt(2))
    assert got["p_value"] > 4 * normal_tail
    # a certain improvement everywhere: p = 0 (infinite t); no change anywhere: p = 1/2, sign p = 1
    assert _one_sided_tests(np.full(10, 0.2))["p_value"] == 0.0
    flat = _one_sided_tests(np.zeros(10))
    assert flat["p_value"] == 0.5 and flat["sign_p_value"] == 1.0

    # sign test: 9 of the 12 nonzero improvements positive, two ties left out; exact binomial
    # tail P(X >= 9 | 12, 1/2) = (220 + 66 + 12 + 1) / 4096 (the normal approximation: 0.0745)
    u = np.r_[np.full(9, 0.1), np.full(3, -0.1), np.zeros(2)]
    got = _one_sided_tests(u)
    assert got["sign_p_value"] == stats.binomtest(9, 12, 0.5, alternative="greater").pvalue
    assert got["sign_p_value"] == pytest.approx(299 / 4096, rel=1e-12)
    assert got["fraction_improved"] == 9 / 14


def _ar1(n: int, phi: float, rng: np.random.Generator) -> Any:
    e = rng.normal(size=n + 100)
    x = np.zeros_like(e)
    for i in range(1, len(e)):
        x[i] = phi * x[i - 1] + e[i]
    return x[100:]


def test_ljung_box_is_statsmodels_per_segment() -> None:
    from scipy import stats
    from statsmodels.stats.diagnostic import acorr_ljungbox

    from tightscan.diagnose.spectrum import _ljung_box

    rng = np.random.default_rng(7)
    a, b = _ar1(400, 0.5, rng), _ar1(300, 0.5, rng)
    one = _ljung_box(a, np.zeros(len(a), dtype=np.int64), 10)
    lb = acorr_ljungbox(a, lags=[10], return_df=True)
    assert one["q_sum"] == pytest.approx(float(lb["lb_stat"].iloc[0]), rel=1e-12)
    assert one["p_value"] == pytest.approx(float(lb["lb_pvalue"].iloc[0]), rel=1e-9)
    assert one["df"] == 10
    # the textbook statistic, n (n + 2) sum_k rho_k^2 / (n - k), with the sample autocorrelation
    # of the demeaned series
    d = a - a.mean()
    rho = np.array([np.sum(d[k:] * d[:-k]) for k in range(1, 11)]) / np.sum(d * d)
    n = len(a)
    assert one["q_sum"] == pytest.approx(n * (n + 2) * np.sum(rho**2 / (n - np.arange(1, 11))), rel=1e-10)
    assert one["p_value"] < 1e-10  # AR(1) with phi 0.5 is not white

    # segments are series of their own: Q adds up, no lag reaches across, and a segment too
    # short for lag 10 is left out
    r = np.r_[a, b, rng.normal(size=8)]
    seg = np.r_[np.zeros(len(a)), np.ones(len(b)), np.full(8, 2)].astype(np.int64)
    q_a = float(acorr_ljungbox(a, lags=[10], return_df=True)["lb_stat"].iloc[0])
    q_b = float(acorr_ljungbox(b, lags=[10], return_df=True)["lb_stat"].iloc[0])
    both = _ljung_box(r, seg, 10)
    assert both["q_sum"] == pytest.approx(q_a + q_b, rel=1e-12)
    assert both["df"] == 20
    assert both["p_value"] == pytest.approx(float(stats.chi2.sf(q_a + q_b, 20)), rel=1e-9)
    assert both["fraction_rejected_1pct"] == 1.0
    q_joined = float(acorr_ljungbox(np.r_[a, b], lags=[10], return_df=True)["lb_stat"].iloc[0])
    assert abs(both["q_sum"] - q_joined) > 1e-6 * q_joined


def test_spectrum_finds_a_sine_of_known_period_and_amplitude() -> None:
    from tightscan.diagnose.spectrum import _Long, _periodogram, _power_spectra

    rng = np.random.default_rng(11)
    period, amplitude, noise = 45.0, 0.05, 0.02
    n_t = 40
    theta = np.arange(0.0, 760.0, 1.0)
    gid = np.repeat(np.arange(n_t), len(theta))
    th = np.tile(theta, n_t)
    phase = rng.uniform(0, 2 * np.pi, n_t)[gid]
    drift = 0.01 * ((th - 380) / 380) ** 2
    resid = amplitude * np.sin(2 * np.pi * th / period + phase) + drift + rng.normal(0, noise, len(th))

    # the power spectrum puts the sine at its frequency with power A^2 / 2 (720 deg on 512 points)
    step = 720.0 / 512
    grid = 39.0 + step * np.arange(512)
    rows = np.array([np.interp(grid, theta, resid[gid == j]) for j in range(n_t)])
    freq, power = _power_spectra(rows, step)
    mean_power = power.mean(axis=0)
    k = int(np.argmax(mean_power[3:])) + 3
    assert 1.0 / freq[k] == pytest.approx(period, rel=1e-9)
    assert mean_power[k] == pytest.approx(amplitude**2 / 2, rel=0.1)

    # the averaged periodogram of the diagnosis reports that peak first, and nothing in noise alone
    span = np.full(n_t, theta[-1] - theta[0])
    count = np.full(n_t, float(len(theta)))
    level = np.ones(n_t)
    info = _periodogram(_Long(gid, th, resid, level, span, count), n_t)
    assert info["window_deg"] == 720.0 and info["segments"] == n_t
    # (the period is the centroid of the peak's lobe, the amplitude from its excess power)
    assert info["peaks"] and info["peaks"][0]["period_deg"] == pytest.approx(period, rel=1e-3)
    assert info["peaks"][0]["power_ratio"] > 10
    assert info["peaks"][0]["p_value"] < 1e-6
    assert info["peaks"][0]["amplitude_nm"] == pytest.approx(amplitude, rel=0.1)
    quiet = _periodogram(_Long(gid, th, rng.normal(0, noise, len(th)), level, span, count), n_t)
    assert quiet["peaks"] == []
