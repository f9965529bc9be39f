from __future__ import annotations

import pyarrow as pa
import pytest

import tightscan


@pytest.fixture(scope="session")
def simulated() -> tuple[pa.Table, pa.Table]:
    """Labelled curves from the built-in simulator, fixed seed."""
    return tightscan.simulate(600, seed=42)
