"""Time-stepping simulation of a batch of tightenings.

All tightenings of a batch are stepped together (numpy arrays over tightenings, one entry
each, every operation elementwise), at an internal step ``dt = 1 / (fs * m)`` with
``m = max(2, ceil(6 kHz / fs))`` sub-steps per sample. Per step:

1. at a sample instant: measure (channel output + noise, quantised), record, controller cycle;
2. drive: spindle acceleration from the speed command (lag, limits, optional drive inertia);
3. kinematics: motor (encoder) angle; bolt angle = motor angle - socket play - compliance x
   torque, never turning back (self-locking thread);
4. joint: clamp force, friction factors (fault, speed, pressure), bolt torque
   T = F (0.16 P + 0.58 d2 mu_th + Dkm/2 mu_b) + prevailing torque;
5. transducer torque = bolt torque + ripple + J alpha (transducer inertia); once the tool
   stands still after the stop it releases the torque over ``release_s`` (cosine ramp), the
   encoder backing off by the compliance;
6. torque channel dynamics (low-pass / delay) give the noise-free measured torque.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .config import GeneratorConfig
from .controller import (
    DONE,
    PAUSE,
    RAD,
    RELEASE,
    STOPPING,
    STRATEGY_CODES,
    Program,
    drive_acceleration,
)
from .effects import TorqueChannel, ripple_torque
from .joint import FLANK_COEFF, LEAD_COEFF, clamp_force, pressure_friction_factor, speed_friction_factor
from .noise import UnitNoise
from .params import MAX_EPISODES, Tightening

FloatArray = NDArray[np.float64]
INTERNAL_RATE_HZ = 6000.0
CHUNK = 2048
STANDSTILL_DEG_S = 1.0
"""Below this speed [deg/s] a braking spindle counts as standing still."""


def substeps(sample_rate_hz: float) -> int:
    """Internal steps per sample."""
    return max(2, math.ceil(INTERNAL_RATE_HZ / sample_rate_hz))


@dataclass
class CurveData:
    """Recorded channels and the simulated truth of one tightening."""

    angle_counts: NDArray[np.int64]
    torque: FloatArray
    speed_rpm: FloatArray
    clamp_force: FloatArray | None
    n_samples: int
    stop_reason: int
    stop_time: float
    release_time: float
    switch_time: float
    pause_start: float
    window_start_enc: float
    onset_enc: float
    yield_enc: float
    stop_enc: float
    stop_bolt: float
    peak_bolt_torque: float
    peak_clamp_force: float
    relaxation_kn: float


def _col(tights: list[Tightening], name: str) -> FloatArray:
    return np.array([float(getattr(t, name)) for t in tights], dtype=np.float64)


def _icol(tights: list[Tightening], name: str) -> NDArray[np.int64]:
    return np.array([int(getattr(t, name)) for t in tights], dtype=np.int64)


def simulate_batch(config: GeneratorConfig, tights: list[Tightening], noise_rngs: list[np.random.Generator],
                   clamp_rngs: list[np.random.Generator]) -> list[CurveData]:
    """Simulate the tightenings together; each one's result depends only on its own parameters
    and generators."""
    with np.errstate(all="ignore"):
        return _simulate(config, tights, noise_rngs, clamp_rngs)


def _simulate(config: GeneratorConfig, tights: list[Tightening], noise_rngs: list[np.random.Generator],
              clamp_rngs: list[np.random.Generator]) -> list[CurveData]:
    n = len(tights)
    fs = config.sample_rate_hz
    m = substeps(fs)
    dt = 1.0 / (fs * m)
    step_deg = config.encoder_step_deg
    nc = config.noise

    # --- per-tightening constants
    pitch, d2, dkm = _col(tights, "pitch"), _col(tights, "d2"), _col(tights, "dkm")
    lead, flank, bearing = LEAD_COEFF * pitch, FLANK_COEFF * d2, 0.5 * dkm
    mu_th0, mu_b0 = _col(tights, "mu_th"), _col(tights, "mu_b")
    stiffness = _col(tights, "k")
    contact, seating = _col(tights, "contact"), _col(tights, "seating")
    y_angle, y_force = _col(tights, "yield_angle"), _col(tights, "yield_force")
    y_ratio, y_lambda = _col(tights, "yield_ratio"), _col(tights, "yield_lambda")
    tp0, tp_trend, tp_wobble = _col(tights, "tp0"), _col(tights, "tp_trend"), _col(tights, "tp_wobble")
    f_nominal = _col(tights, "f_nominal")
    target = _col(tights, "target")
    play, compliance = _col(tights, "play"), _col(tights, "compliance")
    any_compliance = bool(np.any(compliance > 0))

    # fault: factor 1 + m g(theta) on mu_th (th_on) and mu_b (b_on)
    kind_code = np.array([{None: 0, "abrupt": 1, "incipient": 2, "intermittent": 3}[t.fault_kind] for t in tights],
                         dtype=np.int64)
    any_fault = bool(np.any(kind_code > 0))
    magnitude = _col(tights, "magnitude")
    onset = _col(tights, "onset")
    transition = _col(tights, "transition")
    inc_end = _col(tights, "incipient_end")
    th_on = np.array([1.0 if t.fault_target in ("both", "thread") else 0.0 for t in tights])
    b_on = np.array([1.0 if t.fault_target in ("both", "bearing") else 0.0 for t in tights])
    ep_s = np.full((n, MAX_EPISODES), np.inf)
    ep_e = np.full((n, MAX_EPISODES), np.inf)
    for i, t in enumerate(tights):
        ep_s[i, : len(t.episode_starts)] = t.episode_starts
        ep_e[i, : len(t.episode_ends)] = t.episode_ends

    # effects
    sf_form = _icol(tights, "sf_form")
    any_sf = bool(np.any(sf_form > 0))
    sf_args = [_col(tights, c) for c in ("sf_coeff", "sf_vref", "sf_v0", "sf_rise", "sf_vs")]
    pf_form = _icol(tights, "pf_form")
    any_pf = bool(np.any(pf_form > 0))
    kappa, exponent = _col(tights, "kappa"), _col(tights, "exponent")
    rip_form = _icol(tights, "rip_form")
    any_ripple = bool(np.any(rip_form > 0))
    rip = [_col(tights, c) for c in ("rip_a1", "rip_p1", "rip_a2", "rip_p2")]
    in_form = _icol(tights, "in_form")
    inertia = _col(tights, "inertia")
    j_transducer = np.where(in_form == 1, inertia, 0.0)
    any_j_transducer = bool(np.any(j_transducer > 0))
    j_drive = np.where(in_form == 2, inertia, 0.0)
    any_drive = bool(np.any(j_drive > 0))
    max_torque = _col(tights, "max_torque")
    channel = TorqueChannel(_icol(tights, "dyn_form"), _col(tights, "tau"), _col(tights, "fn_hz"),
                            _col(tights, "zeta"), _col(tights, "delay"), dt)

    # drive / program
    lag, accel, brake = _col(tights, "speed_lag"), _col(tights, "accel"), _col(tights, "brake")
    release_s, tail_s = _col(tights, "release_s"), _col(tights, "tail_s")
    strategy = np.array([STRATEGY_CODES[t.strategy] for t in tights], dtype=np.int64)
    relax_fraction, relax_tau = _col(tights, "relax_fraction"), _col(tights, "relax_tau")
    relax_gain = -np.expm1(-dt / relax_tau)
    program = Program(strategy, target, _col(tights, "switch_torque"), _col(tights, "switch_angle"),
                      _col(tights, "pause_torque"),
                      _col(tights, "pause_s"), _col(tights, "w_rundown"), _col(tights, "w_final"),
                      _col(tights, "w_resume"), _col(tights, "w_min"), _col(tights, "hdt_gain"),
                      _col(tights, "blank_time"), play + 0.5 * contact, _col(tights, "angle_limit"),
                      config.max_duration_s)

    # --- state
    w = np.zeros(n)  # spindle speed [deg/s]
    motor = np.zeros(n)  # encoder angle [deg]
    bolt = np.zeros(n)  # bolt angle from engagement [deg]
    torque_tr = np.zeros(n)  # transducer torque [Nm]
    force = np.zeros(n)
    relax = np.zeros(n)  # clamp force lost in a pause [kN]
    force_at_pause = np.zeros(n)
    hold = np.zeros(n)
    release_t0 = np.full(n, np.nan)
    end_time = np.full(n, np.inf)
    events = np.stack([contact + seating, onset, y_angle], axis=1)
    events_enc = np.full((n, 3), np.nan)
    last_adv_enc = np.zeros(n)
    last_adv_bolt = np.zeros(n)
    peak_bolt_torque = np.zeros(n)
    peak_force = np.zeros(n)
    n_samples = np.zeros(n, dtype=np.int64)
    v_rpm = np.zeros(n)
    zeros = np.zeros(n)
    touched = False
    any_stopping = False
    any_relax = bool(relax_fraction.any())
    any_play = bool(np.any(play > 0))
    inv_contact = 1.0 / contact
    next_event = events.min(axis=1)

    sd_const = nc.sd_nm + nc.sd_target_rel * target
    tnoise = UnitNoise(noise_rngs, nc.colour, nc.phi)
    cnoise = UnitNoise(clamp_rngs, "white", 0.0) if config.clamp_force else None

    # recording in chunks of samples; a chunk keeps the rows of the tightenings still recording
    chunks: list[tuple[int, NDArray[np.int64], list[NDArray[np.generic]]]] = []
    buf_angle = np.zeros((n, CHUNK), dtype=np.int64)
    buf_torque = np.zeros((n, CHUNK))
    buf_speed = np.zeros((n, CHUNK))
    buf_force = np.zeros((n, CHUNK)) if config.clamp_force else None
    chunk_start = 0

    def flush(k_end: int) -> None:
        rows = np.nonzero(n_samples > chunk_start)[0]
        width = k_end - chunk_start
        bufs: list[NDArray[np.generic]] = [buf_angle[rows, :width].copy(), buf_torque[rows, :width].copy(),
                                           buf_speed[rows, :width].copy()]
        if buf_force is not None:
            bufs.append(buf_force[rows, :width].copy())
        chunks.append((chunk_start, rows, bufs))

    j = 0
    k = 0
    while True:
        if j % m == 0:
            k = j // m
            now = k / fs
            done = program.phase == DONE
            if bool(done.all()):
                break
            if k - chunk_start == CHUNK:
                flush(k)
                chunk_start = k
            col = k - chunk_start
            clean = channel.output
            sd = sd_const + nc.sd_rel * np.abs(clean)
            measured = clean + sd * tnoise.next()
            if nc.torque_resolution_nm > 0:
                measured = np.rint(measured / nc.torque_resolution_nm) * nc.torque_resolution_nm
            buf_angle[:, col] = np.floor(motor / step_deg + 1e-9).astype(np.int64)
            buf_torque[:, col] = measured
            buf_speed[:, col] = w / 6.0
            if buf_force is not None and cnoise is not None:
                buf_force[:, col] = force + (nc.clamp_sd_kn + nc.clamp_sd_rel * force) * cnoise.next()
            n_samples = np.where(done, n_samples, k + 1)
            program.update(now, measured, motor, bolt)
            force_at_pause = np.where(program.just_paused, force, force_at_pause)

        tj = j * dt
        phase = program.phase
        # drive
        a = drive_acceleration(w, program.w_ref, lag, accel, brake, dt, j_drive if any_drive else None,
                               max_torque if any_drive else None, torque_tr)
        w_new = np.maximum(w + a * dt, 0.0)
        w_new = np.where((program.w_ref <= 0.0) & (w_new < STANDSTILL_DEG_S), 0.0, w_new)
        alpha = (w_new - w) / dt
        motor_new = motor + 0.5 * (w + w_new) * dt
        releasing = phase >= RELEASE
        candidate = motor_new - play - compliance * torque_tr if any_compliance else motor_new - play
        bolt_new = np.where(releasing, bolt, np.maximum(bolt, candidate))
        moving = bolt_new > bolt
        # friction speed: the sliding speed while the bolt turns; at standstill the bolt sticks
        # and holds the torque it had (the last sliding speed is kept)
        v_rpm = np.where(moving, (bolt_new - bolt) / dt / 6.0, v_rpm)
        # joint (no clamp force before the first head contact of the batch)
        if not touched:
            touched = bool((bolt_new >= contact).any())
        f = clamp_force(bolt_new, contact, seating, stiffness, y_angle, y_force, y_ratio, y_lambda) if touched else zeros
        if any_relax:
            in_pause = phase == PAUSE
            relax = np.where(in_pause, relax + relax_gain * (relax_fraction * force_at_pause - relax), relax)
            f = np.maximum(f - relax, 0.0)
        mu_th, mu_b = mu_th0, mu_b0
        if any_fault and touched:
            g = _fault_shape(kind_code, bolt_new, onset, transition, inc_end, ep_s, ep_e)
            mu_th = mu_th * (1.0 + magnitude * g * th_on)
            mu_b = mu_b * (1.0 + magnitude * g * b_on)
        if any_sf:
            fac = speed_friction_factor(sf_form, v_rpm, *sf_args)
            mu_th, mu_b = mu_th * fac, mu_b * fac
        if any_pf:
            fac = pressure_friction_factor(pf_form, f, f_nominal, kappa, exponent)
            mu_th, mu_b = mu_th * fac, mu_b * fac
        q = np.minimum(bolt_new * inv_contact, 1.0)
        prevailing = tp0 * (1.0 + tp_trend * q + tp_wobble * np.sin(np.pi * q))
        if any_play:
            prevailing = np.where(motor_new >= play, prevailing, 0.0)
        t_bolt = f * (lead + flank * mu_th + bearing * mu_b) + prevailing
        t_tr = t_bolt
        if any_ripple:
            t_tr = t_tr + ripple_torque(rip_form, motor_new, t_bolt, *rip)
        if any_j_transducer:
            t_tr = t_tr + j_transducer * alpha * RAD
        # stop -> release once the tool stands still
        if any_stopping or bool((phase == STOPPING).any()):
            any_stopping = True
            start_release = (phase == STOPPING) & (w_new <= 0.0)
            hold = np.where(start_release, t_tr, hold)
            release_t0 = np.where(start_release, tj + dt, release_t0)
            end_time = np.where(start_release, tj + dt + release_s + tail_s, end_time)
            phase = np.where(start_release, RELEASE, phase)
            released = phase >= RELEASE
            rel = np.minimum(np.maximum((tj + dt - release_t0) / release_s, 0.0), 1.0)
            t_tr = np.where(released, hold * 0.5 * (1.0 + np.cos(np.pi * rel)), t_tr)
            if any_compliance:
                motor_new = np.where(released, bolt_new + play + compliance * t_tr, motor_new)
            phase = np.where((phase == RELEASE) & (tj + dt >= end_time - 1e-12), DONE, phase)
        # events (bolt angle crossings, recorded in encoder angle)
        if bool((bolt_new >= next_event).any()):
            cross = (bolt[:, None] < events) & (bolt_new[:, None] >= events) & np.isnan(events_enc)
            frac = (events - bolt[:, None]) / (bolt_new - bolt)[:, None]
            interp = motor[:, None] + frac * (motor_new - motor)[:, None]
            events_enc = np.where(cross, interp, events_enc)
            next_event = np.where(np.isnan(events_enc), events, np.inf).min(axis=1)
        last_adv_enc = np.where(moving, motor_new, last_adv_enc)
        last_adv_bolt = np.where(moving, bolt_new, last_adv_bolt)
        if touched:
            peak_bolt_torque = np.maximum(peak_bolt_torque, np.where(phase >= RELEASE, 0.0, t_bolt))
            peak_force = np.maximum(peak_force, f)
        channel.step(t_tr)
        program.phase = phase
        w, motor, bolt, torque_tr, force = w_new, motor_new, bolt_new, t_tr, f
        j += 1
    flush(k)

    # assemble each tightening's channels
    per_lane: list[list[list[NDArray[np.generic]]]] = [[] for _ in range(n)]
    for _, rows, bufs in chunks:
        for r_i, lane in enumerate(rows):
            per_lane[int(lane)].append([b[r_i] for b in bufs])
    out: list[CurveData] = []
    for i in range(n):
        parts = per_lane[i]
        ns = int(n_samples[i])
        chans = [np.concatenate([p[c] for p in parts])[:ns] for c in range(len(parts[0]))]
        out.append(CurveData(
            angle_counts=chans[0].astype(np.int64), torque=chans[1].astype(np.float64),
            speed_rpm=chans[2].astype(np.float64),
            clamp_force=chans[3].astype(np.float64) if config.clamp_force else None, n_samples=ns,
            stop_reason=int(program.stop_reason[i]), stop_time=float(program.stop_time[i]),
            release_time=float(release_t0[i]), switch_time=float(program.switch_time[i]),
            pause_start=float(program.pause_start[i]), window_start_enc=float(events_enc[i, 0]),
            onset_enc=float(events_enc[i, 1]), yield_enc=float(events_enc[i, 2]),
            stop_enc=float(last_adv_enc[i]), stop_bolt=float(last_adv_bolt[i]),
            peak_bolt_torque=float(peak_bolt_torque[i]), peak_clamp_force=float(peak_force[i]),
            relaxation_kn=float(relax[i])))
    return out


def _fault_shape(kind: NDArray[np.int64], theta: FloatArray, onset: FloatArray, transition: FloatArray,
                 inc_end: FloatArray, ep_s: FloatArray, ep_e: FloatArray) -> FloatArray:
    """g(theta) in [0, 1]: abrupt (1) a step (or a linear ramp over ``transition``) at the onset,
    incipient (2) linear from the onset to the planned end, intermittent (3) 1 inside an episode."""
    ramp = np.minimum(np.maximum((theta - onset) / np.where(transition > 0, transition, 1.0), 0.0), 1.0)
    abrupt = np.where(transition > 0, ramp, (theta >= onset).astype(np.float64))
    incipient = np.minimum(np.maximum((theta - onset) / (inc_end - onset), 0.0), 1.0)
    inter = ((theta[:, None] >= ep_s) & (theta[:, None] < ep_e)).any(axis=1).astype(np.float64)
    out: FloatArray = np.where(kind == 1, abrupt, np.where(kind == 2, incipient, np.where(kind == 3, inter, 0.0)))
    return out
