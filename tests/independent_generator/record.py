"""Arrow tables from simulated tightenings: the curves (nested layout of docs/data-contract.md)
and the truth (one row per tightening, :data:`TRUTH_SCHEMA`).

Every angle of the truth is in the coordinates of the curves' ``angle`` channel (the encoder:
socket play and arm compliance included), exact where the simulated bolt crossed the point,
else from the quasi-static model. Main truth columns:

- ``faulty``, ``fault_kind``, ``fault_target`` (which mu), ``magnitude`` (signed m: mu x (1+m)),
  ``onset_angle``, ``onset_fraction``, ``onset_reached`` (the bolt got there before the stop),
  ``episode_start_angles``/``episode_end_angles`` (intermittent);
- the true elastic window ``window_start_angle`` (end of seating) to ``window_end_angle`` (where
  the bolt stopped turning, or the yield start), ``window_samples`` (samples in it while the
  tool turns: a CSDT pause's standstill is not counted); ``contact_angle``, ``snug_angle``
  (the elastic line meets the prevailing torque), ``yield_angle``, ``stop_angle``;
- ``mu_th``, ``mu_b``, ``mu_tot`` (the single coefficient with the same torque),
  ``joint_stiffness`` [kN/deg], ``torque_rate`` [Nm/deg] = k (0.16 P + 0.58 d2 mu_th + Dkm/2 mu_b),
  ``prevailing_torque``, ``peak_torque_true`` (bolt torque), ``overshoot_nm``;
- the program (speeds in rpm, switch/pause torques, times) and the drive;
- ``effects`` ("kind:form", comma-separated) and each effect's parameters (null when absent);
  ``operator`` and its parameters; the noise settings, sample rate and encoder step.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pyarrow as pa

from .config import GeneratorConfig
from .engine import CurveData, substeps
from .joint import THREADS, clamp_force, torque_factor
from .params import DYNAMICS_FORMS, INERTIA_FORMS, PRESSURE_FORMS, RIPPLE_FORMS, SPEED_FORMS, Operator, Tightening

_INV = {
    "dyn": {v: k for k, v in DYNAMICS_FORMS.items()},
    "sf": {v: k for k, v in SPEED_FORMS.items()},
    "rip": {v: k for k, v in RIPPLE_FORMS.items()},
    "in": {v: k for k, v in INERTIA_FORMS.items()},
    "pf": {v: k for k, v in PRESSURE_FORMS.items()},
}
STOP_REASONS = {0: None, 1: "target", 2: "angle_limit", 3: "time_limit"}


def _list_column(arrays: list[np.ndarray]) -> pa.Array:
    offsets = np.zeros(len(arrays) + 1, dtype=np.int32)
    if arrays:
        offsets[1:] = np.cumsum([len(a) for a in arrays])
    values = np.concatenate(arrays).astype(np.float64) if arrays else np.zeros(0)
    return pa.ListArray.from_arrays(pa.array(offsets, type=pa.int32()), pa.array(values, type=pa.float64()))


def curves_table(config: GeneratorConfig, tights: list[Tightening], curves: list[CurveData]) -> pa.Table:
    fs = config.sample_rate_hz
    cols: dict[str, Any] = {
        "tightening_id": pa.array([t.index for t in tights], type=pa.int64()),
        "angle": _list_column([c.angle_counts * config.encoder_step_deg for c in curves]),
        "torque": _list_column([c.torque for c in curves]),
        "time": _list_column([np.arange(c.n_samples) / fs for c in curves]),
        "speed": _list_column([c.speed_rpm for c in curves]),
    }
    if config.clamp_force:
        cols["clamp_force"] = _list_column([c.clamp_force for c in curves if c.clamp_force is not None])
    cols["strategy"] = pa.array([t.strategy for t in tights], type=pa.string())
    cols["thread"] = pa.array([t.thread for t in tights], type=pa.string())
    cols["target_torque"] = pa.array([t.target for t in tights], type=pa.float64())
    if config.operators > 0:
        cols["operator"] = pa.array([f"op{t.operator}" for t in tights], type=pa.string())
    if config.joint_stiffness_column:
        cols["joint_stiffness"] = pa.array([t.k for t in tights], type=pa.float64())
    return pa.table(cols)


def _static_encoder(t: Tightening, theta: float) -> float:
    """Encoder angle of a bolt angle in the quasi-static model (socket play plus compliance
    times the torque there): used for points the simulated bolt never crossed, and for
    intermittent episodes."""
    if t.compliance == 0.0:
        return theta + t.play
    arr = np.array([theta])
    f = float(clamp_force(arr, np.array([t.contact]), np.array([t.seating]), np.array([t.k]),
                          np.array([t.yield_angle]), np.array([t.yield_force]), np.array([t.yield_ratio]),
                          np.array([t.yield_lambda]))[0])
    torque = f * float(torque_factor(t.pitch, t.d2, t.dkm, t.mu_th, t.mu_b)) + t.prevailing(theta)
    return theta + t.play + t.compliance * torque


def _nan_to_none(x: float) -> float | None:
    return None if (x is None or not math.isfinite(x)) else float(x)


def truth_table(config: GeneratorConfig, tights: list[Tightening], curves: list[CurveData],
                operators: list[Operator]) -> pa.Table:
    rows: list[dict[str, Any]] = []
    nc = config.noise
    for t, c in zip(tights, curves):
        angle = c.angle_counts * config.encoder_step_deg
        ws = c.window_start_enc if math.isfinite(c.window_start_enc) else _static_encoder(t, t.window_start)
        if t.yields and math.isfinite(c.yield_enc):
            we = c.yield_enc
        else:
            we = c.stop_enc
        onset: float | None = None
        if t.faulty:
            onset = c.onset_enc if math.isfinite(c.onset_enc) else _static_encoder(t, t.onset)
        t_release = c.release_time if math.isfinite(c.release_time) else math.inf
        times = np.arange(c.n_samples) / config.sample_rate_hz
        # samples in the window while the tool turns (a CSDT pause's standstill left out)
        in_window = int(np.count_nonzero((angle >= ws) & (angle <= we) & (times <= t_release) & (c.speed_rpm > 0)))
        effects = []
        if t.dyn_form:
            effects.append(f"torque_dynamics:{_INV['dyn'][t.dyn_form]}")
        if t.sf_form:
            effects.append(f"speed_friction:{_INV['sf'][t.sf_form]}")
        if t.rip_form:
            effects.append(f"ripple:{_INV['rip'][t.rip_form]}")
        if t.in_form:
            effects.append(f"inertia:{_INV['in'][t.in_form]}")
        if t.pf_form:
            effects.append(f"pressure_friction:{_INV['pf'][t.pf_form]}")
        orders = [o for o, a in ((1, t.rip_a1), (2, t.rip_a2)) if t.rip_form and a > 0]
        first_amp = t.rip_a1 if 1 in orders else t.rip_a2
        first_phase = t.rip_p1 if 1 in orders else t.rip_p2
        op = operators[t.operator] if t.operator >= 0 else None
        thr = THREADS[t.thread]
        row: dict[str, Any] = {
            "tightening_id": t.index,
            "strategy": t.strategy,
            "thread": t.thread,
            "pitch_mm": thr.pitch,
            "d2_mm": thr.d2,
            "dkm_mm": thr.dkm,
            "target_torque": t.target,
            "faulty": t.faulty,
            "fault_kind": t.fault_kind,
            "fault_target": t.fault_target,
            "magnitude": t.magnitude if t.faulty else None,
            "onset_fraction": t.onset_fraction if t.faulty else None,
            "onset_angle": onset,
            "onset_reached": bool(t.faulty and math.isfinite(c.onset_enc)),
            "transition_deg": t.transition if t.faulty else None,
            "episode_start_angles": [_static_encoder(t, s) for s in t.episode_starts] if t.fault_kind == "intermittent" else None,
            "episode_end_angles": [_static_encoder(t, e) for e in t.episode_ends] if t.fault_kind == "intermittent" else None,
            "window_start_angle": ws,
            "window_end_angle": we,
            "window_samples": in_window,
            "contact_angle": _static_encoder(t, t.contact),
            "seating_deg": t.seating,
            "snug_angle": t.snug + t.play + t.compliance * t.prevailing(t.contact),
            "yields": t.yields,
            "yield_angle": _nan_to_none(c.yield_enc) if t.yields else None,
            "yield_ratio": t.yield_ratio if t.yields else None,
            "yield_transition_deg": t.yield_lambda if t.yields else None,
            "stop_angle": c.stop_enc,
            "stop_reason": STOP_REASONS[c.stop_reason],
            "stop_time": _nan_to_none(c.stop_time),
            "release_time": _nan_to_none(c.release_time),
            "peak_torque_true": c.peak_bolt_torque,
            "overshoot_nm": c.peak_bolt_torque - t.target,
            "mu_th": t.mu_th,
            "mu_b": t.mu_b,
            "mu_tot": t.mu_tot,
            "joint_stiffness": t.k,
            "axial_stiffness_kn_per_mm": t.axial_stiffness,
            "torque_rate": t.torque_rate,
            "clamp_force_nominal": t.f_nominal,
            "clamp_force_peak": c.peak_clamp_force,
            "prevailing_torque": t.prevailing(t.contact),
            "prevailing_torque_start": t.tp0,
            "rundown_speed_rpm": t.w_rundown / 6.0,
            "final_speed_rpm": t.w_final / 6.0,
            "resume_speed_rpm": t.w_resume / 6.0 if t.strategy == "CSDT" else None,
            "hdt_knee": t.hdt_knee if t.strategy == "HDT" else None,
            "hdt_min_speed_rpm": t.w_min / 6.0 if t.strategy == "HDT" else None,
            "switch_torque": t.switch_torque if t.strategy != "HDT" else None,
            "switch_angle": _nan_to_none(t.switch_angle) if t.strategy != "HDT" else None,
            "switch_time": _nan_to_none(c.switch_time),
            "pause_torque": t.pause_torque if t.strategy == "CSDT" else None,
            "pause_s": t.pause_s if t.strategy == "CSDT" else None,
            "pause_start_time": _nan_to_none(c.pause_start),
            "pause_relaxation_kn": c.relaxation_kn if t.strategy == "CSDT" else None,
            "speed_lag_s": t.speed_lag,
            "accel_deg_s2": t.accel,
            "brake_deg_s2": t.brake,
            "release_s": t.release_s,
            "effects": ",".join(effects),
            "torque_dynamics_form": _INV["dyn"].get(t.dyn_form),
            "tau_s": t.tau if t.dyn_form == 1 else None,
            "natural_freq_hz": t.fn_hz if t.dyn_form == 2 else None,
            "damping": t.zeta if t.dyn_form == 2 else None,
            "delay_s": (round(t.delay * config.sample_rate_hz * _substeps(config)) / (config.sample_rate_hz * _substeps(config)))
            if t.dyn_form == 3 else None,
            "speed_friction_form": _INV["sf"].get(t.sf_form),
            "speed_coeff": t.sf_coeff if t.sf_form else None,
            "speed_v_ref_rpm": t.sf_vref if t.sf_form in (1, 3) else None,
            "speed_v0_rpm": t.sf_v0 if t.sf_form == 2 else None,
            "stribeck_rise": t.sf_rise if t.sf_form == 3 else None,
            "stribeck_speed_rpm": t.sf_vs if t.sf_form == 3 else None,
            "ripple_form": _INV["rip"].get(t.rip_form),
            "ripple_order": ",".join(str(o) for o in orders) if orders else None,
            "ripple_amplitude_nm": (first_amp if t.rip_form == 1 else first_amp * t.target) if orders else None,
            "ripple_phase": first_phase if orders else None,
            "ripple1_amplitude": t.rip_a1 if 1 in orders else None,
            "ripple1_phase": t.rip_p1 if 1 in orders else None,
            "ripple2_amplitude": t.rip_a2 if 2 in orders else None,
            "ripple2_phase": t.rip_p2 if 2 in orders else None,
            "inertia_form": _INV["in"].get(t.in_form),
            "inertia_kgm2": t.inertia if t.in_form else None,
            "max_motor_torque": t.max_torque if t.in_form == 2 else None,
            "pressure_form": _INV["pf"].get(t.pf_form),
            "kappa": t.kappa if t.pf_form == 1 else None,
            "pressure_exponent": t.exponent if t.pf_form == 2 else None,
            "operator": f"op{t.operator}" if op is not None else None,
            "operator_speed_factor": op.speed_factor if op is not None else None,
            "operator_angle_offset_deg": op.angle_offset_deg if op is not None else None,
            "socket_play_deg": t.play if op is not None else None,
            "arm_compliance_deg_per_nm": op.arm_compliance_deg_per_nm if op is not None else None,
            "noise_sd_nm": nc.sd_nm,
            "noise_sd_rel": nc.sd_rel,
            "noise_sd_target_rel": nc.sd_target_rel,
            "noise_colour": nc.colour,
            "noise_phi": nc.phi,
            "sample_rate_hz": config.sample_rate_hz,
            "encoder_step_deg": config.encoder_step_deg,
            "n_samples": c.n_samples,
        }
        rows.append(row)
    return pa.Table.from_pylist(rows, schema=TRUTH_SCHEMA)


def _substeps(config: GeneratorConfig) -> int:
    return substeps(config.sample_rate_hz)


_F, _S, _B, _I = pa.float64(), pa.string(), pa.bool_(), pa.int64()
TRUTH_SCHEMA = pa.schema([
    ("tightening_id", _I), ("strategy", _S), ("thread", _S), ("pitch_mm", _F), ("d2_mm", _F), ("dkm_mm", _F),
    ("target_torque", _F), ("faulty", _B), ("fault_kind", _S), ("fault_target", _S), ("magnitude", _F),
    ("onset_fraction", _F), ("onset_angle", _F), ("onset_reached", _B), ("transition_deg", _F),
    ("episode_start_angles", pa.list_(_F)), ("episode_end_angles", pa.list_(_F)),
    ("window_start_angle", _F), ("window_end_angle", _F), ("window_samples", _I), ("contact_angle", _F),
    ("seating_deg", _F), ("snug_angle", _F), ("yields", _B), ("yield_angle", _F), ("yield_ratio", _F), ("yield_transition_deg", _F),
    ("stop_angle", _F), ("stop_reason", _S), ("stop_time", _F), ("release_time", _F), ("peak_torque_true", _F),
    ("overshoot_nm", _F), ("mu_th", _F), ("mu_b", _F), ("mu_tot", _F), ("joint_stiffness", _F),
    ("axial_stiffness_kn_per_mm", _F), ("torque_rate", _F), ("clamp_force_nominal", _F), ("clamp_force_peak", _F),
    ("prevailing_torque", _F), ("prevailing_torque_start", _F), ("rundown_speed_rpm", _F), ("final_speed_rpm", _F),
    ("resume_speed_rpm", _F), ("hdt_knee", _F), ("hdt_min_speed_rpm", _F), ("switch_torque", _F),
    ("switch_angle", _F), ("switch_time", _F), ("pause_torque", _F), ("pause_s", _F), ("pause_start_time", _F),
    ("pause_relaxation_kn", _F), ("speed_lag_s", _F), ("accel_deg_s2", _F), ("brake_deg_s2", _F),
    ("release_s", _F), ("effects", _S), ("torque_dynamics_form", _S), ("tau_s", _F), ("natural_freq_hz", _F),
    ("damping", _F), ("delay_s", _F), ("speed_friction_form", _S), ("speed_coeff", _F), ("speed_v_ref_rpm", _F),
    ("speed_v0_rpm", _F), ("stribeck_rise", _F), ("stribeck_speed_rpm", _F), ("ripple_form", _S),
    ("ripple_order", _S), ("ripple_amplitude_nm", _F), ("ripple_phase", _F), ("ripple1_amplitude", _F),
    ("ripple1_phase", _F), ("ripple2_amplitude", _F), ("ripple2_phase", _F), ("inertia_form", _S),
    ("inertia_kgm2", _F), ("max_motor_torque", _F), ("pressure_form", _S), ("kappa", _F),
    ("pressure_exponent", _F), ("operator", _S), ("operator_speed_factor", _F), ("operator_angle_offset_deg", _F),
    ("socket_play_deg", _F), ("arm_compliance_deg_per_nm", _F), ("noise_sd_nm", _F), ("noise_sd_rel", _F), ("noise_sd_target_rel", _F),
    ("noise_colour", _S), ("noise_phi", _F), ("sample_rate_hz", _F), ("encoder_step_deg", _F), ("n_samples", _I),
])
