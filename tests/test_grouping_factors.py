"""Level 2 of the diagnosis, grouping factors (issue 12, item 5): an operator effect is found on
the parameter it acts on, no effect is claimed where there is none (also when the operators work
mostly on one thread, and when a factor is the thread itself), bad factors are skipped with a
reason, and the statistics are the standard ones.

Operator effects: the independent generator's hand-held tools (``OperatorConfig``: the tool
housing turns back against the operator's arm by compliance x torque, which the encoder counts,
so the torque rate falls and the tightening angle grows). The built-in simulator has no operator
column; there each operator's tightenings are simulated as their own batch with the documented
``joint_stiffness_range`` scaled by that operator's factor (the same softening the arm
compliance makes) and labelled with an ``operator`` column.
"""

from __future__ import annotations

import gc
import json
import math
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
import scipy.stats as st

import independent_generator as ig
import tightscan
from tightscan.diagnose.groups import factor_columns, grouping_factor_analysis

ALPHA = 0.01  # diagnose's default


def _operator_set(compliance: tuple[float, float], offset: tuple[float, float], speed: tuple[float, float], seed: int = 3, n: int = 200) -> tuple[pa.Table, pa.Table]:
    # one thread and target, narrow friction and stiffness: the spread a single line sees
    cfg = ig.GeneratorConfig(
        n=n,
        seed=seed,
        operators=4,
        strategy="CST",
        threads=("M10",),
        target_torque_nm=(40.0, 40.0),
        axial_stiffness_per_mm=(12.0, 14.0),
        mu_th=(0.12, 0.14),
        mu_b=(0.12, 0.14),
        operator=ig.OperatorConfig(arm_compliance_deg_per_nm=compliance, angle_offset_deg=offset, speed_factor=speed),
    )
    return ig.generate(cfg)


def _claims(d: tightscan.Diagnosis) -> dict[str, Any]:
    return {e.name: e for e in d.effects if "_by_" in e.name}


def test_operator_effect_of_the_independent_generator_is_found_on_the_right_parameters() -> None:
    curves, truth = _operator_set((0.0, 0.1), (0.0, 15.0), (0.8, 1.2))
    d = tightscan.diagnose(curves)
    claims = _claims(d)
    # arm compliance: softer line and a longer angle; the prevailing torque is untouched
    assert "torque_rate_by_operator" in claims and "tightening_angle_by_operator" in claims
    assert "prevailing_torque_by_operator" not in claims
    e = claims["torque_rate_by_operator"]
    assert e.level == "between_tightenings" and e.evidence["p_value_adjusted"] < ALPHA and e.evidence["kruskal_p_value_adjusted"] < ALPHA
    assert e.evidence["correction"] == "holm" and e.evidence["family_size"] == 3
    assert sum(e.evidence["n_per_level"].values()) == e.evidence["tightenings"] > 150
    # the most compliant operator has the lowest torque rate and the longest angle
    comp = dict(zip(truth.column("operator").to_pylist(), truth.column("arm_compliance_deg_per_nm").to_pylist()))
    softest = max(comp, key=lambda k: comp[k])
    rates = {k: v["mean"] for k, v in e.parameters["levels"].items()}
    angles = {k: v["mean"] for k, v in claims["tightening_angle_by_operator"].parameters["levels"].items()}
    assert min(rates, key=lambda k: rates[k]) == softest and max(angles, key=lambda k: angles[k]) == softest
    assert all(v["se"] > 0 for v in e.parameters["levels"].values())
    es = e.parameters["effect_size"]
    assert 0.02 < es["omega_squared_partial"] <= es["eta_squared_partial"] < 1 and es["epsilon_squared"] > 0
    vc = e.parameters["variance_components"]
    assert vc["estimated"] is False or 0 < vc["icc"] < 1
    # the whole table is in the JSON, the existing keys unchanged
    doc = json.loads(d.to_json())
    assert {"model", "rmse_before", "rmse_after", "effects", "unexplained_structure", "level2", "rounds"} <= set(doc)
    g = doc["grouping_factors"]
    assert g["factors"] == ["operator"] and len(g["tests"]) == 3
    assert {t["parameter"] for t in g["tests"]} == {"torque_rate", "prevailing_torque", "tightening_angle"}
    assert g["columns_not_taken"]["strategy"].startswith("one level")


def test_operators_as_labels_only_are_not_claimed() -> None:
    curves, _ = _operator_set((0.0, 0.0), (0.0, 0.0), (1.0, 1.0))
    d = tightscan.diagnose(curves)
    assert not _claims(d)
    g = d.details["grouping_factors"]
    assert g["factors"] == ["operator"] and len(g["tests"]) == 3
    assert all(not t["significant"] for t in g["tests"])


def _builtin_operator_set(factors: list[float], n: int = 50) -> pa.Table:
    parts = []
    for k, f in enumerate(factors):
        c, _ = tightscan.simulate(
            n, seed=10 + k, first_id=k * n, fault_fraction=0.0, threads=["M10"], strategies=["CST"],
            mu_th_range=(0.12, 0.14), mu_b_range=(0.12, 0.14), joint_stiffness_range=(0.30 * f, 0.34 * f),
        )  # fmt: skip
        parts.append(c.append_column("operator", pa.array([f"op{k}"] * n)))
    tab = pa.concat_tables(parts)
    return tab.take(pa.array(np.random.default_rng(0).permutation(tab.num_rows)))  # operators interleaved


def test_operator_effect_on_the_builtin_simulator() -> None:
    # operator 2's joint looks 7 % softer (arm compliance)
    d = tightscan.diagnose(_builtin_operator_set([1.0, 1.0, 0.93, 1.0]))
    claims = _claims(d)
    assert "torque_rate_by_operator" in claims and "prevailing_torque_by_operator" not in claims
    rates = {k: v["mean"] for k, v in claims["torque_rate_by_operator"].parameters["levels"].items()}
    assert min(rates, key=lambda k: rates[k]) == "op2"
    assert rates["op2"] / np.mean([rates[k] for k in ("op0", "op1", "op3")]) == pytest.approx(0.93, abs=0.02)
    # no operator effect: nothing claimed
    assert not _claims(tightscan.diagnose(_builtin_operator_set([1.0, 1.0, 1.0, 1.0])))


def _null_sets(n_sets: int, seed: int) -> list[tuple[dict[str, tuple[Any, str, str]], dict[str, Any], Any]]:
    """Per-tightening parameters without any factor effect, three factors of random labels that
    lean on the specification cell (operators mostly on one thread), two cells far apart."""
    rng = np.random.default_rng(seed)
    out = []
    n = 120
    for _ in range(n_sets):
        cell = np.where(rng.random(n) < 0.5, "M8", "M12").astype(object)
        big = cell == "M12"
        shift = np.where(big, 5.0, 0.0)
        params = {
            "torque_rate": (shift + rng.standard_normal(n), "Nm/deg", "rate"),
            "prevailing_torque": (shift + rng.standard_t(3, n), "Nm", "prevailing"),  # heavy tails
            "tightening_angle": (10 * shift + rng.gamma(2.0, 1.0, n), "deg", "angle"),  # skewed
        }
        factors: dict[str, Any] = {}
        for name, k in (("operator", 4), ("station", 2), ("batch", 6)):
            lean = rng.integers(0, k // 2 + 1, n) + np.where(big, k - k // 2 - 1, 0)  # low levels on M8, high ones on M12
            mixed = np.where(rng.random(n) < 0.7, lean, rng.integers(0, k, n))
            factors[name] = np.array([f"{name}{int(v)}" for v in np.clip(mixed, 0, k - 1)], dtype=object)
        out.append((params, factors, cell))
    return out


def test_null_false_claim_rate_with_holm_across_factors_and_parameters(monkeypatch: pytest.MonkeyPatch) -> None:
    # statsmodels' Holm runs gc.collect() on every call (0.1-0.2 s in a test session): off here
    monkeypatch.setattr(gc, "collect", lambda *a: 0)
    alpha, n_sets = 0.05, 300
    sets_with_claim = 0
    raw_f = raw_k = tests = 0
    for params, factors, cell in _null_sets(n_sets, seed=7):
        effects, det = grouping_factor_analysis(params, factors, cell, alpha=alpha, variance_components=False, two_way=False)
        assert det["family_size"] == 9
        sets_with_claim += bool(effects)
        raw_f += sum(t["anova"]["p_value"] < alpha for t in det["tests"])
        raw_k += sum(t["kruskal_wallis"]["p_value"] < alpha for t in det["tests"])
        tests += len(det["tests"])
    rate = sets_with_claim / n_sets
    tol = 3 * math.sqrt(alpha * (1 - alpha) / n_sets)
    # family-wise: at most alpha (plus the binomial tolerance); without the correction it would
    # be about 1 - 0.95^9 = 0.37, and without the cell as a fixed effect near 1
    assert rate <= alpha + tol, rate
    # each test alone is calibrated: its raw rejection rate is alpha (not a test that never rejects)
    for raw in (raw_f, raw_k):
        assert abs(raw / tests - alpha) <= 3 * math.sqrt(alpha * (1 - alpha) / tests) + 0.01, raw / tests


def test_power_against_a_planted_level_shift_and_holm_keeps_it(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(gc, "collect", lambda *a: 0)
    rng = np.random.default_rng(11)
    found, n_sets = 0, 100
    for _ in range(n_sets):
        n = 120
        op = rng.integers(0, 4, n)
        params = {
            "torque_rate": (np.where(op == 2, 0.8, 0.0) + rng.standard_normal(n), "Nm/deg", "rate"),
            "prevailing_torque": (rng.standard_normal(n), "Nm", "prevailing"),
        }
        effects, _ = grouping_factor_analysis(params, {"operator": np.array([f"op{v}" for v in op], dtype=object), "station": np.array([f"s{v}" for v in rng.integers(0, 3, n)], dtype=object)}, alpha=0.05, variance_components=False, two_way=False)
        names = [e.name for e in effects]
        assert set(names) <= {"torque_rate_by_operator"}
        found += names == ["torque_rate_by_operator"]
    # power of the F-test alone at Holm's first step (alpha / 4), noncentral F with
    # lambda = n var(level means) / sigma^2; the claim also needs Kruskal-Wallis, a little less
    lam = 120 * np.var([0.0, 0.0, 0.8, 0.0])
    power = float(st.ncf.sf(st.f.isf(0.05 / 4, 3, 116), 3, 116, lam))
    assert 0.6 < power < 0.85
    assert found / n_sets >= power - 3 * math.sqrt(power * (1 - power) / n_sets) - 0.05, (found, power)
    assert found / n_sets <= power + 3 * math.sqrt(power * (1 - power) / n_sets) + 0.1, (found, power)


def test_one_way_statistics_are_the_standard_ones() -> None:
    rng = np.random.default_rng(2)
    lab = np.array([f"g{v}" for v in rng.integers(0, 5, 300)], dtype=object)
    y = rng.standard_normal(300) + np.array([0.0, 0.1, 0.3, 0.0, -0.2])[np.array([int(v[1]) for v in lab])]
    _, det = grouping_factor_analysis({"torque_rate": (y, "Nm/deg", "rate")}, {"operator": lab}, alpha=0.05, two_way=False)
    t = det["tests"][0]
    groups = [y[lab == g] for g in sorted(set(lab))]
    assert t["anova"]["p_value"] == pytest.approx(st.f_oneway(*groups).pvalue, rel=1e-9)
    assert t["kruskal_wallis"]["p_value"] == pytest.approx(st.kruskal(*groups).pvalue, rel=1e-9)
    f = t["anova"]["f_statistic"]
    assert t["effect_size"]["omega_squared_partial"] == pytest.approx(4 * (f - 1) / (4 * (f - 1) + 300), rel=1e-9)


def test_variance_component_of_a_random_operator_effect() -> None:
    rng = np.random.default_rng(4)
    k, per = 12, 60
    lab = np.repeat([f"op{i}" for i in range(k)], per).astype(object)
    y = np.repeat(rng.standard_normal(k), per) + rng.standard_normal(k * per)  # ICC 0.5
    _, det = grouping_factor_analysis({"torque_rate": (y, "Nm/deg", "rate")}, {"operator": lab}, two_way=False)
    vc = det["tests"][0]["variance_components"]
    assert vc["estimated"] and 0.25 < vc["icc"] < 0.75
    assert vc["residual_variance"] == pytest.approx(1.0, rel=0.1)
    # two levels: no variance between levels estimated, a reason given
    lab2 = np.array(["a", "b"] * 50, dtype=object)
    _, det2 = grouping_factor_analysis({"torque_rate": (rng.standard_normal(100), "Nm/deg", "rate")}, {"station": lab2}, two_way=False)
    assert det2["tests"][0]["variance_components"]["estimated"] is False and "levels" in det2["tests"][0]["variance_components"]["reason"]


def test_a_factor_that_is_the_thread_is_not_claimed_when_the_spec_is_in_the_cell() -> None:
    cfg = ig.GeneratorConfig(n=160, seed=5, strategy="CST", threads=("M8", "M12"))
    curves, _ = ig.generate(cfg)
    station = pa.array(["st_" + t for t in curves.column("thread").to_pylist()])
    curves = curves.append_column("station", station)
    d = tightscan.diagnose(curves, covariates=None)
    assert not _claims(d)
    g = d.details["grouping_factors"]
    assert "thread" in g["specification_columns"]
    assert all(s["skipped"].startswith("confounded with the specification cell") for s in g["skipped_tests"] if s["factor"] == "station")
    assert len([s for s in g["skipped_tests"] if s["factor"] == "station"]) == 3
    # without the specification the same column is an (apparent) station effect
    d0 = tightscan.diagnose(curves, covariates=None, spec_columns=None, grouping_factors=["station"])
    assert {"torque_rate_by_station", "prevailing_torque_by_station"} <= set(_claims(d0))


def test_bad_factors_are_skipped_with_a_reason() -> None:
    curves, _ = _operator_set((0.0, 0.0), (0.0, 0.0), (1.0, 1.0), n=60)
    n = curves.num_rows
    curves = curves.append_column("line", pa.array(["L1"] * n))
    curves = curves.append_column("batch", pa.array([None] * n, type=pa.string()))
    curves = curves.append_column("nest", pa.array(["a"] * (n - 2) + ["b", "b"]))
    d = tightscan.diagnose(curves, grouping_factors=["line", "batch", "nest", "operator"])
    g = d.details["grouping_factors"]
    skip = g["columns_not_taken"]
    assert skip["line"].startswith("one level") and "all null" in skip["batch"] and "fewer than two levels" in skip["nest"]
    assert g["factors"] == ["operator"]
    json.loads(d.to_json())
    with pytest.raises(tightscan.SchemaError):
        tightscan.diagnose(curves, grouping_factors=["no_such_column"])
    off = tightscan.diagnose(curves, grouping_factors=None)
    assert off.details["grouping_factors"]["factors"] == [] and off.details["grouping_factors"]["tests"] == []
    # direct: a level too small is left out, a parameter with no values is skipped
    y = np.r_[np.random.default_rng(0).standard_normal(40), np.nan * np.ones(10)]
    lab = np.array(["a"] * 20 + ["b"] * 18 + ["c"] * 2 + [None] * 10, dtype=object)
    _, det = grouping_factor_analysis({"p": (y, "1", "p"), "q": (np.full(50, np.nan), "1", "q")}, {"f": lab}, two_way=False)
    assert det["tests"][0]["levels_left_out"]["levels"] == ["c"] and det["tests"][0]["levels"] == 2
    assert det["skipped_tests"][0]["parameter"] == "q" and "only 0 tightenings" in det["skipped_tests"][0]["skipped"]


def test_auto_detection_of_grouping_columns() -> None:
    n = 100
    rng = np.random.default_rng(0)
    table = pa.table(
        {
            "tightening_id": np.arange(n),
            "operator": [f"op{v}" for v in rng.integers(0, 4, n)],
            "spindle": rng.integers(1, 3, n),  # integer, few levels
            "workpiece_usage": rng.integers(0, 25, n),  # a count: a covariate
            "workpiece_id": rng.integers(0, 10, n),  # an identifier
            "temperature": rng.standard_normal(n),  # continuous
            "tool": pa.array([f"t{v}" for v in rng.integers(0, 3, n)]).dictionary_encode(),
            "thread": ["M8"] * n,
            "result": ["OK"] * n,
        }
    )
    factors, skipped = factor_columns(table, np.arange(n), "auto", ["thread"])
    assert set(factors) == {"operator", "spindle", "tool"}
    assert "count" in skipped["workpiece_usage"] and skipped["workpiece_id"] == "an identifier"


def test_two_way_anova_with_interaction() -> None:
    rng = np.random.default_rng(9)
    n = 240
    op = rng.integers(0, 3, n)
    stn = rng.integers(0, 2, n)
    y = 0.3 * op + np.where((op == 2) & (stn == 1), 1.5, 0.0) + rng.standard_normal(n)
    factors = {"operator": np.array([f"op{v}" for v in op], dtype=object), "station": np.array([f"s{v}" for v in stn], dtype=object)}
    _, det = grouping_factor_analysis({"torque_rate": (y, "Nm/deg", "rate"), "prevailing_torque": (rng.standard_normal(n), "Nm", "p")}, factors, alpha=0.01)
    tw = {t["parameter"]: t for t in det["two_way"]}
    assert set(tw) == {"torque_rate", "prevailing_torque"} and tw["torque_rate"]["factors"] == ["operator", "station"]
    tab = tw["torque_rate"]["table"]
    assert {"a", "b", "interaction", "residual"} <= set(tab) and tab["interaction"]["df"] == 2 and tab["residual"]["df"] == n - 6
    assert tab["interaction"]["p_value"] < 1e-4 and tw["torque_rate"]["interaction_significant"]
    assert not tw["prevailing_torque"]["interaction_significant"]
    json.dumps(det, allow_nan=False)
    # not crossed: skipped with the reason
    stn2 = np.where(op == 0, "s0", "s1").astype(object)
    _, det2 = grouping_factor_analysis({"torque_rate": (y, "Nm/deg", "rate")}, {"operator": factors["operator"], "station": stn2})
    assert "not fully crossed" in det2["two_way"][0]["skipped"]


def test_repeated_tightenings_of_one_thread_are_not_replicates(monkeypatch: pytest.MonkeyPatch) -> None:
    # 40 threads re-used 25 times each, every thread its own level (random intercept, sd 1) and
    # a position constant per thread that does nothing: tested on the tightenings, the thread's
    # own level would look like a position effect; on the thread means it must not
    monkeypatch.setattr(gc, "collect", lambda *a: 0)
    rng = np.random.default_rng(21)
    alpha, n_sets = 0.05, 100
    with_clusters = without = 0
    for _ in range(n_sets):
        thread = np.repeat(np.arange(40), 25)
        y = rng.standard_normal(40)[thread] + 0.3 * rng.standard_normal(1000)
        pos = np.array(["left", "right"])[rng.permutation(np.arange(40) % 2)][thread].astype(object)
        params = {"prevailing_torque": (y, "Nm", "p")}
        clusters = np.array([f"t{v}" for v in thread], dtype=object)
        e1, d1 = grouping_factor_analysis(params, {"workpiece_location": pos}, clusters=clusters, alpha=alpha, variance_components=False)
        e0, _ = grouping_factor_analysis(params, {"workpiece_location": pos}, alpha=alpha, variance_components=False)
        assert d1["tests"][0]["test_unit"] == "cluster mean" and d1["tests"][0]["unit"] == "Nm" and d1["tests"][0]["units"] == 40
        with_clusters += bool(e1)
        without += bool(e0)
    assert with_clusters / n_sets <= alpha + 3 * math.sqrt(alpha * (1 - alpha) / n_sets)
    assert without / n_sets > 0.3  # pseudo-replication (0.46 measured, seed 21)
    # a factor that varies within the clusters stays on the tightenings
    op = np.array([f"op{v}" for v in rng.integers(0, 3, 1000)], dtype=object)
    _, d = grouping_factor_analysis({"p": (rng.standard_normal(1000), "Nm", "p")}, {"operator": op}, clusters=clusters, variance_components=False)
    assert d["tests"][0]["test_unit"] == "tightening" and "varies within clusters" in d["tests"][0]["clusters_note"]


def test_degenerate_designs_do_not_warn_or_raise() -> None:
    # (pytest turns warnings into errors) a parameter that does not vary, a level confined to
    # one cell (rank-deficient design), clusters whose cells differ
    rng = np.random.default_rng(3)
    lab = np.array(["a"] * 10 + ["b"] * 10, dtype=object)
    _, d = grouping_factor_analysis({"p": (np.ones(20), "1", "p")}, {"f": lab, "g": np.array(["x", "y"] * 10, dtype=object)})
    assert [t["anova"]["p_value"] for t in d["tests"]] == [1.0, 1.0] and d["two_way"][0]["skipped"] == "the parameter does not vary"
    cell = np.array(["M8"] * 30 + ["M12"] * 30, dtype=object)
    f = np.array(["a", "b", "c"] * 10 + ["a", "b"] * 15, dtype=object)  # c only on M8
    _, d = grouping_factor_analysis({"p": (rng.standard_normal(60), "1", "p")}, {"f": f}, cell)
    assert d["tests"][0]["anova"]["df"] == [2, 56]
    clusters = np.array([f"k{i // 5}" for i in range(60)], dtype=object)
    cell2 = np.where(rng.random(60) < 0.8, cell, "M10").astype(object)
    f2 = np.array([["a", "b"][(i // 5) % 2] for i in range(60)], dtype=object)
    _, d = grouping_factor_analysis({"p": (rng.standard_normal(60), "1", "p")}, {"f": f2}, cell2, clusters=clusters)
    assert d["tests"][0]["test_unit"] == "cluster mean" and d["tests"][0]["units"] == 12


def test_strategy_as_a_grouping_factor_and_mu_tot_from_the_thread_column() -> None:
    """Issue 12, item 5 (open items): CST, CSDT and HDT in one table with their ``strategy``
    column are a grouping factor like an operator, tested within the specification cells although
    the target torque varies per tightening (its quartiles form the cells; before, every
    tightening was a cell of its own and every test was skipped as confounded); ``mu_tot`` comes
    from the ISO designation of the ``thread`` column when the geometry columns are absent. On a
    clean set nothing depends on the program: no factor is claimed."""
    cfg = ig.GeneratorConfig(n=150, seed=4, strategy="mix", clamp_force=True)
    curves, truth = ig.generate(cfg)
    assert "pitch_mm" not in curves.column_names and "thread" in curves.column_names
    d = tightscan.diagnose(curves)
    g = d.details["grouping_factors"]
    assert "strategy" in g["factors"]
    tested = {(t["factor"], t["parameter"]): t for t in g["tests"]}
    for p in ("torque_rate", "prevailing_torque", "tightening_angle", "mu_tot"):
        assert ("strategy", p) in tested, g["skipped_tests"]
    assert "mu_tot" not in g or g["mu_tot"] is None
    assert _claims(d) == {}
    # mu_tot per program as the generator drew it (its mean friction, to a few %)
    mu_true = np.array(truth.column("mu_tot").to_pylist(), dtype=float)
    strategy = np.array(truth.column("strategy").to_pylist())
    for level, row in tested[("strategy", "mu_tot")]["per_level"].items():
        assert row["mean"] == pytest.approx(float(np.mean(mu_true[strategy == level])), rel=0.08)


def test_thread_table_agrees_with_the_independent_generators() -> None:
    """The engine's thread table, as diagnose reads it, against the geometry the
    independent generator wrote from ISO 261/724 on its own."""
    from tightscan.diagnose.threads import thread_geometry

    for name, t in ig.THREADS.items():
        geo = thread_geometry(name)
        assert geo is not None, name
        pitch, d2, dkm = geo
        assert pitch == t.pitch
        assert d2 == pytest.approx(t.d - 0.649519 * t.pitch, rel=1e-6)
        assert dkm == pytest.approx(0.5 * (t.dw + t.dh), rel=1e-6)
    assert thread_geometry("M10x1.25") == pytest.approx((1.25, 10 - 0.649519 * 1.25, 12.815))
    assert thread_geometry("bolt") is None and thread_geometry(None) is None
