"""Ready-made configurations."""

from __future__ import annotations

import dataclasses
from typing import Any

from .config import (
    GeneratorConfig,
    Inertia,
    NoiseConfig,
    PressureFriction,
    SpeedFriction,
    TorqueDynamics,
    TorqueRipple,
)


def clean_config(n: int = 100, seed: int = 0, **overrides: Any) -> GeneratorConfig:
    """The bare model: no effects, no faults, white noise (0.01 Nm + 0.4 % of torque), 2 kHz,
    0.05 deg encoder; keyword overrides replace any field."""
    return GeneratorConfig(n=n, seed=seed, **overrides)


def production(n: int = 100, seed: int = 0, hand_held: bool = False, **overrides: Any) -> GeneratorConfig:
    """Production-line data: strategies mixed, 2 kHz, 0.1 deg encoder, coloured noise, and
    moderate doses of every effect (a 0.5-2 ms transducer low-pass, 1x and 2x ripple, spindle
    inertia, logarithmic speed friction, pressure-dependent friction). ``hand_held``: four
    operators with hand-held tools."""
    base = GeneratorConfig(
        n=n, seed=seed, strategy="mix", sample_rate_hz=2000.0, encoder_step_deg=0.1,
        noise=NoiseConfig(sd_nm=0.01, sd_rel=0.003, colour="ar1", phi=0.3),
        effects=(
            TorqueDynamics("lowpass1", tau_s=(0.0005, 0.002)),
            TorqueRipple("drag", orders=(1, 2), amplitude_fraction=(0.001, 0.005)),
            Inertia("transducer", inertia_kgm2=(3e-5, 2e-4)),
            SpeedFriction("log", coeff=(0.0, 0.04)),
            PressureFriction("linear", kappa=(-0.05, 0.05)),
        ),
        operators=4 if hand_held else 0,
    )
    return dataclasses.replace(base, **overrides)


def rig(n: int = 100, seed: int = 0, **overrides: Any) -> GeneratorConfig:
    """Test-rig data: CST on M8 and M10, 5 kHz, 0.02 deg encoder, low noise, a clamp-force
    channel and the true joint stiffness as a column."""
    base = GeneratorConfig(
        n=n, seed=seed, strategy="CST", sample_rate_hz=5000.0, encoder_step_deg=0.02,
        noise=NoiseConfig(sd_nm=0.005, sd_rel=0.001), clamp_force=True, threads=("M8", "M10"),
        joint_stiffness_column=True,
    )
    return dataclasses.replace(base, **overrides)
