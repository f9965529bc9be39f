"""Importing Bosch Rexroth JSON exports: the 5,000 real runs, broken files, restarting axes,
labels, and the CLI. The real data is required: CI has it, so its absence fails, never skips."""

from __future__ import annotations

import json
import os
import shutil
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

import tightscan

from tightscan.cli import main
from tightscan.rexroth import ANGLE_RESTART_TOLERANCE_DEG, read_rexroth, rexroth_schema, write_rexroth

REPO = Path(__file__).resolve().parents[1]
N_RUNS = 5000
# Real runs picked for their step counts (4, 3, 2 and 1 steps).
FOUR_STEPS = "Ch_000001596334.json"


def _row(table: pa.Table, file_name: str) -> dict[str, Any]:
    rows: list[dict[str, Any]] = table.filter(pc.equal(table.column("file_name"), file_name)).to_pylist()
    assert len(rows) == 1
    return rows[0]


def _as_parquet(table: pa.Table) -> pa.Table:
    """Parquet has no seconds unit: timestamp[s] columns come back as timestamp[ms]."""
    schema = pa.schema(
        [f.with_type(pa.timestamp("ms")) if f.type == pa.timestamp("s") else f for f in table.schema]
    )
    return table.cast(schema)


def _file_with_steps(rexroth_dir: Path, rexroth_s01: pa.Table, n_steps: int) -> Path:
    names: list[str] = rexroth_s01.filter(pc.equal(rexroth_s01.column("n_steps"), n_steps)).column("file_name").to_pylist()
    return rexroth_dir / "runs" / names[0]


# ---------------------------------------------------------------------------------------------
# The real runs


def test_every_real_run_imports(rexroth_s01: pa.Table, rexroth_dir: Path) -> None:
    assert rexroth_s01.num_rows == N_RUNS
    assert set(rexroth_s01.column("import_status").to_pylist()) == {"ok"}
    assert dict(Counter(rexroth_s01.column("n_steps").to_pylist())) == {4: 4151, 2: 766, 3: 82, 1: 1}
    assert dict(Counter(rexroth_s01.column("result").to_pylist())) == {"OK": 4089, "NOK": 911}
    names = rexroth_s01.column("file_name").to_pylist()
    assert names == sorted(p.name for p in (rexroth_dir / "runs").glob("*.json"))
    assert rexroth_s01.column("tightening_id").equals(rexroth_s01.column("cycle"))
    assert rexroth_s01.column("tightening_id").to_pylist() == [int(n[3:-5]) for n in names]
    assert rexroth_s01.schema.field("date").type == pa.timestamp("s")
    assert set(rexroth_s01.column("program").to_pylist()) == {"SMW_4step"}
    assert set(rexroth_s01.column("nominal_torque").to_pylist()) == {6.0}  # the tool's, not the target
    assert rexroth_s01.column("tool_serial").null_count == 0
    # The schema up to the channels is the documented one; labels come after it.
    assert rexroth_s01.schema.names[: len(rexroth_schema().names)] == rexroth_schema().names


def test_channels_and_steps_are_consistent(rexroth_s01: pa.Table) -> None:
    channels = ["time", "angle", "torque", "gradient", "step"]
    lengths = [pc.list_value_length(rexroth_s01.column(c)).to_numpy() for c in channels]
    for c, n in zip(channels[1:], lengths[1:]):
        assert np.array_equal(n, lengths[0]), c
    assert lengths[0].min() > 0
    cols = {c: rexroth_s01.column(c).to_pylist() for c in ["angle", "time", "step", "step_start_index", "n_steps"]}
    for i in range(rexroth_s01.num_rows):
        angle, t, step = np.array(cols["angle"][i]), np.array(cols["time"][i]), np.array(cols["step"][i])
        starts, n_steps = cols["step_start_index"][i], cols["n_steps"][i]
        assert len(starts) == n_steps and starts[0] == 0
        # the step channel counts up by one exactly where step_start_index says
        assert step[0] == 0 and step[-1] == n_steps - 1
        assert np.flatnonzero(np.diff(step)).tolist() == [s - 1 for s in starts[1:]]
        assert set(np.diff(step).tolist()) <= {0, 1}
        for s in starts[1:]:
            assert angle[s] >= angle[s - 1], (i, s)
            # this export repeats the join sample: a step starts where the last one ended
            assert angle[s] == angle[s - 1] and t[s] == t[s - 1]
        assert np.all(np.diff(t) >= 0)


def test_step_targets(rexroth_s01: pa.Table) -> None:
    n_steps = np.array(rexroth_s01.column("n_steps").to_pylist())
    target = np.array(rexroth_s01.column("target_torque").to_pylist(), dtype=float)  # None -> nan
    assert np.all(target[n_steps == 4] == 1.4)
    assert np.all(target[n_steps == 3] == 1.1)  # stopped after pre-tightening
    assert np.all(np.isnan(target[n_steps <= 2]))  # finding/thread forming have no TF Torque
    row = _row(rexroth_s01, FOUR_STEPS)
    assert row["step_names"] == ["Finding", "Thread forming", "Pre-tightening", "Tightening 1.4"]
    assert row["step_target_torque"] == [None, None, 1.1, 1.4]
    assert row["step_target_angle"] == [100.0, 1400.0, None, None]
    assert row["step_speeds"] == [150.0, 600.0, 200.0, 40.0]
    assert row["step_results"] == ["OK"] * 4
    assert row["step_start_index"] == [0, 96, 423, 551]
    assert len(row["angle"]) == 96 + 327 + 128 + 73
    assert row["angle"][0] == 0.0 and row["angle"][-1] == 1696.0
    assert row["torque"][550:553] == [1.108, 1.108, 1.159]


def test_labels_join_every_run(rexroth_s01: pa.Table) -> None:
    usage = rexroth_s01.column("workpiece_usage")
    assert usage.null_count == 0
    assert pc.min(usage).as_py() == 0 and pc.max(usage).as_py() == 24
    assert set(Counter(usage.to_pylist()).values()) == {200}  # 100 workpieces x 2 positions
    assert Counter(rexroth_s01.column("workpiece_location").to_pylist()) == {"left": 2500, "right": 2500}
    assert "run_id" not in rexroth_s01.column_names  # the key is not repeated
    # the labels' own file_name collides with ours: prefixed, and it matches row for row
    assert rexroth_s01.column("label_file_name").equals(rexroth_s01.column("file_name"))
    # independent fields agree, so the join matched the right runs and the date parsed right
    assert rexroth_s01.column("workpiece_date").equals(rexroth_s01.column("date"))
    assert rexroth_s01.column("workpiece_result").equals(rexroth_s01.column("result"))
    assert pc.cast(rexroth_s01.column("id_code"), pa.int64()).equals(rexroth_s01.column("workpiece_id"))


def test_detect_batch_gives_one_row_per_run(rexroth_s01: pa.Table) -> None:
    results = tightscan.detect_batch(rexroth_s01, passthrough=["file_name", "workpiece_usage"])
    assert isinstance(results, pa.Table)
    assert results.num_rows == N_RUNS
    assert results.column("tightening_id").equals(rexroth_s01.column("tightening_id"))
    assert results.column("file_name").equals(rexroth_s01.column("file_name"))
    statuses = results.column("status").to_pylist()
    codes = Counter(s.split(":")[0] for s in statuses)
    assert "null_tightening" not in codes and "length_mismatch" not in codes
    assert codes["ok"] > 0
    assert "loosening" not in codes and "flat_signal" not in codes  # real tightenings, all of them
    # No ok row has its snug angle outside its curve's angles.
    ok = pc.starts_with(results.column("status"), "ok")
    snug = results.column("snug_angle").filter(ok).to_numpy()
    angles = rexroth_s01.column("angle").filter(ok).to_pylist()
    assert all(min(a) <= s <= max(a) for a, s in zip(angles, snug))


# ---------------------------------------------------------------------------------------------
# Broken files


def _load(path: Path) -> dict[str, Any]:
    doc: dict[str, Any] = json.loads(path.read_text())
    return doc


def test_broken_files_get_a_row_and_a_status(tmp_path: Path, rexroth_dir: Path, rexroth_s01: pa.Table) -> None:
    runs = rexroth_dir / "runs"
    good = sorted(runs.glob("*.json"))[:3]
    for p in good:
        shutil.copy(p, tmp_path / p.name)
    source = _load(runs / FOUR_STEPS)
    text = (runs / FOUR_STEPS).read_text()
    (tmp_path / "Ch_000000000001.json").write_text(text[: len(text) // 2])  # truncated

    no_graph = json.loads(text)
    no_graph["cycle"] = 2
    del no_graph["tightening steps"][1]["graph"]
    (tmp_path / "Ch_000000000002.json").write_text(json.dumps(no_graph))

    unequal = json.loads(text)
    unequal["cycle"] = 3
    unequal["tightening steps"][1]["graph"]["torque values"].pop()
    (tmp_path / "Ch_000000000003.json").write_text(json.dumps(unequal))

    text_value = json.loads(text)
    text_value["cycle"] = 4
    text_value["tightening steps"][2]["graph"]["angle values"][5] = "n/a"
    (tmp_path / "Ch_000000000004.json").write_text(json.dumps(text_value))

    boolean = json.loads(text)
    boolean["cycle"] = 5
    boolean["tightening steps"][0]["graph"]["time values"][1] = True
    (tmp_path / "Ch_000000000005.json").write_text(json.dumps(boolean))

    no_steps = dict(source, cycle=6, **{"tightening steps": []})
    (tmp_path / "Ch_000000000006.json").write_text(json.dumps(no_steps))

    (tmp_path / "Ch_000000000007.json").write_text(json.dumps({k: v for k, v in source.items() if k != "tightening steps"} | {"cycle": 7}))
    (tmp_path / "notes.json").write_text("[1, 2")  # neither readable nor an id in its name

    table = read_rexroth(tmp_path, progress=False)
    assert table.num_rows == 3 + 8
    status = dict(zip(table.column("file_name").to_pylist(), table.column("import_status").to_pylist()))
    assert status["Ch_000000000001.json"].startswith("unreadable_json: ")
    assert status["Ch_000000000002.json"] == "missing_field: step 2 'Thread forming' has no 'graph'"
    assert status["Ch_000000000003.json"] == (
        "length_mismatch: step 2 'Thread forming' has 327 angle values and 326 torque values"
    )
    assert status["Ch_000000000004.json"] == "bad_values: step 3 'Pre-tightening' angle values[5] is \"n/a\", not a number"
    assert status["Ch_000000000005.json"] == "bad_values: step 1 'Finding' time values[1] is true, not a number"
    assert status["Ch_000000000006.json"] == "no_steps: 'tightening steps' is empty"
    assert status["Ch_000000000007.json"] == "missing_field: no 'tightening steps'"
    assert status["notes.json"].startswith("unreadable_json: ")
    for p in good:
        assert status[p.name] == "ok"

    broken = table.filter(pc.not_equal(table.column("import_status"), "ok"))
    assert broken.num_rows == 8
    for c in ["time", "angle", "torque", "gradient", "step", "step_names", "step_start_index", "target_torque"]:
        assert broken.column(c).null_count == 8, c
    ids = dict(zip(table.column("file_name").to_pylist(), table.column("tightening_id").to_pylist()))
    assert ids["Ch_000000000001.json"] == 1  # unreadable: from the file name
    assert ids["Ch_000000000002.json"] == 2 and ids["Ch_000000000007.json"] == 7  # from `cycle`
    assert ids["notes.json"] is None
    # a readable but broken file keeps its top-level metadata
    row = _row(table, "Ch_000000000003.json")
    assert row["result"] == "OK" and row["program"] == "SMW_4step" and row["n_steps"] == 4

    # good rows are exactly what the full import made of them
    ok = table.filter(pc.equal(table.column("import_status"), "ok"))
    assert ok.column("file_name").to_pylist() == [p.name for p in good]
    expected = rexroth_s01.slice(0, 3).select(ok.column_names)
    assert ok.equals(expected)

    # the engine sees the broken rows as null tightenings, one row each, in order
    results = tightscan.detect_batch(table, passthrough=["import_status"])
    assert isinstance(results, pa.Table)
    assert results.num_rows == table.num_rows
    assert results.column("tightening_id").equals(table.column("tightening_id"))
    for s, imported in zip(results.column("status").to_pylist(), table.column("import_status").to_pylist()):
        if imported != "ok":
            assert s.startswith("null_tightening"), s


# ---------------------------------------------------------------------------------------------
# Axes that restart at each step


def _restart(doc: dict[str, Any], channels: tuple[str, ...]) -> dict[str, Any]:
    """The same run as an export that starts ``channels`` at 0 in every step."""
    out: dict[str, Any] = json.loads(json.dumps(doc))
    for step in out["tightening steps"]:
        graph = step["graph"]
        for key in channels:
            first = graph[key][0]
            graph[key] = [v - first for v in graph[key]]
    return out


@pytest.mark.parametrize("channels", [("angle values", "time values"), ("angle values",), ("time values",)])
def test_restarting_axes_become_cumulative(tmp_path: Path, rexroth_dir: Path, rexroth_s01: pa.Table, channels: tuple[str, ...]) -> None:
    # The rule: a step whose first value lies below the previous step's (already offset) last
    # value by more than the tolerance is shifted to start exactly at that last value. This data
    # set repeats the join sample, so the shifted copy must give back the original axes.
    originals = [rexroth_dir / "runs" / FOUR_STEPS, _file_with_steps(rexroth_dir, rexroth_s01, 3), _file_with_steps(rexroth_dir, rexroth_s01, 2)]
    for p in originals:
        (tmp_path / p.name).write_text(json.dumps(_restart(_load(p), channels)))
    restarted = read_rexroth([tmp_path / p.name for p in originals], progress=False)
    assert restarted.column("import_status").to_pylist() == ["ok"] * 3
    # the copies really restart: every later step begins at 0
    assert _load(tmp_path / FOUR_STEPS)["tightening steps"][3]["graph"][channels[0]][0] == 0
    for p, row in zip(originals, restarted.to_pylist()):
        want = _row(rexroth_s01, p.name)
        for c in ["angle", "time"]:
            np.testing.assert_allclose(row[c], want[c], rtol=0, atol=1e-9, err_msg=f"{p.name} {c}")
            for s in row["step_start_index"][1:]:
                assert row[c][s] == row[c][s - 1]  # starts where the last step ended
        assert row["torque"] == want["torque"] and row["step"] == want["step"]


def test_small_backward_step_is_not_a_restart(tmp_path: Path, rexroth_dir: Path) -> None:
    doc = _load(rexroth_dir / "runs" / FOUR_STEPS)
    graph = doc["tightening steps"][1]["graph"]
    back = ANGLE_RESTART_TOLERANCE_DEG / 2
    graph["angle values"] = [v - back for v in graph["angle values"]]  # real reversal, kept
    shifted = doc["tightening steps"][2]["graph"]
    shifted["angle values"] = [v - 3 * ANGLE_RESTART_TOLERANCE_DEG for v in shifted["angle values"]]  # restart
    (tmp_path / "run.json").write_text(json.dumps(doc))
    row = read_rexroth(tmp_path / "run.json", progress=False).to_pylist()[0]
    starts = row["step_start_index"]
    assert row["angle"][starts[1]] == pytest.approx(row["angle"][starts[1] - 1] - back)
    assert row["angle"][starts[2]] == row["angle"][starts[2] - 1]


# ---------------------------------------------------------------------------------------------
# Paths, labels, options


def test_paths_globs_lists_and_errors(tmp_path: Path, rexroth_dir: Path) -> None:
    runs = rexroth_dir / "runs"
    picked = sorted(runs.glob("*.json"))[10:14]
    listed = read_rexroth([picked[2], picked[0]], progress=False)
    assert listed.column("file_name").to_pylist() == [picked[2].name, picked[0].name]  # as given
    globbed = read_rexroth(str(runs / "Ch_00000159634*.json"), progress=False)
    assert globbed.num_rows == 10
    assert globbed.column("file_name").to_pylist() == sorted(globbed.column("file_name").to_pylist())
    assert read_rexroth(str(picked[1]), progress=False).num_rows == 1

    with pytest.raises(tightscan.DataFileError) as e:
        read_rexroth(tmp_path / "nope", progress=False)
    assert e.value.path == str(tmp_path / "nope")
    with pytest.raises(tightscan.DataFileError) as e:
        read_rexroth(tmp_path, progress=False)  # a directory without *.json
    assert e.value.path == str(tmp_path)
    assert isinstance(e.value, OSError)
    with pytest.raises(tightscan.DataFileError):
        read_rexroth(str(tmp_path / "*.json"), progress=False)


def test_labels_from_a_table_keys_cast_and_errors(tmp_path: Path, rexroth_dir: Path) -> None:
    files = sorted((rexroth_dir / "runs").glob("*.json"))[:5]
    ids = [int(p.name[3:-5]) for p in files]
    labels = pa.table({"run_id": [str(i) for i in ids[1:]][::-1], "usage": [1, 2, 3, 4], "result": ["a", "b", "c", "d"]})
    table = read_rexroth(files, labels=labels, progress=False)
    assert table.column("tightening_id").to_pylist() == ids  # order and rows kept
    assert table.column("usage").to_pylist() == [None, 4, 3, 2, 1]  # string keys cast to int64
    assert table.column("label_result").to_pylist() == [None, "d", "c", "b", "a"]
    assert table.column("result").equals(read_rexroth(files, progress=False).column("result"))  # untouched

    by_name = read_rexroth(files, labels=rexroth_dir / "labels.csv", on=("file_name", "file_name"), progress=False)
    assert by_name.column("run_id").to_pylist() == ids

    with pytest.raises(tightscan.SchemaError) as e:
        read_rexroth(files, labels=labels.rename_columns(["id", "usage", "result"]), progress=False)
    assert e.value.column == "run_id"
    with pytest.raises(tightscan.SchemaError) as e:
        read_rexroth(files, labels=labels, on=("workpiece", "run_id"), progress=False)
    assert e.value.column == "workpiece"
    with pytest.raises(tightscan.SchemaError) as e:
        read_rexroth(files, labels=pa.table({"run_id": ["x"]}), progress=False)
    assert e.value.column == "run_id"
    with pytest.raises(tightscan.SchemaError) as e:
        read_rexroth(files, labels=pa.table({"run_id": [ids[0], ids[0]]}), progress=False)
    assert e.value.column == "run_id"
    with pytest.raises(tightscan.DataFileError):
        read_rexroth(files, labels=tmp_path / "labels.csv", progress=False)


def test_redundant_channels_write_and_progress(tmp_path: Path, rexroth_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    files = sorted((rexroth_dir / "runs").glob("*.json"))[:20]
    table = read_rexroth(files, keep_redundant=True, progress=True)
    assert table.schema.names == rexroth_schema(keep_redundant=True).names
    assert table.schema.names[-3:] == ["step", "torque_red", "angle_red"]
    for c in ["torque_red", "angle_red"]:
        assert set(pc.list_flatten(table.column(c)).to_pylist()) == {0.0}  # unused transducer
    assert "torque_red" not in read_rexroth(files[:1], progress=False).column_names
    capsys.readouterr()

    out = tmp_path / "runs.parquet"
    assert write_rexroth(files, out, compression="snappy", progress=False) == 20
    meta = pq.read_metadata(out)
    assert meta.num_rows == 20 and meta.row_group(0).column(0).compression == "SNAPPY"
    assert pq.read_table(out).equals(_as_parquet(read_rexroth(files, progress=False)))
    with pytest.raises(tightscan.InvalidParameterError) as e:
        write_rexroth(files, out, compression="gzip")
    assert e.value.parameter == "compression"


# ---------------------------------------------------------------------------------------------
# Command line


def test_cli_import_rexroth(tmp_path: Path, rexroth_dir: Path, rexroth_s01: pa.Table, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "runs"
    src.mkdir()
    picked = sorted((rexroth_dir / "runs").glob("*.json"))[::100]
    assert len(picked) == 50
    for p in picked:
        shutil.copy(p, src / p.name)
    out = tmp_path / "out.parquet"
    argv = ["import", "rexroth", str(src), "-o", str(out), "--labels", str(rexroth_dir / "labels.csv"), "--on", "cycle=run_id", "--no-progress"]
    assert main(argv) == 0
    captured = capsys.readouterr()
    assert "50 Rexroth runs written to" in captured.out and "50 imported, 0 failed, 0 files skipped" in captured.out
    assert captured.err == ""
    written = pq.read_table(out)
    assert written.num_rows == 50
    assert written.column("workpiece_usage").null_count == 0
    expected = rexroth_s01.take(pa.array(range(0, N_RUNS, 100)))
    assert written.equals(_as_parquet(expected))

    (src / "Ch_000000000009.json").write_text("{")
    (src / "README.txt").write_text("not an export")
    # A failed file is a data error (exit 3), named on stderr; its row is written all the same.
    assert main(["import", "rexroth", str(src), "-o", str(out), "--no-progress", "--keep-redundant"]) == 3
    captured = capsys.readouterr()
    assert "51 Rexroth runs written to" in captured.out and "50 imported, 1 failed (unreadable_json: 1), 1 files skipped" in captured.out
    assert "  failed: Ch_000000000009.json: unreadable_json: " in captured.out
    assert captured.err.startswith("tightscan: error: 1 of 51 files failed to import (first: Ch_000000000009.json: unreadable_json")
    assert len(captured.err.splitlines()) == 1
    assert "angle_red" in pq.read_schema(out).names and pq.read_metadata(out).num_rows == 51

    assert main(["import", "rexroth", str(tmp_path / "missing"), "-o", str(out)]) == 3
    assert "missing" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["import", "rexroth", str(src), "-o", str(out), "--on", "=run_id"])
    with pytest.raises(SystemExit):
        main(["import"])  # the tool format is required
