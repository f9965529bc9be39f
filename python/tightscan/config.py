"""Detection parameters.

The defaults come from the Rust core (``_core.default_config()``): one source of truth.
"""

from __future__ import annotations

import collections.abc
import dataclasses
import os
import sys
import types
import typing
from dataclasses import dataclass, field
from typing import Any, Mapping, Union

from . import _core
from .exceptions import InvalidParameterError

__all__ = [
    "CusumConfig",
    "ElasticZoneConfig",
    "BlockConfig",
    "FrictionConfig",
    "BreakConfig",
    "L1Config",
    "DecisionConfig",
    "ResidualTestConfig",
    "ParticleFilterConfig",
    "DetectConfig",
    "ConfigLike",
    "config_from_toml",
    "config_to_toml",
]

_DEFAULTS: dict[str, Any] = _core.default_config()


@dataclass(frozen=True)
class CusumConfig:
    """Two-sided CUSUM on the standardised block torque rate (sigma units).

    By default each tightening's threshold h is the one at which the CUSUM alarms within the
    blocks it monitors with probability equal to the CUSUM's share of the decision rule's
    alpha (the exact finite-horizon probability). ``arl0``, the in-control average run length
    in blocks, sets one h for every tightening by Siegmund's approximation; ``threshold`` sets
    h itself.
    """

    kappa: float = _DEFAULTS["kappa"]
    arl0: float | None = _DEFAULTS["arl0"]
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
class BreakConfig:
    """The sup-LR scan for one break of the elastic line (torque on angle) at any sample.

    ``alpha`` is its false-alarm probability per tightening, from a shipped null table; ``None``
    takes its share of the decision rule's alpha. A quantised angle encoder makes torque steps
    of one encoder increment (torque rate x resolution); a break is credited only when its jump
    exceeds ``min_jump_steps`` of them, or its statistic is three times the critical value, or
    twice it with the change of slope alone significant (an encoder offset shifts the level; a
    friction change turns the slope).

    The scan needs ten samples or more after a break, so the last samples up to the peak get a
    predictive (Chow) test of their own, with ``tail_fraction`` of ``alpha``: a large friction
    rise late in the curve makes the tool reach its target within a sample or two. 0 turns it
    off. It also needs ten samples before a break, so the window's first samples get the same
    test read backwards, with ``head_fraction`` of ``alpha``: an abrupt friction change early
    in the window makes the torque jump by the clamp force times the change. 0 turns it off.
    An intermittent friction fault leaves a stretch of the window off the line, which returns to
    it after: a pulse, not a break, and it may come back. The episode scan looks for up to three
    such stretches (at least three samples each, inside the window, not at a pause), with
    ``episode_fraction`` of ``alpha`` (half of it where the window's noise has a lag-1
    autocorrelation of 0.7 or more, the scan keeping the other half; the stretches are whitened
    as the samples are, so strong colour does not hide them), where that share and the scan's
    are both 0.001 or more (the shipped tables' range: a
    rule ``alpha`` of about 0.0045 and up with the default split; below it the scan keeps the
    share). 0 turns it off."""

    alpha: float | None = _DEFAULTS["break_alpha"]
    min_jump_steps: float = _DEFAULTS["break_min_jump_steps"]
    tail_fraction: float = _DEFAULTS["break_tail_fraction"]
    head_fraction: float = _DEFAULTS["break_head_fraction"]
    episode_fraction: float = _DEFAULTS["break_episode_fraction"]


@dataclass(frozen=True)
class L1Config:
    """L1 (sign-residual) sequential monitoring of the elastic line (Huskova and Koubkova):
    torque on angle, or on clamp force when present, trained on the start of the window, with
    the boundary c sqrt(m) (1 + k/m) (k/(m+k))^gamma. ``gamma`` must be a table value (0, 0.1,
    0.15, 0.25, 0.35, 0.45, 0.49); ``alpha=None`` takes its share of the rule's alpha."""

    gamma: float = _DEFAULTS["l1_gamma"]
    alpha: float | None = _DEFAULTS["l1_alpha"]


@dataclass(frozen=True)
class DecisionConfig:
    """How the detectors decide ``change_detected``.

    ``alpha`` is the false-alarm probability per tightening of the decision. With ``rule="any"``
    each detector of ``detectors`` gets a weighted share of it (break 3, others 1), so the
    union bound keeps the rule at or below ``alpha`` whatever the data (no calibration to a
    simulator: one measured on our own curves did not transfer to curves we did not
    generate); ``"K-of-n"`` (e.g. ``"2-of-n"``) asks K detectors to agree, a subset of those
    alarms. Detectors: ``break`` (sup-LR scan), ``l1``,
    ``cusum``, ``kde`` (needs ``ResidualTestConfig(kde=True)``), ``pf`` (needs
    ``ParticleFilterConfig(enabled=True)``).

    ``rule`` may also be a table of detector responses, one mapping per row, e.g.
    ``({"break": True}, {"cusum": True, "l1": True})``: a change when any row matches, a row
    matching when the detectors it names fire (``True``) or stay silent (``False``); detectors
    it does not name do not matter. Every row must require one detector to fire, so the table
    stays within the union bound."""

    alpha: float = _DEFAULTS["alpha"]
    rule: str | tuple[Mapping[str, bool], ...] = _DEFAULTS["rule"]
    detectors: tuple[str, ...] = tuple(_DEFAULTS["detectors"])


@dataclass(frozen=True)
class ResidualTestConfig:
    """Tests on the residuals of the robust elastic line.

    The first ``training_fraction`` of the window is the reference. The kernel-density test (L2
    distance of Gaussian KDEs = biased squared MMD, block-permutation p-value) costs about 1 ms
    per tightening and is off unless ``kde=True``. The k-sigma chart (``shewhart_k = 3``: the
    classical 3-sigma test) is the baseline every report can compare with."""

    training_fraction: float = _DEFAULTS["residual_training_fraction"]
    kde: bool = _DEFAULTS["kde"]
    kde_alpha: float | None = _DEFAULTS["kde_alpha"]
    kde_permutations: int = _DEFAULTS["kde_permutations"]
    kde_seed: int = _DEFAULTS["kde_seed"]
    shewhart_k: float = _DEFAULTS["shewhart_k"]


@dataclass(frozen=True)
class ParticleFilterConfig:
    """The particle-filter fault test (opt-in): the torque rate tracked sample by sample over
    the whitened elastic window, with a fault mode in which it has jumped.

    Its statistic (``pf_statistic``) is the largest log Bayes factor of the fault model against
    no fault; being invariant to the line and the noise scale, its null distribution depends on
    the window length only, and ``pf_p_value`` comes from a shipped null table by length,
    averaged over the whitening's uncertainty (``exp(-pf_statistic)`` is Ville's bound: valid
    for any length and particle count, but conservative). On an alarm, ``pf_change_*`` come from
    the exact posterior of the change's sample. ``particles`` trades cost (about 25-35 ns per particle and window sample)
    against the Monte Carlo error of the Bayes factor; ``seed + row`` seeds each tightening,
    so results do not depend on the threads. ``friction_track`` adds ``pf_friction``, the
    posterior mean torque rate after every tested sample (for plots). Not in the default rule: it adds no recall to
    the rule at an equal false-alarm rate (benches/README.md); it adds the online view (the posterior of
    the fault mode and of where it began)."""

    enabled: bool = _DEFAULTS["pf"]
    particles: int = _DEFAULTS["pf_particles"]
    alpha: float | None = _DEFAULTS["pf_alpha"]
    seed: int = _DEFAULTS["pf_seed"]
    friction_track: bool = _DEFAULTS["pf_friction"]


@dataclass(frozen=True)
class DetectConfig:
    """All detection parameters."""

    zone: ElasticZoneConfig = field(default_factory=ElasticZoneConfig)
    friction: FrictionConfig = field(default_factory=FrictionConfig)
    blocks: BlockConfig = field(default_factory=BlockConfig)
    cusum: CusumConfig = field(default_factory=CusumConfig)
    breaks: BreakConfig = field(default_factory=BreakConfig)
    l1: L1Config = field(default_factory=L1Config)
    decision: DecisionConfig = field(default_factory=DecisionConfig)
    residual_tests: ResidualTestConfig = field(default_factory=ResidualTestConfig)
    pf: ParticleFilterConfig = field(default_factory=ParticleFilterConfig)

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
            "break_alpha": self.breaks.alpha,
            "break_min_jump_steps": self.breaks.min_jump_steps,
            "break_tail_fraction": self.breaks.tail_fraction,
            "break_head_fraction": self.breaks.head_fraction,
            "break_episode_fraction": self.breaks.episode_fraction,
            "l1_gamma": self.l1.gamma,
            "l1_alpha": self.l1.alpha,
            "alpha": self.decision.alpha,
            "rule": self.decision.rule if isinstance(self.decision.rule, str) else [dict(row) for row in self.decision.rule],
            "detectors": list(self.decision.detectors),
            "residual_training_fraction": self.residual_tests.training_fraction,
            "kde": self.residual_tests.kde,
            "kde_alpha": self.residual_tests.kde_alpha,
            "kde_permutations": self.residual_tests.kde_permutations,
            "kde_seed": self.residual_tests.kde_seed,
            "shewhart_k": self.residual_tests.shewhart_k,
            "pf": self.pf.enabled,
            "pf_particles": self.pf.particles,
            "pf_alpha": self.pf.alpha,
            "pf_seed": self.pf.seed,
            "pf_friction": self.pf.friction_track,
        }


ConfigLike = Union[DetectConfig, CusumConfig, Mapping[str, Any], None]

# What a TOML file may set: one table per sub-config of DetectConfig (its field name), with the
# sub-config's field names as keys. TOML has no null: a parameter left out keeps its default,
# and a default of None (derived from other parameters) is written as a comment only.
_UNSET_NOTES = {
    "friction": "columns of this name in the data, else no mu_tot",
    "cusum.arl0": "from the CUSUM's share of decision.alpha",
    "cusum.threshold": "from arl0; a threshold overrides arl0",
    "breaks.alpha": "the break scan's share of decision.alpha",
    "l1.alpha": "the L1 monitor's share of decision.alpha",
    "residual_tests.kde_alpha": "the KDE test's share of decision.alpha",
    "pf.alpha": "the particle filter's share of decision.alpha",
}


def _parameter_error(message: str, parameter: str) -> InvalidParameterError:
    error = InvalidParameterError(message)
    error.parameter = parameter
    return error


def _toml_value(value: Any, hint: Any, where: str, source: str) -> Any:
    """``value`` read from TOML checked against the field's type ``hint``; ints are taken for
    floats (``kappa = 1``), lists for tuples."""
    options = typing.get_args(hint) if typing.get_origin(hint) in (Union, types.UnionType) else (hint,)
    for option in options:
        if option is type(None):
            continue
        if option is bool and isinstance(value, bool):
            return value
        if option is int and isinstance(value, int) and not isinstance(value, bool):
            return value
        if option is float and isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        if option is str and isinstance(value, str):
            return value
        if typing.get_origin(option) is tuple and isinstance(value, list):
            (item,) = typing.get_args(option)[:1]
            if item is str and all(isinstance(v, str) for v in value):
                return tuple(value)
            if typing.get_origin(item) is collections.abc.Mapping and all(
                isinstance(v, dict) and all(isinstance(b, bool) for b in v.values()) for v in value
            ):
                return tuple(dict(v) for v in value)
    raise _parameter_error(f"{source}: {where} = {value!r} has the wrong type (expected {hint})", where)


def config_from_toml(path: str | os.PathLike[str], base: DetectConfig | None = None) -> DetectConfig:
    """The :class:`DetectConfig` of a TOML file: ``base`` (the defaults) with what the file sets.

    The file has one table per part of :class:`DetectConfig` (``[zone]``, ``[cusum]``,
    ``[decision]`` ...) with that part's field names as keys; ``tightscan config --show`` prints
    every one with its default. An unknown table or key, or a value of the wrong type, raises
    :class:`InvalidParameterError` naming it and the file, so that a misspelt parameter is never
    silently ignored. The values' ranges are checked by the engine when it runs.
    """
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover - Python 3.10 reads TOML with tomli, the same parser
        import tomli as tomllib

    source = os.fspath(path)
    with open(source, "rb") as f:
        try:
            document = tomllib.load(f)
        except tomllib.TOMLDecodeError as e:
            raise _parameter_error(f"{source}: not valid TOML: {e}", "config") from None
    config = base or DetectConfig()
    parts: dict[str, Any] = {}
    sections = {f.name: f for f in dataclasses.fields(DetectConfig)}
    for name, table in document.items():
        if name not in sections:
            raise _parameter_error(
                f"{source}: unknown table [{name}] (known: {', '.join(sections)})", name
            )
        if not isinstance(table, dict):
            raise _parameter_error(f"{source}: {name} must be a table [{name}] of parameters", name)
        part = getattr(config, name)
        hints = typing.get_type_hints(type(part))
        changes: dict[str, Any] = {}
        for key, value in table.items():
            if key not in hints:
                raise _parameter_error(
                    f"{source}: unknown key {name}.{key} (known in [{name}]: {', '.join(hints)})", f"{name}.{key}"
                )
            changes[key] = _toml_value(value, hints[key], f"{name}.{key}", source)
        parts[name] = dataclasses.replace(part, **changes)
    return dataclasses.replace(config, **parts)


def config_to_toml(config: DetectConfig | None = None) -> str:
    """``config`` (the defaults if None) as the TOML :func:`config_from_toml` reads back to the
    same config. Parameters that are None are left out, with a comment naming them.

    >>> print(config_to_toml(DetectConfig(cusum=CusumConfig(kappa=0.75, threshold=5.0))).split("[cusum]")[1].split("[")[0].strip())
    kappa = 0.75
    threshold = 5.0
    # arl0: unset (from the CUSUM's share of decision.alpha)
    """
    import tomli_w

    config = config or DetectConfig()
    out = []
    for section in dataclasses.fields(DetectConfig):
        part = getattr(config, section.name)
        values: dict[str, Any] = {}
        for f in dataclasses.fields(part):
            value = getattr(part, f.name)
            if value is None:
                continue
            if isinstance(value, tuple):
                value = [dict(v) if isinstance(v, Mapping) else v for v in value]
            values[f.name] = value
        text = tomli_w.dumps({section.name: values}) if values else f"[{section.name}]\n"
        for f in dataclasses.fields(part):
            if getattr(part, f.name) is None:
                note = _UNSET_NOTES.get(f"{section.name}.{f.name}") or _UNSET_NOTES.get(section.name, "")
                text += f"# {f.name}: unset" + (f" ({note})" if note else "") + "\n"
        out.append(text)
    return "\n".join(out)


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
