from __future__ import annotations

import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # makes `import independent_generator` work

import pyarrow as pa
import pytest

import tightscan

REPO = Path(__file__).resolve().parents[1]
N_RUNS = 5000


def rexroth_data_dir() -> Path:
    """``$TIGHTSCAN_SHARED_DATA`` (the shared data directory, or rexroth-s01 itself), else the
    checkout's sibling ``shared/data``."""
    env = os.environ.get("TIGHTSCAN_SHARED_DATA")
    base = Path(env) if env else REPO.parent / "shared" / "data"
    return base if (base / "runs").is_dir() else base / "rexroth-s01"


@pytest.fixture(scope="session")
def rexroth_dir() -> Path:
    """The measured Rexroth s01 runs. CI has them: their absence fails, never skips."""
    d = rexroth_data_dir()
    runs = d / "runs"
    if not runs.is_dir() or not (d / "labels.csv").is_file():
        pytest.fail(f"the Rexroth data set is missing at {d} (set TIGHTSCAN_SHARED_DATA to its location)")
    count = sum(1 for _ in runs.glob("*.json"))
    assert count == N_RUNS, f"{runs} holds {count} JSON files, expected {N_RUNS}"
    return d


@pytest.fixture(scope="session")
def rexroth_s01(rexroth_dir: Path) -> pa.Table:
    """The whole data set, imported once for the session, labels joined."""
    return tightscan.read_rexroth(rexroth_dir / "runs", labels=rexroth_dir / "labels.csv", progress=False)


@pytest.fixture(scope="session")
def simulated() -> tuple[pa.Table, pa.Table]:
    """Labelled curves from the built-in simulator, fixed seed."""
    return tightscan.simulate(600, seed=42)
