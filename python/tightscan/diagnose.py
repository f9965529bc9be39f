"""Close the loop on measured data: fit the declared tightening model, look for structure in its
residuals, trace it to the effect the model lacks, add that effect, and report the error before
and after, out of sample.

Two levels (docs/diagnose-s01.md explains the method and what it found on real data):

- **Within a tightening** (level 1). Per tightening ``j`` the declared model is the elastic line
  ``T = a_j + b_j x`` over the elastic window of :func:`tightscan.detect_batch` (``x`` is the
  clamp force when the table has it, else the angle) and the prevailing torque ``T = c_j`` over
  a rundown stretch before snug. ``a_j, b_j, c_j`` are the tightening's own (nuisance)
  parameters. A candidate effect adds regressors built from the data -- never from the measured
  torque of the sample itself, only from the fitted torque and from the other channels -- with
  *global* coefficients (physical constants shared by all tightenings: a delay, an inertia, a
  friction law), or, where physics makes it so, per-tightening coefficients (the phase of a
  run-out).
- **Between tightenings** (level 2). The per-tightening parameters (torque rate, prevailing
  torque, tightening angle) against tightening-level covariates found in the table (re-use
  count, position, order in the sequence, date ...).

Every comparison is out of sample: K-fold across tightenings (grouped so that one thread or part
never sits on both sides) for global coefficients, and alternate blocks of samples within a
tightening for per-tightening parameters, the declared model going through exactly the same
protocol. A candidate is added when its gain is significant (one-sided test on per-tightening
improvements, Bonferroni over the candidates of the round, ``alpha``) *and* practically relevant
(``min_gain`` of the RMSE); the loop repeats until nothing significant remains.

>>> import tightscan
>>> curves, _ = tightscan.simulate(150, seed=5, fault_fraction=0.0, strategies=["CSDT", "HDT"],
...                                torque_lowpass_ms=5.0)
>>> result = tightscan.diagnose(curves.drop_columns(["strategy", "thread"]))
>>> [e.name for e in result.effects], round(result.effects[0].parameters["tau_ms"]["value"])
(['channel_delay'], 5)
>>> result.rmse_after < 0.8 * result.rmse_before, result.unexplained_structure
(True, False)
"""

from __future__ import annotations

import json
import math
import os
import re
import sys
import time
import types
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence, Union

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.compute as pc

from .exceptions import DataFileError, InvalidParameterError, SchemaError

__all__ = ["diagnose", "Diagnosis", "Effect", "write_report", "load_table", "EFFECT_NAMES"]

PathLike = Union[str, "os.PathLike[str]"]
F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
B8 = npt.NDArray[np.bool_]

#: Stable names of the level-1 (within-tightening) effects the loop can name, with what they
#: mean. Level-2 effects are named ``<parameter>_vs_<covariate>``.
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

# Columns that are channels, identifiers or outcomes of the tightening itself: never covariates.
_CHANNELS = ("angle", "torque", "time", "speed", "clamp_force", "gradient", "step", "torque_red", "angle_red")
_NOT_COVARIATES = re.compile(
    r"^(tightening_id|file_name|label_file_name|import_status|status|result|cycle|n_steps|n_samples"
    r"|step_.*|.*_result|.*_status|has_change|fault_.*|magnitude|onset_.*|effects|runout_phase)$"
)
_SPEC_DEFAULT = ("thread", "target_torque", "nominal_torque", "program", "pitch_mm", "d2_mm", "dkm_mm", "joint_stiffness")
_GROUP_DEFAULT = (("workpiece_id", "workpiece_location"), ("part_id",), ("id_code",), ("serial_number",))


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

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "description": self.description,
            "level": self.level,
            "significant": self.significant,
            "parameters": self.parameters,
            "rmse_after": self.rmse_after,
            "rmse_unit": self.rmse_unit,
            "evidence": self.evidence,
        }


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


# ---------------------------------------------------------------------------------------------
# Input


def _read_path(path: Path) -> pa.Table:
    from .rexroth import read_rexroth

    if path.is_dir():
        runs = path / "runs"
        if runs.is_dir() and any(runs.glob("*.json")):
            labels = path / "labels.csv"
            return read_rexroth(runs, labels=labels if labels.is_file() else None, progress=False)
        if any(path.glob("*.json")):
            labels = path / "labels.csv"
            return read_rexroth(path, labels=labels if labels.is_file() else None, progress=False)
        parquet = sorted(path.rglob("*.parquet"))
        if parquet:
            import pyarrow.dataset as ds

            return ds.dataset([str(p) for p in parquet], format="parquet").to_table()
        raise DataFileError(f"{path} holds neither Rexroth runs (runs/*.json, *.json) nor Parquet files", str(path))
    if path.is_file():
        if path.suffix.lower() == ".json":
            return read_rexroth([path], progress=False)
        import pyarrow.parquet as pq

        try:
            return pq.read_table(path)
        except (pa.ArrowInvalid, OSError) as e:
            raise DataFileError(f"cannot read Parquet file {path}: {e}", str(path)) from e
    raise DataFileError(f"no such file or directory: {path}", str(path))


def load_table(data: Any) -> pa.Table:
    """The tightening table behind ``data`` (as :func:`diagnose` reads it): a table, or a path
    to a Rexroth export directory, a Parquet file or a directory of them."""
    return _as_table(data)


def _as_table(data: Any) -> pa.Table:
    if isinstance(data, (str, os.PathLike)):
        table = _read_path(Path(data))
    elif isinstance(data, pa.Table):
        table = data
    elif isinstance(data, pa.RecordBatch):
        table = pa.Table.from_batches([data])
    elif type(data).__module__.split(".")[0] == "polars":
        table = data.to_arrow()
    elif hasattr(data, "__arrow_c_stream__"):
        table = pa.table(data)
    else:
        raise TypeError(f"diagnose needs a table (pyarrow, polars ...) or a path, not {type(data).__name__}")
    for name in ("angle", "torque"):
        if name not in table.column_names:
            raise SchemaError(f"the table has no column {name!r}", name)
    if not pa.types.is_list(table.schema.field("angle").type) and not pa.types.is_large_list(table.schema.field("angle").type):
        table = _nest(table)
    return table


def _nest(table: pa.Table) -> pa.Table:
    """Long layout (one row per sample) to one row per tightening, in order of appearance."""
    if "tightening_id" not in table.column_names:
        raise SchemaError("a table with one row per sample needs a tightening_id column", "tightening_id")
    channels = [c for c in table.column_names if c in _CHANNELS]
    others = [c for c in table.column_names if c not in channels and c != "tightening_id"]
    table = table.append_column("__order", pa.array(np.arange(table.num_rows)))
    g = table.group_by("tightening_id", use_threads=False).aggregate(
        [(c, "list") for c in channels] + [(c, "first") for c in others] + [("__order", "min")]
    )
    g = g.sort_by("__order_min").drop_columns(["__order_min"])
    names = {f"{c}_list": c for c in channels} | {f"{c}_first": c for c in others}
    return g.rename_columns([names.get(n, n) for n in g.column_names])


def _list_values(table: pa.Table, name: str, dtype: type = np.float64) -> tuple[npt.NDArray[Any], I64, B8]:
    """Flat values, per-row offsets (n_rows + 1, into the flat values) and row validity."""
    arr = table.column(name).combine_chunks()
    if isinstance(arr, pa.ChunkedArray):  # pragma: no cover - pyarrow < 15
        arr = arr.combine_chunks()
    if not (pa.types.is_list(arr.type) or pa.types.is_large_list(arr.type)):
        raise SchemaError(f"channel {name!r} must be a list column in the nested layout, not {arr.type}", name)
    valid = np.asarray(arr.is_valid().to_numpy(zero_copy_only=False), dtype=bool)
    lengths = np.asarray(pc.fill_null(pc.list_value_length(arr), 0).to_numpy(zero_copy_only=False), dtype=np.int64)
    flat = pc.list_flatten(arr)  # respects slicing, skips null rows
    values: npt.NDArray[Any] = np.asarray(flat.to_numpy(zero_copy_only=False), dtype=dtype)
    lengths = np.where(valid, lengths, 0)
    offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    return values, offsets, valid


# ---------------------------------------------------------------------------------------------
# Grouped helpers (samples are contiguous per tightening)


class _Groups:
    def __init__(self, gid: I64, n_groups: int) -> None:
        self.gid = gid
        self.n = n_groups
        self.starts = np.flatnonzero(np.r_[True, gid[1:] != gid[:-1]]).astype(np.int64)
        self.count = np.diff(np.r_[self.starts, len(gid)]).astype(np.float64)

    def sum(self, v: F64) -> F64:
        out: F64 = np.add.reduceat(v, self.starts) if len(v) else np.zeros(self.n)
        return out

    def mean(self, v: F64) -> F64:
        out: F64 = self.sum(v) / self.count
        return out

    def fit(self, cols: Sequence[F64], ys: Sequence[F64], w: F64 | None = None, ridge: float = 1e-9) -> tuple[F64, F64]:
        """Per-group weighted least squares of each y on the columns.

        Returns (coefficients (G, p, m), fitted (n, m)). Columns that are zero in a group get 0.
        """
        p, m = len(cols), len(ys)
        G = np.empty((self.n, p, p))
        H = np.empty((self.n, p, m))
        wc = [c if w is None else c * w for c in cols]
        for a in range(p):
            for b in range(a, p):
                G[:, a, b] = G[:, b, a] = self.sum(wc[a] * cols[b])
            for k in range(m):
                H[:, a, k] = self.sum(wc[a] * ys[k])
        scale = np.trace(G, axis1=1, axis2=2) / max(p, 1)
        G[:, np.arange(p), np.arange(p)] += (ridge * scale + 1e-300)[:, None]
        coef = np.linalg.solve(G, H)
        fitted = np.zeros((len(self.gid), m))
        for a in range(p):
            fitted += cols[a][:, None] * coef[self.gid, a, :]
        out: F64 = np.asarray(coef, dtype=np.float64)
        return out, fitted


def _normal_sf(z: float) -> float:
    return 0.5 * math.erfc(z / math.sqrt(2.0))


def _one_sided_tests(u: F64) -> dict[str, float]:
    """One-sided tests that per-tightening improvements ``u`` are > 0: t (mean) and sign."""
    u = u[np.isfinite(u)]
    n = len(u)
    if n < 3:
        return {"t_statistic": float("nan"), "p_value": 1.0, "sign_p_value": 1.0, "fraction_improved": float("nan"), "n": n}
    sd = float(np.std(u, ddof=1))
    t = float(np.mean(u)) / (sd / math.sqrt(n)) if sd > 0 else (math.inf if np.mean(u) > 0 else 0.0)
    pos = int(np.sum(u > 0))
    nz = int(np.sum(u != 0))
    zs = (pos - 0.5 - 0.5 * nz) / (0.5 * math.sqrt(nz)) if nz else 0.0
    return {
        "t_statistic": t,
        "p_value": _normal_sf(t) if math.isfinite(t) else (0.0 if t > 0 else 1.0),
        "sign_p_value": _normal_sf(zs),
        "fraction_improved": pos / n,
        "n": n,
    }


# ---------------------------------------------------------------------------------------------
# Curves -> samples of the level-1 model


@dataclass
class _Samples:
    n_tight: int
    rows: I64  # table row of each tightening
    ids: list[Any]
    gid: I64
    seg: npt.NDArray[np.int8]  # 0 elastic, 1 rundown
    y: F64
    theta: F64  # dequantised angle [deg]
    x: F64  # declared elastic regressor (smoothed clamp force or dequantised angle)
    xf: F64  # clamp force or its proxy (angle past snug)
    xf_ref: F64  # per tightening: xf at the end of the tightening
    t: F64 | None  # time within the tightening [s]
    omega: F64 | None  # angular speed [deg/s]
    alpha: F64 | None  # angular acceleration [rad/s^2]
    step: I64 | None
    half: B8  # alternate blocks within each segment (within-tightening cross-validation)
    scale: F64  # per tightening: peak torque [Nm]
    prevailing: F64  # per tightening: prevailing torque of detect_batch [Nm]
    has_clamp: bool
    speed_source: str
    phases: dict[str, F64]
    pos_in_window: F64  # 0..1 position of an elastic sample in its window (-1..0 for rundown)
    step_t: F64 | None  # per sample: time since the current program step began [s]
    step_theta: F64 | None  # per sample: angle since the current program step began [deg]
    restart_y: F64  # per sample: measured torque at the end of a pause just before it (NaN if none)
    restart_t: F64  # its time
    pre_y: F64  # per tightening: measured torque just before the elastic window (smoothed)
    pre_t: F64  # its time
    pre_theta: F64  # its angle
    long_gid: I64  # long rundown stretch before the declared one (periodicities): tightening
    long_theta: F64
    long_y: F64


def _window_sums(v: F64, lo: I64, hi: I64) -> F64:
    c = np.concatenate([[0.0], np.cumsum(v)])
    out: F64 = c[hi + 1] - c[lo]
    return out


def _local_linear(tt: F64, v: F64, lo: I64, hi: I64) -> tuple[F64, F64]:
    """Local linear regression of v on tt over index windows [lo, hi]: (level at tt, slope)."""
    n = (hi - lo + 1).astype(np.float64)
    st, sv = _window_sums(tt, lo, hi), _window_sums(v, lo, hi)
    stt, stv = _window_sums(tt * tt, lo, hi), _window_sums(tt * v, lo, hi)
    mt, mv = st / n, sv / n
    sxx = stt - n * mt * mt
    sxy = stv - n * mt * mv
    slope = np.where(sxx > 1e-12 * np.maximum(stt, 1e-300), sxy / np.where(sxx > 0, sxx, 1.0), 0.0)
    return mv + slope * (tt - mt), slope


def _speed_channel(speed: F64, clock: F64, pos: I64, start: I64, end: I64, k: int = 5) -> tuple[F64, F64]:
    """Speed [deg/s] and angular acceleration [rad/s^2] from a noisy speed channel [rpm].

    Program steps are jumps of the speed between two samples: differences beyond five robust
    sds of the sample-to-sample noise are kept whole (a step gives a one-sample acceleration, as
    a stiff drive does); the rest of the speed is smoothed by a local linear fit over +-k samples
    and differentiated. Raw differences would carry the channel's noise into every prediction.
    """
    n = len(speed)
    dv = np.r_[0.0, np.diff(speed)]
    dv[pos == 0] = 0.0
    # a step stands out from the differences around it (a deceleration ramp does not): the
    # excess over the median of the 3 differences on either side
    pad = np.pad(dv, 3, mode="edge")
    win = np.lib.stride_tricks.sliding_window_view(pad, 7)
    neigh = np.median(np.delete(win, 3, axis=1), axis=1)
    excess = dv - neigh
    sd = 1.4826 * float(np.median(np.abs(excess[pos > 0]))) if np.any(pos > 0) else 0.0
    jump = np.where(np.abs(excess) > max(5.0 * sd, 1e-9), excess, 0.0)
    cj = np.cumsum(jump)
    cj = cj - cj[start]  # within the tightening
    clean = speed - cj
    idx = np.arange(n)
    lo, hi = np.maximum(start, idx - k), np.minimum(end, idx + k)
    level, slope = _local_linear(clock, clean, lo, hi)
    dt = np.r_[np.nan, np.diff(clock)]
    dt_med = float(np.median(dt[(pos > 0) & (dt > 0)])) if np.any((pos > 0) & (dt > 0)) else 1.0
    step_rate = np.where((pos > 0) & (dt > 0), jump / np.where(dt > 0, dt, dt_med), 0.0)
    rpm_to_rad = 2 * math.pi / 60.0
    return 6.0 * (level + cj), (slope + step_rate) * rpm_to_rad


def _prepare(table: pa.Table, rundown_deg: float | None, min_samples: int, long_deg: float) -> _Samples:
    from ._api import detect_batch

    n_rows = table.num_rows
    angle, offsets, valid = _list_values(table, "angle")
    torque, toff, tvalid = _list_values(table, "torque")
    ok = valid & tvalid & (np.diff(offsets) == np.diff(toff)) & (np.diff(offsets) >= 20)
    chans: dict[str, F64] = {}
    for name in ("time", "speed", "clamp_force", "step"):
        if name in table.column_names:
            vals, off, v = _list_values(table, name)
            good = v & (np.diff(off) == np.diff(offsets))
            if good[ok].mean() < 0.5:
                continue  # a channel missing from most rows is not used at all
            ok &= good
            # realign to the angle offsets (same lengths where ok)
            chans[name] = vals
            if not np.array_equal(off[:-1][ok], offsets[:-1][ok]):
                idx = _gather_index(off, offsets, ok)
                chans[name] = vals[idx] if len(idx) else vals[:0]
    # keep rows with finite samples
    lengths = np.diff(offsets)
    row_of = np.repeat(np.arange(n_rows), lengths)
    finite = np.isfinite(angle) & np.isfinite(torque)
    for name in ("time", "speed", "clamp_force"):
        if name in chans and len(chans[name]) == len(angle):
            finite &= np.isfinite(chans[name])
    bad_rows = np.unique(row_of[~finite])
    ok[bad_rows] = False

    detect_cols = ["angle", "torque"] + [c for c in ("time", "speed", "clamp_force") if c in chans]
    det = detect_batch(table.select(detect_cols))
    assert isinstance(det, pa.Table)

    def col(name: str) -> F64:
        return np.asarray(det.column(name).to_numpy(zero_copy_only=False), dtype=np.float64)

    es, ee, snug = col("elastic_start_angle"), col("elastic_end_angle"), col("snug_angle")
    prevailing, peak_angle = col("prevailing_torque"), col("peak_angle")
    ok &= np.isfinite(es) & np.isfinite(ee) & np.isfinite(snug) & (ee > es)

    # samples of usable rows
    sel = ok[row_of]
    a = angle[sel]
    y = torque[sel]
    r_of = row_of[sel]
    rows = np.flatnonzero(ok)
    gid = np.searchsorted(rows, r_of).astype(np.int64)
    n_t = len(rows)
    if n_t < 10:
        raise InvalidParameterError(f"only {n_t} tightenings have an elastic zone; diagnose needs at least 10", "data")
    groups = _Groups(gid, n_t)
    start = groups.starts[gid]
    end = np.r_[groups.starts[1:], len(gid)][gid] - 1
    pos = np.arange(len(gid)) - start
    tt = chans["time"][sel] if "time" in chans else None
    speed = chans["speed"][sel] if "speed" in chans else None
    clamp = chans["clamp_force"][sel] if "clamp_force" in chans else None
    step = chans["step"][sel].astype(np.int64) if "step" in chans else None
    if tt is not None:
        tt = tt - tt[groups.starts][gid]

    # stops: runs of unchanged angle ten times longer than usual (a CSDT pause); left out
    new_run = np.r_[True, (a[1:] != a[:-1]) | (gid[1:] != gid[:-1])]
    run_id = np.cumsum(new_run) - 1
    run_len = np.bincount(run_id).astype(np.int64)
    typical = float(np.median(run_len))
    stop = run_len[run_id] > max(10.0 * typical, 8.0)

    # dequantised angle: local linear regression of angle on time over a few quanta
    steps = np.abs(np.diff(a))
    positive = steps[steps > 0]
    quantum = float(np.percentile(positive, 5)) if len(positive) else 0.0
    median_step = float(np.median(steps[(steps > 0) & (steps < 10 * max(quantum, 1e-12))])) if len(positive) else 0.0
    per_sample = float(np.mean(steps[~stop[1:]])) if len(steps) else 0.0
    k = int(np.clip(math.ceil(2.0 * quantum / max(per_sample, 1e-12)), 1, 10)) if quantum > 0 else 1
    clock = tt if tt is not None else pos.astype(np.float64)
    lo = np.maximum(start, np.arange(len(a)) - k)
    hi = np.minimum(end, np.arange(len(a)) + k)
    a0 = a[groups.starts][gid]
    theta, slope = _local_linear(clock, a - a0, lo, hi)
    theta = theta + a0
    theta = np.where(stop, a, theta)
    del median_step

    # speed [deg/s] and acceleration [rad/s^2]
    omega: F64 | None = None
    alpha: F64 | None = None
    speed_source = "none"
    if speed is not None:
        omega, alpha = _speed_channel(speed, clock, pos, start, end)
        speed_source = "speed channel"
        if tt is None:
            alpha = None
    elif tt is not None:
        kk = max(k, 3)
        lo3, hi3 = np.maximum(start, np.arange(len(a)) - kk), np.minimum(end, np.arange(len(a)) + kk)
        _, om = _local_linear(tt, a - a0, lo3, hi3)
        omega = om
        speed_source = "angle/time"
        _, acc = _local_linear(tt, om, lo3, hi3)
        alpha = acc * math.pi / 180.0
    del slope

    # peak index per tightening (first maximum of the torque)
    peak_val = np.maximum.reduceat(y, groups.starts)
    cand = np.where(y >= peak_val[gid], pos, np.iinfo(np.int64).max)
    peak_pos = np.minimum.reduceat(cand, groups.starts)
    before_peak = pos <= peak_pos[gid]

    es_t, ee_t, snug_t = es[rows], ee[rows], snug[rows]
    span = ee_t - es_t
    elastic = (a >= es_t[gid]) & (a <= ee_t[gid]) & before_peak & ~stop
    gap = np.maximum(0.1 * span, es_t - snug_t)
    # ... and before the torque leaves the prevailing level (within 5 % of the rise) on its way
    # to the window: a lagging channel or a soft seating moves the tangent-method snug late
    first_el_pos = np.minimum.reduceat(np.where(elastic, pos, np.iinfo(np.int64).max), groups.starts)
    rise = peak_val - prevailing[rows]
    low = (pos < first_el_pos[gid]) & (y <= (prevailing[rows] + 0.05 * rise)[gid])
    last_low = np.maximum.reduceat(np.where(low, a, -np.inf), groups.starts)
    r_end = np.minimum(snug_t - gap, np.where(np.isfinite(last_low), last_low - 0.1 * span, snug_t - gap))
    r_len = span if rundown_deg is None else np.maximum(span, rundown_deg)
    r_start = r_end - r_len
    rundown = (a >= r_start[gid]) & (a <= r_end[gid]) & before_peak & ~stop
    n_el = np.bincount(gid, weights=elastic.astype(float), minlength=n_t)
    n_rd = np.bincount(gid, weights=rundown.astype(float), minlength=n_t)
    keep_t = n_el >= min_samples
    rundown &= (n_rd >= min_samples)[gid]
    use = (elastic | rundown) & keep_t[gid]
    # the long stretch before the declared rundown, where a periodicity over the angle can show
    long_mask = (a >= (r_start - long_deg)[gid]) & (a < r_start[gid]) & before_peak & ~stop & keep_t[gid]

    # per-tightening references on the full curve
    if clamp is not None:
        idx_peak = groups.starts + peak_pos
        xf_ref_all = np.array([np.mean(clamp[max(s, i - 4): i + 1]) for s, i in zip(groups.starts, idx_peak)])
    else:
        xf_ref_all = peak_angle[rows] - snug_t
    scale_all = peak_val.astype(np.float64)

    # compact to the used samples
    keep_rows = np.flatnonzero(keep_t)
    remap = -np.ones(n_t, dtype=np.int64)
    remap[keep_rows] = np.arange(len(keep_rows))
    gid2 = remap[gid[use]]
    seg = np.where(elastic[use], 0, 1).astype(np.int8)

    def sub(v: F64 | None) -> F64 | None:
        return None if v is None else v[use]

    theta_u = theta[use]
    g2 = _Groups(gid2, len(keep_rows))
    xf: F64
    if clamp is not None:
        # clamp force smoothed by a quadratic in angle over the window: its noise stays out of
        # the torque residual (errors in variables)
        e = (seg == 0).astype(np.float64)
        tc = (theta_u - g2.mean(theta_u * e)[gid2] / np.maximum(g2.mean(e)[gid2], 1e-12)) * e
        sc = np.sqrt(g2.sum(tc * tc) / np.maximum(g2.sum(e), 1))[gid2]
        tc = tc / np.where(sc > 0, sc, 1.0)
        _, fhat = g2.fit([e, tc, tc * tc], [clamp[use]], w=e)
        xf = np.where(seg == 0, fhat[:, 0], 0.0)
        x = xf
    else:
        xf = np.where(seg == 0, theta_u - snug_t[keep_rows][gid2], 0.0)
        x = theta_u
    # alternate blocks within each (tightening, segment) for within-tightening validation
    key = gid2 * 2 + seg
    first_of = np.r_[True, key[1:] != key[:-1]]
    seg_start = np.maximum.accumulate(np.where(first_of, np.arange(len(key)), 0))
    rank = np.arange(len(key)) - seg_start
    seg_n = np.bincount(np.cumsum(first_of) - 1)[np.cumsum(first_of) - 1]
    block = np.maximum(2, seg_n // 16)
    half = ((rank // block) % 2) == 0
    # position within the window, for plots
    es_u, ee_u = es_t[keep_rows][gid2], ee_t[keep_rows][gid2]
    rs_u, re_u = r_start[keep_rows][gid2], r_end[keep_rows][gid2]
    pos_w = np.where(seg == 0, (a[use] - es_u) / np.maximum(ee_u - es_u, 1e-12), (a[use] - re_u) / np.maximum(re_u - rs_u, 1e-12))

    long_g = remap[gid[long_mask]]
    step_t = step_theta = None
    if step is not None:
        new_step = np.r_[True, (step[1:] != step[:-1]) | (gid[1:] != gid[:-1])]
        first_of_step = np.maximum.accumulate(np.where(new_step, np.arange(len(step)), 0))
        step_t = (clock - clock[first_of_step])[use]
        step_theta = (a - a[first_of_step])[use]
    # restarts after a pause: the measured torque at the end of the pause (left out of the model)
    idx_all = np.arange(len(a))
    after_stop = np.r_[False, stop[:-1] & (gid[1:] == gid[:-1])] & ~stop
    prev = np.maximum(idx_all - 1, 0)
    lo_r = np.maximum(np.maximum(groups.starts[gid], prev - 2), 0)
    lo_r = np.minimum(lo_r, prev)
    restart_y = np.where(after_stop, _window_sums(y, lo_r, prev) / (prev - lo_r + 1), np.nan)
    restart_t = np.where(after_stop, clock[prev], np.nan)
    # the torque just before the elastic window: where a filter of the torque channel starts
    first_el = np.where(elastic, pos, np.iinfo(np.int64).max)
    i0 = groups.starts + np.minimum(np.minimum.reduceat(first_el, groups.starts), np.diff(np.r_[groups.starts, len(gid)]) - 1)
    has_pre = i0 - 1 >= groups.starts
    ip = np.where(has_pre, i0 - 1, i0)
    lo_p = np.maximum(groups.starts, ip - 4)
    mean_y = _window_sums(y, lo_p, ip) / (ip - lo_p + 1)
    mean_c = _window_sums(clock, lo_p, ip) / (ip - lo_p + 1)
    # local linear value at the last sample before the window
    sl = np.where(ip > lo_p, _pre_slope(clock, y, lo_p, ip), 0.0)
    pre_y = np.where(has_pre, mean_y + sl * (clock[ip] - mean_c), np.nan)
    pre_t = np.where(has_pre, clock[ip], np.nan)
    pre_th = np.where(has_pre, theta[ip], np.nan)
    ids = table.column("tightening_id").to_pylist() if "tightening_id" in table.column_names else list(range(n_rows))
    rows_final = rows[keep_rows]
    return _Samples(
        n_tight=len(keep_rows),
        rows=rows_final,
        ids=[ids[i] for i in rows_final],
        gid=gid2,
        seg=seg,
        y=y[use],
        theta=theta_u,
        x=x,
        xf=xf,
        xf_ref=np.asarray(xf_ref_all[keep_rows], dtype=np.float64),
        t=sub(tt),
        omega=sub(omega),
        alpha=sub(alpha),
        step=None if step is None else step[use],
        half=half,
        scale=scale_all[keep_rows],
        prevailing=prevailing[rows_final],
        has_clamp=clamp is not None,
        speed_source=speed_source,
        phases={
            "elastic_start_angle": es[rows_final],
            "elastic_end_angle": ee[rows_final],
            "snug_angle": snug[rows_final],
            "peak_angle": peak_angle[rows_final],
            "torque_rate": col("torque_rate")[rows_final],
            "change_angle": np.where(col("change_detected")[rows_final] > 0, col("change_angle")[rows_final], np.nan),
        },
        pos_in_window=pos_w,
        step_t=step_t,
        step_theta=step_theta,
        restart_y=restart_y[use],
        restart_t=restart_t[use],
        pre_y=pre_y[keep_rows],
        pre_t=pre_t[keep_rows],
        pre_theta=pre_th[keep_rows],
        long_gid=long_g,
        long_theta=theta[long_mask],
        long_y=y[long_mask],
    )


def _pre_slope(clock: F64, y: F64, lo: I64, hi: I64) -> F64:
    """Least-squares slope of y on clock over the index ranges [lo, hi] (one per tightening)."""
    n = (hi - lo + 1).astype(np.float64)
    st, sy = _window_sums(clock, lo, hi), _window_sums(y, lo, hi)
    stt, sty = _window_sums(clock * clock, lo, hi), _window_sums(clock * y, lo, hi)
    sxx = stt - st * st / n
    out: F64 = np.where(sxx > 0, (sty - st * sy / n) / np.where(sxx > 0, sxx, 1.0), 0.0)
    return out


def _gather_index(off: I64, offsets: I64, ok: B8) -> I64:
    """Indices into a channel's flat values that line it up with the angle's offsets."""
    parts = [np.arange(off[i], off[i + 1]) if ok[i] else np.arange(0) for i in range(len(ok))]
    lens = np.diff(offsets)
    parts = [p if len(p) == lens[i] else np.zeros(lens[i], dtype=np.int64) for i, p in enumerate(parts)]
    return np.concatenate(parts).astype(np.int64) if parts else np.zeros(0, dtype=np.int64)


# ---------------------------------------------------------------------------------------------
# The level-1 engine


@dataclass
class _Fit:
    beta: F64
    se: F64
    beta_folds: F64
    e_oos: F64
    mse_t: F64
    rmse: float
    resid: F64  # in-sample residual
    pcoef: F64  # per-tightening coefficients (G, p) of the in-sample fit
    pcov_diag: F64  # per-tightening coefficient variances (G, p)
    sigma_t: F64  # per-tightening in-sample residual sd


class _Engine:
    def __init__(self, s: _Samples, fold_of_t: I64, n_folds: int) -> None:
        self.s = s
        self.g = _Groups(s.gid, s.n_tight)
        self.fold_t = fold_of_t
        self.fold = fold_of_t[s.gid]
        self.n_folds = n_folds
        self.weights_t = np.ones(s.n_tight)
        self.h0 = s.half.astype(np.float64)
        self.h1 = 1.0 - self.h0
        self._cache: dict[tuple[str, str], tuple[F64, F64]] = {}
        self._pairs: dict[tuple[str, str, str], F64] = {}
        self._xtx: dict[str, F64] = {}
        self._w = np.ones(len(s.y))
        self.memo: dict[Any, Any] = {}

    def keep_only(self, pkey: str, names: Sequence[str]) -> None:
        """Forget cached projections other than the current model's (memory)."""
        keep = set(names) | {"__y"}
        self._cache = {k: v for k, v in self._cache.items() if k[0] == pkey and k[1] in keep}
        self._pairs = {k: v for k, v in self._pairs.items() if k[0] == pkey and k[1] in keep and k[2] in keep}
        self._xtx = {k: v for k, v in self._xtx.items() if k == pkey}

    def _proj(self, pkey: str, pcols: Sequence[F64], name: str, v: F64) -> tuple[F64, F64]:
        """In-sample residual and within-tightening cross-validated residual of v on pcols."""
        hit = self._cache.get((pkey, name))
        if hit is not None:
            return hit
        _, fit = self.g.fit(pcols, [v])
        r_in = v - fit[:, 0]
        _, f0 = self.g.fit(pcols, [v], w=self.h0)
        _, f1 = self.g.fit(pcols, [v], w=self.h1)
        r_cv = np.where(self.s.half, v - f1[:, 0], v - f0[:, 0])
        self._cache[(pkey, name)] = (r_in, r_cv)
        return r_in, r_cv

    def _pair(self, pkey: str, n1: str, n2: str, r1: F64, r2: F64) -> F64:
        """Per-tightening weighted cross product of two projected columns (cached)."""
        key = (pkey, n1, n2) if n1 <= n2 else (pkey, n2, n1)
        hit = self._pairs.get(key)
        if hit is None:
            hit = self.g.sum(self._w * r1 * r2)
            self._pairs[key] = hit
        return hit

    def _inv_diag(self, pkey: str, pcols: Sequence[F64]) -> F64:
        hit = self._xtx.get(pkey)
        if hit is not None:
            return hit
        g = self.g
        p = len(pcols)
        XtX = np.empty((g.n, p, p))
        for a in range(p):
            for b in range(a, p):
                XtX[:, a, b] = XtX[:, b, a] = g.sum(pcols[a] * pcols[b])
        XtX[:, np.arange(p), np.arange(p)] += 1e-9 * (np.trace(XtX, axis1=1, axis2=2) / p)[:, None] + 1e-300
        out: F64 = np.diagonal(np.linalg.inv(XtX), axis1=1, axis2=2).copy()
        self._xtx[pkey] = out
        return out

    def evaluate(self, pkey: str, pcols: Sequence[F64], znames: Sequence[str], zcols: Sequence[F64]) -> _Fit:
        g = self.g
        ry, ey = self._proj(pkey, pcols, "__y", self.s.y)
        k = len(zcols)
        self._w = self.weights_t[self.s.gid]
        if k:
            pr = [self._proj(pkey, pcols, n, z) for n, z in zip(znames, zcols)]
            A = np.empty((g.n, k, k))
            c = np.empty((g.n, k))
            for i in range(k):
                for j in range(i, k):
                    A[:, i, j] = A[:, j, i] = self._pair(pkey, znames[i], znames[j], pr[i][0], pr[j][0])
                c[:, i] = self._pair(pkey, znames[i], "__y", pr[i][0], ry)
            At, ct = A.sum(0), c.sum(0)
            ridge = 1e-10 * np.trace(At) / k * np.eye(k)
            beta = np.linalg.solve(At + ridge, ct)
            Ainv = np.linalg.inv(At + ridge)
            score = c - np.einsum("gij,j->gi", A, beta)
            meat = score.T @ score
            cov = Ainv @ meat @ Ainv
            se = np.sqrt(np.maximum(np.diag(cov), 0.0))
            bf = np.empty((self.n_folds, k))
            for f in range(self.n_folds):
                m = self.fold_t == f
                bf[f] = np.linalg.solve(At - A[m].sum(0) + ridge, ct - c[m].sum(0))
            e = ey.copy()
            resid = ry.copy()
            ytil = self.s.y.copy()
            for i in range(k):
                e -= pr[i][1] * bf[:, i][self.fold]
                resid -= pr[i][0] * beta[i]
                ytil -= zcols[i] * beta[i]
        else:
            beta = se = np.zeros(0)
            bf = np.zeros((self.n_folds, 0))
            e = ey
            resid = ry
            ytil = self.s.y
        coef, _ = g.fit(pcols, [ytil])
        sig2 = g.sum(resid * resid) / np.maximum(g.count - len(pcols) - 0.0, 1.0)
        inv_diag = self._inv_diag(pkey, pcols)
        mse_t = g.mean(e * e)
        return _Fit(
            beta=beta,
            se=se,
            beta_folds=bf,
            e_oos=e,
            mse_t=mse_t,
            rmse=float(np.sqrt(np.mean(e * e))),
            resid=resid,
            pcoef=coef[:, :, 0],
            pcov_diag=inv_diag * sig2[:, None],
            sigma_t=np.sqrt(sig2),
        )


@dataclass
class _Term:
    """Regressors of one effect: global columns (one shared coefficient each) or per-tightening
    columns (each tightening its own coefficients)."""

    name: str
    description: str
    per_tightening: bool
    labels: list[str]
    columns: list[F64]
    parameters: Callable[[_Fit, list[int]], dict[str, Any]]
    info: dict[str, Any] = field(default_factory=dict)
    key: str = ""
    tag: int = 0


# ---------------------------------------------------------------------------------------------
# The loop


def _folds(table: pa.Table, rows: I64, n_folds: int, group_by: Sequence[str] | str | None, seed: int) -> tuple[I64, list[str]]:
    cols: list[str] = []
    if group_by == "auto":
        for option in _GROUP_DEFAULT:
            if all(c in table.column_names for c in option):
                cols = list(option)
                break
    elif isinstance(group_by, str):
        cols = [group_by]
    elif group_by:
        cols = list(group_by)
    for c in cols:
        if c not in table.column_names:
            raise SchemaError(f"group_by: the table has no column {c!r}", c)
    if cols:
        keys = [tuple(v) for v in zip(*[table.column(c).take(pa.array(rows)).to_pylist() for c in cols])]
        uniq = {k: i for i, k in enumerate(dict.fromkeys(keys))}
        group = np.array([uniq[k] for k in keys], dtype=np.int64)
    else:
        group = np.arange(len(rows), dtype=np.int64)
    rng = np.random.default_rng(seed)
    perm = rng.permutation(int(group.max()) + 1)
    return (perm[group] % n_folds).astype(np.int64), cols


def diagnose(
    data: Any,
    *,
    folds: int = 5,
    alpha: float = 0.01,
    min_gain: float = 0.01,
    max_effects: int = 6,
    group_by: Sequence[str] | str | None = "auto",
    covariates: Sequence[str] | str | None = "auto",
    spec_columns: Sequence[str] | str | None = "auto",
    rundown_deg: float | None = None,
    whiteness_tolerance: float = 0.05,
    min_samples: int = 10,
    parsimony: float = 0.8,
    periodic_span_deg: float = 720.0,
    seed: int = 0,
) -> Diagnosis:
    """Diagnose what the declared tightening model misses, out of sample.

    ``data``: a tightening table in the contract layout (pyarrow, polars, anything with the
    Arrow stream interface), or a path: a Rexroth export directory (``runs/*.json`` with an
    optional ``labels.csv`` beside, or ``*.json``), a Parquet file or a directory of them.

    Returns a :class:`Diagnosis`; ``to_dict()`` gives the JSON document (``model``,
    ``rmse_before``, ``rmse_after`` [Nm, level-1 curve residual, out of sample], ``effects``
    in the order added, ``unexplained_structure``, and details).

    ``folds``: K of the K-fold split across tightenings, grouped by ``group_by`` (``"auto"``:
    ``workpiece_id`` + ``workpiece_location`` when present, ...; ``None``: every tightening its
    own group). ``alpha``: family-wise level per round (Bonferroni over its candidates).
    ``min_gain``: smallest relative RMSE reduction an effect must bring. ``max_effects``: level-1
    effects at most. ``covariates``: level-2 covariates (``"auto"``: every scalar metadata
    column that is not an identifier, outcome or specification, plus the order of the tightening).
    ``spec_columns``: columns whose cells form the level-2 baseline (``"auto"``: thread, target
    torque, program ... when present). ``rundown_deg``: length of the rundown stretch (default:
    the elastic window's angle span). ``periodic_span_deg``: how much rundown before that
    stretch is searched for periodicities (run-out). ``whiteness_tolerance``: largest share of
    the final residual variance a pooled AR(10) may predict before ``unexplained_structure``
    is set. ``parsimony``: a term with per-tightening coefficients is added before a global one
    only if the global one's gain is below this fraction of its gain. ``min_samples``: fewest
    samples of a tightening's elastic window (and rundown stretch) to use it. ``seed``: of the
    fold assignment.
    """
    started = time.perf_counter()
    if folds < 2:
        raise InvalidParameterError("folds must be at least 2", "folds")
    if not 0 < alpha < 1:
        raise InvalidParameterError("alpha must be in (0, 1)", "alpha")
    table = _as_table(data)
    s = _prepare(table, rundown_deg, min_samples, periodic_span_deg)
    fold_t, group_cols = _folds(table, s.rows, folds, group_by, seed)
    eng = _Engine(s, fold_t, folds)
    g = eng.g
    el = (s.seg == 0).astype(np.float64)
    rd = (s.seg == 1).astype(np.float64)
    # declared per-tightening columns: elastic intercept and slope, rundown level
    xc = (s.x - g.sum(s.x * el)[s.gid] / np.maximum(g.sum(el)[s.gid], 1)) * el
    xs = np.sqrt(g.sum(xc * xc) / np.maximum(g.sum(el), 1))[s.gid]
    xn = xc / np.where(xs > 0, xs, 1.0)
    declared: list[F64] = [el, xn, rd]
    declared_labels = ["a (elastic intercept)", "b (elastic slope)", "c (prevailing torque)"]
    x_scale_t = np.sqrt(g.sum(xc * xc) / np.maximum(g.sum(el), 1))

    def assemble(model: dict[str, _Term]) -> tuple[list[F64], str, list[str], list[F64], dict[str, list[int]]]:
        pc: list[F64] = list(declared)
        pk = "declared"
        zn: list[str] = []
        zc: list[F64] = []
        idx: dict[str, list[int]] = {}
        for key, t in model.items():
            if t.per_tightening:
                idx[key] = list(range(len(pc), len(pc) + len(t.columns)))
                pc = pc + t.columns
                pk += f"|{key}@{t.tag}"
            else:
                idx[key] = list(range(len(zc), len(zc) + len(t.columns)))
                zn = zn + [f"{key}:{lab}@{t.tag}" for lab in t.labels]
                zc = zc + t.columns
        return pc, pk, zn, zc, idx

    def evaluate_with(model: dict[str, _Term], extra: _Term | None) -> tuple[_Fit, dict[str, list[int]]]:
        both = dict(model)
        if extra is not None:
            both[extra.key] = extra
        pc, pk, zn, zc, idx = assemble(both)
        return eng.evaluate(pk, pc, zn, zc), idx

    model: dict[str, _Term] = {}
    base, _ = evaluate_with(model, None)
    # weights: 1 / sigma_j^2 of the declared fit (robust to smooth structure: first differences)
    d = np.r_[0.0, np.diff(base.resid)]
    same = np.r_[False, (s.gid[1:] == s.gid[:-1]) & (s.seg[1:] == s.seg[:-1])]
    absd = np.where(same, np.abs(d), np.nan)
    sig_t = _grouped_median(absd, s.gid, s.n_tight) * 1.4826 / math.sqrt(2.0)
    sig_t = np.where(np.isfinite(sig_t) & (sig_t > 0), sig_t, np.nanmedian(sig_t[sig_t > 0]) if np.any(sig_t > 0) else 1.0)
    eng.weights_t = 1.0 / (sig_t * sig_t)
    eng._cache.clear()
    eng._pairs.clear()
    base, _ = evaluate_with(model, None)
    rmse_before = base.rmse
    mse_before_t = base.mse_t.copy()
    e_before = base.e_oos.copy()
    current = base
    current_idx: dict[str, list[int]] = {}
    effects: list[Effect] = []
    rounds: list[dict[str, Any]] = []
    leftover_significant = False
    periodogram_info: dict[str, Any] = {}
    partial: dict[str, Any] = {}
    build = 0
    for round_no in range(max_effects + 1):
        build += 1
        periods = [t.info["period_deg"] for t in model.values() if "period_deg" in t.info]
        terms, pinfo = _candidates(s, eng, current, declared, build, periods, _hints(model, current, current_idx))
        if round_no == 0:
            periodogram_info = pinfo
        pc, pk, zn, zc, _ = assemble(model)
        eng.keep_only(pk, zn)
        cands_all = [t for key, t in terms.items() if key not in model]
        tried: list[dict[str, Any]] = []
        significant_terms: list[tuple[float, _Term, _Fit, dict[str, Any]]] = []
        m = max(len(cands_all), 1)
        for term in cands_all:
            fit, _ = evaluate_with(model, term)
            # relative improvement per tightening, in [-1, 1]: it cannot exceed 1, and a
            # tightening that got more than twice as bad counts as -1 (no single curve decides)
            u = np.clip((current.mse_t - fit.mse_t) / np.maximum(current.mse_t, 1e-300), -1.0, 1.0)
            tests = _one_sided_tests(u)
            gain = (current.rmse - fit.rmse) / current.rmse
            # practical relevance: pooled, or in the typical tightening (a minority of curves
            # with a large misfit of another cause, e.g. friction faults, must not hide it)
            median_gain = float(np.median(1.0 - np.sqrt(fit.mse_t / np.maximum(current.mse_t, 1e-300))))
            significant = tests["p_value"] < alpha / m and max(gain, median_gain) >= min_gain
            tried.append(
                {
                    "name": term.name,
                    "key": term.key,
                    "per_tightening": term.per_tightening,
                    "rmse": fit.rmse,
                    "rmse_gain": gain,
                    "median_tightening_rmse_gain": median_gain,
                    "p_value": tests["p_value"],
                    "sign_p_value": tests["sign_p_value"],
                    "t_statistic": tests["t_statistic"],
                    "fraction_improved": tests["fraction_improved"],
                    "significant": significant,
                }
            )
            if significant:
                significant_terms.append((max(gain, median_gain), term, fit, tests | {"bonferroni_alpha": alpha / m, "candidates_in_round": m, "median_gain": median_gain}))
        rounds.append({"round": round_no + 1, "rmse": current.rmse, "candidates": sorted(tried, key=lambda r: -r["rmse_gain"])})
        if effects:
            by_name = {r["name"]: r["rmse_gain"] for r in tried}
            for alt in effects[-1].evidence.get("alternatives", []):
                alt["rmse_gain_after_it"] = by_name.get(alt["name"])
        if not significant_terms:
            break
        if round_no == max_effects:
            leftover_significant = True
            break
        significant_terms.sort(key=lambda r: -r[0])
        best = significant_terms[0]
        parsimony_note = None
        if best[1].per_tightening:
            # Occam: per-tightening coefficients (2 per tightening) must beat the best global
            # term clearly; else the global one goes first and the other must prove itself after
            glob_terms = [r for r in significant_terms if not r[1].per_tightening]
            if glob_terms and glob_terms[0][0] >= parsimony * best[0]:
                parsimony_note = f"preferred to {best[1].name} (gain {best[0]:.4f}, per-tightening coefficients) by the parsimony rule"
                best = glob_terms[0]
        gain, term, fit, tests = best
        pc_prev, pk_prev = pc, pk
        corr_before = _partial_corr(eng, current, term, pk_prev, pc_prev)
        model[term.key] = term
        rmse_prev = current.rmse
        # rebuild the model's regressors from the updated fit (a Gauss-Newton step for the
        # terms built on the fitted torque or on a current estimate), until it settles
        for _ in range(6):
            build += 1
            idx_now = assemble(model)[4]
            hints_before = _hints(model, fit, idx_now)
            fresh, _info = _candidates(s, eng, fit, declared, build, [t.info["period_deg"] for t in model.values() if "period_deg" in t.info], hints_before)
            trial = {key: fresh.get(key, t) for key, t in model.items()}
            rmse_old = fit.rmse
            fit_try, idx_try = evaluate_with(trial, None)
            if not fit_try.rmse <= rmse_old * (1 + 1e-3):
                current_idx = assemble(model)[4]
                break  # the rebuilt regressors do not fit better: keep the previous ones
            model, fit, current_idx = trial, fit_try, idx_try
            hints_after = _hints(model, fit, current_idx)
            moved = any(abs(hints_after.get(k, 0.0) - v) > 0.005 * abs(v) for k, v in hints_before.items())
            if abs(rmse_old - fit.rmse) < 1e-4 * fit.rmse and not moved:
                break
        evidence = {
            "rmse_before": rmse_prev,
            "rmse_gain": (rmse_prev - fit.rmse) / rmse_prev,
            "median_tightening_rmse_gain": tests["median_gain"],
            "p_value": tests["p_value"],
            "sign_p_value": tests["sign_p_value"],
            "t_statistic": tests["t_statistic"],
            "fraction_of_tightenings_improved": tests["fraction_improved"],
            "bonferroni_alpha": tests["bonferroni_alpha"],
            "candidates_in_round": tests["candidates_in_round"],
            "correlation_with_residual": corr_before,
            "per_tightening_coefficients": term.per_tightening,
            "folds": folds,
            "tightenings": s.n_tight,
            "round": round_no + 1,
        } | {k: v for k, v in term.info.items()}
        if parsimony_note:
            evidence["parsimony"] = parsimony_note
        # other candidates that explained much of the same residual: what the data cannot tell
        # apart from the winner (their gain after it was added is filled in next round)
        evidence["alternatives"] = [
            {"name": r[1].name, "rmse_gain": r[0]} for r in significant_terms if r[1] is not term and r[0] >= 0.3 * gain
        ]
        partial[term.name] = _partial_residual(eng, s, model[term.key], fit, current_idx[term.key], pc_prev, current.resid)
        effects.append(
            Effect(
                name=term.name,
                description=term.description,
                level="within_tightening",
                significant=True,
                parameters={},
                rmse_after=fit.rmse,
                evidence=evidence,
            )
        )
        current = fit
    final = current
    # parameters of the added effects from the final model
    for eff, key in zip(effects, list(model)):
        eff.parameters = model[key].parameters(final, current_idx[key])
    white = _whiteness(s, final.resid)
    unexplained = bool(white["ar_r2"] > whiteness_tolerance or leftover_significant)

    # level 2
    level2, l2_details, l2_plots = _level2(table, s, final, fold_t, folds, alpha, min_gain, covariates, spec_columns, group_cols, x_scale_t)
    effects_all = effects + level2

    model_str = _model_string(s, effects)
    per_t = pa.table(
        {
            "tightening_id": pa.array(s.ids),
            "n_samples": pa.array(g.count.astype(np.int64)),
            "rmse_before": pa.array(np.sqrt(mse_before_t)),
            "rmse_after": pa.array(np.sqrt(final.mse_t)),
            "torque_rate": pa.array(final.pcoef[:, 1] / np.where(x_scale_t > 0, x_scale_t, 1.0)),
            "prevailing_torque": pa.array(np.where(g.sum(rd) > 0, g.sum((s.y - final.resid) * rd) / np.maximum(g.sum(rd), 1), np.nan)),
            "noise_sd": pa.array(sig_t),
        }
    )
    rb, ra = np.sqrt(mse_before_t), np.sqrt(final.mse_t)
    details: dict[str, Any] = {
        "declared_model": {
            "elastic": "T = a_j + b_j * " + ("clamp_force (smoothed along the angle)" if s.has_clamp else "angle (dequantised)"),
            "rundown": "T = c_j",
            "per_tightening_parameters": declared_labels,
        },
        "tightenings": s.n_tight,
        "tightenings_in_table": table.num_rows,
        "samples": int(len(s.y)),
        "elastic_samples": int(el.sum()),
        "rundown_samples": int(rd.sum()),
        "speed_source": s.speed_source,
        "clamp_force": s.has_clamp,
        "folds": folds,
        "group_by": group_cols,
        "alpha": alpha,
        "min_gain": min_gain,
        "per_tightening_rmse": {
            "before": _quantiles(rb),
            "after": _quantiles(ra),
            "fraction_improved": float(np.mean(ra < rb)),
        },
        "noise_floor_estimate": float(np.sqrt(np.sum(g.count * sig_t**2) / np.sum(g.count))),
        "whiteness": white,
        "periodogram": periodogram_info,
        "rounds": rounds,
        "level2": l2_details,
        "seconds": time.perf_counter() - started,
    }
    plot = {
        "e_before": e_before,
        "e_after": final.e_oos,
        "gid": s.gid,
        "seg": s.seg,
        "pos": s.pos_in_window,
        "theta": s.theta,
        "sigma_t": sig_t,
        "ids": s.ids,
        "rb": rb,
        "ra": ra,
        "terms": [(t.name, t.columns if not t.per_tightening else []) for t in model.values()],
        "level2": l2_plots,
        "partial": partial,
        "periodogram": periodogram_info.get("_curve"),
    }
    periodogram_info.pop("_curve", None)
    return Diagnosis(
        model=model_str,
        rmse_before=rmse_before,
        rmse_after=final.rmse,
        effects=effects_all,
        unexplained_structure=unexplained,
        details=details,
        per_tightening=per_t,
        plot_data=plot,
    )


def _partial_residual(eng: _Engine, s: _Samples, term: _Term, fit: _Fit, idx: list[int], pcols_before: list[F64], resid_before: F64) -> tuple[F64, F64, F64]:
    """Binned partial-residual plot of an added effect: its fitted contribution (each tightening's
    declared part projected out) against the residual before it was added."""
    if term.per_tightening:
        contrib = np.zeros(len(s.y))
        for col, i in zip(term.columns, idx):
            contrib += col * fit.pcoef[s.gid, i]
    else:
        contrib = np.zeros(len(s.y))
        for col, i in zip(term.columns, idx):
            contrib += col * fit.beta[i]
    _, fitted = eng.g.fit(pcols_before, [contrib])
    x = contrib - fitted[:, 0]
    edges = np.unique(np.percentile(x, np.linspace(0, 100, 41)))
    if len(edges) < 3:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    k = np.clip(np.digitize(x, edges) - 1, 0, len(edges) - 2)
    cnt = np.bincount(k, minlength=len(edges) - 1).astype(np.float64)
    mx = np.bincount(k, weights=x, minlength=len(edges) - 1) / np.maximum(cnt, 1)
    my = np.bincount(k, weights=resid_before, minlength=len(edges) - 1) / np.maximum(cnt, 1)
    ok = cnt > 0
    return mx[ok], my[ok], cnt[ok]


def _hints(model: dict[str, _Term], fit: _Fit, idx: dict[str, list[int]]) -> dict[str, float]:
    """Current estimates that shape the regressors of nonlinear terms (Gauss-Newton refresh)."""
    out: dict[str, float] = {}
    if "channel_delay" in model and "channel_delay" in idx and len(fit.beta) > idx["channel_delay"][0]:
        tau = float(fit.beta[idx["channel_delay"][0]])
        if 0 < tau < 1.0:
            out["tau_s"] = tau
    return out


def _grouped_median(v: F64, gid: I64, n: int) -> F64:
    order = np.lexsort((v, gid))
    vs, gs = v[order], gid[order]
    ok = np.isfinite(vs)
    vs, gs = vs[ok], gs[ok]
    counts = np.bincount(gs, minlength=n)
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    out = np.full(n, np.nan)
    has = counts > 0
    lo = starts + (counts - 1) // 2
    hi = starts + counts // 2
    out[has] = 0.5 * (vs[lo[has]] + vs[hi[has]])
    return out


def _quantiles(v: F64) -> dict[str, float]:
    v = v[np.isfinite(v)]
    if not len(v):
        return {}
    q = np.percentile(v, [5, 25, 50, 75, 95])
    return {"p05": float(q[0]), "p25": float(q[1]), "median": float(q[2]), "p75": float(q[3]), "p95": float(q[4]), "mean": float(np.mean(v))}


def _model_string(s: _Samples, effects: list[Effect]) -> str:
    x = "F" if s.has_clamp else "theta"
    base = f"elastic: T = a_j + b_j {x}; rundown: T = c_j"
    if effects:
        base += "; + " + " + ".join(e.name for e in effects)
    return base


def _partial_corr(eng: _Engine, fit: _Fit, term: _Term, pkey: str, pcols: Sequence[F64]) -> float:
    """Correlation of the current in-sample residual with the term's first regressor, both with
    each tightening's declared (nuisance) part projected out."""
    zr, _ = eng._proj(pkey + "|corr", pcols, term.name, term.columns[0])
    r = fit.resid
    den = float(np.sqrt(np.sum(zr * zr) * np.sum(r * r)))
    return float(np.sum(zr * r) / den) if den > 0 else 0.0


# ---------------------------------------------------------------------------------------------
# Candidates


def _fitted_declared(s: _Samples, fit: _Fit, declared: list[F64]) -> F64:
    th = np.zeros(len(s.y))
    for k, col in enumerate(declared):
        th += col * fit.pcoef[s.gid, k]
    return th


@dataclass
class _Long:
    """Per tightening fit of the long rundown stretch: level + quadratic drift + modulation."""

    gid: I64
    theta: F64
    resid: F64  # after the quadratic drift (for the periodogram)
    level: F64  # per tightening mean torque of the stretch
    span: F64  # per tightening angle span of the stretch
    count: F64


def _long_stretch(s: _Samples) -> _Long | None:
    if len(s.long_gid) == 0:
        return None
    n = s.n_tight
    cnt = np.bincount(s.long_gid, minlength=n).astype(np.float64)
    lo = np.full(n, np.inf)
    hi = np.full(n, -np.inf)
    np.minimum.at(lo, s.long_gid, s.long_theta)
    np.maximum.at(hi, s.long_gid, s.long_theta)
    span = np.where(cnt > 0, hi - lo, 0.0)
    level = np.bincount(s.long_gid, weights=s.long_y, minlength=n) / np.maximum(cnt, 1)
    resid = s.long_y - _poly_fit(s.long_gid, s.long_theta, s.long_y, n, [])[0]
    return _Long(s.long_gid, s.long_theta, resid, level, span, cnt)


def _poly_fit(gid: I64, theta: F64, y: F64, n: int, extra: list[F64]) -> tuple[F64, F64, F64]:
    """Per tightening least squares of y on (1, u, u^2, *extra), u the scaled angle.

    Returns (fitted, coefficients (n, 3 + len(extra)), coefficient variances (n, ...))."""
    present = np.unique(gid)
    remap = -np.ones(n, dtype=np.int64)
    remap[present] = np.arange(len(present))
    g = _Groups(remap[gid], len(present))
    um = g.mean(theta)[g.gid]
    us = np.sqrt(np.maximum(g.mean((theta - um) ** 2), 1e-12))[g.gid]
    u = (theta - um) / us
    cols = [np.ones_like(theta), u, u * u] + list(extra)
    coef, fitted = g.fit(cols, [y])
    res = y - fitted[:, 0]
    p = len(cols)
    sig2 = g.sum(res * res) / np.maximum(g.count - p, 1.0)
    XtX = np.empty((g.n, p, p))
    for a in range(p):
        for b in range(a, p):
            XtX[:, a, b] = XtX[:, b, a] = g.sum(cols[a] * cols[b])
    XtX[:, np.arange(p), np.arange(p)] += 1e-9 * (np.trace(XtX, axis1=1, axis2=2) / p)[:, None] + 1e-300
    var = np.diagonal(np.linalg.inv(XtX), axis1=1, axis2=2) * sig2[:, None]
    full_coef = np.full((n, p), np.nan)
    full_var = np.full((n, p), np.nan)
    full_coef[present] = coef[:, :, 0]
    full_var[present] = var
    return fitted[:, 0], full_coef, full_var


def _periodogram(lg: _Long | None, n_tight: int) -> dict[str, Any]:
    """Average periodogram of the long-stretch residual against angle (each stretch resampled
    onto a uniform angle grid, tapered, its power normalised to mean 1, then averaged)."""
    info: dict[str, Any] = {"window_deg": None, "peaks": [], "stretch": "rundown before the declared stretch, after a quadratic drift per tightening"}
    if lg is None:
        info["note"] = "no rundown before the declared stretch: periodicities over the angle cannot be examined"
        return info
    window = None
    for w in (720.0, 360.0, 180.0):
        if np.sum(lg.span >= w) >= max(20, 0.2 * n_tight):
            window = w
            break
    if window is None:
        info["note"] = "the rundown stretches are too short for a periodogram"
        return info
    n_grid = 512
    grid_step = window / n_grid
    powers = []
    order = np.argsort(lg.gid, kind="stable")
    gs, th, rr_all = lg.gid[order], lg.theta[order], lg.resid[order]
    starts = np.flatnonzero(np.r_[True, gs[1:] != gs[:-1]])
    ends = np.r_[starts[1:], len(gs)]
    taper = np.hanning(n_grid)
    for b, e in zip(starts, ends):
        if lg.span[gs[b]] < window or e - b < 64:
            continue
        t, r = th[b:e], rr_all[b:e]
        o = np.argsort(t, kind="stable")
        t, r = t[o], r[o]
        grid = t[-1] - window + grid_step * np.arange(n_grid)
        v = np.interp(grid, t, r)
        v = v - np.polyval(np.polyfit(np.arange(n_grid), v, 2), np.arange(n_grid))
        spec = np.abs(np.fft.rfft(v * taper)) ** 2
        tot = spec[1:].mean()
        if tot > 0:
            powers.append(spec / tot)
        if len(powers) >= 3000:
            break
    if len(powers) < 20:
        info["note"] = "too few long rundown stretches for a periodogram"
        return info
    P = np.mean(powers, axis=0)
    kk = np.arange(len(P))
    periods = window / np.maximum(kk, 1)
    # periods shorter than a few sample spacings are interpolation and aliasing, not data
    d_theta = np.diff(lg.theta)
    d_theta = d_theta[(np.diff(lg.gid) == 0) & (d_theta > 0)]
    spacing = float(np.median(d_theta)) if len(d_theta) else 0.0
    min_period = max(4.0 * spacing, 4.0 * grid_step)
    info["sample_spacing_deg"] = spacing
    info["shortest_period_deg"] = min_period
    info["window_deg"] = window
    info["segments"] = len(powers)
    keep_curve = periods[1:] >= min_period
    info["_curve"] = (periods[1:][keep_curve], P[1:][keep_curve])
    peaks = []
    se = 1.0 / math.sqrt(len(powers))
    # from the third bin on: the first two carry the drift left by the detrending and taper
    for i in range(3, len(P) - 1):
        lo, hi = max(1, i - 8), min(len(P), i + 9)
        neigh = float(np.median(np.r_[P[lo:i - 1], P[i + 2:hi]]))
        if periods[i] < min_period:
            break
        if P[i] >= P[i - 1] and P[i] >= P[i + 1] and P[i] > neigh * (1 + 10 * se) and P[i] > 1.5 * neigh:
            peaks.append({"period_deg": float(periods[i]), "power_ratio": float(P[i] / neigh)})
    peaks.sort(key=lambda p: -p["power_ratio"])
    info["peaks"] = peaks[:5]
    return info


class _Grid:
    """Samples of one segment laid out as (row = tightening, column = sample), rows sorted by
    length (longest first) so that the rows still running at a column are a prefix."""

    def __init__(self, s: _Samples, segment: int) -> None:
        idx = np.flatnonzero(s.seg == segment)
        g = s.gid[idx]
        starts = np.flatnonzero(np.r_[True, g[1:] != g[:-1]]) if len(idx) else np.zeros(0, dtype=np.int64)
        lens = np.diff(np.r_[starts, len(idx)])
        order = np.argsort(-lens, kind="stable")
        row_of_run = np.empty(len(starts), dtype=np.int64)
        row_of_run[order] = np.arange(len(starts))
        self.idx = idx
        self.lens = lens[order]
        self.tg = g[starts][order]
        self.rank = np.arange(len(idx)) - np.repeat(starts, lens)
        self.row = np.repeat(row_of_run, lens)
        self.n_rows = len(starts)
        self.width = int(lens.max()) if len(lens) else 0
        # live[j]: number of rows longer than j (a prefix, rows being sorted by length)
        self.live = np.searchsorted(-self.lens, -np.arange(self.width), side="left").astype(np.int64)

    def grid(self, v: npt.NDArray[Any], fill: float = 0.0) -> npt.NDArray[Any]:
        shape = (self.n_rows, self.width) + v.shape[1:]
        out = np.full(shape, fill, dtype=np.float64)
        out[self.row, self.rank] = v[self.idx]
        return out

    def factors(self, t: F64, tau: float) -> tuple[F64, F64]:
        """Per (row, column) decay a = exp(-dt / tau) and ramp factor tau (1 - a) / dt, with dt
        from the previous column (a = 1, factor 0 where dt <= 0: the state holds)."""
        TT = self.grid(t)
        dt = np.zeros_like(TT)
        dt[:, 1:] = TT[:, 1:] - TT[:, :-1]
        return _decay(dt, tau)


def _decay(dt: F64, tau: float) -> tuple[F64, F64]:
    ok = dt > 0
    a = np.where(ok, np.exp(-np.where(ok, dt, 1.0) / tau), 1.0)
    f = np.where(ok, tau * (1 - a) / np.where(ok, dt, 1.0), 0.0)
    return a, f


def _lowpass_parts(s: _Samples, X: F64, x_pre: F64, tau: float) -> tuple[F64, F64, F64, F64]:
    """A first-order low-pass of the input path ``X`` over each elastic window, exact for inputs
    linear between samples (a transducer filter), in parts that are linear in the recorded
    state at the anchors: the sample just before the window and the end of each pause.

    Returns per sample (0 outside the elastic zone): the decay D since the last anchor, the
    anchor's input value x_r and measured torque y_r, and the lag R of ``X`` started settled at
    the anchor, so that ``LP[X] - X = D (y_r - x_r) + R`` when the state at the anchor is y_r.
    """
    n = len(X)
    D_out, xr_out, yr_out, R_out = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    if s.t is None or tau <= 0 or not np.any(s.seg == 0):
        return D_out, xr_out, yr_out, R_out
    gr = _Grid(s, 0)
    XX, TT = gr.grid(X), gr.grid(s.t)
    a, f = gr.factors(s.t, tau)
    tg = gr.tg
    RY, RT = gr.grid(s.restart_y, np.nan), gr.grid(s.restart_t, np.nan)
    has_pre = np.isfinite(s.pre_t[tg]) & np.isfinite(s.pre_y[tg])
    # the first column: from the sample before the window (an anchor), else settled
    x_prev0 = np.where(has_pre, x_pre[tg], XX[:, 0])
    a[:, 0], f[:, 0] = _decay(TT[:, 0] - np.where(has_pre, s.pre_t[tg], TT[:, 0]), tau)
    dX = np.zeros_like(XX)
    dX[:, 0] = XX[:, 0] - x_prev0
    dX[:, 1:] = XX[:, 1:] - XX[:, :-1]
    restart = np.isfinite(RY)
    rr, rc = np.nonzero(restart)
    # after a pause the state restarts from the recorded torque at its end
    a[rr, rc], f[rr, rc] = _decay(TT[rr, rc] - RT[rr, rc], tau)
    restart_cols = set(int(j) for j in np.unique(rc))
    decay = np.where(has_pre, 1.0, 0.0)
    x_r = x_prev0.copy()
    y_r = np.where(has_pre, s.pre_y[tg], 0.0)
    lag = np.zeros(gr.n_rows)
    outs = [np.zeros((gr.n_rows, gr.width)) for _ in range(4)]
    for j in range(gr.width):
        m = int(gr.live[j])
        if j in restart_cols:
            r = restart[:m, j]
            prev = XX[:m, j - 1] if j > 0 else x_prev0[:m]
            x_r[:m] = np.where(r, prev, x_r[:m])
            y_r[:m] = np.where(r, RY[:m, j], y_r[:m])
            decay[:m] = np.where(r, 1.0, decay[:m])
            lag[:m] = np.where(r, 0.0, lag[:m])
        decay[:m] *= a[:m, j]
        lag[:m] = a[:m, j] * lag[:m] - dX[:m, j] * f[:m, j]
        outs[0][:m, j] = decay[:m]
        outs[1][:m, j] = x_r[:m]
        outs[2][:m, j] = y_r[:m]
        outs[3][:m, j] = lag[:m]
    for dst, src in zip((D_out, xr_out, yr_out, R_out), outs):
        dst[gr.idx] = src[gr.row, gr.rank]
    return D_out, xr_out, yr_out, R_out


def _lowpass_filter_many(s: _Samples, cols: list[F64], tau: float) -> list[F64]:
    """``LP_tau`` of many regressors at once, per segment, each started settled (exact for
    inputs linear between samples): one pass over the samples for all columns."""
    if s.t is None or tau <= 0:
        return cols
    Z = np.column_stack(cols)
    out = Z.copy()
    for segment in (0, 1):
        if not np.any(s.seg == segment):
            continue
        gr = _Grid(s, segment)
        XX = gr.grid(Z)
        a, f = gr.factors(s.t, tau)
        dX = np.zeros_like(XX)
        dX[:, 1:] = XX[:, 1:] - XX[:, :-1]
        dev = np.zeros((gr.n_rows, Z.shape[1]))
        D = np.zeros_like(XX)
        for j in range(1, gr.width):
            m = int(gr.live[j])
            dev[:m] = a[:m, j, None] * dev[:m] - dX[:m, j] * f[:m, j, None]
            D[:m, j] = dev[:m]
        out[gr.idx] = Z[gr.idx] + D[gr.row, gr.rank]
    return [out[:, i].copy() for i in range(out.shape[1])]


def _lowpass_regressor(s: _Samples, g: _Groups, slope_x: F64, tau: float) -> F64:
    """``(LP_tau[T_hat] - T_hat) / tau`` (about -dT_hat/dt) for the declared line refitted
    exactly under a low-pass of ``tau``: with the parts of :func:`_lowpass_parts`,
    y = a + b x + D (y_r - a - b x_r) + b R is linear in (a, b) given tau."""
    el = (s.seg == 0).astype(np.float64)
    rd = 1.0 - el
    first = np.flatnonzero(np.r_[True, (s.gid[1:] != s.gid[:-1]) | (s.seg[1:] != s.seg[:-1])] & (s.seg == 0))
    x_first = np.full(s.n_tight, np.nan)
    th_first = np.full(s.n_tight, np.nan)
    x_first[s.gid[first]] = s.x[first]
    th_first[s.gid[first]] = s.theta[first]
    x_pre = np.nan_to_num(np.where(np.isfinite(s.pre_theta), x_first + slope_x * (s.pre_theta - th_first), x_first))
    D, x_r, y_r, R = _lowpass_parts(s, s.x, x_pre, tau)
    mean_x = (g.sum(s.x * el) / np.maximum(g.sum(el), 1))[s.gid]
    col_a = (1.0 - D) * el
    col_b = ((s.x - mean_x) - D * (x_r - mean_x) + R) * el
    target = s.y - D * y_r
    coef, _ = g.fit([col_a, col_b, rd], [target])
    a_t, b_t = coef[s.gid, 0, 0], coef[s.gid, 1, 0]
    dev = D * (y_r - a_t - b_t * (x_r - mean_x)) + b_t * R
    out: F64 = dev / tau
    return out


def _candidates(
    s: _Samples, eng: _Engine, fit: _Fit, declared: list[F64], tag: int, model_periods: Sequence[float], hints: dict[str, float]
) -> tuple[dict[str, _Term], dict[str, Any]]:
    """Every candidate term, its regressors built from the fit (fitted torque, slopes) and the
    channels other than the measured torque; keyed by a stable key."""
    g = eng.g
    gid = s.gid
    el = s.seg == 0
    rd = s.seg == 1
    elf, rdf = el.astype(np.float64), rd.astype(np.float64)
    th = _fitted_declared(s, fit, declared)
    # elastic slope dT/dx per tightening, and dT/dtheta per sample
    xc = (s.x - g.sum(s.x * elf)[gid] / np.maximum(g.sum(elf)[gid], 1)) * elf
    xs = np.sqrt(g.sum(xc * xc) / np.maximum(g.sum(elf), 1))
    b_t = fit.pcoef[:, 1] / np.where(xs > 0, xs, 1.0)
    if s.has_clamp:
        dth = np.r_[np.diff(s.x), 0.0]
        dang = np.r_[np.diff(s.theta), 0.0]
        ok = el & np.r_[(gid[1:] == gid[:-1]) & (s.seg[1:] == 0), False] & (np.abs(dang) > 0)
        num = g.sum(np.where(ok, dth * dang, 0.0))
        den = g.sum(np.where(ok, dang * dang, 0.0))
        k_t = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
        dT_dtheta = b_t[gid] * k_t[gid] * elf
    else:
        k_t = np.ones(s.n_tight)
        dT_dtheta = b_t[gid] * elf
    tp = np.where(g.sum(rdf) > 0, fit.pcoef[:, 2], s.prevailing)
    tp = np.where(np.isfinite(tp), tp, 0.0)
    cands: dict[str, _Term] = {}

    def glob(name: str, cols: list[F64], labels: list[str], params: Callable[[_Fit, list[int]], dict[str, Any]], info: dict[str, Any] | None = None, description: str | None = None) -> None:
        cols = [np.where(np.isfinite(c), c, 0.0) for c in cols]
        if not any(np.any(c != 0) for c in cols):
            return
        info = dict(info or {})
        cands[name] = _Term(name, description or EFFECT_NAMES[name], False, labels, cols, params, info, name, tag)

    def pv(fit2: _Fit, idx: list[int], scale: float = 1.0) -> dict[str, float]:
        return {"value": float(fit2.beta[idx[0]] * scale), "se": float(fit2.se[idx[0]] * abs(scale))}

    if s.omega is not None:
        om = np.maximum(np.abs(s.omega), 6.0)  # 1 rpm floor
        ref = float(np.median(om[el]))
        lnv = np.log(om / ref)
        # speed-dependent friction: the friction torque above the prevailing level scales
        fr = (th - tp[gid]) * elf
        spread = float(np.std(lnv[el]))

        def p_speed(f2: _Fit, idx: list[int]) -> dict[str, Any]:
            return {
                "a_eff": pv(f2, idx),
                "reference_speed_rpm": ref / 6.0,
                "law": "T - T_prevailing = (T0 - T_prevailing) (1 + a_eff ln(v / v_ref))",
                "note": "a_eff = a * (friction share of the torque per clamp force, about 0.85-0.9 for ISO metric threads): the lead term 0.16 P does not depend on speed",
            }

        if spread > 0.01:
            glob("speed_dependent_friction", [fr * lnv], ["a_eff"], p_speed, {"speed_source": s.speed_source, "ln_speed_sd_in_window": spread})
        lnr = lnv * rdf
        if float(np.std(lnv[rd])) > 0.01 if np.any(rd) else False:

            def p_sp(f2: _Fit, idx: list[int]) -> dict[str, Any]:
                return {"a_prevailing": pv(f2, idx), "reference_speed_rpm": ref / 6.0}

            glob("speed_dependent_prevailing_torque", [tp[gid] * lnr], ["a_prevailing"], p_sp)
        # channel delay: recorded T(t - tau) = T - tau dT/dt (first order); once tau is known
        # roughly, the fitted torque path through a first-order low-pass with that tau
        tau0 = hints.get("tau_s", 0.0)
        if tau0 > 1e-5 and s.t is not None:
            zd = _lowpass_regressor(s, g, k_t if s.has_clamp else np.ones(s.n_tight), tau0)
            form = f"low-pass path, refined at tau = {1000 * tau0:.3g} ms"
        else:
            zd = -dT_dtheta * s.omega
            form = "first order: -dT_hat/dt"

        def p_delay(f2: _Fit, idx: list[int]) -> dict[str, Any]:
            return {"tau_ms": pv(f2, idx, 1000.0)}

        lag = _lag_xcorr(s, fit.resid, th, el)
        glob("channel_delay", [zd], ["tau"], p_delay, {"cross_correlation_lag": lag, "regressor": form})
    if s.alpha is not None:

        def p_inertia(f2: _Fit, idx: list[int]) -> dict[str, Any]:
            return {"J_kg_m2": pv(f2, idx)}

        glob("inertia", [s.alpha], ["J"], p_inertia, {"acceleration_source": "speed channel (first difference)" if s.speed_source == "speed channel" else "angle/time (second derivative)"})
    # curvature / pressure-dependent friction: b L w^2 in the elastic zone, w = (x - x_s) / L the
    # position in the window (x_s its start, L its span in x): kappa is the relative change of
    # the slope across half the window (slope at the end / at the start = 1 + 2 kappa)
    x_lo = np.full(s.n_tight, np.inf)
    x_hi = np.full(s.n_tight, -np.inf)
    np.minimum.at(x_lo, gid[el], s.x[el])
    np.maximum.at(x_hi, gid[el], s.x[el])
    span_x = np.where(x_hi > x_lo, x_hi - x_lo, np.nan)
    w = (s.x - x_lo[gid]) / span_x[gid]
    zq = np.nan_to_num(b_t[gid] * span_x[gid] * w * w) * elf
    name_q = "pressure_dependent_friction" if s.has_clamp else "elastic_curvature"
    b_base = b_t.copy()
    x0 = np.zeros(s.n_tight) if s.has_clamp else s.phases["snug_angle"]
    x_ref = s.xf_ref  # x - x0 at the end of the tightening

    def p_curv(f2: _Fit, idx: list[int]) -> dict[str, Any]:
        kappa = float(f2.beta[idx[0]])
        b_new = f2.pcoef[:, 1] / np.where(xs > 0, xs, 1.0)
        # quadratic in x_F = x - x0: Q x_F^2 + B x_F; pressure law: B = K0 (1 - c), Q = K0 c / x_ref
        q = kappa * b_base / span_x
        bb = b_new + 2 * q * (x0 - x_lo)
        den = bb + q * x_ref
        ok = np.isfinite(q) & np.isfinite(den) & (den > 0) & (x_ref > 0) & (x0 <= x_lo)
        cprime = np.where(ok, q * x_ref / np.where(ok, den, 1.0), np.nan)
        c_med = float(np.nanmedian(cprime)) if np.any(ok) else float("nan")
        out: dict[str, Any] = {
            "kappa": pv(f2, idx),
            "slope_change_across_window": {"value": 2 * kappa, "se": 2 * float(f2.se[idx[0]]), "unit": "relative (end / start - 1)"},
            "pressure_coefficient": {
                "value": c_med,
                "se": abs(c_med) * float(f2.se[idx[0]]) / max(abs(kappa), 1e-300),
                "tightenings": int(np.sum(ok)),
            },
            "law": "T - T_p = K0 F (1 + c_eff (F / F_end - 1)), F_end the clamp force at the end of the tightening",
        }
        if not s.has_clamp:
            out["note"] = (
                "without clamp force F is taken proportional to the angle past snug: the bend may be friction "
                "changing with pressure or a joint stiffness changing with load, which the data cannot separate"
            )
        else:
            out["note"] = "c_eff = c * (friction share of the torque per clamp force, about 0.85-0.9 for ISO metric threads)"
        return out

    glob(name_q, [zq], ["kappa"], p_curv)
    # time within the tightening (additive drift, relative to the tightening's peak torque)
    if s.t is not None:

        def p_time(f2: _Fit, idx: list[int]) -> dict[str, Any]:
            return {"drift_per_s_relative": pv(f2, idx)}

        glob("time_drift", [s.scale[gid] * s.t], ["drift"], p_time)
    # program steps: per step of the tool program (those seen in the elastic window of at least
    # 5 % of the tightenings), an offset, a change of the torque rate from the step's start and
    # a short transient after it (global coefficients, relative to the tightening's scale)
    if s.step is not None and s.step_theta is not None and s.step_t is not None:
        cols = []
        labels: list[str] = []
        for seg_id, seg_mask in ((0, el), (1, rd)):
            # a step's terms are identified only against another step in the same stretch: keep
            # the steps that share a stretch with another one in enough tightenings, and measure
            # offsets against the most common of them
            steps_here = np.unique(s.step[seg_mask])
            n_steps_t = np.zeros(s.n_tight)
            for v in steps_here:
                n_steps_t += np.bincount(gid[seg_mask & (s.step == v)], minlength=s.n_tight) > 0
            mixed = n_steps_t > 1
            shared = [v for v in steps_here if np.sum(mixed & (np.bincount(gid[seg_mask & (s.step == v)], minlength=s.n_tight) > 0)) >= max(10, 0.05 * s.n_tight)]
            if len(shared) < 2:
                continue
            counts = [int(np.sum(seg_mask & (s.step == v))) for v in shared]
            reference = shared[int(np.argmax(counts))]
            where = "elastic" if seg_id == 0 else "rundown"
            for v in shared:
                ind = (seg_mask & (s.step == v)).astype(np.float64)
                if v != reference:
                    cols.append(s.scale[gid] * ind)
                    labels.append(f"{where}, step {v}: offset from step {reference}")
                if seg_id == 0:
                    cols.append(dT_dtheta * s.step_theta * ind)
                    labels.append(f"{where}, step {v}: torque-rate change")
                    for tau_ms in (5.0, 25.0):
                        cols.append(s.scale[gid] * np.exp(-s.step_t / (tau_ms / 1000.0)) * ind)
                        labels.append(f"{where}, step {v}: transient {tau_ms:g} ms")
        if cols:
            step_labels = list(labels)

            def p_step(f2: _Fit, idx: list[int]) -> dict[str, Any]:
                out: dict[str, Any] = {}
                for lab, i in zip(step_labels, idx):
                    unit = "relative to the torque rate" if "rate" in lab else "fraction of the peak torque"
                    out[lab] = {"value": float(f2.beta[i]), "se": float(f2.se[i]), "unit": unit}
                return out

            glob("program_step", cols, labels, p_step)
    # periodicities: once per revolution always, other periods from the averaged periodogram of
    # the long rundown stretch. Each tightening's modulation (amplitude and phase) is estimated on
    # that stretch and predicted into the samples of the model, which it has not seen.
    if "long" not in eng.memo:
        eng.memo["long"] = _long_stretch(s)
        eng.memo["periodogram"] = _periodogram(eng.memo["long"], s.n_tight)
    lg = eng.memo["long"]
    pinfo = dict(eng.memo["periodogram"])
    periods = [360.0] + [p["period_deg"] for p in pinfo.get("peaks", []) if abs(p["period_deg"] - 360.0) > 36.0][:2]
    for period in list(model_periods):
        if all(abs(period - q) > 1e-9 for q in periods):
            periods.append(period)
    for period in periods:
        if lg is None:
            break
        usable = (lg.span >= 0.5 * period) & (lg.count >= 30)
        if usable.sum() < max(10, 0.05 * s.n_tight):
            continue
        name = "runout" if period == 360.0 else "periodic_disturbance"
        key = name if period == 360.0 else f"{name}:{period:.6g}"
        memo_key = ("period", period)
        if memo_key not in eng.memo:
            sel = usable[lg.gid]
            ph_l = 2 * math.pi * lg.theta[sel] / period
            lev = lg.level[lg.gid[sel]]
            eng.memo[memo_key] = _poly_fit(lg.gid[sel], lg.theta[sel], s.long_y[sel], s.n_tight, [lev * np.sin(ph_l), lev * np.cos(ph_l)])
        _, coef, var = eng.memo[memo_key]
        c1 = np.nan_to_num(coef[:, 3])
        c2 = np.nan_to_num(coef[:, 4])
        v1, v2 = var[:, 3], var[:, 4]
        ph = 2 * math.pi * s.theta / period
        z = th * (c1[gid] * np.sin(ph) + c2[gid] * np.cos(ph))
        ok = usable & np.isfinite(v1 + v2) & (v1 + v2 > 0)
        amp = np.sqrt(c1**2 + c2**2)
        w = np.zeros(s.n_tight)
        w[ok] = 1.0 / (v1[ok] + v2[ok]) ** 2
        r2 = float(np.sum(w[ok] * (amp[ok] ** 2 - v1[ok] - v2[ok])) / np.sum(w[ok])) if ok.any() else float("nan")
        r2_se = float(np.sqrt(np.sum(w[ok] ** 2 * (2 * (v1[ok] + v2[ok]) ** 2 + 2 * amp[ok] ** 2 * (v1[ok] + v2[ok])))) / np.sum(w[ok])) if ok.any() else float("nan")
        r_hat = math.sqrt(max(r2, 0.0))
        snr = float(np.median(amp[ok] / np.sqrt((v1[ok] + v2[ok]) / 2))) if ok.any() else float("nan")

        def p_per(f2: _Fit, idx: list[int], period: float = period, r_hat: float = r_hat, r2_se: float = r2_se, n_ok: int = int(ok.sum()), med_amp: float = float(np.median(amp[ok])) if ok.any() else float("nan")) -> dict[str, Any]:
            return {
                "period_deg": period,
                "amplitude": {"value": r_hat, "se": r2_se / (2 * r_hat) if r_hat > 0 else float("nan")},
                "kappa": {"value": float(f2.beta[idx[0]]), "se": float(f2.se[idx[0]])},
                "amplitude_median_per_tightening": med_amp,
                "tightenings_with_a_long_rundown": n_ok,
                "law": "T (1 + r sin(2 pi theta / period + phi_j)), phase phi_j per tightening",
                "note": "r and phi_j from the rundown before the declared stretch; kappa (about 1 when the modulation "
                "found there is the one in the rest of the curve; below 1 by the noise of the per-tightening estimates) "
                "scales its prediction into the model's samples",
            }

        glob(
            name,
            [z],
            ["kappa"],
            p_per,
            {"period_deg": period, "median_amplitude_snr_in_rundown": snr},
            EFFECT_NAMES[name] if name == "runout" else f"periodic modulation of the torque with a period of {period:.1f} deg",
        )
        if key != name:
            cands[key] = cands.pop(name)
            cands[key].key = key
    tau_lp = hints.get("tau_s", 0.0)
    if tau_lp > 0:
        # the recorded torque is the transducer's low-pass of everything: so are the regressors
        todo = [t for t in cands.values() if not t.per_tightening and t.name != "channel_delay"]
        flat = [c for t in todo for c in t.columns]
        if flat:
            filtered = _lowpass_filter_many(s, flat, tau_lp)
            i = 0
            for t in todo:
                t.columns = filtered[i : i + len(t.columns)]
                i += len(t.columns)
                t.info["filtered_by_channel_low_pass_ms"] = 1000 * tau_lp
    return cands, pinfo


def _lag_xcorr(s: _Samples, resid: F64, th: F64, el: B8, max_lag: int = 12) -> dict[str, Any]:
    """Lag (samples) at which the fitted torque, shifted, best explains the residual in the
    elastic zone: the residual of a delayed channel looks like T_hat(t - L) - T_hat(t)."""
    n = len(resid)
    best = (0.0, 0)
    out = []
    for lag in range(1, max_lag + 1):
        i = np.arange(lag, n)
        ok = el[i] & el[i - lag] & (s.gid[i] == s.gid[i - lag])
        d = th[i - lag] - th[i]
        r = resid[i]
        dd, rr = d[ok], r[ok]
        den = float(np.sqrt(np.sum(dd * dd) * np.sum(rr * rr)))
        c = float(np.sum(dd * rr) / den) if den > 0 else 0.0
        out.append(c)
        if c > best[0]:
            best = (c, lag)
    dt = None
    if s.t is not None:
        dts = np.diff(s.t)[(np.diff(s.gid) == 0)]
        dt = float(np.median(dts[dts > 0])) if np.any(dts > 0) else None
    return {
        "best_lag_samples": best[1],
        "best_lag_ms": best[1] * dt * 1000 if dt else None,
        "correlation": best[0],
        "by_lag": out,
    }


# ---------------------------------------------------------------------------------------------
# Whiteness


def _whiteness(s: _Samples, r: F64, lags: int = 10) -> dict[str, Any]:
    key = s.gid * 2 + s.seg
    n = len(r)
    acf = []
    num_t = np.zeros((lags, s.n_tight))
    den_t = np.bincount(s.gid, weights=r * r, minlength=s.n_tight)
    X = np.zeros((n, lags))
    valid = np.ones(n, dtype=bool)
    for k in range(1, lags + 1):
        i = np.arange(k, n)
        same = key[i] == key[i - k]
        prod = np.where(same, r[i] * r[i - k], 0.0)
        acf.append(float(prod.sum() / max(np.sum(r * r), 1e-300)))
        num_t[k - 1] = np.bincount(s.gid[i], weights=prod, minlength=s.n_tight)
        X[k:, k - 1] = np.where(same, r[:-k], 0.0)
        valid[k:] &= same
        valid[:k] = False
    nt = np.bincount(s.gid, minlength=s.n_tight).astype(np.float64)
    rho = num_t / np.maximum(den_t, 1e-300)
    q = nt * (nt + 2) * np.sum(rho**2 / np.maximum(nt - np.arange(1, lags + 1)[:, None], 1), axis=0)
    q_tot = float(np.sum(q))
    df = lags * s.n_tight
    z_lb = (q_tot - df) / math.sqrt(2 * df)
    # pooled AR(lags) predictability of the residual from its own past (effect size)
    Xv, rv = X[valid], r[valid]
    r2 = 0.0
    if len(rv) > 10 * lags:
        coef, *_ = np.linalg.lstsq(Xv, rv, rcond=None)
        pred = Xv @ coef
        r2 = float(1 - np.sum((rv - pred) ** 2) / max(np.sum(rv * rv), 1e-300))
    # runs test on signs within segments
    sg = r > 0
    new = np.r_[True, key[1:] != key[:-1]]
    runs = np.sum(new | (sg != np.r_[~sg[0], sg[:-1]]))
    n1 = np.bincount(key, weights=sg.astype(float))
    nn = np.bincount(key).astype(float)
    n2 = nn - n1
    okk = nn > 1
    mu = np.sum(np.where(okk, 2 * n1 * n2 / np.maximum(nn, 1) + 1, 1))
    var = np.sum(np.where(okk, 2 * n1 * n2 * (2 * n1 * n2 - nn) / np.maximum(nn**2 * (nn - 1), 1), 0))
    z_runs = float((runs - mu) / math.sqrt(var)) if var > 0 else 0.0
    return {
        "lag_autocorrelation": acf,
        "ljung_box_q_sum": q_tot,
        "ljung_box_df": df,
        "ljung_box_z": z_lb,
        "ar_r2": r2,
        "runs_test_z": z_runs,
        "note": "ar_r2: fraction of the residual variance predictable from its own past 10 samples (pooled AR(10)); "
        "with thousands of tightenings any autocorrelation is 'significant', so the structure flag uses this effect size",
    }


# ---------------------------------------------------------------------------------------------
# Level 2


def _covariate_columns(table: pa.Table, rows: I64, covariates: Sequence[str] | str | None, spec: list[str], group_cols: list[str]) -> dict[str, tuple[str, npt.NDArray[Any]]]:
    """name -> (kind 'numeric'|'categorical', values per tightening)."""
    out: dict[str, tuple[str, npt.NDArray[Any]]] = {}
    idx = pa.array(rows)
    n = len(rows)
    if covariates == "auto":
        names = []
        for f in table.schema:
            if f.name in _CHANNELS or f.name in spec or f.name in group_cols or _NOT_COVARIATES.match(f.name):
                continue
            if pa.types.is_list(f.type) or pa.types.is_large_list(f.type) or pa.types.is_struct(f.type):
                continue
            names.append(f.name)
    elif covariates is None:
        names = []
    else:
        names = [covariates] if isinstance(covariates, str) else list(covariates)
        for c in names:
            if c not in table.column_names:
                raise SchemaError(f"covariates: the table has no column {c!r}", c)
    seen: list[npt.NDArray[Any]] = []
    for name in names:
        col = table.column(name).take(idx)
        t = col.type
        if pa.types.is_timestamp(t) or pa.types.is_date(t):
            v = np.asarray(pc.cast(pc.cast(col, pa.timestamp("s")) if pa.types.is_date(t) else col, pa.int64()).to_numpy(zero_copy_only=False), dtype=np.float64)
            v = v - np.nanmin(v) if np.any(np.isfinite(v)) else v
            kind = "numeric"
        elif pa.types.is_integer(t) or pa.types.is_floating(t) or pa.types.is_boolean(t):
            v = np.asarray(pc.cast(col, pa.float64()).to_numpy(zero_copy_only=False), dtype=np.float64)
            kind = "numeric"
        elif pa.types.is_string(t) or pa.types.is_large_string(t) or pa.types.is_dictionary(t):
            v = np.array([str(x) for x in col.to_pylist()], dtype=object)
            kind = "categorical"
        else:
            continue
        if kind == "numeric":
            fin = v[np.isfinite(v)]
            if len(np.unique(fin)) < 2:
                continue
            if len(np.unique(fin)) > 0.9 * n and covariates == "auto" and not re.search(r"date|time|order|seq", name):
                # an identifier-like number with all values distinct: only as an order
                pass
        else:
            levels = set(v.tolist())
            if len(levels) < 2 or len(levels) > max(2, min(50, n // 20)):
                continue
        if any(len(s_) == len(v) and np.array_equal(s_, v) for s_ in seen if s_.dtype == v.dtype):
            continue
        seen.append(v)
        out[name] = (kind, v)
    out["sequence_order"] = ("numeric", np.arange(n, dtype=np.float64))
    return out


def _effect_fit(kind: str, form: str, xtr: npt.NDArray[Any], rtr: F64, xte: npt.NDArray[Any]) -> tuple[F64, dict[str, Any]]:
    """Fit a covariate effect on training residuals; predict for test rows."""
    if form == "linear":
        ok = np.isfinite(xtr)
        if ok.sum() < 3:
            return np.zeros(len(xte)), {}
        xm = float(np.mean(xtr[ok]))
        sxx = float(np.sum((xtr[ok] - xm) ** 2))
        slope = float(np.sum((xtr[ok] - xm) * rtr[ok]) / sxx) if sxx > 0 else 0.0
        icpt = float(np.mean(rtr[ok])) - slope * xm
        pred = np.where(np.isfinite(xte), icpt + slope * np.nan_to_num(xte), 0.0)
        return pred, {"slope": slope, "intercept": icpt}
    # level means (categorical, or binned numeric)
    if kind == "numeric":
        edges = _bin_edges(xtr)
        ktr = np.digitize(np.nan_to_num(xtr, nan=np.inf), edges).astype(str)
        kte = np.digitize(np.nan_to_num(xte, nan=np.inf), edges).astype(str)
    else:
        ktr, kte = xtr.astype(str), xte.astype(str)
    means: dict[str, float] = {}
    counts: dict[str, int] = {}
    order = np.argsort(ktr, kind="stable")
    ks, rs = ktr[order], rtr[order]
    uniq, first = np.unique(ks, return_index=True)
    sums = np.add.reduceat(rs, first) if len(rs) else np.zeros(0)
    cnt = np.diff(np.r_[first, len(rs)])
    for u, s_, c in zip(uniq, sums, cnt):
        # shrink a little towards 0 so that rare levels do not win by noise
        means[str(u)] = float(s_ / (c + 2.0))
        counts[str(u)] = int(c)
    pred = np.array([means.get(str(k), 0.0) for k in kte])
    return pred, {"means": means, "counts": counts}


def _bin_edges(x: F64) -> F64:
    fin = x[np.isfinite(x)]
    u = np.unique(fin)
    if len(u) <= 30:
        return (u[:-1] + u[1:]) / 2 if len(u) > 1 else np.zeros(0)
    return np.unique(np.percentile(fin, np.linspace(0, 100, 11)[1:-1]))


def _level2(
    table: pa.Table,
    s: _Samples,
    fit: _Fit,
    fold_t: I64,
    n_folds: int,
    alpha: float,
    min_gain: float,
    covariates: Sequence[str] | str | None,
    spec_columns: Sequence[str] | str | None,
    group_cols: list[str],
    x_scale_t: F64,
) -> tuple[list[Effect], dict[str, Any], dict[str, Any]]:
    g = _Groups(s.gid, s.n_tight)
    rd = (s.seg == 1).astype(np.float64)
    el = (s.seg == 0).astype(np.float64)
    rate = fit.pcoef[:, 1] / np.where(x_scale_t > 0, x_scale_t, 1.0)
    # the fitted rundown level (declared level plus whatever the added effects put there)
    fitted = s.y - fit.resid
    prevailing = np.where(g.sum(rd) > 0, g.sum(fitted * rd) / np.maximum(g.sum(rd), 1), np.nan)
    final_angle = s.phases["peak_angle"] - s.phases["snug_angle"]
    xvar = x_scale_t**2
    params: dict[str, tuple[F64, str, str]] = {
        "torque_rate": (rate, "Nm/kN" if s.has_clamp else "Nm/deg", "torque rate b_j of the elastic line"),
        "prevailing_torque": (prevailing, "Nm", "prevailing (rundown) torque c_j"),
        "tightening_angle": (final_angle, "deg", "angle from snug to the peak torque"),
    }
    if spec_columns == "auto":
        spec = [c for c in _SPEC_DEFAULT if c in table.column_names]
    elif spec_columns is None:
        spec = []
    else:
        spec = [spec_columns] if isinstance(spec_columns, str) else list(spec_columns)
    idx = pa.array(s.rows)
    if spec:
        keys = list(zip(*[table.column(c).take(idx).to_pylist() for c in spec]))
        cell = np.array([str(k) for k in keys], dtype=object)
    else:
        cell = np.array(["all"] * s.n_tight, dtype=object)
    covs = _covariate_columns(table, s.rows, covariates, spec, group_cols)
    effects: list[Effect] = []
    details: dict[str, Any] = {"specification_columns": spec, "covariates": {k: v[0] for k, v in covs.items()}, "parameters": {}}
    plots: dict[str, Any] = {}
    forms = [(name, kind, form) for name, (kind, _) in covs.items() for form in (("linear", "levels") if kind == "numeric" else ("levels",))]
    m = max(1, len(forms) * len(params))
    for pname, (pval, unit, pdesc) in params.items():
        ok = np.isfinite(pval)
        if ok.sum() < 30:
            continue
        # robust: drop gross outliers of the parameter (5 MADs), reported
        med = float(np.median(pval[ok]))
        mad = float(np.median(np.abs(pval[ok] - med))) * 1.4826
        inl = ok & (np.abs(pval - med) <= 8 * max(mad, 1e-12))
        use = np.flatnonzero(inl)
        y = pval[use]
        folds = fold_t[use]
        added: list[tuple[str, str, str]] = []
        base_pred = _l2_predict(y, folds, n_folds, cell[use], covs, use, added)
        err_base = y - base_pred
        rmse0 = float(np.sqrt(np.mean(err_base**2)))
        prow: dict[str, Any] = {"unit": unit, "tightenings": int(len(use)), "outliers_left_out": int(ok.sum() - len(use)), "rmse_declared": rmse0, "rounds": []}
        current = err_base
        for _round in range(4):
            tried: list[dict[str, Any]] = []
            best: tuple[float, tuple[str, str, str], F64, dict[str, float]] | None = None
            for name, kind, form in forms:
                if any(a[0] == name for a in added):
                    continue
                pred = _l2_predict(y, folds, n_folds, cell[use], covs, use, added + [(name, kind, form)])
                err = y - pred
                d = current**2 - err**2
                tests = _one_sided_tests(d / max(float(np.mean(current**2)), 1e-300))
                rm = float(np.sqrt(np.mean(err**2)))
                gain = (float(np.sqrt(np.mean(current**2))) - rm) / max(float(np.sqrt(np.mean(current**2))), 1e-300)
                sig = tests["p_value"] < alpha / m and gain >= min_gain
                tried.append({"covariate": name, "form": form, "rmse": rm, "rmse_gain": gain, "p_value": tests["p_value"], "significant": sig})
                if sig and (best is None or gain > best[0]):
                    best = (gain, (name, kind, form), err, tests)
            prow["rounds"].append(sorted(tried, key=lambda r: -float(r["rmse_gain"]))[:8])
            if best is None:
                break
            gain, spec_, err, tests = best
            before = float(np.sqrt(np.mean(current**2)))
            previous = current
            added.append(spec_)
            current = err
            name, kind, form = spec_
            summary = _l2_summary(y, cell[use], covs, use, added, spec_)
            consequence: dict[str, Any] = {}
            if pname == "prevailing_torque":
                consequence = {"curve_rmse_nm_before": before, "curve_rmse_nm_after": float(np.sqrt(np.mean(err**2))), "where": "rundown torque level, if c_j were predicted from the covariates"}
            elif pname == "torque_rate":
                w = xvar[use]
                consequence = {
                    "curve_rmse_nm_before": float(np.sqrt(np.mean(previous**2 * w))),
                    "curve_rmse_nm_after": float(np.sqrt(np.mean(err**2 * w))),
                    "where": "elastic window, if b_j were predicted from the covariates",
                }
            eff_name = f"{pname}_vs_{name}"
            effects.append(
                Effect(
                    name=eff_name,
                    description=_l2_description(pname, pdesc, name, kind),
                    level="between_tightenings",
                    significant=True,
                    parameters=summary,
                    rmse_after=float(np.sqrt(np.mean(err**2))),
                    rmse_unit=unit,
                    evidence={
                        "rmse_before": before,
                        "rmse_gain": gain,
                        "p_value": tests["p_value"],
                        "sign_p_value": tests["sign_p_value"],
                        "t_statistic": tests["t_statistic"],
                        "fraction_of_tightenings_improved": tests["fraction_improved"],
                        "bonferroni_alpha": alpha / m,
                        "form": form,
                        "folds": n_folds,
                        "tightenings": int(len(use)),
                    }
                    | ({"curve_level": consequence} if consequence else {}),
                )
            )
            plots[eff_name] = (covs[name][1][use], y, kind)
        details["parameters"][pname] = prow
    return effects, details, plots


def _l2_predict(y: F64, folds: I64, n_folds: int, cell: npt.NDArray[Any], covs: dict[str, tuple[str, npt.NDArray[Any]]], use: I64, added: list[tuple[str, str, str]]) -> F64:
    pred = np.zeros(len(y))
    for f in range(n_folds):
        te = folds == f
        tr = ~te
        if not te.any() or not tr.any():
            continue
        # baseline: specification cell means (grand mean for unseen cells)
        base_tr, base_te = _cell_means(y[tr], cell[tr], cell[te])
        r = y[tr] - base_tr
        p_te = base_te.copy()
        for name, kind, form in added:
            x = covs[name][1][use]
            ptr, _ = _effect_fit(kind, form, x[tr], r, x[tr])
            pte, _ = _effect_fit(kind, form, x[tr], r, x[te])
            r = r - ptr
            p_te += pte
        pred[te] = p_te
    return pred


def _cell_means(y: F64, cell_tr: npt.NDArray[Any], cell_te: npt.NDArray[Any]) -> tuple[F64, F64]:
    grand = float(np.mean(y))
    means: dict[str, float] = {}
    for c in np.unique(cell_tr):
        means[str(c)] = float(np.mean(y[cell_tr == c]))
    return np.array([means[str(c)] for c in cell_tr]), np.array([means.get(str(c), grand) for c in cell_te])


def _l2_summary(y: F64, cell: npt.NDArray[Any], covs: dict[str, tuple[str, npt.NDArray[Any]]], use: I64, added: list[tuple[str, str, str]], spec_: tuple[str, str, str]) -> dict[str, Any]:
    """The effect fitted on all tightenings: slope or level means with standard errors."""
    base, _ = _cell_means(y, cell, cell)
    r = y - base
    for name, kind, form in added:
        x = covs[name][1][use]
        if (name, kind, form) == spec_:
            break
        p, _ = _effect_fit(kind, form, x, r, x)
        r = r - p
    name, kind, form = spec_
    x = covs[name][1][use]
    out: dict[str, Any] = {"covariate": name, "form": form}
    if form == "linear":
        ok = np.isfinite(x)
        xm = float(np.mean(x[ok]))
        sxx = float(np.sum((x[ok] - xm) ** 2))
        slope = float(np.sum((x[ok] - xm) * r[ok]) / sxx)
        res = r[ok] - slope * (x[ok] - xm) - float(np.mean(r[ok]))
        se = float(np.sqrt(np.sum(res**2) / max(ok.sum() - 2, 1) / sxx))
        out["slope"] = {"value": slope, "se": se, "unit": "per unit of " + name}
        lo, hi = float(np.min(x[ok])), float(np.max(x[ok]))
        out["effect_range"] = {"from": lo, "to": hi, "change": slope * (hi - lo)}
    else:
        if kind == "numeric":
            edges = _bin_edges(x)
            k = np.digitize(np.nan_to_num(x, nan=np.inf), edges)
            labels = {}
            fin = np.isfinite(x)
            for b in np.unique(k):
                sel = (k == b) & fin
                labels[int(b)] = f"{float(np.min(x[sel])):g}..{float(np.max(x[sel])):g}" if sel.any() else "missing"
            keys = np.array([labels[int(b)] for b in k], dtype=object)
            order_keys = [labels[int(b)] for b in np.unique(k)]
        else:
            keys = x.astype(str)
            order_keys = [str(u) for u in np.unique(keys)]
        levels = {}
        for lab in order_keys:
            sel = keys == lab
            vals = y[sel]
            levels[lab] = {"mean": float(np.mean(vals)), "se": float(np.std(vals, ddof=1) / math.sqrt(len(vals))) if len(vals) > 1 else None, "n": int(len(vals))}
        out["levels"] = levels
        means = [float(v["mean"]) for v in levels.values() if v["mean"] is not None]
        out["effect_range"] = {"change": float(max(means) - min(means)), "first": means[0], "last": means[-1]}
    return out


def _l2_description(pname: str, pdesc: str, cov: str, kind: str) -> str:
    low = cov.lower()
    if re.search(r"usage|reuse|re_use|count|cycles|use_", low):
        what = "wear with re-use"
    elif re.search(r"order|date|time|seq", low):
        what = "drift over the sequence of tightenings (tool or material drift, temperature)"
    elif kind == "categorical":
        what = f"difference between groups ({cov})"
    else:
        what = f"dependence on {cov}"
    return f"{what}: {pdesc} changes with {cov}"


# ---------------------------------------------------------------------------------------------
# Report


def write_report(diagnosis: Diagnosis, directory: PathLike, prefix: str = "diagnose") -> list[Path]:
    """Figures of a diagnosis: residual before, the evidence, residual after (PNG).

    Needs matplotlib (``pip install 'tightscan[report]'``); the diagnosis itself does not."""
    try:
        import matplotlib
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("the --report figures need matplotlib: pip install 'tightscan[report]'") from e

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    p = diagnosis.plot_data
    paths: list[Path] = []
    for which, key in (("before", "e_before"), ("after", "e_after")):
        fig = _residual_figure(plt, p, key, which, diagnosis)
        path = out / f"{prefix}-residual-{which}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    fig = _evidence_figure(plt, p, diagnosis)
    path = out / f"{prefix}-evidence.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    paths.append(path)
    return paths


def _residual_figure(plt: Any, p: dict[str, Any], key: str, which: str, d: Diagnosis) -> Any:
    e = p[key]
    seg, pos, gid = p["seg"], p["pos"], p["gid"]
    sig = p["sigma_t"][gid]
    z = e / np.where(sig > 0, sig, 1.0)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for ax, sv, title, rng in ((axes[0], 1, "rundown stretch", (-1, 0)), (axes[1], 0, "elastic window", (0, 1))):
        m = seg == sv
        if not m.any():
            ax.set_visible(False)
            continue
        bins = np.linspace(rng[0], rng[1], 41)
        k = np.clip(np.digitize(pos[m], bins) - 1, 0, 39)
        cnt = np.bincount(k, minlength=40)
        mean = np.bincount(k, weights=z[m], minlength=40) / np.maximum(cnt, 1)
        sq = np.bincount(k, weights=z[m] ** 2, minlength=40) / np.maximum(cnt, 1)
        q = np.sqrt(np.maximum(sq - mean**2, 0))
        mid = (bins[1:] + bins[:-1]) / 2
        ax.fill_between(mid, mean - q, mean + q, alpha=0.25, label="mean +- sd across tightenings")
        ax.plot(mid, mean, lw=2, label="mean residual")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_title(f"{title}: residual / noise sd ({which})")
        ax.set_xlabel("position in the stretch (0 = start of the elastic window)" if sv == 0 else "position before the gap to snug")
        ax.legend(fontsize=8)
    ax = axes[2]
    rb, ra = p["rb"], p["ra"]
    hi = float(np.percentile(np.r_[rb, ra], 99))
    bins = np.linspace(0, hi, 60)
    ax.hist(rb, bins=bins, alpha=0.5, label=f"before (median {np.median(rb):.3g} Nm)")
    if which == "after":
        ax.hist(ra, bins=bins, alpha=0.5, label=f"after (median {np.median(ra):.3g} Nm)")
    ax.set_title("per-tightening out-of-sample RMSE [Nm]")
    ax.legend(fontsize=8)
    fig.suptitle(f"residual {which}: RMSE {d.rmse_before if which == 'before' else d.rmse_after:.4g} Nm (out of sample)")
    fig.tight_layout()
    return fig


def _evidence_figure(plt: Any, p: dict[str, Any], d: Diagnosis) -> Any:
    l1 = [e for e in d.effects if e.level == "within_tightening"]
    l2 = [e for e in d.effects if e.level == "between_tightenings"]
    panels: list[tuple[str, Any]] = [("rmse", None)]
    panels += [("partial", e) for e in l1[:4]]
    if p.get("periodogram") is not None:
        panels.append(("periodogram", None))
    panels += [("level2", e) for e in l2[:3]]
    cols = min(4, len(panels))
    rows = (len(panels) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 3.9 * rows), squeeze=False)
    for ax in axes.flat[len(panels):]:
        ax.set_visible(False)
    for ax, (kind, e) in zip(axes.flat, panels):
        if kind == "rmse":
            names = ["declared"] + [x.name for x in l1]
            vals = [d.rmse_before] + [x.rmse_after for x in l1]
            ax.bar(range(len(vals)), vals, color=["gray"] + ["C0"] * len(l1))
            ax.set_xticks(range(len(vals)))
            ax.set_xticklabels(names, rotation=30, ha="right", fontsize=7)
            ax.set_ylabel("out-of-sample RMSE [Nm]")
            ax.set_title("level 1: RMSE as effects are added", fontsize=9)
            nf = d.details.get("noise_floor_estimate")
            if nf:
                ax.axhline(nf, color="k", ls="--", lw=1, label="noise estimate")
                ax.legend(fontsize=7)
        elif kind == "partial":
            mx, my, _ = p["partial"].get(e.name, (np.zeros(0), np.zeros(0), None))
            ax.plot(mx, my, "o", ms=3, label="residual before it, binned")
            if len(mx):
                lim = [float(min(mx.min(), my.min())), float(max(mx.max(), my.max()))]
                ax.plot(lim, lim, "k--", lw=1, label="what the effect predicts")
            ax.set_xlabel("effect's contribution [Nm] (tightening's own line removed)", fontsize=7)
            ax.set_ylabel("residual [Nm]")
            ax.set_title(f"{e.name} (gain {100 * e.evidence['rmse_gain']:.1f} %)", fontsize=9)
            ax.legend(fontsize=7)
        elif kind == "periodogram":
            per, P = p["periodogram"]
            ax.loglog(per, P)
            ticks = [t for t in (5, 10, 20, 45, 90, 180, 360, 720) if per.min() <= t <= per.max()]
            ax.set_xticks(ticks)
            ax.set_xticklabels([str(t) for t in ticks])
            ax.minorticks_off()
            ax.set_xlabel("period [deg]")
            ax.set_ylabel("mean normalised power")
            ax.set_title("periodogram, rundown before the declared stretch", fontsize=9)
        else:
            x, y, ckind = p["level2"][e.name]
            if ckind == "numeric":
                ax.plot(x, y, ".", ms=2, alpha=0.25)
                u = np.unique(x[np.isfinite(x)])
                if len(u) <= 30:
                    med = [np.median(y[x == v]) for v in u]
                    ax.plot(u, med, "r-o", ms=3, lw=2, label="median per value")
                    ax.legend(fontsize=7)
                elif "slope" in e.parameters:
                    xs = np.linspace(np.nanmin(x), np.nanmax(x), 50)
                    ax.plot(xs, np.nanmean(y) + e.parameters["slope"]["value"] * (xs - np.nanmean(x)), "r", lw=2)
            else:
                labs = sorted(set(x.tolist()))
                ax.boxplot([y[x == lab] for lab in labs], showfliers=False)
                ax.set_xticks(range(1, len(labs) + 1))
                ax.set_xticklabels(labs, rotation=30, fontsize=7)
            lo, hi = np.nanpercentile(y, [1, 99])
            ax.set_ylim(lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo))
            ax.set_title(e.name, fontsize=9)
            ax.set_xlabel(e.parameters.get("covariate", ""))
            ax.set_ylabel(e.rmse_unit)
    fig.tight_layout()
    return fig


class _CallableModule(types.ModuleType):
    """``tightscan.diagnose`` is both this module and the function exported under its name; an
    import of the submodule (e.g. pytest collecting its doctests) rebinds the package attribute
    to the module, so the module forwards calls to the function."""

    def __call__(self, *args: Any, **kwargs: Any) -> Diagnosis:
        return diagnose(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule
