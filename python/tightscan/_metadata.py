"""How a results table was made, recorded with it: the tightscan version, the rule's alpha, the
full effective detector configuration and the decision rule's shares of alpha, as JSON under the
schema metadata key ``b"tightscan"`` (:data:`RESULTS_METADATA_KEY`) of a pyarrow Table and of
the Parquet files ``tightscan scan`` writes, and in ``DataFrame.attrs["tightscan"]`` of a pandas
result. polars frames carry no schema metadata: ask :func:`scan_metadata` for the same dict.
"""

from __future__ import annotations

import json
import os
from typing import Any, Union

import pyarrow as pa

from . import _core
from .config import ConfigLike, as_dict
from .exceptions import DataFileError

__all__ = ["RESULTS_METADATA_KEY", "scan_metadata", "results_metadata"]

#: Schema metadata key of the record (bytes, as Arrow and Parquet keep keys).
RESULTS_METADATA_KEY = b"tightscan"

PathLike = Union[str, "os.PathLike[str]"]


def scan_metadata(config: ConfigLike = None) -> dict[str, Any]:
    """The record of a run with ``config``: ``version``, ``alpha``, ``rule``, ``detectors``,
    ``shares`` (each detector of the rule: its share of alpha, by the union bound),
    ``derived`` (what the engine derives: the CUSUM threshold, each detector's alpha, the L1
    boundary's critical value) and ``config`` (every parameter, defaults filled in, as the flat
    dict ``detect_batch`` takes). Raises as ``detect_batch`` would for an invalid config.

    >>> m = scan_metadata({"alpha": 0.02})
    >>> m["alpha"], m["shares"]["break"], m["config"]["kappa"]
    (0.02, 0.015, 0.5)
    """
    effective = _core.effective_config(as_dict(config))
    full = effective["config"]
    return {
        "version": _core.__version__,
        "alpha": full["alpha"],
        "rule": full["rule"],
        "detectors": full["detectors"],
        "shares": effective["shares"],
        "derived": effective["derived"],
        "config": full,
    }


def encoded(metadata: dict[str, Any]) -> bytes:
    return json.dumps(metadata, sort_keys=True).encode()


def with_metadata(table: pa.Table, metadata: dict[str, Any]) -> pa.Table:
    """``table`` with the record in its schema metadata (other keys kept)."""
    kv = dict(table.schema.metadata or {})
    kv[RESULTS_METADATA_KEY] = encoded(metadata)
    return table.replace_schema_metadata(kv)


def schema_with_metadata(schema: pa.Schema, metadata: dict[str, Any]) -> pa.Schema:
    kv = dict(schema.metadata or {})
    kv[RESULTS_METADATA_KEY] = encoded(metadata)
    return schema.with_metadata(kv)


def results_metadata(results: Any) -> dict[str, Any] | None:
    """The record of how ``results`` were made (see :func:`scan_metadata`), or None where there
    is none: from a pyarrow Table or Schema, a pandas DataFrame (``attrs``), or the path of a
    results Parquet file or directory of them (its first file's footer).

    >>> import tightscan
    >>> curves, _ = tightscan.simulate(3, seed=1)
    >>> results_metadata(tightscan.detect_batch(curves, {"alpha": 0.02}))["alpha"]
    0.02
    """
    if isinstance(results, (str, os.PathLike)):
        import pyarrow.parquet as pq
        from pathlib import Path

        p = Path(results)
        files = [p] if p.is_file() else sorted(q for q in p.rglob("*.parquet") if not any(part.startswith(("_", ".")) for part in q.relative_to(p).parts))
        if not files:
            return None
        try:
            schema = pq.read_schema(files[0])
        except (pa.ArrowInvalid, OSError) as e:
            raise DataFileError(f"cannot read results {os.fspath(files[0])}: {e}", os.fspath(files[0])) from e
        return results_metadata(schema)
    if isinstance(results, pa.Table):
        results = results.schema
    if isinstance(results, pa.Schema):
        raw = (results.metadata or {}).get(RESULTS_METADATA_KEY)
        return None if raw is None else dict(json.loads(raw))
    attrs = getattr(results, "attrs", None)  # pandas
    if isinstance(attrs, dict) and isinstance(attrs.get("tightscan"), dict):
        return dict(attrs["tightscan"])
    return None
