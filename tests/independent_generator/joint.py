"""Joint physics: thread geometry, clamp force over angle, friction laws, the torque equation.

Torque model (VDI 2230 Part 1, R13/1; METHODS.md section 1), F in kN and lengths in mm so that
T is in Nm::

    T = F (0.16 P + 0.58 d2 mu_th + Dkm/2 mu_b) + T_prevailing

with 0.16 P the lead term (P / 2 pi) and 0.58 d2 the flank term (d2 / (2 cos 30 deg)).

Clamp force over the bolt angle theta (measured from where the bolt is engaged):

- rundown (theta < contact): F = 0, only the prevailing torque;
- seating (contact <= theta < contact + s): the joint stiffness ramps up from 0 to k with a
  smoothstep in u = (theta - contact) / s, so F = k s (u^3 - u^4 / 2) (F = k s / 2 at u = 1);
- elastic: F = k (theta - snug), snug = contact + s / 2 (the tangent point: the elastic line
  meets F = 0 there), k = P c / 360 [kN/deg];
- yield (optional, from theta_y where F = F_y): the gradient falls from k to r k,
  F = F_y + k (r (theta - theta_y) + (1 - r) lam (1 - exp(-(theta - theta_y) / lam))).

All functions are vectorised over arrays of tightenings (the simulation steps many at once).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

LEAD_COEFF = 0.16
"""VDI 2230 coefficient of P in the thread torque (P / 2 pi = 0.159 P)."""
FLANK_COEFF = 0.58
"""VDI 2230 coefficient of d2 mu_th (1 / (2 cos 30 deg) = 0.577)."""


@dataclass(frozen=True)
class Thread:
    """ISO metric coarse thread with a hexagon head screw (ISO 4017 grade A) in a medium
    clearance hole (ISO 273). Lengths in mm."""

    name: str
    d: float
    pitch: float
    dw: float
    dh: float
    target_nm: tuple[float, float]

    @property
    def d2(self) -> float:
        """Pitch diameter, ISO 724: d2 = d - 0.649519 P."""
        return self.d - 0.649519 * self.pitch

    @property
    def dkm(self) -> float:
        """Effective bearing diameter (VDI 2230): Dkm = (dw + dh) / 2."""
        return 0.5 * (self.dw + self.dh)


# Own table: coarse pitch (ISO 261), minimum bearing face dw of ISO 4017 grade A heads, medium
# clearance hole dh (ISO 273); target ranges for property class 8.8 at a typical preload.
THREADS: dict[str, Thread] = {
    t.name: t
    for t in (
        Thread("M5", 5.0, 0.8, 6.88, 5.5, (5.0, 6.5)),
        Thread("M6", 6.0, 1.0, 8.88, 6.6, (8.0, 11.0)),
        Thread("M8", 8.0, 1.25, 11.63, 9.0, (20.0, 27.0)),
        Thread("M10", 10.0, 1.5, 14.63, 11.0, (40.0, 53.0)),
        Thread("M12", 12.0, 1.75, 16.63, 13.5, (70.0, 90.0)),
        Thread("M16", 16.0, 2.0, 22.49, 17.5, (170.0, 210.0)),
    )
}


def torque_factor(pitch: FloatArray | float, d2: FloatArray | float, dkm: FloatArray | float,
                  mu_th: FloatArray | float, mu_b: FloatArray | float) -> FloatArray:
    """dT/dF [Nm/kN = mm]: 0.16 P + 0.58 d2 mu_th + Dkm/2 mu_b."""
    return np.asarray(LEAD_COEFF * np.asarray(pitch) + FLANK_COEFF * np.asarray(d2) * mu_th
                      + 0.5 * np.asarray(dkm) * mu_b, dtype=np.float64)


def mu_tot_equivalent(d2: float, dkm: float, mu_th: float, mu_b: float) -> float:
    """The single coefficient that gives the same torque as (mu_th, mu_b) in the model."""
    return (FLANK_COEFF * d2 * mu_th + 0.5 * dkm * mu_b) / (FLANK_COEFF * d2 + 0.5 * dkm)


def joint_stiffness(pitch: float, axial_kn_per_mm: float) -> float:
    """k [kN/deg] = P c / 360."""
    return pitch * axial_kn_per_mm / 360.0


def clamp_force(theta: FloatArray, contact: FloatArray, seating: FloatArray, k: FloatArray,
                yield_angle: FloatArray, yield_force: FloatArray, yield_ratio: FloatArray,
                yield_lambda: FloatArray) -> FloatArray:
    """Clamp force [kN] at bolt angle ``theta`` [deg] (see the module docstring). A tightening
    without yield has ``yield_angle`` = inf."""
    u = np.minimum(np.maximum((theta - contact) / seating, 0.0), 1.0)
    seat = k * seating * (u * u * u - 0.5 * u * u * u * u)
    elastic = k * (theta - contact - 0.5 * seating)
    force = np.where(theta < contact + seating, seat, elastic)
    x = np.maximum(theta - yield_angle, 0.0)  # 0 where not yielding (inf - inf is avoided below)
    x = np.where(np.isfinite(x), x, 0.0)
    plastic = yield_force + k * (yield_ratio * x + (1.0 - yield_ratio) * yield_lambda * (1.0 - np.exp(-x / yield_lambda)))
    out: FloatArray = np.where(theta > yield_angle, plastic, force)
    return out


def speed_friction_factor(form: NDArray[np.int64], v_rpm: FloatArray, coeff: FloatArray, v_ref: FloatArray,
                          v0: FloatArray, rise: FloatArray, v_s: FloatArray) -> FloatArray:
    """Factor on mu for bolt speed v [rpm]: form 0 none, 1 linear, 2 log, 3 Stribeck."""
    v = np.abs(v_rpm)
    lin = 1.0 + coeff * v / v_ref
    log = 1.0 + coeff * np.log1p(v / v0)
    strib = 1.0 + rise * np.exp(-(v / v_s) ** 2) + coeff * v / v_ref
    out: FloatArray = np.where(form == 1, lin, np.where(form == 2, log, np.where(form == 3, strib, 1.0)))
    return out


def pressure_friction_factor(form: NDArray[np.int64], force: FloatArray, f_ref: FloatArray, kappa: FloatArray,
                             exponent: FloatArray) -> FloatArray:
    """Factor on mu for clamp force F: form 0 none, 1 linear (1 + kappa F/F_ref),
    2 power ((max(F, 0.05 F_ref)/F_ref)^exponent)."""
    ratio = force / f_ref
    lin = 1.0 + kappa * ratio
    power = np.maximum(ratio, 0.05) ** exponent
    out: FloatArray = np.where(form == 1, lin, np.where(form == 2, power, 1.0))
    return out
