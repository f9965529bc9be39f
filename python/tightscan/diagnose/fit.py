"""Step 2, fit: the fitting engine. Per-tightening nuisance parameters are profiled out, global
coefficients are shared by all tightenings, and every comparison is out of sample (folds across
tightenings, alternate blocks within one)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import pyarrow as pa
from scipy import stats

from ..exceptions import SchemaError
from .prepare import _GROUP_DEFAULT, _Groups, _Samples, F64, I64


def _one_sided_tests(u: F64) -> dict[str, float]:
    """One-sided tests that per-tightening improvements ``u`` are > 0: Student t on the mean, and
    the exact sign test."""
    u = u[np.isfinite(u)]
    n = len(u)
    if n < 3:
        return {"t_statistic": float("nan"), "p_value": 1.0, "sign_p_value": 1.0, "fraction_improved": float("nan"), "n": n}
    sd = float(np.std(u, ddof=1))
    t = float(np.mean(u)) / (sd / math.sqrt(n)) if sd > 0 else (math.inf if np.mean(u) > 0 else 0.0)
    pos = int(np.sum(u > 0))
    nz = int(np.sum(u != 0))
    # The sd is estimated from the same n improvements, so the mean over its standard error is
    # referred to Student's t with n - 1 degrees of freedom (exact for normal improvements), not to
    # the normal: it matters at level 2 (from 30 tightenings on) and in the far tail that the
    # reported p-values reach with thousands of tightenings.
    p_t = float(stats.t.sf(t, n - 1))
    # Under no effect each nonzero improvement is positive with probability 1/2: the count of
    # positives is binomial, its tail exact at any n. Ties (exactly 0) carry no sign.
    p_sign = float(stats.binomtest(pos, nz, 0.5, alternative="greater").pvalue) if nz else 1.0
    return {
        "t_statistic": t,
        "p_value": p_t,
        "sign_p_value": p_sign,
        "fraction_improved": pos / n,
        "n": n,
    }


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
    #: sandwich covariance of the global coefficients (for parameters derived from several)
    cov: F64 | None = None


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
            cov: F64 = Ainv @ meat @ Ainv
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
            cov = np.zeros((0, 0))
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
            cov=cov,
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
    #: regressors that extend the effect's own law by one degree of freedom (a second time
    #: constant, the other speed law, a cubic bend): structure left after the effect is in that
    #: such an extension takes up is a misfit of its form, not a further effect
    extension: list[F64] = field(default_factory=list)
    #: a Stribeck law's static column and its derivative by ln v_s, each sample at a Stribeck
    #: speed of its own [rpm] (the exponent held): what the per-tightening refinement fits each
    #: tightening's own Stribeck speed with
    static_at: Callable[[F64], tuple[F64, F64]] | None = None


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
