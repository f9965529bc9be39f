"""scan_parquet holds a few batches, not a file: deterministic checks on Arrow's own memory
accounting (bytes allocated, not timings and not the RSS)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import tightscan
from tightscan import _scan

N = 200
BATCH = 20
BIG = 3000


@pytest.fixture(scope="module")
def one_row_group(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """N tightenings in ONE row group: pyarrow.dataset's scanner would decode it whole."""
    curves, _ = tightscan.simulate(N, seed=11)
    path = tmp_path_factory.mktemp("mem") / "curves.parquet"
    pq.write_table(curves, path, row_group_size=N)
    return path


@pytest.fixture(scope="module")
def big_row_group(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """BIG tightenings (~55 MB decoded) in one row group, for the reader alone (no detection)."""
    curves, _ = tightscan.simulate(BIG, seed=12)
    path = tmp_path_factory.mktemp("mem") / "big.parquet"
    pq.write_table(curves, path, row_group_size=BIG)
    return path


def _decoded_bytes(path: Path) -> int:
    meta = pq.read_metadata(path)
    return sum(meta.row_group(i).total_byte_size for i in range(meta.num_row_groups))


# Runs in a process of its own, so that the memory pool's peak is the reader's alone.
READER = """
import json, sys
import pyarrow as pa
from tightscan import _scan
setup = _scan._plan_scan(sys.argv[1], sys.argv[2], batch_size=int(sys.argv[3]))
task = setup.tasks[0]
schema, cols = _scan._check_file(task, setup.plan)
sizes = [b.num_rows for b in _scan._parquet_batches(task, setup.plan, schema, cols)]
print(json.dumps({"sizes": sizes, "peak": pa.default_memory_pool().max_memory()}))
"""


def test_the_reader_decodes_a_batch_at_a_time(big_row_group: Path, tmp_path: Path) -> None:
    out = subprocess.run(
        [sys.executable, "-c", READER, str(big_row_group), str(tmp_path / "r.parquet"), str(BATCH)],
        capture_output=True, text=True, check=True,
    )
    got = json.loads(out.stdout)
    assert got["sizes"] == [BATCH] * (BIG // BATCH)  # batch_size honoured inside the row group
    if not got["peak"]:
        pytest.skip("this memory pool does not report its peak")
    # a batch of 20 tightenings is ~0.5 MB; the read buffers (1 MB a column) are most of the
    # peak. Decoding the row group whole (pyarrow.dataset's scanner) would take all of it.
    assert got["peak"] < _decoded_bytes(big_row_group) / 3, got


def test_results_do_not_keep_their_input_batches(one_row_group: Path, tmp_path: Path) -> None:
    setup = _scan._plan_scan(one_row_group, tmp_path / "r.parquet", batch_size=BATCH)
    before = pa.total_allocated_bytes()
    results = list(_scan._detect_file(setup.tasks[0], setup.plan))
    held = pa.total_allocated_bytes() - before
    assert sum(r.num_rows for r in results) == N and len(results) == N // BATCH
    # the results' own copies (~430 B a tightening), not the curves (~25 KB a tightening)
    assert held < _decoded_bytes(one_row_group) / 10, held


def test_auto_batches_are_about_batch_bytes(one_row_group: Path, tmp_path: Path) -> None:
    setup = _scan._plan_scan(one_row_group, tmp_path / "r.parquet")
    rows = _scan._batch_rows(setup.plan, pq.read_metadata(one_row_group), long_layout=False)
    per_row = _decoded_bytes(one_row_group) / N
    assert rows == int(_scan.BATCH_BYTES // per_row)
    assert 100 < rows < 5000  # ~25 KB per simulated tightening: several hundred per batch


def test_streamed_single_file_equals_detect_batch(one_row_group: Path, tmp_path: Path) -> None:
    out = tmp_path / "results.parquet"
    summary = tightscan.scan_parquet(one_row_group, out, batch_size=BATCH * 3, progress=False)
    assert summary.tightenings == N
    written = pq.read_table(out)
    expected = tightscan.detect_batch(pq.read_table(one_row_group))
    assert written.equals(expected.cast(written.schema))
    # results gathered into row groups, not one per batch of 60
    assert pq.read_metadata(out).num_row_groups == 1


def test_detect_batch_results_do_not_keep_their_input(one_row_group: Path) -> None:
    # The engine copies the id and pass-through columns: a zero-copy slice of an input that came
    # through the Arrow C interface kept the whole input (every curve) alive with the results.
    import gc

    base = pa.total_allocated_bytes()
    curves = pq.read_table(one_row_group)
    results = tightscan.detect_batch(curves, passthrough=["strategy"])
    del curves
    gc.collect()
    held = pa.total_allocated_bytes() - base
    assert results.num_rows == N
    assert held < _decoded_bytes(one_row_group) / 10, held
