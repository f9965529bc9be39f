"""An independent tightening-curve generator (plain numpy), written from the physics texts
(docs/physics.md, METHODS.md section 1) and the input contract (docs/data-contract.md) alone,
to test tightscan on data nobody tuned it for.

>>> import independent_generator as ig
>>> curves, truth = ig.generate(ig.GeneratorConfig(n=2, seed=1, strategy="CST"))
>>> curves.num_rows, truth.num_rows
(2, 2)
>>> curves.column_names[:5]
['tightening_id', 'angle', 'torque', 'time', 'speed']

API: :func:`generate` (config -> ``(curves, truth)``), :class:`GeneratorConfig` with
:class:`NoiseConfig`, :class:`FaultConfig`, :class:`ProcessConfig`, :class:`OperatorConfig`
and the effects :class:`TorqueDynamics`, :class:`SpeedFriction`, :class:`TorqueRipple`,
:class:`Inertia`, :class:`PressureFriction`; presets :func:`clean_config`, :func:`production`,
:func:`rig`; the noise process :func:`unit_noise`.

Model in brief (details in the module docstrings):

- joint (:mod:`.joint`): own ISO coarse-thread table M5-M16 (P, d2 = d - 0.649519 P,
  Dkm = (dw + dh)/2); T = F (0.16 P + 0.58 d2 mu_th + Dkm/2 mu_b) + prevailing torque; rundown
  of 3-5 revolutions with a prevailing torque drifting +-30 % with a slight hump; seating over
  2-8 deg with a smoothstep stiffness ramp; elastic F = k (theta - snug), k = P c / 360 with c
  log-uniform in 6-25 kN/mm per mm of diameter (elastic angle ~20-110 deg); optional yield
  (gradient falls to 10-25 % of k over 3-8 % of the elastic angle).
- tool (:mod:`.controller`): a speed-controlled drive (first-order lag 0.5-2 ms, acceleration
  and braking limits, bang braking at a stop) commanded by the program, which acts at every
  sample on the measured torque (noise and channel dynamics included): CST, CSDT (pause at
  40-75 % of target), HDT (speed proportional to the remaining torque, floor). After the stop
  the tool releases the torque over 3-10 ms and the recording runs on >= 20 ms.
- time stepping (:mod:`.engine`): all tightenings of a batch together at an internal step of
  1/(fs m), m = max(2, ceil(6 kHz / fs)); tightening i depends only on its own draws.
- recording: angle floor-quantised to the encoder step, noise sd = sd_nm + sd_target_rel target
  + sd_rel |torque| (white, AR(1) with the same marginal sd, or Student t4), optional torque
  resolution, clamp force with its own noise, time and speed channels.
- faults and effects: multiplicative friction faults placed on the planned elastic span, and
  effects acting in the physics (mu(v), mu(F), J alpha, the transducer's dynamics, ripple of
  the spindle, hand-held tools); every parameter is in the truth table, every angle in the
  coordinates of the ``angle`` channel.
"""

from __future__ import annotations

from .config import (
    Effect,
    FaultConfig,
    GeneratorConfig,
    Inertia,
    NoiseConfig,
    OperatorConfig,
    PressureFriction,
    ProcessConfig,
    Range,
    SpeedFriction,
    TorqueDynamics,
    TorqueRipple,
)
from .generate import generate
from .joint import THREADS, Thread, torque_factor
from .noise import UnitNoise, torque_noise_sd, unit_noise
from .presets import clean_config, production, rig

__all__ = [
    "THREADS",
    "Effect",
    "FaultConfig",
    "GeneratorConfig",
    "Inertia",
    "NoiseConfig",
    "OperatorConfig",
    "PressureFriction",
    "ProcessConfig",
    "Range",
    "SpeedFriction",
    "Thread",
    "TorqueDynamics",
    "TorqueRipple",
    "UnitNoise",
    "clean_config",
    "generate",
    "production",
    "rig",
    "torque_factor",
    "torque_noise_sd",
    "unit_noise",
]
