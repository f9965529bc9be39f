"""Import Bosch Rexroth controller JSON exports (one file per tightening) into the nested
tightening table of the data contract (docs/data-contract.md, docs/rexroth-import.md).

The controller writes one JSON file per run: metadata at the top level and the curve split into
``tightening steps``, each with its own ``graph``. The engine wants one row per tightening with
the channels concatenated, so that is what :func:`read_rexroth` builds. A broken file is data,
not an exception: it gets its row, with null channels and an ``import_status`` saying why, so
that a directory of thousands of exports is never stopped by one bad file.

>>> import json, tempfile
>>> from pathlib import Path
>>> run = {"cycle": 7, "result": "OK", "date": "2022-09-05 13:43:39", "tightening steps": [
...     {"name": "Finding", "graph": {"time values": [0.0, 0.1], "angle values": [0.0, 5.0],
...      "torque values": [0.0, 0.2], "gradient values": [0.0, 0.04]}},
...     {"name": "Tightening", "tightening functions": [{"name": "TF Torque", "nom": 1.4, "act": 1.41}],
...      "graph": {"time values": [0.0, 0.1], "angle values": [0.0, 3.0],
...      "torque values": [0.2, 1.41], "gradient values": [0.04, 0.4]}}]}
>>> folder = Path(tempfile.mkdtemp())
>>> _ = (folder / "Ch_000000000007.json").write_text(json.dumps(run))
>>> _ = (folder / "Ch_000000000008.json").write_text("{ truncated")
>>> table = read_rexroth(folder, progress=False)
>>> table.column("import_status").to_pylist()[1].split(":")[0]
'unreadable_json'
>>> row = table.slice(0, 1).to_pylist()[0]
>>> row["tightening_id"], row["import_status"], row["target_torque"], row["step_start_index"]
(7, 'ok', 1.4, [0, 2])
>>> row["angle"], row["time"], row["step"]   # each step restarted at 0: made cumulative
([0.0, 5.0, 5.0, 8.0], [0.0, 0.1, 0.1, 0.2], [0, 0, 1, 1])
>>> table.column("tightening_id").to_pylist()   # an unreadable file keeps the id in its name
[7, 8]
"""

from __future__ import annotations

import bisect
import glob
import json
import math
import os
import re
import warnings
from array import array
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence, Union

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from ._progress import Progress
from .exceptions import DataFileError, InvalidParameterError, SchemaError

__all__ = [
    "read_rexroth",
    "write_rexroth",
    "join_labels",
    "rexroth_schema",
    "rexroth_files",
    "import_summary",
    "RexrothFiles",
    "RexrothImport",
    "ImportSummary",
    "DuplicateRunWarning",
    "STATUS_CODES",
]

PathLike = Union[str, "os.PathLike[str]"]

_loads: Callable[[bytes], Any]
try:  # optional: several times faster than the standard library, never required
    import orjson

    _loads = orjson.loads
except ImportError:  # pragma: no cover - depends on the environment
    _loads = json.loads
# The standard library reads the `NaN` / `Infinity` tokens some controllers write (orjson
# refuses them); they then get the `bad_values` status like any value that is not a number.
_loads_with_nan: Callable[[bytes], Any] = json.loads
# json.JSONDecodeError and orjson.JSONDecodeError are ValueErrors; bad UTF-8 is one too.
_JSON_ERRORS: tuple[type[Exception], ...] = (ValueError, RecursionError)

#: ``import_status`` codes, besides ``ok``. Stable: downstream code may match on them.
STATUS_CODES: dict[str, str] = {
    "unreadable_json": "the file cannot be read, is not JSON, or its top level is not an object",
    "missing_field": "`tightening steps`, a step's `graph`, or its `angle values` or `torque values` are absent",
    "no_steps": "`tightening steps` is an empty list",
    "length_mismatch": "the value lists of one step differ in length",
    "bad_values": "a value list holds something that is not a finite number (NaN, Infinity, a string, null, "
    "true/false), or a field has the wrong type",
}

# A step whose first value lies this far below the previous step's last value restarted its axis
# (exports differ: some write angle and time cumulative over the run, others from 0 per step).
# The angle tolerance is above the backlash seen inside real steps (down to -1 deg at 0.25 deg
# resolution) so that a real small reversal at a join is kept as measured, not "repaired".
ANGLE_RESTART_TOLERANCE_DEG = 1.0
TIME_RESTART_TOLERANCE_S = 1e-6

# (output column, key in a step's graph); the first four always, the others on request. Only
# angle and torque are required: detection needs nothing else, and exports differ in the rest
# (a nutrunner's loosening curves carry angle, torque and time only). A graph may also name a
# channel without the " values" suffix (`angle`, `torque`).
_CHANNELS: tuple[tuple[str, str], ...] = (
    ("time", "time values"),
    ("angle", "angle values"),
    ("torque", "torque values"),
    ("gradient", "gradient values"),
)
_REQUIRED = ("angle", "torque")
_REDUNDANT: tuple[tuple[str, str], ...] = (("torque_red", "torqueRed values"), ("angle_red", "angleRed values"))
_RESTART_TOLERANCE = {"time": TIME_RESTART_TOLERANCE_S, "angle": ANGLE_RESTART_TOLERANCE_DEG}

_F64 = pa.float64()
_METADATA_FIELDS: tuple[pa.Field, ...] = (
    pa.field("tightening_id", pa.int64()),
    pa.field("file_name", pa.utf8()),
    pa.field("import_status", pa.utf8()),
    pa.field("duplicate_id", pa.bool_()),
    pa.field("result", pa.utf8()),
    pa.field("cycle", pa.int64()),
    pa.field("date", pa.timestamp("s")),
    pa.field("program", pa.utf8()),
    pa.field("id_code", pa.utf8()),
    pa.field("nominal_torque", _F64),
    pa.field("tool_serial", pa.int64()),
    pa.field("target_torque", _F64),
    pa.field("n_steps", pa.int32()),
    pa.field("step_names", pa.list_(pa.utf8())),
    pa.field("step_results", pa.list_(pa.utf8())),
    pa.field("step_speeds", pa.list_(_F64)),
    pa.field("step_target_torque", pa.list_(_F64)),
    pa.field("step_target_angle", pa.list_(_F64)),
    pa.field("step_start_index", pa.list_(pa.int32())),
)


def rexroth_schema(keep_redundant: bool = False) -> pa.Schema:
    """The schema :func:`read_rexroth` returns (before any label columns).

    >>> rexroth_schema().names[-5:]
    ['time', 'angle', 'torque', 'gradient', 'step']
    """
    channels = _CHANNELS + (_REDUNDANT if keep_redundant else ())
    fields = list(_METADATA_FIELDS) + [pa.field(name, pa.list_(_F64)) for name, _ in channels]
    fields.insert(len(_METADATA_FIELDS) + 4, pa.field("step", pa.list_(pa.int32())))
    return pa.schema(fields)


# ---------------------------------------------------------------------------------------------
# One file


class _ImportProblem(Exception):
    """Why one file cannot be imported; becomes its ``import_status``, never escapes."""

    def __init__(self, code: str, detail: str) -> None:
        super().__init__(f"{code}: {detail}")
        self.status = f"{code}: {detail}"


@dataclass(frozen=True)
class RexrothImport:
    """One file's row: metadata as Python values, channels as packed float arrays.

    Channels stay ``array('d')`` (not Python lists) so that 5,000 files concatenate into one
    Arrow buffer per channel with memcpy, not element by element.
    """

    file_name: str
    tightening_id: int | None
    import_status: str
    meta: dict[str, Any] = field(default_factory=dict)
    channels: dict[str, "array[float]"] | None = None
    step: "array[int]" | None = None


_ID_IN_NAME = re.compile(r"(\d+)(?!.*\d)")
_INT64_MAX = 2**63 - 1


def _id_from_name(name: str) -> int | None:
    """``Ch_000001596334.json`` -> 1596334: the last run of digits in the name."""
    m = _ID_IN_NAME.search(Path(name).stem)
    if m is None:
        return None
    value = int(m.group(1))
    return value if value <= _INT64_MAX else None


def _as_str(v: object) -> str | None:
    if isinstance(v, str):
        return v
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return str(v)
    return None


def _as_int(v: object) -> int | None:
    """Integers, integral floats and digit strings (some exports quote numbers)."""
    if isinstance(v, bool):
        return None
    if isinstance(v, int):
        out = v
    elif isinstance(v, float) and v.is_integer():
        out = int(v)
    elif isinstance(v, str) and v.strip().lstrip("+-").isdigit():
        out = int(v.strip())
    else:
        return None
    return out if -_INT64_MAX - 1 <= out <= _INT64_MAX else None


def _as_float(v: object) -> float | None:
    """A finite number, else None (a `NaN` in the metadata is as good as absent)."""
    if isinstance(v, bool):
        return None
    out: float | None = None
    if isinstance(v, (int, float)):
        try:
            out = float(v)
        except OverflowError:
            return None
    elif isinstance(v, str):
        try:
            out = float(v)
        except ValueError:
            return None
    return out if out is not None and math.isfinite(out) else None


def _as_date(v: object) -> datetime | None:
    """Controller local time, naive; an offset, if any, is dropped (wall clock kept)."""
    if not isinstance(v, str):
        return None
    try:
        parsed = datetime.fromisoformat(v.strip())
    except ValueError:
        return None
    return parsed.replace(tzinfo=None, microsecond=0)


def _function_nom(step: dict[str, Any], name: str) -> float | None:
    """``nom`` of the step's first tightening function called ``name`` ("TF Torque" ...)."""
    functions = step.get("tightening functions")
    if not isinstance(functions, list):
        return None
    for f in functions:
        if isinstance(f, dict) and f.get("name") == name:
            return _as_float(f.get("nom"))
    return None


def _step_label(i: int, step: dict[str, Any]) -> str:
    name = step.get("name")
    return f"step {i + 1} {name!r}" if isinstance(name, str) else f"step {i + 1}"


def _first_non_number(values: list[Any]) -> tuple[int, Any]:
    for j, v in enumerate(values):
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            return j, v
        try:
            float(v)
        except OverflowError:
            return j, v
    return -1, None  # pragma: no cover - only called after a failed conversion


def _packed(values: list[Any], label: str, key: str, has_literals: bool) -> "array[float]":
    """The list as packed doubles; anything but a JSON number is ``bad_values``.

    ``array('d', ...)`` converts in C and refuses null and strings, but takes ``true`` as 1.0,
    so booleans are looked for element by element only when the file contains the literals.
    """
    try:
        out = array("d", values)
        if has_literals and any(isinstance(v, bool) for v in values):
            raise TypeError("a boolean is not a number")
    except (TypeError, OverflowError):
        j, v = _first_non_number(values)
        raise _ImportProblem("bad_values", f"{label} {key}[{j}] is {json.dumps(v)[:40]}, not a number") from None
    return out


def _check_finite(channels: dict[str, "array[float]"], starts: list[int], labels: list[str], keys: list[dict[str, str]]) -> None:
    """`NaN` / `Infinity` tokens (and numbers too large for a double) are ``bad_values``: JSON has
    no such numbers. Checked once per channel of the run, located only when found."""
    for name, values in channels.items():
        samples = np.frombuffer(values, dtype=np.float64)
        if math.isfinite(float(np.add.reduce(samples))):  # one pass; a sum is finite only if all are
            continue
        finite = np.isfinite(samples)
        if not finite.all():  # else finite values whose sum overflowed
            at = int(np.argmin(finite))
            i = bisect.bisect_right(starts, at) - 1
            raise _ImportProblem("bad_values", f"{labels[i]} {keys[i][name]}[{at - starts[i]}] is {json.dumps(values[at])}, not a finite number")


def _shift(values: "array[float]", offset: float) -> "array[float]":
    shifted = array("d")
    shifted.frombytes((np.frombuffer(values, dtype=np.float64) + offset).tobytes())
    return shifted


def _channel_values(graph: dict[str, Any], key: str) -> tuple[str, Any] | None:
    """The graph's entry for ``key`` (``angle values``), or for its bare name (``angle``)."""
    for candidate in (key, key.removesuffix(" values")):
        values = graph.get(candidate)
        if values is not None:
            return candidate, values
    return None


def _parse_run(doc: dict[str, Any], channel_keys: Sequence[tuple[str, str]], has_literals: bool) -> tuple[dict[str, Any], dict[str, "array[float]"], "array[int]"]:
    """Step-derived metadata and the concatenated channels; raises :class:`_ImportProblem`."""
    if "tightening steps" not in doc:
        raise _ImportProblem("missing_field", "no 'tightening steps'")
    steps = doc["tightening steps"]
    if not isinstance(steps, list):
        raise _ImportProblem("bad_values", f"'tightening steps' is a {type(steps).__name__}, not a list")
    if not steps:
        raise _ImportProblem("no_steps", "'tightening steps' is empty")
    channels = {name: array("d") for name, _ in channel_keys}
    step_channel = array("i")
    last: dict[str, float] = {}  # last value so far of each restart-checked channel, after offsets
    starts: list[int] = []
    absent: set[str] = set()  # optional channels some step lacks
    labels: list[str] = []
    keys: list[dict[str, str]] = []  # per step: channel -> the key it was found under
    for i, step in enumerate(steps):
        if not isinstance(step, dict):
            raise _ImportProblem("bad_values", f"step {i + 1} is a {type(step).__name__}, not an object")
        label = _step_label(i, step)
        graph = step.get("graph")
        if graph is None:
            raise _ImportProblem("missing_field", f"{label} has no 'graph'")
        if not isinstance(graph, dict):
            raise _ImportProblem("bad_values", f"{label} 'graph' is a {type(graph).__name__}, not an object")
        lists: dict[str, tuple[str, list[Any]]] = {}
        for name, key in channel_keys:
            found = _channel_values(graph, key)
            if found is None:
                if name in _REQUIRED:
                    raise _ImportProblem("missing_field", f"{label} has no '{key}'")
                absent.add(name)  # optional: the whole row's channel becomes null
                continue
            used_key, values = found
            if not isinstance(values, list):
                raise _ImportProblem("bad_values", f"{label} '{used_key}' is a {type(values).__name__}, not a list")
            lists[name] = (used_key, values)
        n = len(lists["angle"][1])  # angle is the engine's axis: the others are measured against it
        for key, values in lists.values():
            if len(values) != n:
                raise _ImportProblem(
                    "length_mismatch", f"{label} has {n} angle values and {len(values)} {key.replace(' values', '')} values"
                )
        starts.append(len(step_channel))
        labels.append(label)
        keys.append({name: key for name, (key, _) in lists.items()})
        for name, (key, values) in lists.items():
            packed = _packed(values, label, key, has_literals)
            tolerance = _RESTART_TOLERANCE.get(name)
            if tolerance is not None and n:
                previous = last.get(name)
                if previous is not None and packed[0] < previous - tolerance:
                    packed = _shift(packed, previous - packed[0])
                last[name] = packed[-1]
            channels[name].extend(packed)
        step_channel.extend(array("i", [i]) * n)
    present = {k: v for k, v in channels.items() if k not in absent}
    _check_finite(present, starts, labels, keys)
    last_step = steps[-1]
    meta = {
        "target_torque": _function_nom(last_step, "TF Torque"),
        "step_names": [_as_str(s.get("name")) for s in steps],
        "step_results": [_as_str(s.get("result")) for s in steps],
        "step_speeds": [_as_float(s.get("speed")) for s in steps],
        "step_target_torque": [_function_nom(s, "TF Torque") for s in steps],
        "step_target_angle": [_function_nom(s, "TF Angle") for s in steps],
        "step_start_index": starts,
    }
    return meta, present, step_channel


def _import_file(path: str, name: str, channel_keys: Sequence[tuple[str, str]]) -> RexrothImport:
    try:
        with open(path, "rb") as fh:
            raw = fh.read()
    except OSError as e:
        return RexrothImport(name, _id_from_name(name), f"unreadable_json: cannot read the file: {e.strerror or e}")
    try:
        doc = _loads(raw)
    except _JSON_ERRORS as e:
        try:
            if _loads is _loads_with_nan or not (b"NaN" in raw or b"Infinity" in raw):
                raise
            doc = _loads_with_nan(raw)
        except _JSON_ERRORS:
            return RexrothImport(name, _id_from_name(name), f"unreadable_json: {str(e)[:200]}")
    if not isinstance(doc, dict):
        return RexrothImport(name, _id_from_name(name), f"unreadable_json: top level is a {type(doc).__name__}, not an object")
    cycle = _as_int(doc.get("cycle"))
    steps = doc.get("tightening steps")
    meta: dict[str, Any] = {
        "result": _as_str(doc.get("result")),
        "cycle": cycle,
        "date": _as_date(doc.get("date")),
        "program": _as_str(doc.get("prg name")),
        "id_code": _as_str(doc.get("id code")),
        "nominal_torque": _as_float(doc.get("nominal torque")),
        "tool_serial": _as_int(doc.get("tool serial")),
        "n_steps": len(steps) if isinstance(steps, list) else None,
    }
    tid = cycle if cycle is not None else _id_from_name(name)
    try:
        step_meta, channels, step = _parse_run(doc, channel_keys, b"true" in raw or b"false" in raw)
    except _ImportProblem as problem:
        return RexrothImport(name, tid, problem.status, meta)
    meta.update(step_meta)
    return RexrothImport(name, tid, "ok", meta, channels, step)


# ---------------------------------------------------------------------------------------------
# Many files


@dataclass(frozen=True)
class RexrothFiles:
    """The export files an import reads, and the files it passed over.

    ``paths`` are the files in import order, ``names`` what each row's ``file_name`` becomes
    (the path below the directory searched, or the base name of a file given), ``skipped`` the
    files found in the searched directories that are not ``*.json``.
    """

    paths: tuple[str, ...]
    names: tuple[str, ...]
    skipped: tuple[str, ...] = ()


def _is_json_name(name: str) -> bool:
    # Controllers and file shares disagree on case: `Ch_1.json` and `CH_1.JSON` are both exports.
    return name.lower().endswith(".json")


def _walk(directory: str) -> Iterator[tuple[str, str]]:
    """(path, path relative to ``directory`` with ``/``) of every file below ``directory``, in
    sub-directories too, in sorted order. Strings, not Paths: 5,000 Path objects cost more than
    the walk."""
    for root, dirs, files in os.walk(directory):
        dirs.sort()
        prefix = os.path.relpath(root, directory).replace(os.sep, "/")
        prefix = "" if prefix == "." else prefix + "/"
        for f in sorted(files):
            yield os.path.join(root, f), prefix + f


def rexroth_files(paths: PathLike | Sequence[PathLike] | RexrothFiles) -> RexrothFiles:
    """The files :func:`read_rexroth` reads for ``paths``.

    A directory gives every ``*.json`` below it, in sub-directories too, the extension matched
    in any case (``.json``, ``.JSON``), sorted by path; a glob its matches (sorted); a file
    itself; a list keeps its order, so a caller's list comes back row for row. Other files in
    a searched directory are counted as ``skipped``.

    Raises :class:`DataFileError` naming a path that does not exist or holds no export.

    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> (folder / "line2").mkdir()
    >>> for name in ["Ch_1.json", "line2/CH_2.JSON", "notes.txt"]:
    ...     _ = (folder / name).write_text("{}")
    >>> found = rexroth_files(folder)
    >>> found.names, [Path(p).name for p in found.skipped]
    (('Ch_1.json', 'line2/CH_2.JSON'), ['notes.txt'])
    """
    if isinstance(paths, RexrothFiles):
        return paths
    items = [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)
    if not items:
        raise DataFileError("no input files given", "")
    found: list[str] = []
    names: list[str] = []
    skipped: list[str] = []
    for item in items:
        text = os.fspath(item)
        path = Path(text)
        if path.is_dir():
            n_before = len(found)
            for file_path, relative in _walk(text):
                if _is_json_name(relative):
                    found.append(file_path)
                    names.append(relative)
                else:
                    skipped.append(file_path)
            if len(found) == n_before:
                raise DataFileError(f"no .json files in directory {text} or below it", text)
        elif path.is_file():
            found.append(text)
            names.append(path.name)
        elif glob.has_magic(text):
            matches = sorted(m for m in glob.glob(text, recursive=True) if os.path.isfile(m))
            if not matches:
                raise DataFileError(f"no files match {text}", text)
            found.extend(matches)
            names.extend(os.path.basename(m) for m in matches)
        else:
            raise DataFileError(f"no such file or directory: {text}", text)
    return RexrothFiles(tuple(found), tuple(names), tuple(skipped))


def _duplicate_ids(ids: list[int | None]) -> list[bool]:
    counts: dict[int, int] = {}
    for i in ids:
        if i is not None:
            counts[i] = counts.get(i, 0) + 1
    return [i is not None and counts[i] > 1 for i in ids]


def _list_array(lengths: list[int | None], values: pa.Array) -> pa.Array:
    """One list per row from flat values; a ``None`` length is a null row."""
    counts = np.fromiter((n or 0 for n in lengths), dtype=np.int64, count=len(lengths))
    offsets = np.zeros(len(lengths) + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    mask = pa.array([n is None for n in lengths], pa.bool_())
    if offsets[-1] > np.iinfo(np.int32).max:  # pragma: no cover - needs > 2**31 samples in memory
        return pa.LargeListArray.from_arrays(pa.array(offsets), values, mask=mask)
    return pa.ListArray.from_arrays(pa.array(offsets.astype(np.int32)), values, mask=mask)


def _build_table(rows: list[RexrothImport], keep_redundant: bool) -> pa.Table:
    schema = rexroth_schema(keep_redundant)
    columns: dict[str, pa.Array] = {
        "tightening_id": pa.array([r.tightening_id for r in rows], pa.int64()),
        "file_name": pa.array([r.file_name for r in rows], pa.utf8()),
        "import_status": pa.array([r.import_status for r in rows], pa.utf8()),
        "duplicate_id": pa.array(_duplicate_ids([r.tightening_id for r in rows]), pa.bool_()),
    }
    for f in _METADATA_FIELDS[4:]:
        columns[f.name] = pa.array([r.meta.get(f.name) for r in rows], f.type)
    lengths = [len(r.step) if r.step is not None else None for r in rows]
    for name, _ in _CHANNELS + (_REDUNDANT if keep_redundant else ()):
        flat = array("d")
        channel_lengths: list[int | None] = []
        for r, n in zip(rows, lengths):
            samples = r.channels.get(name) if r.channels is not None else None
            channel_lengths.append(None if samples is None else n)
            if samples is not None:
                flat.extend(samples)
        columns[name] = _list_array(channel_lengths, pa.array(np.frombuffer(flat, dtype=np.float64)))
    steps = array("i")
    for r in rows:
        if r.step is not None:
            steps.extend(r.step)
    columns["step"] = _list_array(lengths, pa.array(np.frombuffer(steps, dtype=np.int32)))
    return pa.Table.from_arrays([columns[name] for name in schema.names], schema=schema)


def _read_labels(labels: PathLike | pa.Table) -> pa.Table:
    if isinstance(labels, pa.Table):
        return labels
    text = os.fspath(labels)
    if not Path(text).is_file():
        raise DataFileError(f"no such labels file: {text}", text)
    try:
        return pacsv.read_csv(text)
    except (pa.ArrowInvalid, OSError) as e:
        raise DataFileError(f"cannot read labels CSV {text}: {e}", text) from e


def join_labels(table: pa.Table, labels: PathLike | pa.Table, on: tuple[str, str] = ("cycle", "run_id")) -> pa.Table:
    """Left join of ``labels`` onto ``table``: every row kept, in order; label columns appended.

    ``on`` is ``(table column, label column)``. The label key is cast to the table key's type
    (a CSV may read ids as strings) and not repeated; a label column whose name is taken gets a
    ``label_`` prefix. Rows without a match (or with a null key) get nulls. A key that appears
    twice in the labels would need two rows for one run, so it raises :class:`SchemaError`.
    """
    left_key, right_key = on
    label_table = _read_labels(labels)
    if left_key not in table.column_names:
        raise SchemaError(f"the imported table has no column {left_key!r} to join labels on", left_key)
    if right_key not in label_table.column_names:
        raise SchemaError(f"the labels have no key column {right_key!r}", right_key)
    key_type = table.schema.field(left_key).type
    try:
        right = pc.cast(label_table.column(right_key), key_type)
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError) as e:
        raise SchemaError(f"label column {right_key!r} cannot be cast to {key_type} to match {left_key!r}: {e}", right_key) from e
    position: dict[Any, int] = {}
    for i, key in enumerate(right.to_pylist()):
        if key is None:
            continue
        if key in position:
            raise SchemaError(f"the labels have more than one row with {right_key} = {key!r}", right_key)
        position[key] = i
    take = pa.array([position.get(k) for k in table.column(left_key).to_pylist()], pa.int64())
    out = table
    taken = set(table.column_names)
    for name in label_table.column_names:
        if name == right_key:
            continue
        new_name = name
        while new_name in taken:
            new_name = f"label_{new_name}"
        taken.add(new_name)
        out = out.append_column(new_name, label_table.column(name).take(take))
    return out


class DuplicateRunWarning(UserWarning):
    """Two or more imported files carry the same run (the same ``tightening_id``)."""


@dataclass(frozen=True)
class ImportSummary:
    """What an import made of its files: counts, the first failures, the duplicate runs.

    >>> table = pa.table({"tightening_id": [1, 2, 2, 3], "file_name": ["a", "b", "c", "d"],
    ...     "import_status": ["ok", "ok", "ok", "no_steps: 'tightening steps' is empty"],
    ...     "duplicate_id": [False, True, True, False]})
    >>> s = import_summary(table, skipped=("README.txt",))
    >>> s.imported, s.failed, s.skipped, s.duplicates
    (3, 1, 1, {2: ('b', 'c')})
    """

    imported: int
    failed: int
    skipped: int
    #: ``import_status`` code -> files with it.
    failure_codes: dict[str, int]
    #: The first few failures as (file_name, import_status), in import order.
    first_failures: tuple[tuple[str, str], ...]
    #: ``tightening_id`` -> the files that carry it, for every id found more than once.
    duplicates: dict[int, tuple[str, ...]]


def import_summary(table: pa.Table, skipped: Sequence[str] = (), first: int = 5) -> ImportSummary:
    """Counts of an imported table (:func:`read_rexroth`, or the Parquet it wrote): rows with
    ``import_status`` ok, the others (with their ``first`` reasons), ``skipped`` files, and the
    runs that more than one file carries."""
    statuses = table.column("import_status").to_pylist()
    names = table.column("file_name").to_pylist()
    codes: dict[str, int] = {}
    failures: list[tuple[str, str]] = []
    for name, status in zip(names, statuses):
        if status != "ok":
            codes[str(status).split(":")[0]] = codes.get(str(status).split(":")[0], 0) + 1
            if len(failures) < first:
                failures.append((str(name), str(status)))
    duplicates: dict[int, list[str]] = {}
    if "duplicate_id" in table.column_names:
        marked = table.column("duplicate_id").to_pylist()
        for tid, name, dup in zip(table.column("tightening_id").to_pylist(), names, marked):
            if dup:
                duplicates.setdefault(int(tid), []).append(str(name))
    failed = sum(codes.values())
    return ImportSummary(
        imported=len(statuses) - failed,
        failed=failed,
        skipped=len(skipped),
        failure_codes=codes,
        first_failures=tuple(failures),
        duplicates={k: tuple(v) for k, v in duplicates.items()},
    )


def _warn_duplicates(table: pa.Table) -> None:
    duplicates = import_summary(table).duplicates
    if duplicates:
        ids = ", ".join(f"{tid} ({' and '.join(files[:3])}{' ...' if len(files) > 3 else ''})" for tid, files in list(duplicates.items())[:5])
        more = f" and {len(duplicates) - 5:,} more" if len(duplicates) > 5 else ""
        warnings.warn(
            f"{len(duplicates):,} runs are imported from more than one file (column duplicate_id): {ids}{more}",
            DuplicateRunWarning,
            stacklevel=3,
        )


def read_rexroth(
    paths: PathLike | Sequence[PathLike] | RexrothFiles,
    *,
    labels: PathLike | pa.Table | None = None,
    on: tuple[str, str] = ("cycle", "run_id"),
    keep_redundant: bool = False,
    progress: bool | None = None,
) -> pa.Table:
    """Reads Rexroth JSON exports into the nested tightening table, one row per file.

    ``paths`` is a file, a directory (every ``*.json`` below it, any case, sorted), a glob, or a
    list of them (:func:`rexroth_files`). Channels ``time`` [s], ``angle`` [deg], ``torque``
    [Nm], ``gradient`` [Nm/deg] and ``step`` (0-based step number) are the steps' graphs
    concatenated; an axis that restarts at a step is offset so that the step starts where the
    previous one ended. Only angle and torque are required: a run without ``time values`` or
    ``gradient values`` gets a null list there. A file that cannot be imported keeps its row
    with null channels and an ``import_status`` of ``code: detail`` (:data:`STATUS_CODES`).
    Rows whose ``tightening_id`` another file carries too are marked in ``duplicate_id``
    and named in a :class:`DuplicateRunWarning`; both rows are kept, never merged.
    ``labels`` (a CSV file or a table) is left-joined on ``on`` (:func:`join_labels`).
    ``keep_redundant`` adds the second transducer's ``torque_red`` and ``angle_red``. A
    progress bar shows on an interactive terminal (``progress`` forces it).

    Raises :class:`DataFileError` naming a path that does not exist or holds no ``*.json``.
    """
    files = rexroth_files(paths)
    channel_keys = _CHANNELS + (_REDUNDANT if keep_redundant else ())
    bar = Progress("importing Rexroth runs", len(files.paths), progress, unit="runs")
    rows: list[RexrothImport] = []
    try:
        for path, name in zip(files.paths, files.names):
            rows.append(_import_file(path, name, channel_keys))
            bar.advance()
    finally:
        bar.close()
    table = _build_table(rows, keep_redundant)
    _warn_duplicates(table)
    if labels is not None:
        table = join_labels(table, labels, on)
    return table


def write_rexroth(
    paths: PathLike | Sequence[PathLike] | RexrothFiles,
    output: PathLike,
    *,
    labels: PathLike | pa.Table | None = None,
    on: tuple[str, str] = ("cycle", "run_id"),
    keep_redundant: bool = False,
    progress: bool | None = None,
    compression: str = "zstd",
) -> int:
    """:func:`read_rexroth`, written to Parquet at ``output``; returns the number of rows.

    The whole import is held in memory (5,000 runs are about 100 MB), which a per-file JSON
    format makes cheap to redo in parts if ever needed.
    """
    if compression not in ("zstd", "snappy"):
        error = InvalidParameterError(f"compression must be 'zstd' or 'snappy', not {compression!r}")
        error.parameter = "compression"
        raise error
    table = read_rexroth(paths, labels=labels, on=on, keep_redundant=keep_redundant, progress=progress)
    pq.write_table(table, os.fspath(output), compression=compression)
    return int(table.num_rows)

