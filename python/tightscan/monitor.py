"""Sequential monitoring of a linear regression, with the whole detector and boundary path.

``detect_batch`` runs the L1 procedure on every tightening and reports the alarm; this module
is for looking at one series closely (a response on up to three regressors besides the
intercept, e.g. block torque rates as a location), with the path for
a plot.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Sequence

import numpy as np

from . import _core
from .exceptions import InvalidParameterError


@dataclass(frozen=True)
class RegressionMonitor:
    """Outcome of :func:`monitor_regression`.

    ``statistic`` and ``boundary`` hold the detector and boundary for each monitored step
    k = 1..``monitored`` (observation ``training + k - 1``) on the scale of the alarm rule: for
    L1 the quadratic form of the sign residuals against c^2 (1 + k/m)^2 (k/(m+k))^(2 gamma); for
    OLS-CUSUM |Q(m, k)| / sigma_m against c (1 + k/m) (k/(m+k))^gamma. ``max_ratio`` is the
    largest detector / boundary on the scale of c (above 1: alarm)."""

    method: str
    alarm: bool
    alarm_index: int | None
    statistic_at_alarm: float | None
    boundary_at_alarm: float | None
    max_ratio: float
    gamma: float
    alpha: float
    critical_value: float
    training: int
    monitored: int
    coefficients: tuple[float, ...]
    scale: float
    statistic: np.ndarray | None
    boundary: np.ndarray | None

    def __repr__(self) -> str:
        # The statistic and boundary paths are long: the outcome only.
        return (
            f"RegressionMonitor(method={self.method!r}, alarm={self.alarm}, alarm_index={self.alarm_index}, "
            f"max_ratio={self.max_ratio:.4g}, gamma={self.gamma}, alpha={self.alpha}, critical_value={self.critical_value:.4g}, "
            f"training={self.training}, monitored={self.monitored})"
        )

    def _repr_html_(self) -> str:
        """For notebooks: the outcome and the settings behind it."""
        from ._html import key_value_table

        return key_value_table(
            f"monitor_regression ({self.method})",
            [
                ("alarm", self.alarm),
                ("alarm index", self.alarm_index),
                ("max detector / boundary", self.max_ratio),
                ("critical value c", self.critical_value),
                ("gamma", self.gamma),
                ("alpha", self.alpha),
                ("training observations m", self.training),
                ("monitored steps", self.monitored),
            ],
        )


def _path(values: list[float] | None) -> np.ndarray | None:
    return None if values is None else np.asarray(values, dtype=np.float64)


def monitor_regression(
    response: Sequence[float] | np.ndarray,
    regressors: Sequence[Sequence[float]] | np.ndarray | None = None,
    *,
    training: int = 20,
    gamma: float = 0.25,
    alpha: float = 0.05,
    method: Literal["l1", "ols_cusum"] = "l1",
    keep_path: bool = True,
    long_run_variance: bool = False,
    critical_value: float | None = None,
) -> RegressionMonitor:
    """Monitors ``response`` on ``regressors`` (columns besides the intercept; ``None``: a
    location) after the first ``training`` observations, with the boundary
    g(m, k, gamma) = c sqrt(m) (1 + k/m) (k/(m+k))^gamma and c from the shipped table at
    (``alpha``, ``gamma``, p). ``method="l1"``: least-absolute-deviation fit and sign residuals
    (Huskova and Koubkova); ``"ols_cusum"``: Horvath et al. (2004). ``long_run_variance``
    corrects L1 for dependent errors (Bartlett). ``critical_value`` replaces the table's c, e.g.
    ``monitoring_critical_value(alpha, gamma, p, simulate=True)`` for a level or gamma off the
    table's grid, or with ``horizon_ratio`` for a finite horizon.

    Regressors should be stationary (speed, a block's torque rate): a trending one such
    as the angle or the clamp force is extrapolated far beyond its training range, which tilts the signs
    and alarms without a change. Block torque rates with a 10 % step after 150 blocks:

    >>> import numpy as np
    >>> rate = 0.5 + np.random.default_rng(1).normal(0.0, 0.02, 300)
    >>> rate[150:] *= 1.1
    >>> m = monitor_regression(rate, training=60)
    >>> m.alarm, m.alarm_index is not None and m.alarm_index >= 150
    (True, True)
    >>> m.statistic is not None and m.statistic.shape == (240,)
    True
    """
    y = np.asarray(response, dtype=np.float64).ravel()
    if regressors is None:
        columns: list[list[float]] = []
    else:
        x = np.asarray(regressors, dtype=np.float64)
        if x.ndim == 1:
            x = x[None, :]
        columns = [list(map(float, c)) for c in x]
    try:
        out = _core.monitor_regression(
            y.tolist(), columns, training, gamma, alpha, method, keep_path, long_run_variance, critical_value
        )
    except InvalidParameterError as err:
        if critical_value is None and err.parameter in ("alpha", "gamma"):
            raise InvalidParameterError(
                f"{err}; off the table, pass critical_value=monitoring_critical_value("
                f"{alpha}, {gamma}, {len(columns) + 1}, simulate=True)",
                parameter=err.parameter,
            ) from err
        raise
    return RegressionMonitor(
        method=out["method"],
        alarm=bool(out["alarm"]),
        alarm_index=out["alarm_index"],
        statistic_at_alarm=out["statistic_at_alarm"],
        boundary_at_alarm=out["boundary_at_alarm"],
        max_ratio=float(out["max_ratio"]),
        gamma=float(out["gamma"]),
        alpha=float(out["alpha"]),
        critical_value=float(out["critical_value"]),
        training=int(out["training"]),
        monitored=int(out["monitored"]),
        coefficients=tuple(float(c) for c in out["coefficients"]),
        scale=float(out["scale"]),
        statistic=_path(out["statistic"]),
        boundary=_path(out["boundary"]),
    )


def monitoring_critical_value(
    alpha: float,
    gamma: float,
    p: int = 1,
    *,
    simulate: bool = False,
    repetitions: int = 10_000,
    grid: int = 256,
    seed: int = 0,
    horizon_ratio: float | None = None,
) -> float:
    """Critical value c(alpha, gamma, p) of the boundary c sqrt(m) (1 + k/m) (k/(m+k))^gamma
    (p: parameters of the regression, intercept included). From the shipped table (alpha 0.1,
    0.05, 0.025, 0.01; gamma 0 to 0.49), or with ``simulate=True`` by Monte Carlo for any
    alpha and gamma: ``repetitions`` Brownian paths on ``grid`` steps per unit, corrected to the
    continuous supremum as the table was; standard error about 0.02 at alpha 0.05 with 10^4
    paths. ``horizon_ratio`` T gives the value for monitoring T training lengths instead of
    open-ended (smaller; simulated only).

    >>> round(monitoring_critical_value(0.05, 0.0), 4)
    2.2418
    """
    return _core.monitoring_critical_value(alpha, gamma, p, simulate, repetitions, grid, seed, horizon_ratio)
