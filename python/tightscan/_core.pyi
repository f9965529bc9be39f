"""Type stubs of the Rust extension `tightscan._core` (checked by mypy.stubtest in tests)."""

from typing import Any

import pyarrow as pa

__version__: str
DEBUG_BUILD: bool

def detect(
    data: Any,
    config: dict[str, Any] | None = None,
    passthrough: list[str] | None = None,
    first_row: int = 0,
) -> pa.Table: ...
def flag_duplicate_ids(results: Any) -> pa.Table: ...
def detector_traces(
    data: Any,
    row_number: int = 0,
    config: dict[str, Any] | None = None,
) -> tuple[pa.Table, dict[str, Any]]: ...
def effective_config(config: dict[str, Any] | None = None) -> dict[str, Any]: ...
def result_schema(
    schema: Any,
    config: dict[str, Any] | None = None,
    passthrough: list[str] | None = None,
) -> pa.Schema: ...
def default_config() -> dict[str, Any]: ...
def thread_geometry(designation: str) -> tuple[float, float, float] | None: ...
def simulate(config: dict[str, Any] | None = None) -> tuple[pa.Table, pa.Table]: ...
def cusum_threshold(arl0: float, kappa: float, two_sided: bool = True) -> float: ...
def cusum_arl(h: float, kappa: float, shift: float = 0.0, two_sided: bool = True) -> float: ...
def result_columns() -> list[tuple[str, str, str, str]]: ...
def monitor_series(
    values: list[float],
    training: int = 10,
    alpha: float = 0.05,
    kappa: float = 0.5,
    gamma: float = 0.25,
) -> dict[str, Any]: ...

def monitor_regression(
    response: list[float],
    regressors: list[list[float]] = ...,
    training: int = 20,
    gamma: float = 0.25,
    alpha: float = 0.05,
    method: str = "l1",
    keep_path: bool = True,
    long_run_variance: bool = False,
    critical_value: float | None = None,
) -> dict[str, Any]: ...
def monitoring_critical_value(
    alpha: float,
    gamma: float,
    p: int = 1,
    simulate: bool = False,
    repetitions: int = 10_000,
    grid: int = 256,
    seed: int = 0,
    horizon_ratio: float | None = None,
) -> float: ...

__all__ = [
    "monitor_regression",
    "monitoring_critical_value",
    "monitor_series",
    "DEBUG_BUILD",
    "__version__",
    "cusum_arl",
    "cusum_threshold",
    "default_config",
    "thread_geometry",
    "detect",
    "detector_traces",
    "effective_config",
    "flag_duplicate_ids",
    "result_columns",
    "result_schema",
    "simulate",
]
