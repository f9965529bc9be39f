"""tightscan: find friction changes in bolted-joint tightening curves.

>>> import tightscan
>>> curves, truth = tightscan.simulate(100, seed=3)
>>> results = tightscan.detect_batch(curves)
>>> results.column_names[:3]
['tightening_id', 'status', 'n_samples']
"""

from __future__ import annotations

import sys
import types
import warnings
from typing import TYPE_CHECKING

from . import _core
from ._api import ResultColumn, result_columns, cusum_arl, cusum_threshold, detect_batch, result_schema, simulate
from ._metadata import RESULTS_METADATA_KEY, results_metadata, scan_metadata
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
    ParticleFilterConfig,
    config_from_toml,
    config_to_toml,
)
from .exceptions import DataFileError, InvalidParameterError, SchemaError, TightscanError
from .rexroth import read_rexroth
from .monitor import RegressionMonitor, monitor_regression, monitoring_critical_value
from .sequence import SequenceMonitor, monitor_sequence
from .traces import BreakTrace, CusumTrace, DetectorTraces, KdeTrace, L1Trace, detector_traces

if TYPE_CHECKING:
    from .diagnose import diagnose

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
    "results_metadata",
    "scan_metadata",
    "RESULTS_METADATA_KEY",
    "detector_traces",
    "DetectorTraces",
    "CusumTrace",
    "L1Trace",
    "BreakTrace",
    "KdeTrace",
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
    "ParticleFilterConfig",
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


class _Package(types.ModuleType):
    """``tightscan.diagnose`` stays the function once the subpackage of that name is imported
    (``from tightscan.diagnose import Diagnosis`` would otherwise bind the package over it,
    as the import system does for every submodule)."""

    def __setattr__(self, name: str, value: object) -> None:
        if name == "diagnose" and isinstance(value, types.ModuleType):
            from .diagnose import diagnose as run_diagnosis

            value = run_diagnosis
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package


def __getattr__(name: str) -> object:
    """``tightscan.plot`` and ``tightscan.report`` on first use: they need matplotlib (and
    Jinja2), which ``import tightscan`` does not import. ``tightscan.diagnose`` too: the
    residual loop needs scipy and statsmodels (about 100 MB and 1.5 s to import), which a
    scan or a simulation never uses."""
    if name in ("plot", "report"):
        import importlib

        return importlib.import_module(f"{__name__}.{name}")
    if name == "diagnose":
        from .diagnose import diagnose as run_diagnosis

        globals()["diagnose"] = run_diagnosis  # the function, not the subpackage of that name
        return run_diagnosis
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
