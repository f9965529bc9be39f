"""Nothing lost on faults: a scan killed with SIGKILL midway leaves no results file that
looks complete, and ``resume`` finishes it to the same results as a clean scan."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import tightscan
from tightscan._scan import _FileTask, _Plan, _plan_scan, _scan_file

N_FILES = 16
PER_FILE = 30


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("faults") / "data"
    root.mkdir()
    curves, _ = tightscan.simulate(N_FILES * PER_FILE, seed=31)
    for i in range(N_FILES):
        pq.write_table(curves.slice(i * PER_FILE, PER_FILE), root / f"day-{i:02d}.parquet", row_group_size=10)
    return root


def start_scan(source: Path, destination: Path) -> subprocess.Popen[bytes]:
    package_root = str(Path(tightscan.__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([package_root, os.environ.get("PYTHONPATH", "")]))
    code = "import sys, tightscan; tightscan.scan_parquet(sys.argv[1], sys.argv[2], batch_size=10, progress=False)"
    return subprocess.Popen([sys.executable, "-c", code, str(source), str(destination)], env=env)


def kill_when(process: subprocess.Popen[bytes], ready: object, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not ready() and process.poll() is None and time.monotonic() < deadline:  # type: ignore[operator]
        time.sleep(0.005)
    process.send_signal(signal.SIGKILL)
    process.wait()


def test_killed_scan_leaves_only_complete_files_and_resumes(tmp_path: Path, inputs: Path) -> None:
    out = tmp_path / "results"
    scan = start_scan(inputs, out)
    kill_when(scan, lambda: any(out.glob("day-*.parquet")))
    assert scan.returncode == -signal.SIGKILL
    finished = sorted(out.glob("day-*.parquet"))
    assert 1 <= len(finished) < N_FILES, "the scan was to be killed midway"
    # every file under a final name is whole: its footer reads and it holds all its rows
    for path in finished:
        assert pq.read_metadata(path).num_rows == PER_FILE
    # what was being written is hidden (a temporary name readers skip), never a final name
    assert {p for p in out.iterdir() if p.is_file() and not p.name.startswith(".")} == set(finished)
    assert tightscan.read_results(out).num_rows == PER_FILE * len(finished)
    done = len(list((out / "_tightscan").glob("*.json")))
    assert done <= len(finished)

    summary = tightscan.scan_parquet(inputs, out, resume=True)
    assert summary.resumed_files == done and summary.files == N_FILES - done
    assert summary.tightenings == N_FILES * PER_FILE
    clean = tmp_path / "clean"
    tightscan.scan_parquet(inputs, clean)
    assert tightscan.read_results(out).equals(tightscan.read_results(clean))
    assert not [p for p in out.rglob("*") if ".tightscan-tmp-" in p.name]
    # a second resume has nothing left to do
    again = tightscan.scan_parquet(inputs, out, resume=True)
    assert again.files == 0 and again.resumed_files == N_FILES


def test_killed_scan_to_one_file_leaves_no_results_file(tmp_path: Path, inputs: Path) -> None:
    out = tmp_path / "results.parquet"
    scan = start_scan(inputs, out)
    kill_when(scan, lambda: any(p.stat().st_size > 0 for p in tmp_path.glob(".results.parquet.tightscan-tmp-*")))
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir() if not p.name.startswith(".")] == []
    tightscan.scan_parquet(inputs, out)
    assert pq.read_metadata(out).num_rows == N_FILES * PER_FILE
    assert not list(tmp_path.glob(".results.parquet.tightscan-tmp-*"))  # the killed run's leftovers are gone


def test_a_retried_task_writes_its_file_once(tmp_path: Path, inputs: Path) -> None:
    """What Dask or Ray do after a worker dies: run the same file's task again."""
    out = tmp_path / "results"
    tightscan.scan_parquet(inputs, out)
    first = pq.read_table(out / "day-03.parquet")
    plan, tasks = _plan_of(inputs, out)
    task = next(t for t in tasks if t.name.endswith("day-03.parquet"))
    for _ in range(2):
        outcome = _scan_file(task, plan)
        assert outcome.error is None and outcome.outputs == [str(out / "day-03.parquet")]
    assert sorted(p.name for p in out.iterdir() if p.name.startswith("day-03")) == ["day-03.parquet"]
    assert pq.read_table(out / "day-03.parquet").equals(first)
    assert len(list((out / "_tightscan").glob("*.json"))) == N_FILES


def _plan_of(inputs: Path, out: Path) -> tuple[_Plan, list[_FileTask]]:
    setup = _plan_scan(inputs, out)
    assert isinstance(setup.plan.out_schema, pa.Schema)
    return setup.plan, setup.tasks
