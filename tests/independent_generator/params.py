"""Per-tightening parameters, drawn from the tightening's own random streams.

Tightening ``i`` of a set with seed ``s`` draws from ``SeedSequence(s, spawn_key=(0, i))``
(independent of the set size ``n``), split into one child stream per concern (strategy, joint,
process, fault, noise, operator, each effect, yield), so switching an effect on or off leaves
every other parameter and the noise of that tightening unchanged. The per-operator table comes
from ``SeedSequence(s, spawn_key=(1,))``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .config import (
    FAULT_KINDS,
    FAULT_TARGETS,
    STRATEGIES,
    GeneratorConfig,
    Inertia,
    PressureFriction,
    Range,
    SpeedFriction,
    TorqueDynamics,
    TorqueRipple,
    range_bounds,
)
from .joint import THREADS, joint_stiffness, mu_tot_equivalent, torque_factor

# child-stream indices of a tightening's SeedSequence
S_STRATEGY, S_JOINT, S_PROCESS, S_FAULT, S_NOISE, S_CLAMP_NOISE, S_OPERATOR = range(7)
S_DYNAMICS, S_SPEED_FRICTION, S_RIPPLE, S_INERTIA, S_PRESSURE, S_YIELD = range(7, 13)
N_STREAMS = 16

RPM = 6.0  # deg/s per rpm

DYNAMICS_FORMS = {"lowpass1": 1, "lowpass2": 2, "delay": 3}
SPEED_FORMS = {"linear": 1, "log": 2, "stribeck": 3}
RIPPLE_FORMS = {"drag": 1, "gauge": 2}
INERTIA_FORMS = {"transducer": 1, "drive": 2}
PRESSURE_FORMS = {"linear": 1, "power": 2}
MAX_EPISODES = 8


def _u(rng: np.random.Generator, r: Range, name: str = "range") -> float:
    lo, hi = range_bounds(r, name)
    return float(rng.uniform(lo, hi))


def _logu(rng: np.random.Generator, r: Range, name: str = "range") -> float:
    lo, hi = range_bounds(r, name)
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


@dataclass(frozen=True)
class Operator:
    """One operator's parameters (hand-held tools)."""

    index: int
    speed_factor: float
    angle_offset_deg: float
    arm_compliance_deg_per_nm: float


def operator_table(config: GeneratorConfig) -> list[Operator]:
    """The set's operators, drawn from their own stream (independent of n)."""
    rng = np.random.default_rng(np.random.SeedSequence(config.seed, spawn_key=(1,)))
    oc = config.operator
    ops = []
    for j in range(config.operators):
        ops.append(Operator(j, _u(rng, oc.speed_factor, "speed_factor"), _u(rng, oc.angle_offset_deg, "angle_offset_deg"),
                            _u(rng, oc.arm_compliance_deg_per_nm, "arm_compliance_deg_per_nm")))
    return ops


@dataclass
class Tightening:
    """Everything that defines one tightening (plus the generators of its noise)."""

    index: int
    strategy: str
    thread: str
    d: float
    pitch: float
    d2: float
    dkm: float
    target: float
    mu_th: float
    mu_b: float
    axial_stiffness: float  # kN/mm
    k: float  # kN/deg
    contact: float  # bolt angle of head contact [deg]
    seating: float  # seating (alignment) angle span [deg]
    tp0: float  # prevailing torque at the start of the rundown [Nm]
    tp_trend: float  # relative change of the prevailing torque over the rundown
    tp_wobble: float  # relative hump of the prevailing torque over the rundown
    f_nominal: float  # clamp force at the target with the nominal friction [kN]
    planned_end: float  # bolt angle where the nominal elastic zone ends [deg]
    angle_limit: float
    # yield
    yields: bool = False
    yield_angle: float = math.inf
    yield_force: float = 0.0
    yield_ratio: float = 1.0
    yield_lambda: float = 1.0
    # process (speeds in deg/s)
    w_rundown: float = 0.0
    w_final: float = 0.0
    w_resume: float = 0.0
    w_min: float = 0.0
    hdt_gain: float = 0.0  # (deg/s)/Nm
    hdt_knee: float = 0.0
    switch_torque: float = 0.0
    switch_angle: float = math.inf  # encoder angle where CST/CSDT slow down to the final speed
    pause_torque: float = math.inf
    pause_s: float = 0.0
    relax_fraction: float = 0.0
    relax_tau: float = 0.05
    speed_lag: float = 0.001
    accel: float = 1e5
    brake: float = 4e5
    release_s: float = 0.005
    tail_s: float = 0.02
    blank_time: float = 0.05
    # fault
    faulty: bool = False
    fault_kind: str | None = None
    fault_target: str | None = None
    magnitude: float = 0.0
    onset_fraction: float = math.nan
    onset: float = math.inf  # bolt angle
    transition: float = 0.0
    incipient_end: float = math.inf
    episode_starts: list[float] = field(default_factory=list)
    episode_ends: list[float] = field(default_factory=list)
    # effects (0 = absent)
    dyn_form: int = 0
    tau: float = 0.0
    fn_hz: float = 0.0
    zeta: float = 0.0
    delay: float = 0.0
    sf_form: int = 0
    sf_coeff: float = 0.0
    sf_vref: float = 100.0
    sf_v0: float = 10.0
    sf_rise: float = 0.0
    sf_vs: float = 20.0
    rip_form: int = 0
    rip_a1: float = 0.0
    rip_p1: float = 0.0
    rip_a2: float = 0.0
    rip_p2: float = 0.0
    in_form: int = 0
    inertia: float = 0.0
    max_torque: float = math.inf
    pf_form: int = 0
    kappa: float = 0.0
    exponent: float = 0.0
    # operator
    operator: int = -1
    play: float = 0.0
    compliance: float = 0.0
    speed_factor: float = 1.0

    @property
    def snug(self) -> float:
        return self.contact + 0.5 * self.seating

    @property
    def window_start(self) -> float:
        return self.contact + self.seating

    @property
    def planned_window_end(self) -> float:
        return self.yield_angle if self.yields else self.planned_end

    @property
    def torque_rate(self) -> float:
        """Nominal elastic torque rate dT/dtheta [Nm/deg] in bolt angle."""
        return self.k * float(torque_factor(self.pitch, self.d2, self.dkm, self.mu_th, self.mu_b))

    @property
    def mu_tot(self) -> float:
        return mu_tot_equivalent(self.d2, self.dkm, self.mu_th, self.mu_b)

    def prevailing(self, theta: float) -> float:
        q = min(max(theta / self.contact, 0.0), 1.0)
        return self.tp0 * (1.0 + self.tp_trend * q + self.tp_wobble * math.sin(math.pi * q))


def draw_tightening(config: GeneratorConfig, index: int, operators: list[Operator]
                    ) -> tuple[Tightening, np.random.Generator, np.random.Generator]:
    """Parameters of tightening ``index`` and the generators of its torque and clamp noise."""
    ss = np.random.SeedSequence(config.seed, spawn_key=(0, index))
    streams = [np.random.default_rng(c) for c in ss.spawn(N_STREAMS)]
    pc = config.process

    # strategy
    rs = streams[S_STRATEGY]
    strategy = config.strategy if config.strategy != "mix" else STRATEGIES[int(rs.integers(len(STRATEGIES)))]

    # joint
    rj = streams[S_JOINT]
    thread = THREADS[config.threads[int(rj.integers(len(config.threads)))]]
    target = _u(rj, config.target_torque_nm if config.target_torque_nm is not None else thread.target_nm, "target")
    mu_th = _u(rj, config.mu_th, "mu_th")
    mu_b = _u(rj, config.mu_b, "mu_b")
    axial = thread.d * _logu(rj, config.axial_stiffness_per_mm, "axial_stiffness_per_mm")
    k = joint_stiffness(thread.pitch, axial)
    contact = 360.0 * _u(rj, pc.rundown_revolutions, "rundown_revolutions")
    seating = _u(rj, pc.seating_deg, "seating_deg")
    tp0 = target * _u(rj, config.prevailing_fraction, "prevailing_fraction")
    tp_trend = float(rj.uniform(-0.3, 0.3))
    tp_wobble = float(rj.uniform(0.0, 0.1))
    tp_contact = tp0 * (1.0 + tp_trend)
    K0 = float(torque_factor(thread.pitch, thread.d2, thread.dkm, mu_th, mu_b))
    f_nominal = (target - tp_contact) / K0
    elastic_angle = f_nominal / k
    seating = min(seating, 0.3 * elastic_angle)
    snug = contact + 0.5 * seating
    planned_end = snug + elastic_angle

    t = Tightening(index=index, strategy=strategy, thread=thread.name, d=thread.d, pitch=thread.pitch,
                   d2=thread.d2, dkm=thread.dkm, target=target, mu_th=mu_th, mu_b=mu_b,
                   axial_stiffness=axial, k=k, contact=contact, seating=seating, tp0=tp0,
                   tp_trend=tp_trend, tp_wobble=tp_wobble, f_nominal=f_nominal, planned_end=planned_end,
                   angle_limit=planned_end + max(elastic_angle, 20.0))

    # yield
    ry = streams[S_YIELD]
    if ry.random() < config.with_yield_fraction:
        fy = float(ry.uniform(0.75, 0.9))
        t.yields = True
        t.yield_force = fy * f_nominal
        t.yield_angle = snug + t.yield_force / k
        t.yield_ratio = float(ry.uniform(0.1, 0.25))
        t.yield_lambda = float(ry.uniform(0.03, 0.08)) * elastic_angle
        t.angle_limit = t.yield_angle + 4.0 * elastic_angle

    # operator
    ro = streams[S_OPERATOR]
    if operators:
        op = operators[int(ro.integers(len(operators)))]
        t.operator = op.index
        t.speed_factor = op.speed_factor
        t.play = max(0.0, op.angle_offset_deg + config.operator.angle_jitter_deg * float(ro.standard_normal()))
        t.compliance = op.arm_compliance_deg_per_nm

    # effects (each from its own stream)
    eff = config.effect("torque_dynamics")
    if isinstance(eff, TorqueDynamics):
        re = streams[S_DYNAMICS]
        if re.random() < eff.fraction:
            t.dyn_form = DYNAMICS_FORMS[eff.form]
            t.tau = _u(re, eff.tau_s, "tau_s")
            t.fn_hz = _u(re, eff.natural_freq_hz, "natural_freq_hz")
            t.zeta = _u(re, eff.damping, "damping")
            t.delay = _u(re, eff.delay_s, "delay_s")
    eff = config.effect("speed_friction")
    if isinstance(eff, SpeedFriction):
        re = streams[S_SPEED_FRICTION]
        if re.random() < eff.fraction:
            t.sf_form = SPEED_FORMS[eff.form]
            t.sf_coeff = _u(re, eff.coeff, "coeff")
            t.sf_vref = eff.v_ref_rpm
            t.sf_v0 = eff.v0_rpm
            t.sf_rise = _u(re, eff.stribeck_rise, "stribeck_rise")
            t.sf_vs = _u(re, eff.stribeck_speed_rpm, "stribeck_speed_rpm")
    eff = config.effect("ripple")
    if isinstance(eff, TorqueRipple):
        re = streams[S_RIPPLE]
        if re.random() < eff.fraction:
            t.rip_form = RIPPLE_FORMS[eff.form]
            for order in (1, 2):
                if eff.form == "drag":
                    amp = (target * _u(re, eff.amplitude_fraction, "amplitude_fraction")
                           if eff.amplitude_fraction is not None else _u(re, eff.amplitude_nm, "amplitude_nm"))
                else:
                    amp = _u(re, eff.amplitude_rel, "amplitude_rel")
                phase = float(re.uniform(0.0, 2.0 * math.pi))
                if order in eff.orders:
                    if order == 1:
                        t.rip_a1, t.rip_p1 = amp, phase
                    else:
                        t.rip_a2, t.rip_p2 = amp, phase
    eff = config.effect("inertia")
    if isinstance(eff, Inertia):
        re = streams[S_INERTIA]
        if re.random() < eff.fraction:
            t.in_form = INERTIA_FORMS[eff.form]
            t.inertia = eff.draw(re, target)
            factor = _u(re, eff.max_torque_factor, "max_torque_factor")
            if eff.form == "drive":
                t.max_torque = factor * target
    eff = config.effect("pressure_friction")
    if isinstance(eff, PressureFriction):
        re = streams[S_PRESSURE]
        if re.random() < eff.fraction:
            t.pf_form = PRESSURE_FORMS[eff.form]
            t.kappa = _u(re, eff.kappa, "kappa")
            t.exponent = _u(re, eff.exponent, "exponent")

    # process
    rp = streams[S_PROCESS]
    sf = t.speed_factor
    rundown = _u(rp, pc.rundown_rpm, "rundown_rpm") * RPM * sf
    final = _u(rp, pc.final_rpm, "final_rpm") * RPM * sf
    hdt_rundown = _u(rp, pc.hdt_rundown_rpm, "hdt_rundown_rpm") * RPM * sf
    knee = _u(rp, pc.hdt_knee, "hdt_knee")
    w_min = _u(rp, pc.hdt_min_rpm, "hdt_min_rpm") * RPM * sf
    pause_fraction = _u(rp, pc.pause_torque_fraction, "pause_torque_fraction")
    pause_s = _u(rp, pc.pause_s, "pause_s")
    resume = _u(rp, pc.resume_speed_factor, "resume_speed_factor")
    relax = _u(rp, pc.pause_relaxation, "pause_relaxation")
    relax_tau = _u(rp, pc.pause_relaxation_tau_s, "pause_relaxation_tau_s")
    switch_fraction = _u(rp, pc.switch_torque_fraction, "switch_torque_fraction")
    switch_lead = _u(rp, pc.switch_before_contact_deg, "switch_before_contact_deg") \
        if pc.switch_before_contact_deg is not None else math.nan
    t.speed_lag = _u(rp, pc.speed_lag_s, "speed_lag_s")
    t.accel = _u(rp, pc.accel_deg_s2, "accel_deg_s2")
    t.brake = _u(rp, pc.brake_deg_s2, "brake_deg_s2")
    t.release_s = _u(rp, pc.release_s, "release_s")
    if strategy == "HDT":
        # program set up for the joint: decelerating from w at the knee takes
        # rate * w^2 / (knee * target) [deg/s^2]; keep it within half the braking capability
        rate = t.torque_rate
        brake = t.brake if t.in_form != 2 else min(t.brake, t.max_torque / t.inertia * 180.0 / math.pi)
        knee = max(knee, 2.0 * rate * hdt_rundown ** 2 / (brake * target))
        if knee > 0.8:
            knee = 0.8
            hdt_rundown = math.sqrt(knee * target * brake / (2.0 * rate))
        t.w_rundown = hdt_rundown
        t.hdt_knee = knee
        t.hdt_gain = hdt_rundown / (knee * target)
        t.w_min = min(w_min, hdt_rundown)
        t.w_final = t.w_min
    else:
        t.w_rundown = rundown
        t.w_final = final
        t.w_resume = final * resume
        if math.isfinite(switch_lead):
            t.switch_angle = t.play + max(contact - switch_lead, 0.0)
    if strategy == "CSDT":
        t.pause_torque = pause_fraction * target
        t.pause_s = pause_s
        t.relax_fraction = relax
        t.relax_tau = relax_tau
    # switch torque: above what the rundown can show (prevailing torque, ripple, noise)
    tp_max = tp0 * (1.0 + abs(tp_trend) + tp_wobble)
    ripple_max = t.rip_a1 + t.rip_a2 if t.rip_form == 1 else (t.rip_a1 + t.rip_a2) * tp_max
    sd = config.noise.sd_nm + config.noise.sd_target_rel * target + config.noise.sd_rel * tp_max
    noise_margin = 6.0 * sd * (math.sqrt(2.0) * 2.2 if config.noise.colour == "t4" else 1.0)
    t.switch_torque = min(max(switch_fraction * target, tp_max + ripple_max + noise_margin + 0.02 * target), 0.35 * target)
    accel_eff = t.accel
    if t.in_form == 2:
        accel_eff = min(accel_eff, (t.max_torque - tp_max) / t.inertia * 180.0 / math.pi)
    t.blank_time = 1.2 * t.w_rundown / accel_eff + pc.blank_s
    tau_eff = 0.0
    if t.dyn_form == 1:
        tau_eff = t.tau
    elif t.dyn_form == 2:
        tau_eff = 1.0 / (t.zeta * 2.0 * math.pi * t.fn_hz)
    elif t.dyn_form == 3:
        tau_eff = t.delay / 8.0
    t.tail_s = max(pc.tail_s, 8.0 * tau_eff + 0.005)

    # fault
    fc = config.fault
    rf = streams[S_FAULT]
    if fc.kind is not None and rf.random() < fc.fraction_faulty:
        kind = fc.kind if fc.kind != "mix" else FAULT_KINDS[int(rf.integers(len(FAULT_KINDS)))]
        target_mu = fc.acts_on if fc.acts_on != "mix" else FAULT_TARGETS[int(rf.integers(len(FAULT_TARGETS)))]
        m = _u(rf, fc.magnitude, "magnitude")
        if fc.signed and rf.random() < 0.5:
            m = -m
        frac = _u(rf, fc.onset_fraction, "onset_fraction")
        start, end = t.window_start, t.planned_window_end
        span = end - start
        t.faulty = True
        t.fault_kind = kind
        t.fault_target = target_mu
        t.magnitude = m
        t.onset_fraction = frac
        t.onset = start + frac * span
        t.transition = _u(rf, fc.transition_deg, "transition_deg") if kind == "abrupt" else 0.0
        t.incipient_end = end
        if kind == "intermittent":
            n_ep = int(rf.integers(fc.episodes[0], fc.episodes[1] + 1))
            s = t.onset
            for _ in range(n_ep):
                length = _u(rf, fc.episode_fraction, "episode_fraction") * span
                gap = _u(rf, fc.episode_fraction, "episode_fraction") * span
                t.episode_starts.append(s)
                t.episode_ends.append(s + length)
                s += length + gap

    return t, streams[S_NOISE], streams[S_CLAMP_NOISE]
