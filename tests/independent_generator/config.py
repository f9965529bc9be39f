"""Configuration of the independent tightening-curve generator.

Every parameter that varies between tightenings is a :data:`Range`: a single number (fixed) or a
``(low, high)`` pair drawn uniformly per tightening (log-uniformly where a field says so).
All effects are off by default; a default :class:`GeneratorConfig` gives clean curves of the
bare torque model with white noise.

Units: angles in degrees, speeds in rpm, torque in Nm, clamp force in kN, lengths in mm,
times in s, inertia in kg m^2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal, Union

if TYPE_CHECKING:
    import numpy as np

Range = Union[float, tuple[float, float]]
"""A fixed value or a ``(low, high)`` interval drawn uniformly per tightening."""

Strategy = Literal["CST", "CSDT", "HDT", "mix"]
FaultKind = Literal["abrupt", "incipient", "intermittent", "mix"]
FaultTarget = Literal["both", "thread", "bearing", "mix"]
NoiseColour = Literal["white", "ar1", "t4"]

STRATEGIES: tuple[str, ...] = ("CST", "CSDT", "HDT")
FAULT_KINDS: tuple[str, ...] = ("abrupt", "incipient", "intermittent")
FAULT_TARGETS: tuple[str, ...] = ("both", "thread", "bearing")


def range_bounds(value: Range, name: str = "range") -> tuple[float, float]:
    """``(low, high)`` of a :data:`Range`; a number gives ``(x, x)``."""
    if isinstance(value, tuple):
        if len(value) != 2:
            raise ValueError(f"{name}: a range is a number or a (low, high) pair, got {value!r}")
        lo, hi = float(value[0]), float(value[1])
    else:
        lo = hi = float(value)
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi < lo:
        raise ValueError(f"{name}: invalid range {value!r}")
    return lo, hi


@dataclass(frozen=True)
class NoiseConfig:
    """Torque measurement noise (and clamp-force noise when that channel is on).

    The torque noise at a sample has the standard deviation
    ``sd_nm + sd_target_rel * target + sd_rel * |torque|`` (torque = the noise-free measured
    torque at that sample: the ``sd_rel`` part grows along the curve, the ``sd_target_rel`` part
    is a constant set by the tightening's target, as a %-of-full-scale transducer spec).
    ``colour``:

    - ``"white"``: independent normal samples;
    - ``"ar1"``: a stationary AR(1) process with lag-1 autocorrelation ``phi`` and the SAME
      marginal sd (innovation sd = sd * sqrt(1 - phi^2));
    - ``"t4"``: independent Student-t samples with 4 degrees of freedom, scaled to that sd
      (t4 has variance 2, so the draw is divided by sqrt(2)).

    ``torque_resolution_nm`` > 0 rounds the torque channel to that resolution (an ADC step).
    """

    sd_nm: float = 0.01
    sd_rel: float = 0.004
    sd_target_rel: float = 0.0
    colour: NoiseColour = "white"
    phi: float = 0.0
    torque_resolution_nm: float = 0.0
    clamp_sd_kn: float = 0.02
    clamp_sd_rel: float = 0.002

    def __post_init__(self) -> None:
        if self.colour not in ("white", "ar1", "t4"):
            raise ValueError(f"noise colour must be white, ar1 or t4, got {self.colour!r}")
        if not 0.0 <= self.phi < 1.0:
            raise ValueError(f"noise phi must be in [0, 1), got {self.phi}")
        if self.colour != "ar1" and self.phi != 0.0:
            raise ValueError("noise phi is only used with colour='ar1'")
        for name in ("sd_nm", "sd_rel", "sd_target_rel", "torque_resolution_nm", "clamp_sd_kn", "clamp_sd_rel"):
            if getattr(self, name) < 0:
                raise ValueError(f"noise {name} must be >= 0")


@dataclass(frozen=True)
class FaultConfig:
    """Multiplicative friction fault: mu -> mu * (1 + m * g(angle)).

    ``kind``: ``None`` (no fault), ``"abrupt"`` (g steps from 0 to 1 at the onset, over
    ``transition_deg``, 0 = a true step), ``"incipient"`` (g grows linearly from the onset to 1
    at the planned end of the elastic zone), ``"intermittent"`` (g is 1 during ``episodes``
    on-episodes, the first starting at the onset, each ``episode_fraction`` of the elastic span
    long, separated by gaps of the same size distribution), or ``"mix"`` (one of the three
    drawn per tightening).

    ``magnitude``: m drawn in the range (``signed=True``: a random sign is applied to it).
    ``onset_fraction``: onset as a fraction of the planned elastic zone's angle span, from its
    start (end of seating) to its planned end (target torque reached, or yield start).
    ``fraction_faulty``: share of tightenings with a fault. ``acts_on``: which friction
    coefficient(s) the factor multiplies.
    """

    kind: FaultKind | None = None
    magnitude: Range = (0.1, 0.4)
    signed: bool = False
    onset_fraction: Range = (0.2, 0.8)
    fraction_faulty: float = 1.0
    acts_on: FaultTarget = "both"
    transition_deg: Range = 0.0
    episodes: tuple[int, int] = (1, 3)
    episode_fraction: Range = (0.04, 0.12)

    def __post_init__(self) -> None:
        if self.kind is not None and self.kind not in (*FAULT_KINDS, "mix"):
            raise ValueError(f"fault kind must be None, abrupt, incipient, intermittent or mix, got {self.kind!r}")
        if self.acts_on not in (*FAULT_TARGETS, "mix"):
            raise ValueError(f"fault acts_on must be both, thread, bearing or mix, got {self.acts_on!r}")
        lo, hi = range_bounds(self.onset_fraction, "onset_fraction")
        if lo < 0 or hi > 1:
            raise ValueError("onset_fraction must lie within [0, 1]")
        mlo, _ = range_bounds(self.magnitude, "magnitude")
        if mlo <= -1:
            raise ValueError("fault magnitude must be > -1")
        if not 0.0 <= self.fraction_faulty <= 1.0:
            raise ValueError("fraction_faulty must be in [0, 1]")
        if self.episodes[0] < 1 or self.episodes[1] < self.episodes[0] or self.episodes[1] > 8:
            raise ValueError("episodes must be (low, high) with 1 <= low <= high <= 8")
        range_bounds(self.transition_deg, "transition_deg")
        range_bounds(self.episode_fraction, "episode_fraction")


# --- effects -------------------------------------------------------------------------------


@dataclass(frozen=True)
class TorqueDynamics:
    """Dynamics of the torque measurement channel, applied in time to the transducer torque
    (the controller sees the filtered signal; after the stop it leaves a tail).

    ``form``: ``"lowpass1"`` (first order, time constant ``tau_s``), ``"lowpass2"`` (second
    order, ``natural_freq_hz`` and ``damping``, unit DC gain) or ``"delay"`` (pure transport
    delay ``delay_s``, rounded to the internal time step)."""

    form: Literal["lowpass1", "lowpass2", "delay"] = "lowpass1"
    tau_s: Range = (0.001, 0.005)
    natural_freq_hz: Range = (80.0, 300.0)
    damping: Range = (0.4, 1.0)
    delay_s: Range = (0.0005, 0.003)
    fraction: float = 1.0
    kind: Literal["torque_dynamics"] = field(default="torque_dynamics", init=False)


@dataclass(frozen=True)
class SpeedFriction:
    """Speed-dependent friction factor on both coefficients, v = bolt speed [rpm]:

    - ``"linear"``: mu = mu0 (1 + coeff v / v_ref_rpm);
    - ``"log"``: mu = mu0 (1 + coeff ln(1 + v / v0_rpm));
    - ``"stribeck"``: mu = mu0 (1 + rise exp(-(v / stribeck_speed_rpm)^2) + coeff v / v_ref_rpm):
      highest at standstill, falling to a minimum, rising viscously.
    """

    form: Literal["linear", "log", "stribeck"] = "linear"
    coeff: Range = (0.02, 0.10)
    v_ref_rpm: float = 100.0
    v0_rpm: float = 10.0
    stribeck_rise: Range = (0.1, 0.3)
    stribeck_speed_rpm: Range = (15.0, 40.0)
    fraction: float = 1.0
    kind: Literal["speed_friction"] = field(default="speed_friction", init=False)


@dataclass(frozen=True)
class TorqueRipple:
    """Torque ripple at 1x and/or 2x per revolution of the spindle (the socket's position,
    a random phase per tightening), through the whole curve including the rundown.

    ``form``: ``"drag"`` (an eccentric socket/spindle: ``amplitude_nm`` Nm, or
    ``amplitude_fraction`` of the target torque when given) or ``"gauge"`` (the transducer's
    sensitivity varies with its rotation: amplitude ``amplitude_rel`` times the current torque).
    ``orders``: the harmonics present, each with its own amplitude and phase."""

    form: Literal["drag", "gauge"] = "drag"
    orders: tuple[int, ...] = (1,)
    amplitude_nm: Range = (0.05, 0.3)
    amplitude_fraction: Range | None = None
    amplitude_rel: Range = (0.005, 0.02)
    fraction: float = 1.0
    kind: Literal["ripple"] = field(default="ripple", init=False)

    def __post_init__(self) -> None:
        if not self.orders or any(o not in (1, 2) for o in self.orders) or len(set(self.orders)) != len(self.orders):
            raise ValueError(f"ripple orders must be a non-empty subset of (1, 2), got {self.orders!r}")


@dataclass(frozen=True)
class Inertia:
    """Rotating inertia.

    - ``"transducer"``: inertia downstream of the torque transducer (spindle, socket); the
      transducer reads the bolt torque plus J * angular acceleration.
    - ``"drive"``: inertia of the motor and gearbox (reflected to the output) driven by a motor
      whose output torque is limited to ``max_torque_factor`` x target: accelerations and the
      stop are limited by J (more overshoot), the transducer does not see J alpha.

    J is drawn log-uniformly from ``inertia_kgm2`` [kg m^2], or from ``inertia_per_nm``
    [kg m^2 per Nm of target torque: bigger tools for bigger joints]. Neither given: the form's
    default, transducer 5e-5-4e-4 kg m^2, drive 5e-5-2e-4 kg m^2 per Nm."""

    form: Literal["transducer", "drive"] = "transducer"
    inertia_kgm2: Range | None = None
    inertia_per_nm: Range | None = None
    max_torque_factor: Range = (1.3, 2.0)
    fraction: float = 1.0
    kind: Literal["inertia"] = field(default="inertia", init=False)

    def __post_init__(self) -> None:
        if self.inertia_kgm2 is not None and self.inertia_per_nm is not None:
            raise ValueError("give inertia_kgm2 or inertia_per_nm, not both")

    def draw(self, rng: "np.random.Generator", target: float) -> float:
        """J [kg m^2] for a tightening with that target torque."""
        if self.inertia_kgm2 is not None:
            lo, hi = range_bounds(self.inertia_kgm2, "inertia_kgm2")
            scale = 1.0
        elif self.inertia_per_nm is not None:
            lo, hi = range_bounds(self.inertia_per_nm, "inertia_per_nm")
            scale = target
        elif self.form == "transducer":
            lo, hi, scale = 5e-5, 4e-4, 1.0
        else:
            lo, hi, scale = 5e-5, 2e-4, target
        if lo <= 0:
            raise ValueError("inertia must be positive")
        return scale * float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


@dataclass(frozen=True)
class PressureFriction:
    """Contact-pressure (clamp-force) dependent friction on both coefficients, F_ref = the
    planned clamp force at the target torque:

    - ``"linear"``: mu = mu0 (1 + kappa F / F_ref);
    - ``"power"``: mu = mu0 (max(F, 0.05 F_ref) / F_ref)^exponent."""

    form: Literal["linear", "power"] = "linear"
    kappa: Range = (-0.15, 0.15)
    exponent: Range = (-0.1, 0.1)
    fraction: float = 1.0
    kind: Literal["pressure_friction"] = field(default="pressure_friction", init=False)


Effect = Union[TorqueDynamics, SpeedFriction, TorqueRipple, Inertia, PressureFriction]
EFFECT_KINDS: tuple[str, ...] = ("torque_dynamics", "speed_friction", "ripple", "inertia", "pressure_friction")


@dataclass(frozen=True)
class OperatorConfig:
    """Hand-held tools: per-operator parameters (drawn once per set from the seed), each
    tightening assigned an operator uniformly.

    ``speed_factor`` scales every speed of the program (trigger habits); ``angle_offset_deg``
    is free socket play before the bolt is engaged (the encoder counts it: the whole curve
    shifts in angle), with a per-tightening jitter of sd ``angle_jitter_deg``;
    ``arm_compliance_deg_per_nm``: the tool housing turns back against the operator's arm by
    compliance x torque, which the encoder counts (the curve looks softer, and the angle backs
    off when the torque is released)."""

    speed_factor: Range = (0.8, 1.2)
    angle_offset_deg: Range = (0.0, 15.0)
    angle_jitter_deg: float = 1.0
    arm_compliance_deg_per_nm: Range = (0.0, 0.03)


@dataclass(frozen=True)
class ProcessConfig:
    """Tightening program and tool drive.

    CST: rundown at ``rundown_rpm`` until the encoder angle reaches the switch angle
    (``switch_before_contact_deg`` before the nominal head contact, as a program set up for the
    screw length would; None: no angle switch) or the measured torque passes the switch torque
    (``switch_torque_fraction`` of target, raised above prevailing torque, ripple and noise),
    whichever first, then ``final_rpm`` to the target. CSDT: as CST, with a stop of ``pause_s`` when the measured
    torque passes ``pause_torque_fraction`` of target, then ``final_rpm * resume_speed_factor``.
    HDT: speed command min(rundown, max(floor, G (target - measured))) with
    G = ``hdt_rundown_rpm`` / (``hdt_knee`` x target) and floor ``hdt_min_rpm``. The program is
    set up for the joint: the knee is raised (and, beyond 0.8, the rundown speed lowered) until
    the deceleration the law asks at the knee, torque rate x speed^2 / (knee x target), is at
    most half the drive's braking capability.

    The drive follows the speed command with a first-order lag ``speed_lag_s``, its
    acceleration limited to ``accel_deg_s2`` and deceleration to ``brake_deg_s2``. At the target
    the command goes to 0; once the tool stands still it releases the torque over ``release_s``
    (cosine ramp); the recording runs on ``tail_s`` (at least, longer with slow torque dynamics).
    The controller ignores the torque while the tool starts (``blank_s`` beyond the time needed
    to accelerate). ``pause_relaxation``: fraction of the clamp force lost (embedding) during a
    CSDT pause, time constant ``pause_relaxation_tau_s``."""

    rundown_rpm: Range = (250.0, 600.0)
    final_rpm: Range = (60.0, 200.0)
    hdt_rundown_rpm: Range = (400.0, 900.0)
    hdt_knee: Range = (0.3, 0.6)
    hdt_min_rpm: Range = (10.0, 30.0)
    pause_torque_fraction: Range = (0.4, 0.75)
    pause_s: Range = (0.02, 0.15)
    resume_speed_factor: Range = (0.5, 1.0)
    pause_relaxation: Range = 0.0
    pause_relaxation_tau_s: Range = (0.03, 0.1)
    rundown_revolutions: Range = (3.0, 5.0)
    seating_deg: Range = (2.0, 8.0)
    switch_torque_fraction: Range = (0.05, 0.12)
    switch_before_contact_deg: Range | None = (20.0, 90.0)
    speed_lag_s: Range = (0.0005, 0.002)
    accel_deg_s2: Range = (5e4, 1.5e5)
    brake_deg_s2: Range = (2e5, 6e5)
    release_s: Range = (0.003, 0.01)
    tail_s: float = 0.02
    blank_s: float = 0.01


@dataclass(frozen=True)
class GeneratorConfig:
    """A set of tightenings.

    ``threads``: ISO coarse threads drawn uniformly (see :data:`THREADS`). ``target_torque_nm``:
    None takes each thread's own range, else the range for every tightening.
    ``mu_th``/``mu_b``: friction coefficient ranges (drawn independently).
    ``axial_stiffness_per_mm``: joint stiffness c [kN/mm] per mm of nominal diameter, drawn
    log-uniformly; the joint stiffness is k = P c / 360 [kN/deg].
    ``prevailing_fraction``: prevailing (rundown) torque as a fraction of the target.
    ``with_yield_fraction``: share of tightenings that yield before the target.
    ``strategy``: CST, CSDT, HDT or mix (drawn per tightening).
    ``sample_rate_hz`` in [500, 10000]; ``encoder_step_deg`` in (0, 1] (angle floor-quantised).
    ``clamp_force``: add the ``clamp_force`` channel (test rig). ``joint_stiffness_column``:
    add the true joint stiffness as a ``joint_stiffness`` column of the curves table.
    ``operators`` > 0: hand-held tools, an ``operator`` column and per-operator parameters.
    """

    n: int = 100
    seed: int = 0
    strategy: Strategy = "mix"
    sample_rate_hz: float = 2000.0
    encoder_step_deg: float = 0.05
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    clamp_force: bool = False
    with_yield_fraction: float = 0.0
    fault: FaultConfig = field(default_factory=FaultConfig)
    effects: tuple[Effect, ...] = ()
    operators: int = 0
    operator: OperatorConfig = field(default_factory=OperatorConfig)
    threads: tuple[str, ...] = ("M6", "M8", "M10", "M12")
    target_torque_nm: Range | None = None
    mu_th: Range = (0.08, 0.20)
    mu_b: Range = (0.08, 0.20)
    axial_stiffness_per_mm: Range = (6.0, 25.0)
    prevailing_fraction: Range = (0.005, 0.04)
    process: ProcessConfig = field(default_factory=ProcessConfig)
    joint_stiffness_column: bool = False
    max_duration_s: float = 5.0

    def __post_init__(self) -> None:
        from .joint import THREADS

        if self.n < 0:
            raise ValueError("n must be >= 0")
        if self.seed < 0:
            raise ValueError("seed must be >= 0")
        if self.strategy not in (*STRATEGIES, "mix"):
            raise ValueError(f"strategy must be CST, CSDT, HDT or mix, got {self.strategy!r}")
        if not 500.0 <= self.sample_rate_hz <= 10000.0:
            raise ValueError(f"sample_rate_hz must be within 500-10000 Hz, got {self.sample_rate_hz}")
        if not 0.0 < self.encoder_step_deg <= 1.0:
            raise ValueError(f"encoder_step_deg must be in (0, 1], got {self.encoder_step_deg}")
        if not 0.0 <= self.with_yield_fraction <= 1.0:
            raise ValueError("with_yield_fraction must be in [0, 1]")
        if self.operators < 0:
            raise ValueError("operators must be >= 0")
        if not self.threads or any(t not in THREADS for t in self.threads):
            raise ValueError(f"threads must be among {sorted(THREADS)}, got {self.threads!r}")
        kinds = [e.kind for e in self.effects]
        if len(set(kinds)) != len(kinds):
            raise ValueError(f"each effect kind may appear once, got {kinds}")
        for e in self.effects:
            if not 0.0 <= e.fraction <= 1.0:
                raise ValueError(f"{e.kind}: fraction must be in [0, 1]")
        for name in ("mu_th", "mu_b", "axial_stiffness_per_mm", "prevailing_fraction"):
            lo, _ = range_bounds(getattr(self, name), name)
            if lo < 0 or (name == "axial_stiffness_per_mm" and lo <= 0):
                raise ValueError(f"{name} must be positive")
        if self.target_torque_nm is not None:
            lo, _ = range_bounds(self.target_torque_nm, "target_torque_nm")
            if lo <= 0:
                raise ValueError("target_torque_nm must be positive")
        if self.max_duration_s <= 0:
            raise ValueError("max_duration_s must be positive")

    def effect(self, kind: str) -> Effect | None:
        """The configured effect of that kind, or None."""
        for e in self.effects:
            if e.kind == kind:
                return e
        return None
