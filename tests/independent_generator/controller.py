"""The tool: a speed-controlled drive and the tightening program that commands it.

The program acts at every sample instant on the measured torque (noise, channel dynamics and
quantisation included), as a tool controller on its own transducer signal:

- CST: rundown speed until the encoder angle reaches the switch angle (set before the nominal
  head contact) or the measured torque passes the switch torque, then the final speed until
  it passes the target; stop.
- CSDT: as CST, with a stop of ``pause_s`` when the measured torque first passes the pause
  torque, then the resume speed to the target.
- HDT: speed command min(rundown, max(floor, G (target - measured torque))): full speed until
  the torque is within ``knee`` x target of the target, then falling in proportion to the
  remaining torque, with a floor; stop at the target.

While the tool starts, the torque is ignored (start-up blanking: until ``blank_time`` or half
the rundown angle, whichever first). An angle limit (bolt angle) and a time limit also stop it.

The drive (:func:`drive_acceleration`) follows the command with a first-order lag, with limited
acceleration and braking; with a "drive" inertia the motor torque is limited instead and the
inertia sets the accelerations.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

RUNDOWN, FINAL, PAUSE, RESUME, STOPPING, RELEASE, DONE = range(7)
CST, CSDT, HDT = range(3)
STRATEGY_CODES = {"CST": CST, "CSDT": CSDT, "HDT": HDT}
RAD = math.pi / 180.0


class Program:
    """The tightening program of each tool (vectorised over tightenings)."""

    def __init__(self, strategy: IntArray, target: FloatArray, switch_torque: FloatArray, switch_angle: FloatArray,
                 pause_torque: FloatArray,
                 pause_s: FloatArray, w_rundown: FloatArray, w_final: FloatArray, w_resume: FloatArray,
                 w_min: FloatArray, hdt_gain: FloatArray, blank_time: FloatArray, blank_angle: FloatArray,
                 angle_limit: FloatArray, max_duration: float) -> None:
        n = len(strategy)
        self.strategy = strategy
        self.target = target
        self.switch_torque = switch_torque
        self.switch_angle = switch_angle
        self.pause_torque = pause_torque
        self.pause_s = pause_s
        self.w_rundown = w_rundown
        self.w_final = w_final
        self.w_resume = w_resume
        self.w_min = w_min
        self.hdt_gain = hdt_gain
        self.blank_time = blank_time
        self.blank_angle = blank_angle
        self.angle_limit = angle_limit
        self.max_duration = max_duration
        self.phase = np.full(n, RUNDOWN, dtype=np.int64)
        self.w_ref = w_rundown.copy()
        self.pause_start = np.full(n, np.nan)
        self.stop_time = np.full(n, np.nan)
        self.stop_reason = np.zeros(n, dtype=np.int64)
        self.switch_time = np.full(n, np.nan)
        self.just_paused = np.zeros(n, dtype=bool)
        self._hdt = strategy == HDT
        self._not_hdt = ~self._hdt
        self._csdt = strategy == CSDT
        self._any_hdt = bool(self._hdt.any())
        self._any_csdt = bool(self._csdt.any())
        self._any_rundown = True

    def update(self, t: float, measured: FloatArray, motor_angle: FloatArray, bolt_angle: FloatArray) -> None:
        """One controller cycle at time ``t`` on the measured torque."""
        ph = self.phase
        sees = (t >= self.blank_time) | (motor_angle >= self.blank_angle)
        if self._any_rundown:
            switch = (ph == RUNDOWN) & self._not_hdt & (((measured >= self.switch_torque) & sees)
                                                       | (motor_angle >= self.switch_angle))
            if switch.any():
                self.switch_time = np.where(switch, t, self.switch_time)
                ph = np.where(switch, FINAL, ph)
            self._any_rundown = bool((ph == RUNDOWN).any())
        if self._any_csdt:
            pause = (ph == FINAL) & self._csdt & (measured >= self.pause_torque)
            self.just_paused = pause
            self.pause_start = np.where(pause, t, self.pause_start)
            ph = np.where(pause, PAUSE, ph)
            resume = (ph == PAUSE) & (t - self.pause_start >= self.pause_s - 1e-12)
            ph = np.where(resume, RESUME, ph)
        running = (ph == RUNDOWN) | (ph == FINAL) | (ph == RESUME)
        at_target = running & sees & (measured >= self.target)
        at_angle = running & ~at_target & (bolt_angle >= self.angle_limit)
        at_time = running & ~at_target & ~at_angle & (t >= self.max_duration)
        stop = at_target | at_angle | at_time
        if stop.any():
            self.stop_reason = np.where(at_target, 1, np.where(at_angle, 2, np.where(at_time, 3, self.stop_reason)))
            self.stop_time = np.where(stop, t, self.stop_time)
            ph = np.where(stop, STOPPING, ph)
        self.phase = ph
        w = np.where(ph == RUNDOWN, self.w_rundown,
                     np.where(ph == FINAL, self.w_final, np.where(ph == RESUME, self.w_resume, 0.0)))
        if self._any_hdt:
            hdt_cmd = np.minimum(np.maximum(self.hdt_gain * (self.target - measured), self.w_min), self.w_rundown)
            w = np.where(self._hdt & (ph == RUNDOWN) & sees, hdt_cmd, w)
        self.w_ref = w


def drive_acceleration(w: FloatArray, w_ref: FloatArray, lag: FloatArray, accel: FloatArray, brake: FloatArray,
                       dt: float, drive_inertia: FloatArray | None, max_torque: FloatArray | None,
                       load_torque: FloatArray) -> FloatArray:
    """Acceleration [deg/s^2] of the spindle over the next step.

    Ideal speed-controlled drive: a first-order approach to a speed command (exact over the
    step), clipped to +accel / -brake; a stop command (0) brakes at -brake until standstill.
    With a drive inertia J (where > 0): the speed loop asks the motor torque
    J (w_ref - w)/lag + load torque, limited to +-max_torque (a stop: -max_torque), and the
    spindle accelerates by (motor torque - load torque) / J."""
    step = (w_ref - w) * -np.expm1(-dt / lag) / dt
    stopping = w_ref <= 0.0
    a = np.where(stopping, -brake, np.minimum(np.maximum(step, -brake), accel))
    if drive_inertia is not None and max_torque is not None:
        has = drive_inertia > 0
        j = np.where(has, drive_inertia, 1.0)
        motor = np.where(stopping, -max_torque,
                         np.minimum(np.maximum(j * step * RAD + load_torque, -max_torque), max_torque))
        a_inertia = (motor - load_torque) / j / RAD
        a = np.where(has, a_inertia, a)
    out: FloatArray = a
    return out
