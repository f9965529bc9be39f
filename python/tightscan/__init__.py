"""tightscan: find friction changes in bolted-joint tightening curves.

>>> import tightscan
>>> curves, truth = tightscan.simulate(100, seed=3)
>>> results = tightscan.detect_batch(curves)
>>> results.column_names[:3]
['tightening_id', 'status', 'n_samples']
"""

from __future__ import annotations

import warnings

from . import _core
from ._api import ResultColumn, result_columns, cusum_arl, cusum_threshold, detect_batch, result_schema, simulate
from ._scan import ScanSummary, read_results, scan_parquet
from .config import (
    BlockConfig,
    BreakConfig,
    CusumConfig,
    DetectConfig,
    ElasticZoneConfig,
    FrictionConfig,
    L1Config,
    DecisionConfig,
    ResidualTestConfig,
    config_from_toml,
    config_to_toml,
)
from .exceptions import DataFileError, InvalidParameterError, SchemaError, TightscanError
from .diagnose import diagnose
from .rexroth import read_rexroth
from .monitor import RegressionMonitor, monitor_regression, monitoring_critical_value
from .sequence import SequenceMonitor, monitor_sequence

__version__: str = _core.__version__

if _core.DEBUG_BUILD:  # pragma: no cover - depends on how it was built
    warnings.warn(
        "tightscan was built in debug mode and runs many times slower; "
        "build with `maturin develop --release` (or `make demo`)",
        RuntimeWarning,
        stacklevel=2,
    )

__all__ = [
    "detect_batch",
    "diagnose",
    "scan_parquet",
    "read_results",
    "result_schema",
    "result_columns",
    "ResultColumn",
    "read_rexroth",
    "monitor_sequence",
    "monitor_regression",
    "monitoring_critical_value",
    "RegressionMonitor",
    "SequenceMonitor",
    "simulate",
    "cusum_threshold",
    "cusum_arl",
    "ScanSummary",
    "DetectConfig",
    "CusumConfig",
    "ElasticZoneConfig",
    "BlockConfig",
    "FrictionConfig",
    "BreakConfig",
    "ResidualTestConfig",
    "L1Config",
    "DecisionConfig",
    "config_from_toml",
    "config_to_toml",
    "TightscanError",
    "SchemaError",
    "InvalidParameterError",
    "DataFileError",
    "__version__",
]


def __getattr__(name: str) -> object:
    """``tightscan.plot`` and ``tightscan.report`` on first use: they need matplotlib (and
    Jinja2), which ``import tightscan`` does not import."""
    if name in ("plot", "report"):
        import importlib

        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
