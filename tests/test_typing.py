"""The frame kind in is the kind out, for a type checker too (detect_batch's overloads)."""

from __future__ import annotations

from pathlib import Path

from mypy import api

SNIPPET = """
from typing import assert_type
import pandas as pd
import polars as pl
import pyarrow as pa
import tightscan

curves, _ = tightscan.simulate(3, seed=1)
assert_type(tightscan.detect_batch(curves), pa.Table)
assert_type(tightscan.detect_batch(pl.DataFrame(curves)), pl.DataFrame)
assert_type(tightscan.detect_batch(pl.LazyFrame()), pl.DataFrame)
assert_type(tightscan.detect_batch(pd.DataFrame()), pd.DataFrame)
"""


def test_detect_batch_overloads_give_the_frame_kind_back(tmp_path: Path) -> None:
    source = tmp_path / "uses_tightscan.py"
    source.write_text(SNIPPET)
    root = Path(__file__).resolve().parents[1]
    stdout, stderr, status = api.run(
        [str(source), "--config-file", str(root / "pyproject.toml"), "--cache-dir", str(tmp_path / ".mypy_cache"), "--no-incremental"]
    )
    assert status == 0, stdout + stderr
