"""Measurement noise: unit-variance processes drawn per tightening from its own generator.

The generator steps many tightenings at once; :class:`UnitNoise` yields one value per
tightening at each sample, drawing from each tightening's generator in fixed blocks, so a
tightening's noise depends on its own generator only (not on which others run beside it).
:func:`unit_noise` runs the same process for one generator and returns ``n`` samples: it is the
public entry for checking the noise model.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

BLOCK = 1024
"""Samples drawn at a time from each tightening's generator."""


class UnitNoise:
    """Unit-variance noise for several tightenings (one generator each).

    ``colour``: ``"white"`` (N(0, 1)), ``"ar1"`` (stationary AR(1) with lag-1 autocorrelation
    ``phi`` and marginal variance 1: z_k = phi z_{k-1} + sqrt(1 - phi^2) e_k, z_0 = e_0) or
    ``"t4"`` (Student t with 4 degrees of freedom divided by sqrt(2), variance 1)."""

    def __init__(self, rngs: Sequence[np.random.Generator], colour: str = "white", phi: float = 0.0) -> None:
        if colour not in ("white", "ar1", "t4"):
            raise ValueError(f"unknown noise colour {colour!r}")
        if not 0.0 <= phi < 1.0:
            raise ValueError("phi must be in [0, 1)")
        self._rngs = list(rngs)
        self._colour = colour
        self._phi = phi if colour == "ar1" else 0.0
        self._gain = float(np.sqrt(1.0 - self._phi * self._phi))
        self._buffer = np.zeros((len(self._rngs), BLOCK))
        self._pos = BLOCK
        self._state = np.zeros(len(self._rngs))
        self._started = False

    def _refill(self) -> None:
        for i, rng in enumerate(self._rngs):
            if self._colour == "t4":
                self._buffer[i] = rng.standard_t(4.0, BLOCK) / np.sqrt(2.0)
            else:
                self._buffer[i] = rng.standard_normal(BLOCK)
        self._pos = 0

    def next(self) -> FloatArray:
        """The next sample of every tightening's process."""
        if self._pos >= BLOCK:
            self._refill()
        e = self._buffer[:, self._pos]
        self._pos += 1
        if self._phi == 0.0:
            return e.copy()
        if not self._started:
            self._state = e.copy()
            self._started = True
        else:
            self._state = self._phi * self._state + self._gain * e
        return self._state.copy()


def unit_noise(rng: np.random.Generator, n: int, colour: str = "white", phi: float = 0.0) -> FloatArray:
    """``n`` samples of the unit noise process the generator uses (see :class:`UnitNoise`)."""
    proc = UnitNoise([rng], colour, phi)
    out = np.empty(n)
    for k in range(n):
        out[k] = proc.next()[0]
    return out


def torque_noise_sd(torque: FloatArray | float, sd_nm: float, sd_rel: float, target: float = 0.0,
                    sd_target_rel: float = 0.0) -> FloatArray:
    """Standard deviation of the torque noise at a sample:
    sd_nm + sd_target_rel target + sd_rel |torque|."""
    return np.asarray(sd_nm + sd_target_rel * target + sd_rel * np.abs(torque), dtype=np.float64)
