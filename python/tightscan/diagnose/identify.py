"""Identification (issue 12, item 1): which of several candidates that fit the same residual the
data actually point to.

Greedy forward selection names the regressor that fits first. Where candidates are collinear in
the data at hand -- under a hold-down (HDT) program the speed falls while the clamp force and the
torque rate rise, so speed friction, pressure friction and a channel lag all bend the elastic
window the same way -- the first to fit need not be the cause. Two tools:

- **Collinearity of the candidate set** after each tightening's own (nuisance) columns are
  projected out, as the fit sees them: the correlation matrix of the projected regressors, its
  condition number and the variance inflation factors ``VIF_i = [R^-1]_ii`` (the factor by which
  collinearity inflates the variance of a coefficient; Belsley, Kuh & Welsch 1980).
- **Encompassing by out-of-sample comparison** of the joint model with each term left out (a
  non-nested comparison in the spirit of Mizon & Richard's encompassing principle): a term
  encompasses a competitor when it keeps a significant gain with the competitor in the model and
  the competitor loses its gain with the term in. Both keeping their gains: two real effects.
  Neither: the data cannot tell them apart -- a tie, reported with the evidence.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Sequence

import numpy as np

from .fit import _Engine, _Fit, _one_sided_tests, _Term
from .prepare import F64


def _projected_columns(eng: _Engine, pkey: str, pcols: Sequence[F64], terms: Sequence[_Term]) -> tuple[list[str], list[int], F64]:
    """Each term's regressors with every tightening's declared (and per-tightening model) columns
    projected out, weighted as the engine weighs the samples: (term key per column, index of
    the term per column, matrix n x k)."""
    keys: list[str] = []
    owner: list[int] = []
    cols: list[F64] = []
    sw = np.sqrt(eng.weights_t[eng.s.gid])
    for i, t in enumerate(terms):
        for j, c in enumerate(t.columns):
            r, _ = eng._proj(pkey + "|ident", pcols, f"{t.key}:{j}@{t.tag}", c)
            keys.append(t.key)
            owner.append(i)
            cols.append(r * sw)
    return keys, owner, np.column_stack(cols) if cols else np.zeros((len(eng.s.y), 0))


def _collinearity(eng: _Engine, pkey: str, pcols: Sequence[F64], terms: Sequence[_Term]) -> dict[str, Any]:
    """Correlation matrix, condition number and VIFs of the candidates' projected regressors.

    Term-level figures: a term with several columns gets the largest VIF of its columns and, with
    another term, the largest absolute correlation between their columns."""
    _, owner, Z = _projected_columns(eng, pkey, pcols, terms)
    k = Z.shape[1]
    if k == 0:
        return {"terms": [], "condition_number": float("nan"), "vif": {}, "correlation": {}}
    norm = np.sqrt(np.sum(Z * Z, axis=0))
    live = norm > 0
    Zs = Z[:, live] / norm[live]
    R = Zs.T @ Zs
    eig = np.linalg.eigvalsh(R)
    # condition number of the column-scaled design: sqrt of the eigenvalue ratio of R
    cond = float(math.sqrt(eig[-1] / eig[0])) if eig[0] > 1e-300 else float("inf")
    try:
        vif_cols = np.diag(np.linalg.inv(R))
    except np.linalg.LinAlgError:
        vif_cols = np.full(R.shape[0], np.inf)
    own = np.asarray(owner)[live]
    names = [t.key for t in terms]
    vif: dict[str, float] = {}
    for i, name in enumerate(names):
        sel = own == i
        if sel.any():
            vif[name] = float(np.max(vif_cols[sel]))
    corr: dict[str, dict[str, float]] = {}
    for i, a in enumerate(names):
        corr[a] = {}
        for j, b in enumerate(names):
            if i == j:
                continue
            block = R[np.ix_(own == i, own == j)]
            # signed correlation of single-column terms; the largest |r| of multi-column ones
            corr[a][b] = float(block[np.unravel_index(np.argmax(np.abs(block)), block.shape)]) if block.size else float("nan")
    return {"terms": names, "condition_number": cond, "vif": vif, "correlation": corr}


def _gain_test(before: _Fit, after: _Fit, alpha_m: float, min_gain: float) -> dict[str, Any]:
    """The loop's own criterion for a term's gain (out of sample, per-tightening improvements,
    one-sided t test at the round's Bonferroni level, and practical relevance)."""
    u = np.clip((before.mse_t - after.mse_t) / np.maximum(before.mse_t, 1e-300), -1.0, 1.0)
    tests = _one_sided_tests(u)
    gain = (before.rmse - after.rmse) / before.rmse
    median_gain = float(np.median(1.0 - np.sqrt(after.mse_t / np.maximum(before.mse_t, 1e-300))))
    significant = bool(tests["p_value"] < alpha_m and max(gain, median_gain) >= min_gain)
    return {"rmse_gain": gain, "median_tightening_rmse_gain": median_gain, "p_value": tests["p_value"], "t_statistic": tests["t_statistic"], "significant": significant}


def _identify(
    best: _Term,
    competitors: Sequence[_Term],
    alone: dict[str, _Fit],
    joint_fit: Callable[[_Term, _Term], _Fit],
    alpha_m: float,
    min_gain: float,
    correlation: dict[str, dict[str, float]],
    vif: dict[str, float],
) -> tuple[_Term, list[_Term], list[dict[str, Any]]]:
    """Encompassing test of the selected term against each close competitor.

    Returns the term to put in the model (the one that encompasses the others it was compared
    with, or the best-fitting member of a tie), the competitors tied with it, and the evidence
    of every comparison. When a competitor encompasses the selected term, it takes its place and
    is tested in turn against the remaining competitors (a term already beaten cannot come back:
    a cycle ends in a tie)."""
    pool = {t.key: t for t in [best, *competitors]}
    current = best
    beaten: set[str] = set()
    evidence: list[dict[str, Any]] = []
    ties: list[_Term] = []
    for _ in range(len(pool)):
        switched = False
        ties = []
        for c in pool.values():
            if c.key == current.key or c.key in beaten or c.name == current.name:
                continue  # another form of the same effect is no competitor
            joint = joint_fit(current, c)
            keep_term = _gain_test(alone[c.key], joint, alpha_m, min_gain)
            keep_comp = _gain_test(alone[current.key], joint, alpha_m, min_gain)
            if keep_term["significant"] and not keep_comp["significant"]:
                verdict = "encompasses"
            elif keep_term["significant"] and keep_comp["significant"]:
                verdict = "both"
            elif keep_comp["significant"]:
                verdict = "encompassed_by"
            else:
                verdict = "tie"
            evidence.append(
                {
                    "term": current.name,
                    "competitor": c.name,
                    "competitor_form": c.key,
                    "correlation": correlation.get(current.key, {}).get(c.key),
                    "vif_term": vif.get(current.key),
                    "vif_competitor": vif.get(c.key),
                    "term_gain_with_competitor_in": keep_term,
                    "competitor_gain_with_term_in": keep_comp,
                    "verdict": verdict,
                }
            )
            if verdict == "encompassed_by":
                beaten.add(current.key)
                current = c
                switched = True
                break
            if verdict == "tie":
                ties.append(c)
        if not switched:
            break
    else:
        # every switch led on to another: the set cannot be ordered, all of them tie
        ties = [t for t in pool.values() if t.name != current.name]
    # one entry per effect (the best-fitting form first: the pool is in order of gain)
    named: dict[str, _Term] = {}
    for t in ties:
        named.setdefault(t.name, t)
    return current, list(named.values()), evidence
