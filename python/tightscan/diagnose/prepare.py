"""Step 1, prepare: read tables or files, nest them, and turn every tightening into the samples
the fits use (elastic window, rundown stretch, time, speed and other channels, per-tightening
indices)."""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence, Union

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.compute as pc

from ..exceptions import DataFileError, InvalidParameterError, SchemaError

PathLike = Union[str, "os.PathLike[str]"]
F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
B8 = npt.NDArray[np.bool_]

# Columns that are channels, identifiers or outcomes of the tightening itself: never covariates.
_CHANNELS = ("angle", "torque", "time", "speed", "clamp_force", "gradient", "step", "torque_red", "angle_red")
_NOT_COVARIATES = re.compile(
    r"^(tightening_id|file_name|label_file_name|import_status|status|result|cycle|n_steps|n_samples"
    r"|step_.*|.*_result|.*_status|has_change|fault_.*|magnitude|onset_.*|effects|runout_phase)$"
)
_SPEC_DEFAULT = ("thread", "target_torque", "nominal_torque", "program", "pitch_mm", "d2_mm", "dkm_mm", "joint_stiffness")
_GROUP_DEFAULT = (("workpiece_id", "workpiece_location"), ("part_id",), ("id_code",), ("serial_number",))


# ---------------------------------------------------------------------------------------------
# Input


def _read_path(path: Path, progress: bool | None = False) -> pa.Table:
    from ..rexroth import read_rexroth

    if path.is_dir():
        labels = path / "labels.csv"
        # As `import rexroth` searches: below the directory, `.json` in any case.
        runs = path / "runs"
        for folder in (runs, path):
            if folder.is_dir() and any(p.suffix.lower() == ".json" and p.is_file() for p in folder.rglob("*")):
                return read_rexroth(folder, labels=labels if labels.is_file() else None, progress=progress)
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


def load_table(data: Any, progress: bool | None = False) -> pa.Table:
    """The tightening table behind ``data`` (as :func:`diagnose` reads it): a table, or a path
    to a Rexroth export directory, a Parquet file or a directory of them. ``progress`` shows the
    import of a Rexroth directory (``None``: on an interactive terminal)."""
    return _as_table(data, progress)


def _as_table(data: Any, progress: bool | None = False) -> pa.Table:
    if isinstance(data, (str, os.PathLike)):
        table = _read_path(Path(data), progress)
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
    long_t: F64 | None  # time within the tightening [s] of the long stretch (None without a time channel)
    target: F64  # per tightening: target torque [Nm] from the table (NaN where it has none)
    # the speed channel as recorded [deg/s] and its backward difference [rad/s^2] (None without
    # a speed channel): a second estimate of speed and acceleration, to check that a speed law
    # or an inertia does not depend on how they are estimated
    omega_raw: F64 | None = None
    alpha_raw: F64 | None = None
    # the speed channel as recorded at the samples just before and just after each sample of the
    # tightening [deg/s] (its own value at the first and last sample; a stop's samples, left out
    # of the model, included): the speed between samples by linear interpolation, for a friction
    # whose speed is not the one sampled with the torque (``speed_at_timing``)
    omega_raw_prev: F64 | None = None
    omega_raw_next: F64 | None = None


def speed_at_timing(s: Any, shift: float) -> F64 | None:
    """The speed channel as recorded, ``shift`` samples earlier (> 0) or later (< 0), within one
    sample, by linear interpolation between neighbouring recorded samples [deg/s]; None without a
    speed channel.

    Why: the speed a friction law sees at a torque sample need not be the speed sampled with it.
    The torque of a sample is the friction of the sliding that led to it (a transducer's
    anti-aliasing or a converter's integration window, a simulation's last time step), and the
    speed channel and the torque channel are not sampled at exactly the same instant. Where the
    speed is steady the difference is nothing; at a braking corner the tool loses a third of its
    speed from one sample to the next, and a Stribeck law, steepest at low speed, turns a sixth of
    a sample into two noise sds of torque there (CSDT, 2 kHz)."""
    if s.omega_raw is None or s.omega_raw_prev is None or s.omega_raw_next is None:
        return None
    w = np.asarray(s.omega_raw, dtype=np.float64)
    if shift >= 0:
        out: F64 = w - min(shift, 1.0) * (w - s.omega_raw_prev)
    else:
        out = w + min(-shift, 1.0) * (s.omega_raw_next - w)
    return out


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


def _prepare(table: pa.Table, rundown_deg: float | None, min_samples: int, long_deg: float | None) -> _Samples:
    from .._api import detect_batch

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
    omega_raw: F64 | None = None
    omega_raw_prev: F64 | None = None
    omega_raw_next: F64 | None = None
    alpha_raw: F64 | None = None
    speed_source = "none"
    if speed is not None:
        omega, alpha = _speed_channel(speed, clock, pos, start, end)
        speed_source = "speed channel"
        omega_raw = 6.0 * speed
        omega_raw_prev = np.where(pos > 0, np.r_[omega_raw[:1], omega_raw[:-1]], omega_raw)
        omega_raw_next = np.where(np.arange(len(pos)) < end, np.r_[omega_raw[1:], omega_raw[-1:]], omega_raw)
        if tt is not None:
            dts = np.r_[0.0, np.diff(tt)]
            good_dt = (pos > 0) & (dts > 0)
            alpha_raw = np.where(good_dt, np.r_[0.0, np.diff(speed)] / np.where(good_dt, dts, 1.0), 0.0) * (2 * math.pi / 60.0)
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
    # ... and before the torque leaves the prevailing level on its way to the window: a lagging
    # channel or a soft seating moves the tangent-method snug late. Left means above the level by
    # 1 % of the rise or five noise sds of the samples before the window, whichever is more
    # (5 % of the rise, as before, let the foot of a lagged rise into the stretch: 0.4 Nm on a
    # rundown noise of 0.015 Nm, so that the stretch's RMSE was 12 times its noise under a
    # 5 ms low-pass)
    first_el_pos = np.minimum.reduceat(np.where(elastic, pos, np.iinfo(np.int64).max), groups.starts)
    rise = peak_val - prevailing[rows]
    dy = np.abs(np.r_[0.0, np.diff(y)])
    pre_win = (pos > 0) & (pos < first_el_pos[gid])
    sd_pre = _grouped_median_abs(dy, pre_win, gid, n_t) * 1.4826 / math.sqrt(2.0)
    leave = np.maximum(0.01 * rise, np.where(np.isfinite(sd_pre), 5.0 * sd_pre, 0.05 * rise))
    low = (pos < first_el_pos[gid]) & (y <= (prevailing[rows] + leave)[gid])
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
    # (``long_deg`` None: all of the rundown before it, the whole run-down many revolutions long)
    long_lo = r_start - (np.inf if long_deg is None else long_deg)
    long_mask = (a >= long_lo[gid]) & (a < r_start[gid]) & before_peak & ~stop & keep_t[gid]

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
    target = np.full(n_rows, np.nan)
    if "target_torque" in table.column_names and (pa.types.is_floating(table.schema.field("target_torque").type) or pa.types.is_integer(table.schema.field("target_torque").type)):
        target = np.array([np.nan if v is None else float(v) for v in table.column("target_torque").to_pylist()], dtype=np.float64)
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
        long_t=None if tt is None else tt[long_mask],
        target=target[rows_final],
        omega_raw=sub(omega_raw),
        alpha_raw=sub(alpha_raw),
        omega_raw_prev=sub(omega_raw_prev),
        omega_raw_next=sub(omega_raw_next),
    )


def _grouped_median_abs(v: F64, mask: B8, gid: I64, n: int) -> F64:
    """Per group: the median of ``v`` over the masked samples (NaN where none)."""
    out = np.full(n, np.nan)
    idx = np.flatnonzero(mask)
    if not len(idx):
        return out
    order = idx[np.argsort(gid[idx], kind="stable")]
    g = gid[order]
    starts = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
    ends = np.r_[starts[1:], len(g)]
    vals = v[order]
    for a, b in zip(starts, ends):
        out[g[a]] = float(np.median(vals[a:b]))
    return out


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
