"""Step 6, report: figures of a diagnosis (residual before and after, evidence) written to a
directory."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .result import Diagnosis
from .prepare import PathLike


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
