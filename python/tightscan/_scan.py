"""Parquet in, Parquet out: :func:`scan_parquet` over files where they live, on one machine or a cluster.

A scan is a list of input files, each analysed on its own (one task per file: the unit that
an engine fans out, that a retry repeats and that ``resume`` skips). Discovery, hive
partitions, column and row pushdown are pyarrow.dataset's and pyarrow.fs's; the same
per-file function runs in-process (``engine="local"``), on Dask workers or as Ray tasks, so
every engine writes the same rows in the same order.

Nothing that looks complete is written before it is: every output goes to a hidden temporary
name beside its final one and is renamed when it is whole. In a directory destination a small
manifest (``_tightscan/``, ignored by Parquet readers) records which input files are done.
"""

from __future__ import annotations

import hashlib
import json
import os
import queue
import re
import threading
import time
import uuid
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Callable, Generator, Iterator, Literal, Sequence, Union
from urllib.parse import urlparse

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.dataset as ds
import pyarrow.fs as pafs
import pyarrow.parquet as pq

from . import _core
from ._api import _hold_back_last_tightening, _is_long_layout, _passthrough_list
from ._progress import Progress
from ._metadata import scan_metadata, schema_with_metadata
from .config import ConfigLike, as_dict
from .exceptions import DataFileError, InvalidParameterError, SchemaError

__all__ = ["scan_parquet", "read_results", "ScanSummary", "Engine", "SourceLike"]

PathLike = Union[str, "os.PathLike[str]"]
SourceLike = Union[PathLike, Sequence[PathLike], ds.Dataset]
Engine = Literal["local", "dask", "ray"]

# Files and directories whose name starts with these are not data (pyarrow.dataset's own
# rule): Spark's _SUCCESS, our _tightscan manifest and our hidden temporary outputs.
IGNORED_PREFIXES = (".", "_")
PARQUET_SUFFIXES = (".parquet", ".parq", ".pq")
MANIFEST_DIR = "_tightscan"
TMP_MARK = ".tightscan-tmp-"
# A hive key whose every value reads as a 32-bit integer is an int32 column (pyarrow's inference).
_INT32 = re.compile(r"^-?\d{1,9}$")
_HIVE_NULL = "__HIVE_DEFAULT_PARTITION__"


@dataclass
class ScanSummary:
    """What a scan read and found.

    ``files`` input files were analysed in this run; ``resumed_files`` were already complete
    in the destination (``resume=True``) and not read again. ``tightenings``, ``samples``,
    ``changes`` and ``status_counts`` count every result in the destination, resumed ones
    included. ``skipped_files`` lists ``(file, reason)`` of the files left out by
    ``on_bad_file="skip"``: a skipped file is never silent.
    """

    destination: str
    files: int = 0
    tightenings: int = 0
    samples: int = 0
    changes: int = 0
    seconds: float = 0.0
    status_counts: dict[str, int] = field(default_factory=dict)
    skipped_files: list[tuple[str, str]] = field(default_factory=list)
    resumed_files: int = 0
    engine: str = "local"

    def to_dict(self) -> dict[str, Any]:
        """The summary as plain JSON-ready data (``tightscan scan --json``): the fields above,
        ``skipped_files`` as ``{"file", "reason"}`` objects.

        >>> ScanSummary("r.parquet", files=1, tightenings=3, status_counts={"ok": 3}).to_dict()["status_counts"]
        {'ok': 3}
        """
        return {
            "destination": self.destination,
            "files": self.files,
            "resumed_files": self.resumed_files,
            "tightenings": self.tightenings,
            "samples": self.samples,
            "changes": self.changes,
            "status_counts": dict(sorted(self.status_counts.items())),
            "skipped_files": [{"file": f, "reason": r} for f, r in self.skipped_files],
            "seconds": self.seconds,
            "engine": self.engine,
        }

    def _repr_html_(self) -> str:
        """A small table for notebooks: counts, then tightenings per status code."""
        from ._html import grid_table, key_value_table

        rate = self.samples / self.seconds / 1e6 if self.seconds > 0 else float("nan")
        rows: list[tuple[str, Any]] = [
            ("files", self.files),
            ("tightenings", self.tightenings),
            ("samples", self.samples),
            ("changes found", self.changes),
            ("seconds", self.seconds),
            ("M samples/s", rate),
            ("engine", self.engine),
        ]
        if self.resumed_files:
            rows.append(("resumed files", self.resumed_files))
        out = key_value_table(f"tightscan scan: {self.destination}", rows)
        out += grid_table("tightenings by status", ["status", "tightenings"], sorted(self.status_counts.items()))
        if self.skipped_files:
            out += grid_table("skipped files", ["file", "reason"], self.skipped_files)
        return out

    def _add(self, stats: "_Stats") -> None:
        self.tightenings += stats.tightenings
        self.samples += stats.samples
        self.changes += stats.changes
        for code, count in stats.status_counts.items():
            self.status_counts[code] = self.status_counts.get(code, 0) + count


@dataclass
class _Stats:
    tightenings: int = 0
    samples: int = 0
    changes: int = 0
    status_counts: dict[str, int] = field(default_factory=dict)

    def tally(self, result: pa.Table) -> None:
        self.tightenings += result.num_rows
        if result.num_rows == 0:
            return
        self.samples += int(pc.sum(result.column("n_samples")).as_py() or 0)
        self.changes += int(pc.sum(pc.cast(pc.fill_null(result.column("change_detected"), False), pa.int64())).as_py() or 0)
        for item in pc.value_counts(pc.utf8_slice_codeunits(result.column("status"), 0, 64)).to_pylist():
            code = item["values"].split(":")[0]
            self.status_counts[code] = self.status_counts.get(code, 0) + item["counts"]


# ---------------------------------------------------------------------------------------------
# Where things are: filesystems, paths, globs


def _arrow_filesystem(filesystem: Any) -> pafs.FileSystem:
    """A pyarrow filesystem, or an fsspec one wrapped as such (pyarrow's own adapter)."""
    if isinstance(filesystem, pafs.FileSystem):
        return filesystem
    return pafs.PyFileSystem(pafs.FSSpecHandler(filesystem))


def _split_uri(text: str, filesystem: Any) -> tuple[pafs.FileSystem, str]:
    """The filesystem and path of ``text`` (a local path or a URI)."""
    if filesystem is not None:
        fs = _arrow_filesystem(filesystem)
        if "://" in text:
            # A URI beside an explicit filesystem (an S3 endpoint of one's own): the
            # filesystem says how to reach it, the URI only where.
            parsed = urlparse(text)
            text = parsed.path if parsed.scheme == "file" else parsed.netloc + parsed.path
        elif isinstance(fs, pafs.LocalFileSystem):
            text = os.path.abspath(text)
        return fs, text.rstrip("/") or "/"
    if "://" not in text:
        return pafs.LocalFileSystem(), os.path.abspath(text)
    head, magic = _glob_head(text)
    try:
        fs, path = pafs.FileSystem.from_uri(head)
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError, OSError, ValueError) as e:
        try:
            import fsspec  # other schemes (memory://, hf:// ...) through fsspec, when installed

            fsspec_fs, path = fsspec.core.url_to_fs(head)
            fs = _arrow_filesystem(fsspec_fs)
        except (ImportError, ValueError, OSError):
            raise DataFileError(f"no filesystem for {text}: {e}", text) from e
    return fs, (path.rstrip("/") + magic) if magic else path


def _glob_head(text: str) -> tuple[str, str]:
    """``("s3://b/data", "/*/x.parquet")``: the part before the first glob segment, and the rest."""
    parts = text.split("/")
    for i, part in enumerate(parts):
        if any(c in part for c in "*?["):
            return "/".join(parts[:i]), "/" + "/".join(parts[i:])
    return text, ""


def _glob_regex(pattern: str) -> re.Pattern[str]:
    """A glob over whole paths: ``*`` and ``?`` stay within a segment, ``**/`` spans segments.

    >>> bool(_glob_regex("/d/**/*.parquet").fullmatch("/d/a=1/b=2/x.parquet"))
    True
    >>> bool(_glob_regex("/d/*.parquet").fullmatch("/d/a=1/x.parquet"))
    False
    """
    segments = pattern.split("/")
    out = []
    for k, seg in enumerate(segments):
        last = k == len(segments) - 1
        if seg == "**":
            out.append(".*" if last else "(?:[^/]*/)*")
            continue
        rx, i = "", 0
        while i < len(seg):
            c = seg[i]
            j = seg.find("]", i + 2) if c == "[" else -1
            if c == "*":
                rx += "[^/]*"
            elif c == "?":
                rx += "[^/]"
            elif j > 0:
                body = seg[i + 1 : j].replace("\\", "\\\\")
                rx += "[" + ("^" + body[1:] if body.startswith("!") else body) + "]"
                i = j
            else:
                rx += re.escape(c)
            i += 1
        out.append(rx if last else rx + "/")
    return re.compile("".join(out))


def _is_data_file(path: str, base: str) -> bool:
    rel = path[len(base) :].lstrip("/") if path.startswith(base) else path.rsplit("/", 1)[-1]
    return not any(seg.startswith(IGNORED_PREFIXES) for seg in rel.split("/"))


def _display(fs: pafs.FileSystem, path: str) -> str:
    """How errors and the summary name a file: a local path, or a URI."""
    kind = fs.type_name
    return path if kind == "local" or "::" in kind else f"{kind}://{path}"


@dataclass
class _Inputs:
    filesystem: pafs.FileSystem
    files: list[str]
    base: str


def _list_inputs(source: PathLike | Sequence[PathLike], filesystem: Any, exclude: str | None) -> _Inputs:
    """The data files named by ``source`` (sorted per item; a list keeps its order) and the
    directory below which hive keys are read."""
    items = [source] if isinstance(source, (str, os.PathLike)) else list(source)
    if not items:
        raise DataFileError("no input files given", "")
    fs: pafs.FileSystem | None = None
    files: list[str] = []
    bases: list[str] = []
    for item in items:
        text = os.fspath(item)
        item_fs, path = _split_uri(text, filesystem)
        if fs is None:
            fs = item_fs
        elif item_fs.type_name != fs.type_name:
            raise DataFileError(f"{text} is on another filesystem ({item_fs.type_name}) than the first input ({fs.type_name})", text)
        head, magic = _glob_head(path)
        if magic:
            base = head or "/"
            rx = _glob_regex(path)
            try:
                infos = fs.get_file_info(pafs.FileSelector(base, recursive=True, allow_not_found=True))
            except OSError as e:
                raise DataFileError(f"cannot list {text}: {e}", text) from e
            found = sorted(i.path for i in infos if i.type == pafs.FileType.File and rx.fullmatch(i.path) and _is_data_file(i.path, base))
            if not found:
                raise DataFileError(f"no files match {text}", text)
            files.extend(found)
            bases.append(base)
            continue
        try:
            info = fs.get_file_info(path)
        except OSError as e:
            raise DataFileError(f"cannot read {text}: {e}", text) from e
        if info.type == pafs.FileType.Directory:
            try:
                infos = fs.get_file_info(pafs.FileSelector(path, recursive=True))
            except OSError as e:
                raise DataFileError(f"cannot list directory {text}: {e}", text) from e
            found = sorted(
                i.path
                for i in infos
                if i.type == pafs.FileType.File and _is_data_file(i.path, path) and not (exclude and (i.path == exclude or i.path.startswith(exclude + "/")))
            )
            if not found:
                raise DataFileError(f"no data files in directory {text}", text)
            files.extend(found)
            bases.append(path)
        elif info.type == pafs.FileType.File:
            files.append(path)
            bases.append(path.rsplit("/", 1)[0] if "/" in path else "")
        else:
            raise DataFileError(f"no such file or directory: {text}", text)
    assert fs is not None
    base = os.path.commonpath(bases) if len(set(bases)) > 1 and all(b.startswith("/") == bases[0].startswith("/") for b in bases) else bases[0]
    return _Inputs(fs, files, base)


def _hive_partitioning(files: list[str], base: str) -> ds.Partitioning | None:
    """Hive keys of the directories below ``base``: int32 when every value is an integer,
    else string (pyarrow.dataset's inference, without dictionaries)."""
    values: dict[str, list[str]] = {}
    for path in files:
        rel = path[len(base) :].lstrip("/") if base and path.startswith(base) else path.lstrip("/")
        for seg in rel.split("/")[:-1]:
            key, sep, value = seg.partition("=")
            if sep and key:
                values.setdefault(key, []).append(value)
    if not values:
        return None
    fields = [
        pa.field(key, pa.int32() if all(_INT32.match(v) or v == _HIVE_NULL for v in vals) else pa.string())
        for key, vals in values.items()
    ]
    return ds.HivePartitioning(pa.schema(fields))


def _relative(path: str, base: str) -> str:
    rel = path[len(base) :] if base and path.startswith(base) else path.rsplit("/", 1)[-1]
    return rel.lstrip("/")


# ---------------------------------------------------------------------------------------------
# The unit of work: one input file


@dataclass
class _FileTask:
    index: int
    name: str
    fragment: Any
    output: str  # path of its results below a directory destination, or ""
    first_row: int = 0


@dataclass
class _Plan:
    config: dict[str, Any] | None
    pass_cols: list[str]
    columns: list[str] | None
    filter: pc.Expression | None
    batch_size: int | None
    partition_schema: pa.Schema
    out_schema: pa.Schema
    long_layout: bool
    # Directory destination (None: one file, written by the driver)
    out_fs: pafs.FileSystem | None = None
    out_dir: str = ""
    partition_by: list[str] | None = None
    scan_key: str = ""


@dataclass
class _FileOutcome:
    index: int
    name: str
    error: tuple[str, str, str | None] | None = None
    stats: _Stats = field(default_factory=_Stats)
    table: pa.Table | None = None
    ids: pa.Array | None = None
    outputs: list[str] = field(default_factory=list)


def _file_schema(fragment: Any, name: str, partition_schema: pa.Schema) -> pa.Schema:
    try:
        schema: pa.Schema = fragment.physical_schema
    except (pa.ArrowInvalid, pa.ArrowIOError, OSError) as e:
        raise DataFileError(f"cannot read Parquet file {name}: {e}", name) from e
    for f in partition_schema:
        if f.name not in schema.names:
            schema = schema.append(f)
    return schema


def _projection(schema: pa.Schema, columns: Sequence[str] | None, pass_cols: Sequence[str]) -> list[str] | None:
    if columns is None:
        return None
    wanted = list(dict.fromkeys([*columns, *pass_cols]))
    return [c for c in wanted if c in schema.names] + [c for c in wanted if c not in schema.names]


def _check_file(task: _FileTask, plan: _Plan) -> tuple[pa.Schema, list[str] | None]:
    """The file's schema as read, checked against the data contract and the scan's results."""
    schema = _file_schema(task.fragment, task.name, plan.partition_schema)
    cols = _projection(schema, plan.columns, plan.pass_cols)
    missing = [c for c in cols or [] if c not in schema.names]
    if missing:
        raise SchemaError(f"{task.name}: column {missing[0]!r} is missing (file has: {', '.join(schema.names)})", missing[0])
    projected = pa.schema([schema.field(c) for c in cols]) if cols is not None else schema
    try:
        mine: pa.Schema = _core.result_schema(projected, plan.config, plan.pass_cols)
    except SchemaError as e:
        raise SchemaError(f"{task.name}: {e}", e.column) from e
    if [f.name for f in mine] != plan.out_schema.names:
        raise SchemaError(f"{task.name} has other columns than the first file ({', '.join(projected.names)})")
    return schema, cols


# A batch holds about this much decoded data when the caller gives no ``batch_size``: big
# enough that the per-batch Python bookkeeping and the engine's fan-out over cores are
# negligible, small enough that a few batches in flight stay far below the memory goal.
BATCH_BYTES = 16 << 20
# Column chunks are read through a buffer of this size instead of whole (a Parquet row group
# can be hundreds of MB; pyarrow.dataset's scanner decodes one whole at a time).
_READ_BUFFER = 1 << 20
_REMOTE_READ_BUFFER = 8 << 20
# Batches decoded ahead of the engine by the reader thread.
_READ_AHEAD = 2
# Result rows per row group of a results file (~430 B each).
RESULT_ROW_GROUP = 65_536


def _batch_rows(plan: _Plan, metadata: pq.FileMetaData | None, long_layout: bool) -> int:
    """Rows per batch: the caller's ``batch_size``, else about :data:`BATCH_BYTES` of decoded
    data per batch from the file's own row sizes (a nested tightening is ~25 KB, a long-layout
    sample ~30 B).

    >>> _batch_rows(_Plan(None, [], None, None, 500, pa.schema([]), pa.schema([]), False), None, False)
    500
    """
    if plan.batch_size is not None:
        return plan.batch_size
    widest = 0.0
    if metadata is not None:
        for i in range(metadata.num_row_groups):
            rg = metadata.row_group(i)
            if rg.num_rows:
                widest = max(widest, rg.total_byte_size / rg.num_rows)
    if widest <= 0:
        return 1 << 20 if long_layout else 1024
    return max(1, min(1 << 22, int(BATCH_BYTES // widest)))


class _ReadAhead:
    """Batches of an iterator produced by a thread of their own, at most ``depth`` ahead.

    Parquet decoding and the engine both release the GIL, so the next batches decode while the
    engine works on this one; the bounded queue keeps memory at a few batches whatever the
    file's size. An error of the reader comes out of :meth:`__next__` where the batch would have.
    """

    _END = object()

    def __init__(self, source: Iterator[Any], depth: int = _READ_AHEAD) -> None:
        self._finished = False
        self._queue: queue.Queue[tuple[Any, BaseException | None]] = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(source,), name="tightscan-read", daemon=True)
        self._thread.start()

    def _put(self, item: tuple[Any, BaseException | None]) -> bool:
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def _run(self, source: Iterator[Any]) -> None:
        try:
            for item in source:
                if not self._put((item, None)):
                    return
        except BaseException as e:  # handed to the consumer, raised there
            self._put((None, e))
            return
        finally:
            close = getattr(source, "close", None)
            if close is not None:
                close()
        self._put((self._END, None))

    def __iter__(self) -> "_ReadAhead":
        return self

    def __next__(self) -> Any:
        if self._finished:
            raise StopIteration
        item, error = self._queue.get()
        if error is not None:
            self.close()
            raise error
        if item is self._END:
            self.close()
            raise StopIteration
        return item

    def close(self) -> None:
        """Stops the reader (it may be blocked on a full queue) and lets go of what it read."""
        self._finished = True
        self._stop.set()
        while self._thread.is_alive():
            try:
                self._queue.get(timeout=0.05)
            except queue.Empty:
                pass
        self._queue = queue.Queue()


def _filter_columns(plan: _Plan, schema: pa.Schema, wanted: list[str]) -> list[str]:
    """Columns the filter may name beyond those read (over-inclusive: a name anywhere in the
    expression's text), so that rows can be filtered after decoding."""
    if plan.filter is None:
        return []
    text = str(plan.filter)
    return [n for n in schema.names if n not in wanted and n in text]


def _parquet_batches(task: _FileTask, plan: _Plan, schema: pa.Schema, cols: list[str] | None) -> Iterator[pa.RecordBatch]:
    """One Parquet file's rows, batch by batch, in bounded memory: pyarrow's streaming reader
    (column chunks through a buffer, a batch decoded at a time), row groups pruned by the
    filter's statistics, hive keys added as constant columns, rows filtered after decoding;
    the same rows, columns and order as pyarrow.dataset's scanner of the fragment gives."""
    fragment = task.fragment
    wanted = list(cols) if cols is not None else list(schema.names)
    read = wanted + _filter_columns(plan, schema, wanted)
    physical = fragment.physical_schema
    keys = ds.get_partition_keys(fragment.partition_expression)
    if plan.filter is not None:
        row_groups = [rg.id for rg in fragment.subset(filter=plan.filter, schema=schema).row_groups]
    else:
        row_groups = None
    local = isinstance(fragment.filesystem, pafs.LocalFileSystem)
    with fragment.filesystem.open_input_file(fragment.path) as handle:
        reader = pq.ParquetFile(handle, buffer_size=_READ_BUFFER if local else _REMOTE_READ_BUFFER, pre_buffer=False)
        if row_groups is None:
            row_groups = list(range(reader.metadata.num_row_groups))
        if not row_groups:
            return
        rows = _batch_rows(plan, reader.metadata, plan.long_layout)
        file_cols = [c for c in read if c in physical.names]
        for batch in reader.iter_batches(batch_size=rows, row_groups=row_groups, columns=file_cols, use_threads=True):
            arrays, names = [], []
            for name in read:
                if name in physical.names:
                    arrays.append(batch.column(name))
                else:  # a hive key: one value for the whole file
                    kind = schema.field(name).type
                    value = keys.get(name)
                    constant = pa.nulls(batch.num_rows, kind)
                    arrays.append(constant if value is None else constant.fill_null(pa.scalar(value, kind)))
                names.append(name)
            batch = pa.RecordBatch.from_arrays(arrays, schema=pa.schema([schema.field(n) for n in names]))
            if plan.filter is None:
                yield batch
                continue
            kept = ds.dataset(batch).to_table(columns=wanted, filter=plan.filter)
            for out in kept.to_batches():
                if out.num_rows:
                    yield out


def _leading_rows_of(batch: pa.RecordBatch, carried: pa.RecordBatch) -> int:
    """How many rows at the head of ``batch`` go on the tightening ``carried`` holds."""
    ids = carried.column("tightening_id")
    last = ids[len(ids) - 1]
    head = batch.column("tightening_id")
    same = pc.is_null(head) if not last.is_valid else pc.fill_null(pc.equal(head, last), False)
    first_other = pc.index(same, False).as_py()
    return batch.num_rows if first_other < 0 else int(first_other)


def _detect_file(task: _FileTask, plan: _Plan) -> Iterator[pa.Table]:
    """The results of one file, batch by batch: a reader thread decodes a few batches ahead
    while the engine (GIL released) works, so memory holds a few batches, not the file."""
    schema, cols = _check_file(task, plan)
    parquet_file = isinstance(task.fragment, ds.ParquetFileFragment)
    try:
        if parquet_file:
            # bind the projection and the filter now, so a bad one is named before reading
            ds.Scanner.from_batches(iter(()), schema=schema, columns=cols, filter=plan.filter)
            source: Iterator[pa.RecordBatch] = _parquet_batches(task, plan, schema, cols)
        else:
            rows = plan.batch_size or _batch_rows(plan, None, plan.long_layout)
            if isinstance(task.fragment, _DatasetFragment):
                scanner = ds.Scanner.from_dataset(task.fragment.dataset, columns=cols, filter=plan.filter, batch_size=rows)
            else:
                scanner = ds.Scanner.from_fragment(task.fragment, schema=schema, columns=cols, filter=plan.filter, batch_size=rows, use_threads=True)
            source = iter(scanner.to_batches())
    except (pa.ArrowInvalid, pa.ArrowTypeError, pa.ArrowNotImplementedError) as e:
        raise SchemaError(f"{task.name}: {e}") from e
    seen: set[Any] = set()
    carry: pa.RecordBatch | None = None
    done = 0

    def run(batch: pa.RecordBatch) -> pa.Table:
        nonlocal done
        try:
            result = _core.detect(batch, plan.config, plan.pass_cols, task.first_row + done)
        except SchemaError as e:
            raise SchemaError(f"{task.name}: {e}", e.column) from e
        done += result.num_rows
        if plan.long_layout:
            ids = result.column("tightening_id").to_pylist()
            repeated = seen.intersection(ids)
            if repeated:
                raise SchemaError(
                    f"{task.name}: tightening {next(iter(repeated))!r} appears again after other tightenings: "
                    "the long layout must keep each tightening's rows together",
                    "tightening_id",
                )
            seen.update(ids)
        if result.schema != plan.out_schema:
            try:
                result = result.cast(plan.out_schema)
            except (pa.ArrowInvalid, pa.ArrowNotImplementedError, ValueError) as e:
                raise SchemaError(f"{task.name} has columns of other types than the first file: {e}") from e
        return result

    batches = _ReadAhead(source)
    try:
        while True:
            try:
                batch = next(batches)
            except StopIteration:
                break
            except (pa.ArrowInvalid, pa.ArrowIOError, OSError) as e:
                raise DataFileError(f"cannot read Parquet file {task.name}: {e}", task.name) from e
            if plan.long_layout:
                if carry is not None and carry.num_rows:
                    # only the carried tightening is copied together, not the whole batch
                    k = _leading_rows_of(batch, carry)
                    carry = pa.concat_batches([carry, batch.slice(0, k)])
                    if k == batch.num_rows:
                        continue  # the tightening goes on in the next batch too
                    yield run(carry)
                    batch = batch.slice(k)
                batch, carry = _hold_back_last_tightening(batch)
            if batch.num_rows:
                yield run(batch)
        if carry is not None and carry.num_rows:
            yield run(carry)
    finally:
        batches.close()


def _tmp_name(final: str) -> str:
    head, _, tail = final.rpartition("/")
    return f"{head}/.{tail}{TMP_MARK}{uuid.uuid4().hex}" if head else f".{tail}{TMP_MARK}{uuid.uuid4().hex}"


class _AtomicParquet:
    """A Parquet file that appears under its final name only once it is whole.

    Writes go to a thread of their own, one write in flight per file (encoding and
    compressing release the GIL), so that writing overlaps the next batch's detection; an
    error of a write comes out of the next :meth:`write` or of :meth:`commit`.
    """

    def __init__(self, fs: pafs.FileSystem, final: str, schema: pa.Schema) -> None:
        self.fs, self.final, self.tmp = fs, final, _tmp_name(final)
        parent = final.rpartition("/")[0]
        if parent:
            fs.create_dir(parent, recursive=True)
        self.stream = fs.open_output_stream(self.tmp)
        self.writer = pq.ParquetWriter(self.stream, schema)
        self.pending: Future[None] | None = None
        self.buffered: list[pa.Table] = []
        self.buffered_rows = 0

    def _wait(self) -> None:
        pending, self.pending = self.pending, None
        if pending is not None:
            pending.result()

    def write(self, table: pa.Table) -> None:
        # results gathered into row groups of RESULT_ROW_GROUP rows (~30 MB), not one per batch
        self.buffered.append(table)
        self.buffered_rows += table.num_rows
        if self.buffered_rows >= RESULT_ROW_GROUP:
            self._flush()

    def _flush(self) -> None:
        self._wait()
        if self.buffered:
            table = self.buffered[0] if len(self.buffered) == 1 else pa.concat_tables(self.buffered)
            self.buffered, self.buffered_rows = [], 0
            self.pending = _writer_pool().submit(self.writer.write_table, table, RESULT_ROW_GROUP)

    def commit(self) -> None:
        self._flush()
        self._wait()
        self.writer.close()
        self.stream.close()
        self.fs.move(self.tmp, self.final)

    def abort(self) -> None:
        try:
            try:
                self._wait()
            except Exception:
                pass  # the write that failed is why we abort; its error is already on its way
            self.writer.close()
            self.stream.close()
        finally:
            try:
                self.fs.delete_file(self.tmp)
            except OSError:
                pass


_WRITER_POOL: ThreadPoolExecutor | None = None


def _writer_pool() -> ThreadPoolExecutor:
    """One writing thread for the process (made on first use; not pickled with a plan)."""
    global _WRITER_POOL
    if _WRITER_POOL is None:
        _WRITER_POOL = ThreadPoolExecutor(max_workers=1, thread_name_prefix="tightscan-write")
    return _WRITER_POOL


def _manifest_path(plan: _Plan, name: str) -> str:
    return f"{plan.out_dir}/{MANIFEST_DIR}/{hashlib.sha1(name.encode()).hexdigest()[:20]}.json"


def _write_json(fs: pafs.FileSystem, path: str, content: dict[str, Any]) -> None:
    tmp = _tmp_name(path)
    with fs.open_output_stream(tmp) as out:
        out.write(json.dumps(content).encode())
    fs.move(tmp, path)


def _partition_dirs(plan: _Plan, table: pa.Table) -> list[tuple[str, pa.Table]]:
    """``(hive directory, rows)`` of each partition of ``table``, rows in input order."""
    assert plan.partition_by is not None
    keys = plan.partition_by
    partitioning = ds.partitioning(pa.schema([plan.out_schema.field(k) for k in keys]), flavor="hive")
    rest = table.drop_columns(keys)
    out = []
    for combo in table.select(keys).group_by(keys, use_threads=False).aggregate([]).to_pylist():
        expr: pc.Expression | None = None
        mask = None
        for k in keys:
            v = combo[k]
            e = pc.field(k).is_null() if v is None else pc.field(k) == v
            m = pc.is_null(table.column(k)) if v is None else pc.fill_null(pc.equal(table.column(k), v), False)
            expr = e if expr is None else expr & e
            mask = m if mask is None else pc.and_(mask, m)
        directory, _ = partitioning.format(expr)
        out.append((directory, rest.filter(mask)))
    return sorted(out, key=lambda x: x[0])


def _write_file_outputs(task: _FileTask, plan: _Plan, outcome: _FileOutcome) -> None:
    """Stream one file's results to its output(s) under temporary names, then publish them."""
    assert plan.out_fs is not None
    fs = plan.out_fs
    writers: dict[str, _AtomicParquet] = {}
    ids: list[pa.Array] = []

    def writer(rel_dir: str) -> _AtomicParquet:
        if rel_dir not in writers:
            final = "/".join(p for p in (plan.out_dir, rel_dir, task.output) if p)
            keys = plan.partition_by or []
            schema = pa.schema([f for f in plan.out_schema if f.name not in keys], metadata=plan.out_schema.metadata)
            writers[rel_dir] = _AtomicParquet(fs, final, schema)
        return writers[rel_dir]

    try:
        for result in _detect_file(task, plan):
            outcome.stats.tally(result)
            if plan.long_layout:
                ids.append(_one_array(result.column("tightening_id")))
            if plan.partition_by is None:
                writer("").write(result)
            else:
                for rel_dir, rows in _partition_dirs(plan, result):
                    writer(rel_dir).write(rows)
        if not writers and plan.partition_by is None:
            writer("")  # a file without results still gets its (empty) results file
    except BaseException:
        for w in writers.values():
            w.abort()
        raise
    for w in writers.values():
        w.commit()
    outcome.outputs = [w.final for w in writers.values()]
    if ids:
        outcome.ids = pa.concat_arrays(ids)
    _write_json(
        fs,
        _manifest_path(plan, task.name),
        {
            "input": task.name,
            "scan_key": plan.scan_key,
            "outputs": outcome.outputs,
            "stats": {
                "tightenings": outcome.stats.tightenings,
                "samples": outcome.stats.samples,
                "changes": outcome.stats.changes,
                "status_counts": outcome.stats.status_counts,
            },
        },
    )


def _scan_file(task: _FileTask, plan: _Plan, sink: "_AtomicParquet | None" = None) -> _FileOutcome:
    """One file, start to end; what an engine runs as one task. Bad-file errors come back in
    the outcome (the same on every engine), anything else raises and the engine may retry:
    a retry writes the same final names again, never a second copy.

    Into one results file, a ``sink`` (the local engine, when any bad file fails the whole
    scan) takes the results batch by batch as they come; without one (Dask, Ray, or
    ``on_bad_file="skip"``, where a file found bad half-way must leave no rows) the file's
    results come back whole in the outcome for the driver to write."""
    outcome = _FileOutcome(task.index, task.name)
    try:
        if plan.out_fs is None and sink is not None:
            ids: list[pa.Array] = []
            for result in _detect_file(task, plan):
                outcome.stats.tally(result)
                if plan.long_layout:
                    ids.append(_one_array(result.column("tightening_id")))
                sink.write(result)
            if plan.long_layout:
                outcome.ids = pa.concat_arrays(ids) if ids else pa.array([], plan.out_schema.field("tightening_id").type)
        elif plan.out_fs is None:
            tables = list(_detect_file(task, plan))
            outcome.table = pa.concat_tables(tables) if tables else plan.out_schema.empty_table()
            outcome.stats.tally(outcome.table)
            if plan.long_layout:
                outcome.ids = outcome.table.column("tightening_id").combine_chunks()
        else:
            _write_file_outputs(task, plan, outcome)
    except (SchemaError, DataFileError) as e:
        outcome.error = (type(e).__name__, str(e), getattr(e, "column", None))
    return outcome


def _one_array(column: pa.ChunkedArray | pa.Array) -> pa.Array:
    """A column as one array (free when it is one chunk already, as the engine's are)."""
    if isinstance(column, pa.ChunkedArray):
        return column.chunk(0) if column.num_chunks == 1 else column.combine_chunks()
    return column


# ---------------------------------------------------------------------------------------------
# Engines: the same per-file function, here, on Dask or on Ray


def _run_local(tasks: list[_FileTask], plan: _Plan, bar: Progress, sink: "_AtomicParquet | None" = None) -> Generator[_FileOutcome, None, None]:
    for task in tasks:
        yield _scan_file(task, plan, sink)
        bar.advance()


def _run_dask(tasks: list[_FileTask], plan: _Plan, bar: Progress) -> Generator[_FileOutcome, None, None]:
    try:
        from distributed import Client, get_client
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("engine='dask' needs dask.distributed: pip install 'tightscan[dask]'") from e
    own: Any = None
    client: Any
    try:
        client = get_client()
    except ValueError:
        # No client yet: a local cluster for this scan. To use a real cluster, create
        # `dask.distributed.Client(address)` before scanning.
        make_client: Any = Client
        own = client = make_client(processes=True, dashboard_address=":0")
    try:
        scan_id = uuid.uuid4().hex[:12]
        futures = client.map(
            _scan_file, tasks, plan=plan, pure=False, retries=2, key=[f"tightscan-{scan_id}-{t.index}" for t in tasks]
        )
        consumed = 0
        try:
            for future in futures:
                yield future.result()
                consumed += 1
                bar.advance()
        finally:
            if consumed < len(futures):
                client.cancel(futures[consumed:])
    finally:
        if own is not None:
            own.close()


def _run_ray(tasks: list[_FileTask], plan: _Plan, bar: Progress) -> Generator[_FileOutcome, None, None]:
    try:
        import ray
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("engine='ray' needs Ray: pip install 'tightscan[ray]'") from e
    started = False
    if not ray.is_initialized():
        # No Ray yet: a local one for this scan (or the cluster of RAY_ADDRESS). To use a
        # real cluster, call `ray.init(address=...)` before scanning.
        ray.init(include_dashboard=False, log_to_driver=False)
        started = True
    try:
        remote = ray.remote(max_retries=3)(_scan_file)
        plan_ref = ray.put(plan)
        refs = [remote.remote(t, plan_ref) for t in tasks]
        consumed = 0
        try:
            for ref in refs:
                yield ray.get(ref)
                consumed += 1
                bar.advance()
        finally:
            # Only tasks still running or queued (a scan stopped by an error): cancelling
            # finished ones trips Ray's task manager.
            left = refs[consumed:]
            if left:
                _, running = ray.wait(left, num_returns=len(left), timeout=0)
                for ref in running:
                    ray.cancel(ref)
    finally:
        if started:
            ray.shutdown()


_ENGINES: dict[str, Callable[[list[_FileTask], _Plan, Progress], Generator[_FileOutcome, None, None]]] = {
    "local": _run_local,
    "dask": _run_dask,
    "ray": _run_ray,
}


# ---------------------------------------------------------------------------------------------
# The scan


def _scan_key(plan: _Plan) -> str:
    """What makes two scans' results interchangeable: a resumed scan only keeps outputs of the same key."""
    text = json.dumps(
        {
            "version": _core.__version__,
            "config": plan.config,
            "pass": plan.pass_cols,
            "columns": plan.columns,
            "filter": str(plan.filter) if plan.filter is not None else None,
            "partition_by": plan.partition_by,
            "schema": plan.out_schema.to_string(),
        },
        sort_keys=True,
        default=str,
    )
    return hashlib.sha256(text.encode()).hexdigest()


def _destination(destination: PathLike, partition_by: Sequence[str] | None, filesystem: Any) -> tuple[pafs.FileSystem, str, bool]:
    text = os.fspath(destination)
    # The source's filesystem also reaches a destination URI of its kind (s3:// beside an
    # S3 endpoint of one's own); anything else is found from the destination itself.
    same_kind = filesystem is not None and "://" in text and urlparse(text).scheme == _arrow_filesystem(filesystem).type_name
    fs, path = _split_uri(text, filesystem if same_kind else None)
    single = path.lower().endswith(PARQUET_SUFFIXES) and not partition_by
    if partition_by and path.lower().endswith(PARQUET_SUFFIXES):
        raise InvalidParameterError(f"partition_by writes a directory of results; {text} names a file", "partition_by")
    return fs, path, single


def _tasks_from_dataset(dataset: ds.Dataset, filter: pc.Expression | None) -> tuple[list[_FileTask], pa.Schema, str, pafs.FileSystem | None]:
    if isinstance(dataset, ds.FileSystemDataset):
        part = dataset.partitioning
        partition_schema = part.schema if part is not None else pa.schema([])
        fragments = list(dataset.get_fragments(filter=filter) if filter is not None else dataset.get_fragments())
        paths = [f.path for f in fragments]
        base = os.path.commonpath([p.rsplit("/", 1)[0] for p in paths]) if paths and all(p.startswith("/") for p in paths) else ""
        fs = dataset.filesystem
        tasks = [_FileTask(i, _display(fs, f.path), f, _flat_name(_relative(f.path, base))) for i, f in enumerate(fragments)]
        return tasks, partition_schema, base, fs
    # Not files (an InMemoryDataset, a union): one unit, read through the dataset itself.
    return [_FileTask(0, "<dataset>", _DatasetFragment(dataset), "part-0.parquet")], pa.schema([]), "", None


class _DatasetFragment:
    """A whole non-file dataset behind the two calls a file fragment answers."""

    def __init__(self, dataset: ds.Dataset) -> None:
        self.dataset = dataset

    @property
    def physical_schema(self) -> pa.Schema:
        schema: pa.Schema = self.dataset.schema
        return schema


def _flat_name(rel: str) -> str:
    """One output per input file, named after its path below the source: ``plant=A/x.parquet``
    -> ``plant=A__x.parquet`` (flat, so that no input directory reads as a hive key of the results)."""
    name = rel.replace("/", "__")
    return name if name.lower().endswith(PARQUET_SUFFIXES) else name + ".parquet"


@dataclass
class _Setup:
    plan: _Plan
    tasks: list[_FileTask]
    bad: dict[int, tuple[str, str, str | None]]
    single: bool
    out_fs: pafs.FileSystem
    out_path: str


def _plan_scan(
    source: SourceLike,
    destination: PathLike,
    config: ConfigLike = None,
    *,
    columns: Sequence[str] | None = None,
    filter: pc.Expression | None = None,
    partitioning: str | ds.Partitioning | None = "hive",
    filesystem: Any = None,
    passthrough: Sequence[str] | bool | None = None,
    batch_size: int | None = None,
    partition_by: Sequence[str] | None = None,
    on_bad_file: str = "raise",
    resume: bool = False,
) -> _Setup:
    """Everything a scan decides before it reads a row: the files, the schema, the plan."""
    if on_bad_file not in ("raise", "skip"):
        raise InvalidParameterError(f"on_bad_file must be 'raise' or 'skip', not {on_bad_file!r}", "on_bad_file")
    if batch_size is not None and batch_size < 1:
        raise InvalidParameterError(f"batch_size must be positive, not {batch_size}", "batch_size")
    if isinstance(columns, str):
        columns = [columns]
    if isinstance(partition_by, str):
        partition_by = [partition_by]
    out_fs, out_path, single = _destination(destination, partition_by, filesystem)
    if resume and single:
        raise InvalidParameterError("resume needs a directory destination (one results file per input file)", "resume")

    # Which files, and how their paths read as partitions
    if isinstance(source, ds.Dataset):
        tasks, partition_schema, _base, _in_fs = _tasks_from_dataset(source, filter)
        if not tasks:
            raise DataFileError("the dataset has no files (after the filter)", "<dataset>")
    else:
        exclude = out_path if isinstance(out_fs, pafs.LocalFileSystem) else None
        inputs = _list_inputs(source, filesystem, exclude)
        if partitioning == "hive":
            part = _hive_partitioning(inputs.files, inputs.base)
        elif partitioning is None or isinstance(partitioning, ds.Partitioning):
            part = partitioning
        else:
            raise InvalidParameterError(f"partitioning must be 'hive', None or a pyarrow.dataset.Partitioning, not {partitioning!r}", "partitioning")
        partition_schema = part.schema if part is not None else pa.schema([])
        fmt = ds.ParquetFileFormat()
        fragments = []
        for path in inputs.files:
            rel = _relative(path, inputs.base)
            # the directories only, as pyarrow.dataset does: a file name is never a key
            expr = part.parse("/" + rel.rpartition("/")[0] + "/") if part is not None else pc.scalar(True)
            fragments.append(fmt.make_fragment(path, filesystem=inputs.filesystem, partition_expression=expr))
        tasks = [
            _FileTask(i, _display(inputs.filesystem, path), frag, _flat_name(_relative(path, inputs.base)))
            for i, (path, frag) in enumerate(zip(inputs.files, fragments))
        ]
        names = [t.output for t in tasks]
        if len(set(names)) != len(names):
            dup = next(n for n in names if names.count(n) > 1)
            raise InvalidParameterError(f"two input files would write the same results file {dup}: scan them separately", "source")

    # The scan's results schema, from the first file that fits the data contract
    cfg = as_dict(config)
    bad: dict[int, tuple[str, str, str | None]] = {}
    plan: _Plan | None = None
    for task in tasks:
        try:
            schema = _file_schema(task.fragment, task.name, partition_schema)
            names_read = _projection(schema, columns, []) or schema.names
            pass_cols = _passthrough_list(passthrough, [c for c in names_read if c in schema.names])
            cols = _projection(schema, columns, pass_cols)
            missing = [c for c in cols or [] if c not in schema.names]
            if missing:
                raise SchemaError(f"{task.name}: column {missing[0]!r} is missing (file has: {', '.join(schema.names)})", missing[0])
            projected = pa.schema([schema.field(c) for c in cols]) if cols is not None else schema
            try:
                out_schema: pa.Schema = _core.result_schema(projected, cfg, pass_cols)
            except SchemaError as e:
                raise SchemaError(f"{task.name}: {e}", e.column) from e
        except (SchemaError, DataFileError) as e:
            if on_bad_file == "raise":
                raise
            bad[task.index] = (type(e).__name__, str(e), getattr(e, "column", None))
            continue
        plan = _Plan(
            config=cfg,
            pass_cols=pass_cols,
            columns=list(columns) if columns is not None else None,
            filter=filter,
            batch_size=batch_size,
            partition_schema=partition_schema,
            out_schema=out_schema,
            long_layout=_is_long_layout(projected),
            partition_by=list(partition_by) if partition_by else None,
        )
        if "tightening_id" not in projected.names:
            # Row numbers stand in for the id; they go on across files as in one table.
            offset = 0
            for t in tasks:
                t.first_row = offset
                try:
                    t_schema = _file_schema(t.fragment, t.name, partition_schema)
                    offset += ds.Scanner.from_fragment(t.fragment, schema=t_schema, columns=[], filter=filter).count_rows()
                except (pa.ArrowInvalid, OSError, SchemaError, DataFileError):
                    pass  # a bad file: its own task says so
        break
    if plan is None:
        first = next(iter(bad.values()))
        raise SchemaError(f"no input file fits the data contract ({len(bad)} bad; the first: {first[1]})", first[2])
    for col in plan.partition_by or []:
        if col not in plan.out_schema.names:
            raise InvalidParameterError(f"partition_by column {col!r} is not in the results (pass it through)", "partition_by")
    plan.scan_key = _scan_key(plan)
    # how the results were made, in every results file's footer (after the key: the key
    # already holds the version and the config)
    plan.out_schema = schema_with_metadata(plan.out_schema, scan_metadata(plan.config))

    # Prune files whose partitions the filter excludes (the reader prunes row groups)
    if filter is not None and not isinstance(source, ds.Dataset) and len(partition_schema):
        try:
            first_schema = _file_schema(next(t for t in tasks if t.index not in bad).fragment, "", partition_schema)
            pruner = ds.FileSystemDataset([t.fragment for t in tasks], first_schema, ds.ParquetFileFormat(), tasks[0].fragment.filesystem)
            keep = {f.path for f in pruner.get_fragments(filter=filter)}
            tasks = [t for t in tasks if t.fragment.path in keep]
        except (pa.ArrowInvalid, pa.ArrowTypeError, pa.ArrowNotImplementedError):
            pass  # the filter does not bind to the first file: every file is read and filtered

    if not single:
        plan.out_fs, plan.out_dir = out_fs, out_path
    return _Setup(plan, tasks, bad, single, out_fs, out_path)


def scan_parquet(
    source: SourceLike,
    destination: PathLike,
    config: ConfigLike = None,
    *,
    columns: Sequence[str] | None = None,
    filter: pc.Expression | None = None,
    partitioning: str | ds.Partitioning | None = "hive",
    filesystem: Any = None,
    passthrough: Sequence[str] | bool | None = None,
    batch_size: int | None = None,
    progress: bool | None = None,
    engine: Engine = "local",
    partition_by: Sequence[str] | None = None,
    on_bad_file: Literal["raise", "skip"] = "raise",
    resume: bool = False,
) -> ScanSummary:
    """Detect friction changes in Parquet files where they live and write the results as Parquet.

    ``source``: a file, a directory (every data file below it; names starting with ``.`` or
    ``_`` are not data), a glob (``**`` spans directories), a list of them, a URI
    (``file://``, ``s3://``, ``gs://``, ``abfs://``, ``hdfs://``; other schemes through
    fsspec), or a ``pyarrow.dataset.Dataset``. ``filesystem`` (a ``pyarrow.fs`` or fsspec
    filesystem) says how to reach the paths, e.g. an S3 endpoint of one's own.

    Hive directories (``station=7/``) below the source's directory become columns
    (``partitioning="hive"``, or a ``pyarrow.dataset.Partitioning``, or None) that pass
    through like any other (``passthrough=True`` or ``["station"]``). ``columns`` reads only
    those columns; ``filter`` (a ``pyarrow.compute`` expression) skips partitions and row
    groups in the reader. Filter on columns constant within a tightening (station, day):
    a filter on samples would cut curves.

    ``destination``: a ``*.parquet`` file, or a directory (any other name) that gets one
    results file per input file, in hive directories by ``partition_by`` columns of the
    results. Outputs appear only when complete (temporary name, then rename), so a killed
    scan leaves nothing that looks finished; in a directory, ``resume=True`` skips the input
    files whose results are complete (recorded in ``_tightscan/``) and scans the rest.

    Memory stays bounded whatever the files' size: each file is read a batch at a time
    (``batch_size`` rows; by default about 16 MB of decoded data, from the file's own row
    sizes) by a thread that decodes a couple of batches ahead of the engine, column chunks
    through a small buffer rather than whole row groups; results are written as they come.

    ``engine``: ``"local"`` (this process, all cores in Rust), ``"dask"`` (the current
    ``dask.distributed`` client, else a local cluster) or ``"ray"`` (the running Ray, else a
    local one); one task per input file, the same rows in the same order on every engine.

    Raises :class:`DataFileError` naming a file that is missing or unreadable and
    :class:`SchemaError` naming the file and column that breaks the data contract; with
    ``on_bad_file="skip"`` such files are left out and listed in the summary instead. A
    failed scan leaves no results file behind (in a directory: the files completed before).
    Within a file, a long-layout tightening whose rows reappear after other tightenings
    (or in a later file) is an error naming the file and the id.
    """
    started = time.perf_counter()
    if engine not in _ENGINES:
        raise InvalidParameterError(f"engine must be one of {', '.join(_ENGINES)}, not {engine!r}", "engine")
    setup = _plan_scan(
        source,
        destination,
        config,
        columns=columns,
        filter=filter,
        partitioning=partitioning,
        filesystem=filesystem,
        passthrough=passthrough,
        batch_size=batch_size,
        partition_by=partition_by,
        on_bad_file=on_bad_file,
        resume=resume,
    )
    plan, tasks, bad, single = setup.plan, setup.tasks, setup.bad, setup.single
    summary = ScanSummary(destination=os.fspath(destination), engine=engine)
    if not single:
        _prepare_directory(plan, resume)

    # Resume: files complete in the destination are not read again
    if resume:
        done = _complete_files(plan)
        todo = []
        for t in tasks:
            entry = done.get(t.name)
            if entry is not None:
                summary.resumed_files += 1
                summary._add(_Stats(**entry["stats"]))
            else:
                todo.append(t)
        tasks = todo

    bar = Progress("scanning files", len(tasks), progress, unit="files")
    sink: _AtomicParquet | None = _AtomicParquet(setup.out_fs, setup.out_path, plan.out_schema) if single else None
    seen_ids: set[Any] = set()
    todo_tasks = [t for t in tasks if t.index not in bad]
    if engine == "local" and sink is not None and on_bad_file == "raise":
        # results go straight into the file as they come: a bad file fails the scan anyway
        outcomes = _run_local(todo_tasks, plan, bar, sink)
    else:
        outcomes = _ENGINES[engine](todo_tasks, plan, bar)
    try:
        by_index = {t.index: t for t in tasks}
        for task in tasks:
            if task.index in bad:
                summary.skipped_files.append((task.name, _reason(task.name, bad[task.index][1])))
                continue
            outcome = next(outcomes)
            assert outcome.index == task.index
            if outcome.error is None and plan.long_layout and outcome.ids is not None:
                ids = outcome.ids.to_pylist()
                repeated = seen_ids.intersection(ids)
                if repeated:
                    _discard(plan, outcome, by_index[outcome.index])
                    outcome.error = (
                        "SchemaError",
                        f"{outcome.name}: tightening {next(iter(repeated))!r} appears again after other tightenings "
                        "(in an earlier file): the long layout must keep each tightening's rows together",
                        "tightening_id",
                    )
                else:
                    seen_ids.update(ids)
            if outcome.error is not None:
                kind, message, column = outcome.error
                if on_bad_file == "raise":
                    if kind == "DataFileError":
                        raise DataFileError(message, outcome.name)
                    raise SchemaError(message, column)
                summary.skipped_files.append((outcome.name, _reason(outcome.name, message)))
                continue
            if sink is not None and outcome.table is not None:
                sink.write(outcome.table)
            summary.files += 1
            summary._add(outcome.stats)
            if bar.enabled:  # files/s is the bar's rate; the tightenings and their rate beside it
                rate = summary.tightenings / max(time.perf_counter() - started, 1e-9)
                bar.describe(f"scanning files: {summary.tightenings:,} tightenings, {rate:,.0f}/s")
        outcomes.close()  # the engine lets go of its workers before the results are published
        if sink is not None:
            sink.commit()
            sink = None
            _remove_leftovers(setup.out_fs, setup.out_path)
    finally:
        outcomes.close()  # on an error too: cancel what is still queued, stop a cluster of our own
        if sink is not None:
            sink.abort()
        bar.close()
    summary.seconds = time.perf_counter() - started
    return summary


def _reason(name: str, message: str) -> str:
    """An error message without the file name in it (the summary lists that beside it)."""
    if message.startswith(f"{name}: "):
        return message[len(name) + 2 :]
    return message.replace(f" {name}: ", ": ", 1)


def _prepare_directory(plan: _Plan, resume: bool) -> None:
    """A fresh scan into a directory removes what an earlier scan there wrote (its manifest
    lists it) and the temporary files a killed one left; other files are not touched."""
    fs = plan.out_fs
    assert fs is not None
    fs.create_dir(f"{plan.out_dir}/{MANIFEST_DIR}", recursive=True)
    infos = fs.get_file_info(pafs.FileSelector(plan.out_dir, recursive=True))
    for info in infos:
        if info.type == pafs.FileType.File and TMP_MARK in info.base_name and info.base_name.startswith("."):
            fs.delete_file(info.path)
    if resume:
        return
    for info in infos:
        if info.type == pafs.FileType.File and info.path.startswith(f"{plan.out_dir}/{MANIFEST_DIR}/") and info.path.endswith(".json"):
            entry = _read_json(fs, info.path)
            for output in entry.get("outputs", []) if entry else []:
                try:
                    fs.delete_file(output)
                except OSError:
                    pass
            fs.delete_file(info.path)


def _remove_leftovers(fs: pafs.FileSystem, final: str) -> None:
    """The temporary files of earlier, killed scans to the same results file."""
    parent, _, name = final.rpartition("/")
    prefix = f".{name}{TMP_MARK}"
    try:
        infos = fs.get_file_info(pafs.FileSelector(parent or ".", allow_not_found=True))
        for info in infos:
            if info.type == pafs.FileType.File and info.base_name.startswith(prefix):
                fs.delete_file(info.path)
    except OSError:
        pass  # leftovers are hidden and harmless; failing to list them is no reason to fail


def _read_json(fs: pafs.FileSystem, path: str) -> dict[str, Any] | None:
    try:
        with fs.open_input_stream(path) as f:
            content = json.loads(f.read().decode())
    except (OSError, ValueError):
        return None
    return content if isinstance(content, dict) else None


def _complete_files(plan: _Plan) -> dict[str, dict[str, Any]]:
    """Input files whose results are complete in the destination, by the same kind of scan."""
    fs = plan.out_fs
    assert fs is not None
    done: dict[str, dict[str, Any]] = {}
    for info in fs.get_file_info(pafs.FileSelector(f"{plan.out_dir}/{MANIFEST_DIR}", allow_not_found=True)):
        if info.type != pafs.FileType.File or not info.path.endswith(".json"):
            continue
        entry = _read_json(fs, info.path)
        if entry and entry.get("scan_key") == plan.scan_key:
            done[str(entry["input"])] = entry
    # an entry counts only while all its outputs are there (one listing request for all)
    outputs = sorted({str(o) for entry in done.values() for o in entry.get("outputs", [])})
    present = {i.path for i in fs.get_file_info(outputs) if i.type == pafs.FileType.File} if outputs else set()
    return {name: entry for name, entry in done.items() if all(str(o) in present for o in entry.get("outputs", []))}


def _discard(plan: _Plan, outcome: _FileOutcome, task: _FileTask) -> None:
    """Take back the outputs of a file found bad after they were written."""
    if plan.out_fs is None:
        return
    for output in outcome.outputs:
        try:
            plan.out_fs.delete_file(output)
        except OSError:
            pass
    try:
        plan.out_fs.delete_file(_manifest_path(plan, task.name))
    except OSError:
        pass


def read_results(path: PathLike, columns: Sequence[str] | None = None, filesystem: Any = None) -> pa.Table:
    """Reads the results :func:`scan_parquet` wrote: one file, or a directory of them (hive
    directories of ``partition_by`` become columns again; the manifest and temporary files
    are not read). In a directory, files come in name order, rows in input order within each."""
    fs, p = _split_uri(os.fspath(path), filesystem)
    try:
        info = fs.get_file_info(p)
        if info.type == pafs.FileType.Directory:
            dataset = ds.dataset(p, filesystem=fs, format="parquet", partitioning="hive")
            return dataset.to_table(columns=list(columns) if columns is not None else None)
        return pq.read_table(p, filesystem=fs, columns=list(columns) if columns is not None else None)
    except (pa.ArrowInvalid, OSError) as e:
        raise DataFileError(f"cannot read results {os.fspath(path)}: {e}", os.fspath(path)) from e
