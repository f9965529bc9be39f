"""Detection parameters.

The defaults come from the Rust core (``_core.default_config()``): one source of truth.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Union

from . import _core
from .exceptions import InvalidParameterError

__all__ = [
    "CusumConfig",
    "ElasticZoneConfig",
    "BlockConfig",
    "FrictionConfig",
    "DetectConfig",
    "ConfigLike",
]

_DEFAULTS: dict[str, Any] = _core.default_config()


@dataclass(frozen=True)
class CusumConfig:
    """Two-sided CUSUM on the standardised block torque rate (sigma units).

    ``threshold`` (h) is derived from ``arl0``, the in-control average run length in blocks, by
    Siegmund's approximation, unless given explicitly.
    """

    kappa: float = _DEFAULTS["kappa"]
    arl0: float = _DEFAULTS["arl0"]
    threshold: float | None = _DEFAULTS["threshold"]


@dataclass(frozen=True)
class ElasticZoneConfig:
    """Where the elastic window lies: between two fractions of the torque rise from the
    prevailing torque to the peak; it is cut where the gradient falls below
    ``yield_gradient_fraction`` of the elastic gradient (yield)."""

    start_fraction: float = _DEFAULTS["zone_start_fraction"]
    end_fraction: float = _DEFAULTS["zone_end_fraction"]
    trim_fraction: float = _DEFAULTS["zone_trim_fraction"]
    min_samples: int = _DEFAULTS["zone_min_samples"]
    yield_gradient_fraction: float = _DEFAULTS["yield_gradient_fraction"]


@dataclass(frozen=True)
class FrictionConfig:
    """Joint data for ``mu_tot``, used where the table has no column of the same name.

    ``mu_tot`` (ISO 16047) needs clamp force (a ``clamp_force`` channel) or a joint stiffness
    [kN/deg], and the thread geometry: a designation from the ISO table (``"M8"``,
    ``"M10x1.25"``) or ``pitch_mm``, ``d2_mm`` and ``dkm_mm``. Columns of those names in the
    data win over these values, row by row.
    """

    thread: str | None = _DEFAULTS["thread"]
    pitch_mm: float | None = _DEFAULTS["pitch_mm"]
    d2_mm: float | None = _DEFAULTS["d2_mm"]
    dkm_mm: float | None = _DEFAULTS["dkm_mm"]
    joint_stiffness: float | None = _DEFAULTS["joint_stiffness"]


@dataclass(frozen=True)
class BlockConfig:
    """How the window is cut into equal-angle blocks, and how many of them train."""

    max_blocks: int = _DEFAULTS["max_blocks"]
    min_block_samples: int = _DEFAULTS["min_block_samples"]
    training_fraction: float = _DEFAULTS["training_fraction"]
    min_training_blocks: int = _DEFAULTS["min_training_blocks"]


@dataclass(frozen=True)
class DetectConfig:
    """All detection parameters."""

    zone: ElasticZoneConfig = field(default_factory=ElasticZoneConfig)
    friction: FrictionConfig = field(default_factory=FrictionConfig)
    blocks: BlockConfig = field(default_factory=BlockConfig)
    cusum: CusumConfig = field(default_factory=CusumConfig)

    def to_dict(self) -> dict[str, Any]:
        """The flat parameter dict the core reads."""
        return {
            "zone_start_fraction": self.zone.start_fraction,
            "zone_end_fraction": self.zone.end_fraction,
            "zone_trim_fraction": self.zone.trim_fraction,
            "zone_min_samples": self.zone.min_samples,
            "yield_gradient_fraction": self.zone.yield_gradient_fraction,
            "thread": self.friction.thread,
            "pitch_mm": self.friction.pitch_mm,
            "d2_mm": self.friction.d2_mm,
            "dkm_mm": self.friction.dkm_mm,
            "joint_stiffness": self.friction.joint_stiffness,
            "max_blocks": self.blocks.max_blocks,
            "min_block_samples": self.blocks.min_block_samples,
            "training_fraction": self.blocks.training_fraction,
            "min_training_blocks": self.blocks.min_training_blocks,
            "kappa": self.cusum.kappa,
            "arl0": self.cusum.arl0,
            "threshold": self.cusum.threshold,
        }


ConfigLike = Union[DetectConfig, CusumConfig, Mapping[str, Any], None]


def as_dict(config: ConfigLike) -> dict[str, Any] | None:
    """Normalises any accepted config form to the core's flat dict."""
    if config is None:
        return None
    if isinstance(config, DetectConfig):
        return config.to_dict()
    if isinstance(config, CusumConfig):
        return DetectConfig(cusum=config).to_dict()
    if isinstance(config, Mapping):
        return dict(config)
    error = InvalidParameterError(
        f"config must be a DetectConfig, CusumConfig, dict or None, not {type(config).__name__}"
    )
    error.parameter = "config"
    raise error
