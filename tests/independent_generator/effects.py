"""Effects the bare torque model lacks, as they act in the simulation.

- :class:`TorqueChannel`: dynamics of the torque measurement in time (first-order low-pass,
  second-order low-pass, pure delay), discretised exactly (zero-order hold) at the internal
  step, per tightening;
- :func:`ripple_torque`: 1x / 2x per revolution ripple of the spindle;
- speed- and pressure-dependent friction live in :mod:`.joint` (they change mu, so the torque
  equation carries them); inertia is in the drive (:mod:`.controller`) and the transducer
  reading (:mod:`.engine`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def _expm2(m00: FloatArray, m01: FloatArray, m10: FloatArray, m11: FloatArray
           ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """exp of 2x2 matrices given elementwise: exp(M) = e^s (cosh(q) I + sinh(q)/q (M - s I)),
    s = trace/2, q^2 = s^2 - det (Cayley-Hamilton)."""
    s = 0.5 * (m00 + m11)
    det = m00 * m11 - m01 * m10
    q = np.sqrt((s * s - det).astype(np.complex128))
    small = np.abs(q) < 1e-8
    qs = np.where(small, 1.0, q)
    ch = np.cosh(q)
    sh_q = np.where(small, 1.0 + q * q / 6.0, np.sinh(qs) / qs)
    es = np.exp(s)
    e00 = (es * (ch + sh_q * (m00 - s))).real
    e01 = (es * sh_q * m01).real
    e10 = (es * sh_q * m10).real
    e11 = (es * (ch + sh_q * (m11 - s))).real
    return e00, e01, e10, e11


class TorqueChannel:
    """Per-tightening dynamics from the transducer torque u(t) to the noise-free measured
    torque y(t). ``form`` per tightening: 0 none (y = u), 1 first-order low-pass
    (tau y' = u - y), 2 second-order low-pass (y'' + 2 zeta w y' + w^2 y = w^2 u), 3 delay
    (y(t) = u(t - delay), delay rounded to whole steps). Call :meth:`step` once per internal
    step with the input held over that step; :attr:`output` is y at the current time."""

    def __init__(self, form: IntArray, tau: FloatArray, fn_hz: FloatArray, zeta: FloatArray, delay: FloatArray,
                 dt: float) -> None:
        self.form = form
        n = len(form)
        self.output = np.zeros(n)
        self.any_lp1 = bool(np.any(form == 1))
        self.any_lp2 = bool(np.any(form == 2))
        self.any_delay = bool(np.any(form == 3))
        self.any = self.any_lp1 or self.any_lp2 or self.any_delay
        with np.errstate(all="ignore"):
            self.a1 = np.where(form == 1, -np.expm1(-dt / np.where(tau > 0, tau, 1.0)), 1.0)
        self.y1 = np.zeros(n)
        # second order: x = (y, y'), A = [[0, 1], [-w^2, -2 zeta w]], B = (0, w^2)
        w = 2.0 * np.pi * np.where(form == 2, fn_hz, 1.0)
        z = np.where(form == 2, zeta, 1.0)
        a00, a01, a10, a11 = np.zeros(n), np.ones(n), -w * w, -2.0 * z * w
        self.ad = _expm2(a00 * dt, a01 * dt, a10 * dt, a11 * dt)
        # Bd = A^-1 (Ad - I) B, with A^-1 = [[a11, -a01], [-a10, a00]] / det(A), det(A) = w^2
        b1 = w * w
        c0, c1 = self.ad[1] * b1, (self.ad[3] - 1.0) * b1  # (Ad - I) B, B = (0, w^2)
        det = a00 * a11 - a01 * a10
        self.bd0 = (a11 * c0 - a01 * c1) / det
        self.bd1 = (-a10 * c0 + a00 * c1) / det
        self.x0 = np.zeros(n)
        self.x1 = np.zeros(n)
        # delay line
        self.delay_steps = np.where(form == 3, np.rint(delay / dt), 0).astype(np.int64)
        self.size = int(self.delay_steps.max()) + 1 if n else 1
        self.buffer = np.zeros((n, self.size))
        self.pos = 0
        self.rows = np.arange(n)

    def step(self, u: FloatArray) -> None:
        y = u
        if self.any_lp1:
            self.y1 = self.y1 + self.a1 * (u - self.y1)
            y = np.where(self.form == 1, self.y1, y)
        if self.any_lp2:
            ad = self.ad
            x0 = ad[0] * self.x0 + ad[1] * self.x1 + self.bd0 * u
            x1 = ad[2] * self.x0 + ad[3] * self.x1 + self.bd1 * u
            self.x0, self.x1 = x0, x1
            y = np.where(self.form == 2, x0, y)
        if self.any_delay:
            self.buffer[:, self.pos % self.size] = u
            delayed = self.buffer[self.rows, (self.pos - self.delay_steps) % self.size]
            self.pos += 1
            y = np.where(self.form == 3, delayed, y)
        self.output = y


def ripple_torque(form: IntArray, spindle_deg: FloatArray, bolt_torque: FloatArray, a1: FloatArray, p1: FloatArray,
                  a2: FloatArray, p2: FloatArray) -> FloatArray:
    """Ripple added to the transducer torque: form 1 ("drag") a1 sin(phi + p1) + a2 sin(2 phi + p2)
    [Nm], form 2 ("gauge") the same with relative amplitudes times the bolt torque; phi = the
    spindle angle."""
    phi = np.deg2rad(spindle_deg)
    wave = a1 * np.sin(phi + p1) + a2 * np.sin(2.0 * phi + p2)
    out: FloatArray = np.where(form == 1, wave, np.where(form == 2, wave * bolt_torque, 0.0))
    return out
