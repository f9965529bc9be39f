"""scan_parquet where the data lives: hive partitions, URIs, globs, Datasets, pushdown,
directory destinations, bad files, and a real (local) S3 server."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.dataset as ds
import pyarrow.fs as pafs
import pyarrow.parquet as pq
import pytest

import tightscan
from tightscan.cli import main

PLANTS = ["A", "B"]
STATIONS = [1, 2, 3]
PER_FILE = 15


def write_hive(root: Path, curves: pa.Table) -> pa.Table:
    """``root/plant=P/station=S/part-0.parquet``; returns the same rows as one table with the
    partition columns (as pyarrow.dataset reads them: plant string, station int32)."""
    parts, k = [], 0
    for plant in PLANTS:
        for station in STATIONS:
            d = root / f"plant={plant}" / f"station={station}"
            d.mkdir(parents=True)
            part = curves.slice(k, PER_FILE)
            k += PER_FILE
            pq.write_table(part, d / "part-0.parquet", row_group_size=4)
            parts.append(
                part.append_column("plant", pa.array([plant] * PER_FILE)).append_column(
                    "station", pa.array([station] * PER_FILE, pa.int32())
                )
            )
    return pa.concat_tables(parts)


@pytest.fixture(scope="module")
def hive(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, pa.Table]:
    root = tmp_path_factory.mktemp("hive") / "data"
    curves, _ = tightscan.simulate(len(PLANTS) * len(STATIONS) * PER_FILE, seed=11)
    return root, write_hive(root, curves)


def test_hive_partition_columns_pass_through(tmp_path: Path, hive: tuple[Path, pa.Table]) -> None:
    root, full = hive
    out = tmp_path / "r.parquet"
    summary = tightscan.scan_parquet(root, out, passthrough=["station"], batch_size=5)
    expected = tightscan.detect_batch(full, passthrough=["station"])
    assert pq.read_table(out).equals(expected)
    assert summary.files == 6 and summary.tightenings == full.num_rows
    # passthrough=True: every non-channel column, partition keys included
    tightscan.scan_parquet(root, out, passthrough=True)
    names = pq.read_table(out).column_names
    assert {"plant", "station", "strategy", "thread"} <= set(names)
    assert pq.read_table(out).column("plant").to_pylist() == full.column("plant").to_pylist()


def test_columns_and_filter_push_down(tmp_path: Path, hive: tuple[Path, pa.Table]) -> None:
    root, full = hive
    out = tmp_path / "r.parquet"
    summary = tightscan.scan_parquet(
        root, out, columns=["tightening_id", "angle", "torque"], filter=pc.field("station") == 2, passthrough=True
    )
    results = pq.read_table(out)
    # the filter prunes whole partitions: only the station-2 files are read
    assert summary.files == 2
    wanted = full.filter(pc.field("station") == 2)
    assert results.column("tightening_id").equals(wanted.column("tightening_id"))
    # columns= projects: passthrough=True finds no other column to copy
    assert "strategy" not in results.column_names and "station" not in results.column_names
    expected = tightscan.detect_batch(wanted.select(["tightening_id", "angle", "torque"]))
    assert results.equals(expected)
    # a row filter on a file column goes to the reader (row groups) as well
    tightscan.scan_parquet(root, out, filter=pc.field("tightening_id") < 7, passthrough=["station"])
    assert pq.read_table(out).column("tightening_id").to_pylist() == list(range(7))


def test_uri_glob_list_and_dataset_sources_agree(tmp_path: Path, hive: tuple[Path, pa.Table]) -> None:
    root, full = hive
    expected = tightscan.detect_batch(full, passthrough=["plant", "station"])
    files = sorted(root.rglob("*.parquet"))
    sources: list[object] = [
        f"file://{root}",
        f"{root}/**/*.parquet",
        f"file://{root}/plant=*/station=*/part-0.parquet",
        ds.dataset(root, format="parquet", partitioning="hive"),
    ]
    for i, source in enumerate(sources):
        out = tmp_path / f"r{i}.parquet"
        tightscan.scan_parquet(source, out, passthrough=["plant", "station"])  # type: ignore[arg-type]
        assert pq.read_table(out).equals(expected), source
    # a list of files: hive keys below their common directory
    tightscan.scan_parquet(files, tmp_path / "list.parquet", passthrough=["plant", "station"])
    assert pq.read_table(tmp_path / "list.parquet").equals(expected)
    # partitioning=None: the directories are only directories
    tightscan.scan_parquet(root, tmp_path / "np.parquet", partitioning=None, passthrough=True)
    assert "station" not in pq.read_table(tmp_path / "np.parquet").column_names
    with pytest.raises(tightscan.DataFileError, match="no files match"):
        tightscan.scan_parquet(f"{root}/*.csv", tmp_path / "x.parquet")


def test_fsspec_filesystem_and_uri(tmp_path: Path, hive: tuple[Path, pa.Table]) -> None:
    fsspec = pytest.importorskip("fsspec")
    root, full = hive
    memory = fsspec.filesystem("memory")
    for f in sorted(root.rglob("*.parquet")):
        with memory.open(f"/tightscan-test/{f.relative_to(root).as_posix()}", "wb") as out:
            out.write(f.read_bytes())
    expected = tightscan.detect_batch(full, passthrough=["station"])
    try:
        tightscan.scan_parquet("/tightscan-test", tmp_path / "a.parquet", filesystem=memory, passthrough=["station"])
        assert pq.read_table(tmp_path / "a.parquet").equals(expected)
        # a scheme pyarrow does not know goes through fsspec
        tightscan.scan_parquet("memory://tightscan-test", tmp_path / "b.parquet", passthrough=["station"])
        assert pq.read_table(tmp_path / "b.parquet").equals(expected)
    finally:
        memory.rm("/tightscan-test", recursive=True)


def test_row_numbers_stand_in_for_a_missing_id_across_files(tmp_path: Path) -> None:
    curves, _ = tightscan.simulate(12, seed=6)
    curves = curves.drop_columns(["tightening_id"])
    for i in range(3):
        pq.write_table(curves.slice(4 * i, 4), tmp_path / f"f{i}.parquet")
    tightscan.scan_parquet(sorted(tmp_path.glob("f*.parquet")), tmp_path / "out")
    # as if the three files were one table, whichever file a task scans first
    assert tightscan.read_results(tmp_path / "out").equals(tightscan.detect_batch(curves))


def test_directory_partitioning_and_in_memory_dataset(tmp_path: Path) -> None:
    curves, _ = tightscan.simulate(20, seed=4)
    for year in (2024, 2025):
        d = tmp_path / "in" / str(year) / "01"
        d.mkdir(parents=True)
        pq.write_table(curves.slice((year - 2024) * 10, 10), d / "x.parquet")
    by_date = ds.DirectoryPartitioning(pa.schema([("year", pa.int32()), ("month", pa.int32())]))
    tightscan.scan_parquet(tmp_path / "in", tmp_path / "r.parquet", partitioning=by_date, passthrough=["year", "month"])
    results = pq.read_table(tmp_path / "r.parquet")
    assert results.column("year").to_pylist() == [2024] * 10 + [2025] * 10
    assert set(results.column("month").to_pylist()) == {1}
    # a dataset that is not files: one unit, read through the dataset
    summary = tightscan.scan_parquet(ds.dataset(curves), tmp_path / "m.parquet")
    assert summary.files == 1 and pq.read_table(tmp_path / "m.parquet").equals(tightscan.detect_batch(curves))


def test_directory_destination_one_file_per_input_and_partition_by(tmp_path: Path, hive: tuple[Path, pa.Table]) -> None:
    root, full = hive
    expected = tightscan.detect_batch(full, passthrough=["station"])
    out = tmp_path / "results"
    summary = tightscan.scan_parquet(root, out, passthrough=["station"])
    outputs = sorted(p.name for p in out.glob("*.parquet"))
    assert outputs == sorted(f"plant={p}__station={s}__part-0.parquet" for p in PLANTS for s in STATIONS)
    assert summary.files == 6
    one = pq.read_table(out / "plant=B__station=2__part-0.parquet")
    assert one.equals(expected.slice(4 * PER_FILE, PER_FILE))
    assert tightscan.read_results(out).equals(expected)
    # hive directories by a results column; the column comes back when read
    by = tmp_path / "by-station"
    tightscan.scan_parquet(root, by, passthrough=["station"], partition_by=["station"])
    assert sorted(p.name for p in by.iterdir() if not p.name.startswith("_")) == ["station=1", "station=2", "station=3"]
    back = tightscan.read_results(by).sort_by("tightening_id")
    assert back.column("station").to_pylist() == expected.sort_by("tightening_id").column("station").to_pylist()
    assert back.column("change_detected").equals(expected.sort_by("tightening_id").column("change_detected"))
    with pytest.raises(tightscan.InvalidParameterError, match="partition_by"):
        tightscan.scan_parquet(root, tmp_path / "f.parquet", passthrough=["station"], partition_by=["station"])
    with pytest.raises(tightscan.InvalidParameterError, match="not in the results"):
        tightscan.scan_parquet(root, tmp_path / "d2", partition_by=["station"])


def test_unrelated_file_is_named_or_skipped_never_dropped(tmp_path: Path, hive: tuple[Path, pa.Table]) -> None:
    root, full = hive
    data = tmp_path / "data"
    for f in root.rglob("*.parquet"):
        target = data / f.relative_to(root)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(f.read_bytes())
    pq.write_table(pa.table({"operator": ["x"]}), data / "plant=A" / "notes.parquet")
    (data / "_SUCCESS").write_text("")  # not data, by pyarrow's rule (a leading _ or .)
    out = tmp_path / "r.parquet"
    with pytest.raises(tightscan.SchemaError) as e:
        tightscan.scan_parquet(data, out)
    assert "notes.parquet" in str(e.value) and e.value.column == "angle"
    assert not out.exists() and not list(tmp_path.glob(".r.parquet*"))
    summary = tightscan.scan_parquet(data, out, on_bad_file="skip")
    assert [Path(f).name for f, _ in summary.skipped_files] == ["notes.parquet"]
    assert "angle" in summary.skipped_files[0][1]
    assert summary.files == 6 and pq.read_table(out).equals(tightscan.detect_batch(full))


def test_failed_scan_leaves_no_results_file(tmp_path: Path) -> None:
    curves, _ = tightscan.simulate(40, seed=2)
    data = tmp_path / "data"
    data.mkdir()
    pq.write_table(curves.slice(0, 20), data / "a.parquet")
    # the second file's angle is of another type: found only when that file is read
    bad = curves.slice(20).set_column(curves.schema.get_field_index("angle"), "angle", pa.array([["x"]] * 20))
    pq.write_table(bad, data / "b.parquet")
    for out in (tmp_path / "r.parquet", tmp_path / "dir"):
        with pytest.raises(tightscan.SchemaError, match="b.parquet"):
            tightscan.scan_parquet(data, out)
    assert not (tmp_path / "r.parquet").exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".parquet")] == []
    # in a directory, the file done before the bad one is complete (and resumable); the bad one has no output
    assert sorted(p.name for p in (tmp_path / "dir").glob("*.parquet")) == ["a.parquet"]


def long_layout(curves: pa.Table) -> pa.Table:
    import numpy as np

    lengths = pc.list_value_length(curves.column("angle"))

    return pa.table(
        {
            "tightening_id": np.repeat(curves.column("tightening_id").to_numpy(), lengths.to_numpy()),
            "angle": pc.list_flatten(curves.column("angle")),
            "torque": pc.list_flatten(curves.column("torque")),
        }
    )


def test_long_layout_id_reappearing_is_an_error_naming_file_and_id(tmp_path: Path) -> None:
    curves, _ = tightscan.simulate(6, seed=8)
    data = tmp_path / "data"
    data.mkdir()
    pq.write_table(long_layout(curves.slice(0, 3)), data / "a.parquet")
    # b.parquet repeats tightening 2 of a.parquet
    pq.write_table(long_layout(curves.slice(2, 4)), data / "b.parquet")
    out = tmp_path / "r.parquet"
    with pytest.raises(tightscan.SchemaError) as e:
        tightscan.scan_parquet(data, out, batch_size=500)
    assert "b.parquet" in str(e.value) and "tightening 2 " in str(e.value)
    assert not out.exists()
    # within one file: the id comes back in a later batch
    mixed = pa.concat_tables([long_layout(curves.slice(0, 2)), long_layout(curves.slice(0, 1))])
    pq.write_table(mixed, tmp_path / "mixed.parquet")
    with pytest.raises(tightscan.SchemaError, match=r"mixed.parquet: tightening 0 appears again"):
        tightscan.scan_parquet(tmp_path / "mixed.parquet", out, batch_size=300)
    # skipped instead, and listed
    summary = tightscan.scan_parquet(data, tmp_path / "dir", on_bad_file="skip", batch_size=500)
    assert [Path(f).name for f, _ in summary.skipped_files] == ["b.parquet"]
    assert sorted(p.name for p in (tmp_path / "dir").glob("*.parquet")) == ["a.parquet"]


def test_cli_scan_where_data_lives(tmp_path: Path, hive: tuple[Path, pa.Table], capsys: pytest.CaptureFixture[str]) -> None:
    root, full = hive
    out = tmp_path / "res"
    args = ["scan", str(root), "-o", str(out), "--no-progress", "--passthrough", "station"]
    assert main([*args, "--filter", "station=2", "--filter", "plant=B", "--partition-by", "station"]) == 0
    back = tightscan.read_results(out)
    wanted = full.filter((pc.field("station") == 2) & (pc.field("plant") == "B"))
    assert back.column("tightening_id").equals(wanted.column("tightening_id"))
    assert set(back.column("station").to_pylist()) == {2}
    capsys.readouterr()
    assert main([*args, "--partition-by", "station", "--resume", "--columns", "tightening_id", "angle", "torque"]) == 0
    assert "tightenings" in capsys.readouterr().out
    assert tightscan.read_results(out).num_rows == full.num_rows
    # a bad file: exit non-zero naming it, or skipped and listed
    pq.write_table(pa.table({"x": [1]}), tmp_path / "odd.parquet")
    single = tmp_path / "one.parquet"
    files = [str(p) for p in sorted(root.rglob("*.parquet"))[:1]] + [str(tmp_path / "odd.parquet")]
    assert main(["scan", *files, "-o", str(single), "--no-progress"]) != 0
    assert "odd.parquet" in capsys.readouterr().err and not single.exists()
    assert main(["scan", *files, "-o", str(single), "--no-progress", "--on-bad-file", "skip"]) == 0
    assert "odd.parquet" in capsys.readouterr().out


def test_cli_filter_expressions() -> None:
    from tightscan.cli import parse_filter

    assert parse_filter(["station=2"]).equals(pc.field("station") == 2)
    assert parse_filter(["plant = 'B'", "day>=20240101"]).equals((pc.field("plant") == "B") & (pc.field("day") >= 20240101))
    assert parse_filter(["station in 1,3"]).equals(pc.field("station").isin([1, 3]))
    assert parse_filter(["torque_unit!=Nm", "x<1.5"]).equals((pc.field("torque_unit") != "Nm") & (pc.field("x") < 1.5))
    with pytest.raises(ValueError, match="COLUMN OP VALUE"):
        parse_filter(["station"])


@pytest.fixture(scope="module")
def s3_server() -> object:
    """moto's S3 in server mode on a free loopback port, for the module."""
    pytest.importorskip("moto.server", reason="moto[server] is in the test extras (make test installs it)")
    from moto.server import ThreadedMotoServer

    logging.getLogger("werkzeug").setLevel(logging.ERROR)
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    yield server
    server.stop()


def test_s3_object_store_matches_local(tmp_path: Path, hive: tuple[Path, pa.Table], s3_server: object, monkeypatch: pytest.MonkeyPatch) -> None:
    # no instance-metadata lookups for credentials: the keys are given
    monkeypatch.setenv("AWS_EC2_METADATA_DISABLED", "true")
    root, full = hive
    host, port = s3_server.get_host_and_port()  # type: ignore[attr-defined]
    s3 = pafs.S3FileSystem(
        endpoint_override=f"{host}:{port}",
        scheme="http",
        access_key="testing",
        secret_key="testing",
        region="us-east-1",
        allow_bucket_creation=True,
    )
    s3.create_dir("plant-data")
    for f in sorted(root.rglob("*.parquet")):
        with s3.open_output_stream(f"plant-data/curves/{f.relative_to(root).as_posix()}") as out:
            out.write(f.read_bytes())
    s3.open_output_stream("plant-data/curves/_SUCCESS").close()
    local = tmp_path / "local.parquet"
    tightscan.scan_parquet(root, local, passthrough=["plant", "station"])
    expected = pq.read_table(local)
    # a path on the given filesystem, and a URI whose endpoint the filesystem gives
    tightscan.scan_parquet("plant-data/curves", tmp_path / "a.parquet", filesystem=s3, passthrough=["plant", "station"])
    assert pq.read_table(tmp_path / "a.parquet").equals(expected)
    summary = tightscan.scan_parquet(
        "s3://plant-data/curves/", tmp_path / "b", filesystem=s3, passthrough=["plant", "station"], filter=pc.field("plant") == "B"
    )
    assert summary.files == 3
    assert tightscan.read_results(tmp_path / "b").equals(expected.filter(pc.field("plant") == "B"))
    # errors name the object
    s3.open_output_stream("plant-data/curves/plant=A/readme.parquet").close()
    with pytest.raises(tightscan.DataFileError, match=r"s3://plant-data/curves/plant=A/readme.parquet"):
        tightscan.scan_parquet("s3://plant-data/curves", tmp_path / "c.parquet", filesystem=s3)
    # the destination on the object store too (a URI of the given filesystem's kind)
    summary = tightscan.scan_parquet("s3://plant-data/curves", "s3://plant-data/results", filesystem=s3, passthrough=["plant", "station"], on_bad_file="skip")
    assert [f for f, _ in summary.skipped_files] == ["s3://plant-data/curves/plant=A/readme.parquet"]
    assert tightscan.read_results("s3://plant-data/results", filesystem=s3).equals(expected)
    names = [i.base_name for i in s3.get_file_info(pafs.FileSelector("plant-data/results"))]
    assert sorted(n for n in names if n.endswith(".parquet")) == sorted(f"plant={p}__station={s}__part-0.parquet" for p in PLANTS for s in STATIONS)
