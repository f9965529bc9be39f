"""Dask and Ray, real ones: a local cluster each (two worker processes), the same scan as the
local engine, compared file by file; a worker that dies is retried and writes its file once."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any, Iterator

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.fs as pafs
import pyarrow.parquet as pq
import pytest

import tightscan

N_FILES = 6
PER_FILE = 20


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, pa.Table]:
    """Hive-partitioned input, and the local engine's results (a directory) to compare with."""
    base = tmp_path_factory.mktemp("engines")
    root = base / "data"
    curves, _ = tightscan.simulate(N_FILES * PER_FILE, seed=21)
    for i in range(N_FILES):
        d = root / f"station={i % 3}"
        d.mkdir(parents=True, exist_ok=True)
        pq.write_table(curves.slice(i * PER_FILE, PER_FILE), d / f"part-{i}.parquet", row_group_size=6)
    local = base / "local"
    tightscan.scan_parquet(root, local, passthrough=["station", "strategy"])
    return root, local, tightscan.read_results(local)


def assert_same_outputs(local: Path, other: Path) -> None:
    names = sorted(p.name for p in local.glob("*.parquet"))
    assert names == sorted(p.name for p in other.glob("*.parquet")) and len(names) == N_FILES
    for name in names:
        assert pq.read_table(other / name).equals(pq.read_table(local / name)), name
    assert not [p for p in other.rglob("*") if ".tightscan-tmp-" in p.name]


def _in_worker(engine: str) -> bool:
    """True in a Dask worker or a Ray worker process, False in the driver (the test)."""
    if engine == "dask":
        from distributed import get_worker

        try:
            get_worker()
        except ValueError:
            return False
        return True
    import ray

    return bool(ray.is_initialized() and ray.get_runtime_context().worker.mode == 1)  # 1: WORKER_MODE


class DieOnceHandler(pafs.FSSpecHandler):
    """Local files (through fsspec); the first worker that opens ``victim`` dies on the spot."""

    def __init__(self, marker: str, victim: str, engine: str) -> None:
        from fsspec.implementations.local import LocalFileSystem

        super().__init__(LocalFileSystem())
        self.marker, self.victim, self.engine = marker, victim, engine

    def open_input_file(self, path: str) -> Any:
        if path.endswith(self.victim) and _in_worker(self.engine) and not os.path.exists(self.marker):
            Path(self.marker).touch()
            os._exit(1)  # a crashed worker: no exception, no clean-up
        return super().open_input_file(path)


def scan_with_a_dying_worker(engine: str, root: Path, local: Path, tmp_path: Path) -> None:
    marker = tmp_path / "died"
    fs = pafs.PyFileSystem(DieOnceHandler(str(marker), "part-3.parquet", engine))
    out = tmp_path / engine
    summary = tightscan.scan_parquet(str(root), out, passthrough=["station", "strategy"], engine=engine, filesystem=fs)  # type: ignore[arg-type]
    assert marker.exists()  # a worker did die on part-3
    assert summary.files == N_FILES and summary.tightenings == N_FILES * PER_FILE
    assert_same_outputs(local, out)
    assert len(list((out / "_tightscan").glob("*.json"))) == N_FILES


# Class-scoped: each cluster is up only while its class runs (two cores, never both at once).
@pytest.fixture(scope="class")
def client() -> Iterator[Any]:
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=":0", processes=True) as cluster:
        with Client(cluster) as client:
            yield client


@pytest.fixture(scope="class")
def ray_session() -> Iterator[Any]:
    import ray

    # Recent Ray wants a token for a local cluster unless told otherwise
    saved = os.environ.get("RAY_AUTH_MODE")
    os.environ["RAY_AUTH_MODE"] = "disabled"
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        yield ray
    finally:
        ray.shutdown()
        if saved is None:
            os.environ.pop("RAY_AUTH_MODE", None)
        else:
            os.environ["RAY_AUTH_MODE"] = saved


class TestDask:

    def test_dask_engine_matches_local(self, client: Any, data: tuple[Path, Path, pa.Table], tmp_path: Path) -> None:
        root, local, results = data
        summary = tightscan.scan_parquet(root, tmp_path / "dask", passthrough=["station", "strategy"], engine="dask")
        assert summary.engine == "dask" and summary.files == N_FILES
        assert_same_outputs(local, tmp_path / "dask")
        tightscan.scan_parquet(root, tmp_path / "one.parquet", passthrough=["station", "strategy"], engine="dask")
        assert pq.read_table(tmp_path / "one.parquet").equals(results)

    def test_dead_worker_is_retried_and_writes_its_file_once(self, client: Any, data: tuple[Path, Path, pa.Table], tmp_path: Path) -> None:
        import cloudpickle

        # the workers cannot import this test module: ship the filesystem class by value
        cloudpickle.register_pickle_by_value(sys.modules[__name__])
        root, local, _ = data
        scan_with_a_dying_worker("dask", root, local, tmp_path)

    def test_detect_partitions_pandas_in_pandas_out(self, client: Any, data: tuple[Path, Path, pa.Table]) -> None:
        import dask.dataframe as dd
        import pandas as pd

        from tightscan.dask import detect_partitions

        root, _, results = data
        ddf = dd.read_parquet(str(root))
        lazy = detect_partitions(ddf, passthrough=["station", "strategy"])
        frame = lazy.compute()
        assert isinstance(frame, pd.DataFrame)
        assert all(isinstance(t, pd.ArrowDtype) for t in frame.dtypes)
        assert list(frame.columns) == list(lazy._meta.columns) == results.column_names
        got = pa.Table.from_pandas(frame, preserve_index=False).sort_by("tightening_id")
        want = results.sort_by("tightening_id")
        for name in ("tightening_id", "status", "change_detected", "change_angle", "mu_tot", "strategy"):
            assert got.column(name).to_pylist() == want.column(name).to_pylist(), name
        assert got.column("station").to_pylist() == [str(s) if isinstance(s, str) else s for s in want.column("station").to_pylist()]


class TestRay:

    def test_ray_engine_matches_local(self, ray_session: Any, data: tuple[Path, Path, pa.Table], tmp_path: Path) -> None:
        root, local, results = data
        summary = tightscan.scan_parquet(root, tmp_path / "ray", passthrough=["station", "strategy"], engine="ray")
        assert summary.engine == "ray" and summary.files == N_FILES
        assert_same_outputs(local, tmp_path / "ray")
        # a bad file comes back named, as on the local engine
        bad = tmp_path / "bad"
        bad.mkdir()
        for p in sorted(root.rglob("*.parquet"))[:2]:
            (bad / p.name).write_bytes(p.read_bytes())
        pq.write_table(pa.table({"x": [1.0]}), bad / "part-9.parquet")
        with pytest.raises(tightscan.SchemaError, match="part-9.parquet"):
            tightscan.scan_parquet(bad, tmp_path / "r.parquet", engine="ray")
        assert not (tmp_path / "r.parquet").exists()
        summary = tightscan.scan_parquet(bad, tmp_path / "r.parquet", engine="ray", on_bad_file="skip")
        assert [Path(p).name for p, _ in summary.skipped_files] == ["part-9.parquet"]

    def test_dead_worker_is_retried_and_writes_its_file_once(self, ray_session: Any, data: tuple[Path, Path, pa.Table], tmp_path: Path) -> None:
        from ray import cloudpickle

        cloudpickle.register_pickle_by_value(sys.modules[__name__])
        root, local, _ = data
        scan_with_a_dying_worker("ray", root, local, tmp_path)

    # Ray Data's own settings object warns about its own deprecated defaults (not ours to fix)
    @pytest.mark.filterwarnings("ignore::DeprecationWarning:ray.data.context")
    def test_detect_dataset_arrow_batches(self, ray_session: Any, data: tuple[Path, Path, pa.Table]) -> None:
        import ray.data

        from tightscan.ray import detect_dataset

        root, _, results = data
        # from Arrow tables (one block per file): Ray's read_parquet needs aiohttp for its path checks
        dataset = ray.data.from_arrow([pq.read_table(p) for p in sorted(root.rglob("*.parquet"))])
        out = detect_dataset(dataset, passthrough=["strategy"])
        got = pa.concat_tables(ray_session.get(out.to_arrow_refs())).sort_by("tightening_id")
        want = results.drop_columns(["station"]).sort_by("tightening_id")
        assert got.num_rows == want.num_rows
        for name in ("tightening_id", "status", "change_detected", "change_angle", "mu_tot", "strategy"):
            assert got.column(name).to_pylist() == want.column(name).to_pylist(), name
        assert pc.all(pc.equal(got.column("n_samples"), want.column("n_samples"))).as_py()
