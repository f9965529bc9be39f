"""What the residual loop reports: the effects it named, with their evidence, and the whole
diagnosis (RMSE before and after, the spectrum, level-2 findings), as plain data and JSON."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from .prepare import PathLike

#: Stable names of the level-1 (within-tightening) effects the loop can name, with what they
#: mean. Level-2 effects are named ``<parameter>_vs_<covariate>`` (out-of-sample covariate
#: search) and ``<parameter>_by_<factor>`` (a grouping factor shifts the parameter: ANOVA and
#: Kruskal-Wallis within specification cells, Holm-corrected).
EFFECT_NAMES: dict[str, str] = {
    "speed_dependent_friction": "friction torque changes with the tool speed: T (1 + a ln(v / v_ref)) in the elastic zone",
    "speed_dependent_prevailing_torque": "the rundown (prevailing) torque changes with the tool speed",
    "channel_delay": "the torque channel lags (transducer low-pass or a time offset between channels): T(t - tau)",
    "inertia": "torque that accelerates rotating parts is recorded: J * angular acceleration",
    "pressure_dependent_friction": "friction changes with clamp force: the torque-force line bends (needs clamp force)",
    "elastic_curvature": "the torque-angle line bends: pressure-dependent friction or progressive joint stiffness (not separable without clamp force)",
    "runout": "once-per-revolution modulation of the torque (eccentric socket or spindle, misaligned transducer)",
    "periodic_disturbance": "a periodic modulation of the torque over the angle at another period (gears, thread lead ...)",
    "program_step": "speed step / program step transient: the torque is offset while the tool program is in a given step",
    "time_drift": "the torque drifts with time within the tightening (relaxation, temperature)",
}


# ---------------------------------------------------------------------------------------------
# Results


@dataclass
class Effect:
    """One effect tried and added by the loop (level 1) or found between tightenings (level 2)."""

    name: str
    description: str
    level: str
    significant: bool
    parameters: dict[str, Any]
    rmse_after: float
    evidence: dict[str, Any]
    rmse_unit: str = "Nm"
    #: the effects this claim names: one, or several the data cannot tell apart (a tie; then
    #: ``name`` joins them with " or " and none of them is named alone)
    names: list[str] = field(default_factory=list)
    #: how the effect's constant varies between tightenings, by parameter name (random effects
    #: around the pooled value in ``parameters``; empty when not refined): see ``diagnose.refine``
    parameters_spread: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        out = {
            "name": self.name,
            "description": self.description,
            "level": self.level,
            "significant": self.significant,
            "parameters": self.parameters,
            "rmse_after": self.rmse_after,
            "rmse_unit": self.rmse_unit,
            "evidence": self.evidence,
            "names": self.names or [self.name],
        }
        if self.parameters_spread:
            out["parameters_spread"] = self.parameters_spread
        return out


@dataclass
class Diagnosis:
    """What :func:`diagnose` found. ``to_dict()`` is the JSON document of the CLI."""

    model: str
    rmse_before: float
    rmse_after: float
    effects: list[Effect]
    unexplained_structure: bool
    details: dict[str, Any] = field(default_factory=dict)
    per_tightening: pa.Table | None = None
    plot_data: dict[str, Any] = field(default_factory=dict, repr=False)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "model": self.model,
            "rmse_before": self.rmse_before,
            "rmse_after": self.rmse_after,
            "effects": [e.to_dict() for e in self.effects],
            "unexplained_structure": self.unexplained_structure,
        }
        out.update(self.details)
        doc: dict[str, Any] = _jsonable(out)
        return doc

    def __repr__(self) -> str:
        # The details and the per-tightening table are long: the headline only.
        names = [e.name for e in self.effects]
        return (
            f"Diagnosis(model={self.model!r}, rmse_before={self.rmse_before:.4g}, rmse_after={self.rmse_after:.4g}, "
            f"effects={names!r}, unexplained_structure={self.unexplained_structure})"
        )

    def _repr_html_(self) -> str:
        """For notebooks: the RMSE before and after, then each effect with its gain."""
        from .._html import grid_table, key_value_table

        head = key_value_table(
            "tightscan diagnose",
            [
                ("tightenings", self.details.get("tightenings")),
                ("model", self.model),
                ("RMSE before [Nm]", self.rmse_before),
                ("RMSE after [Nm]", self.rmse_after),
                ("unexplained structure left", self.unexplained_structure),
            ],
        )
        rows = []
        for e in self.effects:
            gain = e.evidence.get("rmse_gain")
            rows.append(
                (
                    "1" if e.level == "within_tightening" else "2",
                    e.name,
                    e.significant,
                    f"{e.rmse_after:.4g} {e.rmse_unit}",
                    f"{100 * gain:.1f} %" if isinstance(gain, float) else "",
                )
            )
        return head + grid_table("effects", ["level", "effect", "significant", "RMSE after", "gain"], rows)

    def to_json(self, path: PathLike | None = None, indent: int = 2) -> str:
        text = json.dumps(self.to_dict(), indent=indent, allow_nan=False)
        if path is not None:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            Path(path).write_text(text + "\n")
        return text


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    return obj
