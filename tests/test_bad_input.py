"""Bad tightenings get a status and keep their row; bad tables raise, naming the column."""

from __future__ import annotations

import math

import pyarrow as pa
import pytest

import tightscan

GOOD_ANGLE = [i * 0.25 for i in range(400)]
GOOD_TORQUE = [0.1 if i < 80 else 0.1 + 0.075 * (i - 80) for i in range(400)]


def _table(rows: list[tuple[object, object]], **extra: pa.Array) -> pa.Table:
    angle, torque = zip(*rows)
    return pa.table(
        {
            "tightening_id": list(range(len(rows))),
            "angle": pa.array(list(angle), pa.list_(pa.float64())),
            "torque": pa.array(list(torque), pa.list_(pa.float64())),
            **extra,
        }
    )


CASES = [
    ((GOOD_ANGLE, GOOD_TORQUE), "ok"),
    (([], []), "empty"),
    ((GOOD_ANGLE[:5], GOOD_TORQUE[:5]), "too_short"),
    ((GOOD_ANGLE, GOOD_TORQUE[:-1]), "length_mismatch"),
    ((GOOD_ANGLE, GOOD_TORQUE[:200] + [math.nan] + GOOD_TORQUE[201:]), "non_finite"),
    ((GOOD_ANGLE, GOOD_TORQUE[:200] + [math.inf] + GOOD_TORQUE[201:]), "non_finite"),
    ((GOOD_ANGLE, GOOD_TORQUE[:10] + [None] + GOOD_TORQUE[11:]), "null_values"),
    ((GOOD_ANGLE, [2.0] * 400), "flat_signal"),
    ((None, GOOD_TORQUE), "null_tightening"),
    ((GOOD_ANGLE, GOOD_TORQUE), "ok"),
]


def test_each_bad_tightening_gets_its_status() -> None:
    out = tightscan.detect_batch(_table([c[0] for c in CASES]))
    assert out.column("tightening_id").to_pylist() == list(range(len(CASES)))
    codes = [s.split(":")[0] for s in out.column("status").to_pylist()]
    assert codes == [c[1] for c in CASES]
    for status, detected in zip(out.column("status").to_pylist(), out.column("change_detected").to_pylist()):
        assert (detected is None) == (status != "ok")


def test_status_names_the_channel() -> None:
    speed = pa.array([[1.0] * 400, [1.0] * 399], pa.list_(pa.float64()))
    out = tightscan.detect_batch(_table([(GOOD_ANGLE, GOOD_TORQUE)] * 2, speed=speed))
    assert out.column("status").to_pylist() == ["ok", "length_mismatch: speed has 399 samples, angle has 400"]


@pytest.mark.parametrize(
    ("table", "column"),
    [
        (pa.table({"angle": pa.array([[1.0]], pa.list_(pa.float64()))}), "torque"),
        (pa.table({"torque": pa.array([[1.0]], pa.list_(pa.float64()))}), "angle"),
        (
            pa.table({"angle": pa.array([[1.0]], pa.list_(pa.float64())), "torque": pa.array([["x"]])}),
            "torque",
        ),
        (pa.table({"angle": pa.array(["a"]), "torque": pa.array(["b"])}), "angle"),
        (pa.table({"angle": [1.0], "torque": [2.0]}), "tightening_id"),
        (
            pa.table(
                {
                    "tightening_id": [1.5],
                    "angle": pa.array([[1.0]], pa.list_(pa.float64())),
                    "torque": pa.array([[1.0]], pa.list_(pa.float64())),
                }
            ),
            "tightening_id",
        ),
    ],
)
def test_bad_tables_raise_schema_error_naming_the_column(table: pa.Table, column: str) -> None:
    with pytest.raises(tightscan.SchemaError) as e:
        tightscan.detect_batch(table)
    assert e.value.column == column
    assert f"'{column}'" in str(e.value)
    assert isinstance(e.value, ValueError)


def test_bad_parameters_raise_naming_the_parameter() -> None:
    table = _table([(GOOD_ANGLE, GOOD_TORQUE)])
    with pytest.raises(tightscan.InvalidParameterError) as e:
        tightscan.detect_batch(table, {"kappa": -1.0})
    assert e.value.parameter == "kappa"
    with pytest.raises(tightscan.InvalidParameterError) as e:
        tightscan.detect_batch(table, {"no_such": 1})
    assert e.value.parameter == "no_such"
    with pytest.raises(tightscan.InvalidParameterError) as e:
        tightscan.detect_batch(table, {"kappa": "high"})
    assert e.value.parameter == "kappa"
    with pytest.raises(tightscan.SchemaError):
        tightscan.detect_batch(table, passthrough=["station"])


def test_not_a_table_is_a_type_error() -> None:
    with pytest.raises(TypeError):
        tightscan.detect_batch([1, 2, 3])


def _short_rise(rise_samples: int) -> tuple[list[float], list[float]]:
    """A rundown and a final rise of `rise_samples` samples, with a little deterministic noise."""
    angle = [i * 0.5 for i in range(60 + rise_samples)]
    torque = [
        0.1 + (0.0 if i < 60 else 0.4 * (i - 60)) + 0.002 * math.sin(1.7 * i * i) for i in range(60 + rise_samples)
    ]
    return angle, torque


def test_a_window_too_short_for_the_cusum_is_still_analysed_by_the_break_scan() -> None:
    """The CUSUM needs 50 samples in the window, the break scan 20: with about 35 the row is
    `ok`, decided by the scan, and the CUSUM's columns are null; with about 17 it cannot run,
    the row is `too_short` and keeps its phases."""
    out = tightscan.detect_batch(_table([_short_rise(45), _short_rise(22)])).to_pylist()
    analysed, short = out
    assert analysed["status"] == "ok"
    assert analysed["change_detected"] is False and analysed["break_p_value"] is not None
    assert analysed["cusum_max_statistic"] is None and analysed["cusum_alarm"] is None
    assert short["status"].startswith("too_short")
    assert short["change_detected"] is None and short["torque_rate"] is not None
