"""Detector parameters as TOML: what `config_to_toml` writes, `config_from_toml` reads back to
the same config, for the defaults and for every kind of value a parameter can take."""

from __future__ import annotations

from pathlib import Path

import pytest

import tightscan
from tightscan.config import (
    BreakConfig,
    CusumConfig,
    DecisionConfig,
    DetectConfig,
    FrictionConfig,
    ResidualTestConfig,
    config_from_toml,
    config_to_toml,
)


def _round_trip(config: DetectConfig, tmp_path: Path) -> DetectConfig:
    path = tmp_path / "c.toml"
    path.write_text(config_to_toml(config))
    return config_from_toml(path)


def test_defaults_round_trip(tmp_path: Path) -> None:
    assert _round_trip(DetectConfig(), tmp_path) == DetectConfig()


def test_every_kind_of_value_round_trips(tmp_path: Path) -> None:
    config = DetectConfig(
        friction=FrictionConfig(thread="M10x1.25", joint_stiffness=55.5),
        cusum=CusumConfig(kappa=0.3, arl0=None, threshold=4.25),
        breaks=BreakConfig(alpha=0.002, tail_fraction=0.0),
        decision=DecisionConfig(alpha=0.05, rule=({"break": True}, {"cusum": True, "l1": False}), detectors=("break", "cusum", "l1")),
        residual_tests=ResidualTestConfig(kde=True, kde_permutations=199, shewhart_k=2.5),
    )
    back = _round_trip(config, tmp_path)
    assert back == config
    assert back.to_dict() == config.to_dict()  # what the engine reads is the same too


def test_a_config_from_a_file_runs(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text("[decision]\nalpha = 0.05\n[cusum]\nthreshold = 5\n")
    config = config_from_toml(path)
    assert config.cusum.threshold == 5.0 and isinstance(config.cusum.threshold, float)
    curves, _ = tightscan.simulate(5, seed=1)
    results = tightscan.detect_batch(curves, config=config)
    assert set(results.column("cusum_threshold").to_pylist()) <= {5.0, None}


def test_unknown_keys_are_errors_naming_key_and_file(tmp_path: Path) -> None:
    path = tmp_path / "odd.toml"
    path.write_text("[zone]\nstart = 0.1\n")
    with pytest.raises(tightscan.InvalidParameterError, match=r"odd\.toml: unknown key zone\.start \(known in \[zone\]: start_fraction"):
        config_from_toml(path)
    path.write_text("alpha = 0.05\n")  # a key outside any table
    with pytest.raises(tightscan.InvalidParameterError, match=r"unknown table \[alpha\]"):
        config_from_toml(path)
    path.write_text("[decision]\nrule = [{break = 1}]\n")
    with pytest.raises(tightscan.InvalidParameterError, match=r"decision\.rule .* wrong type"):
        config_from_toml(path)
