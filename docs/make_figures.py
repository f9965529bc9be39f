"""Figures of the README and docs/physics.md: a tightening of the demo dataset drawn by
``tightscan.plot``, and simulated curves of each strategy next to real ones.

Run from the repository root: ``.venv/bin/python docs/make_figures.py [NAME ...]`` (needs
matplotlib; ``simulated_vs_real`` needs the measured data in ``../shared/data``). NAME picks
figures (default: all). Every figure is made from the engine's own output.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pyarrow as pa  # noqa: E402

import tightscan  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TIGHTSCAN_SHARED_DATA", ROOT.parent / "shared" / "data")) / "rexroth-s01"
OUT = ROOT / "docs" / "figures"


def _mark(ax: plt.Axes, row: dict[str, object]) -> None:
    for key, colour, label in [
        ("snug_angle", "tab:green", "snug"),
        ("elastic_start_angle", "tab:blue", "elastic window"),
        ("elastic_end_angle", "tab:blue", None),
        ("yield_angle", "tab:red", "yield"),
    ]:
        value = row.get(key)
        if value is not None:
            ax.axvline(float(value), color=colour, lw=0.8, label=label)  # type: ignore[arg-type]
    prevailing = row.get("prevailing_torque")
    if prevailing is not None:
        ax.axhline(float(prevailing), color="tab:green", ls=":", lw=0.8, label="prevailing torque")  # type: ignore[arg-type]


def _panel(ax: plt.Axes, angle: np.ndarray, torque: np.ndarray, row: dict[str, object], title: str) -> None:
    ax.plot(angle, torque, ".-", ms=1.5, lw=0.5, color="k")
    _mark(ax, row)
    snug = row.get("snug_angle")
    peak = float(np.max(angle))
    if snug is not None:
        span = peak - float(snug)  # type: ignore[arg-type]
        ax.set_xlim(float(snug) - 1.5 * span, peak + 0.1 * span)  # type: ignore[arg-type]
    rate = row["torque_rate"]
    rate_text = "none" if rate is None else f"{rate:.4g} Nm/deg"
    ax.set_title(f"{title}\nstatus {str(row['status']).split(':')[0]}, torque rate {rate_text}", fontsize=8)
    ax.set_xlabel("angle [deg]", fontsize=8)
    ax.set_ylabel("torque [Nm]", fontsize=8)
    ax.tick_params(labelsize=7)


def simulated_vs_real() -> Path:
    curves, truth = tightscan.simulate(300, seed=4, fault_fraction=0.0)
    results = tightscan.detect_batch(curves)
    files = sorted((DATA / "runs").glob("*.json"))
    picks = [files[i] for i in (0, 1700, 3403)]
    real = tightscan.read_rexroth(picks, progress=False)
    real_results = tightscan.detect_batch(real)
    fig, axes = plt.subplots(4, 3, figsize=(13, 14))
    strategies = truth.column("strategy").to_pylist()
    for r, strategy in enumerate(["CST", "CSDT", "HDT"]):
        rows = [i for i, s in enumerate(strategies) if s == strategy][:3]
        for c, i in enumerate(rows):
            row = {k: results.column(k)[i].as_py() for k in results.column_names}
            angle = np.asarray(curves.column("angle")[i].values)
            torque = np.asarray(curves.column("torque")[i].values)
            _panel(axes[r, c], angle, torque, row, f"simulated {strategy}, {curves.column('thread')[i]}")
    for c in range(3):
        row = {k: real_results.column(k)[c].as_py() for k in real_results.column_names}
        angle = np.asarray(real.column("angle")[c].values)
        torque = np.asarray(real.column("torque")[c].values)
        _panel(axes[3, c], angle, torque, row, f"real Rexroth s01, cycle {real.column('cycle')[c]}")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    OUT.mkdir(parents=True, exist_ok=True)
    path = OUT / "simulated_vs_real.png"
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def demo_tightening() -> Path:
    """README figure: a tightening of the demo dataset (``tightscan demo``: seed 2026; the
    first 200 of its tightenings are these) with the change the engine found, drawn by
    :func:`tightscan.plot.plot_tightening`."""
    from tightscan.plot import plot_tightening

    curves, _ = tightscan.simulate(200, seed=2026)
    results = tightscan.detect_batch(curves)
    changed = results.filter(results.column("change_detected")).column("tightening_id").to_pylist()
    fig = plot_tightening(curves, results, changed[0])
    OUT.mkdir(parents=True, exist_ok=True)
    path = OUT / "demo_tightening.png"
    fig.savefig(path, dpi=90)
    return path


def demo_detectors() -> Path:
    """README figure: the detectors' own traces for the tightening of :func:`demo_tightening`,
    drawn by :func:`tightscan.plot.plot_detectors` (from ``tightscan.detector_traces``)."""
    from tightscan.plot import plot_detectors

    curves, _ = tightscan.simulate(200, seed=2026)
    results = tightscan.detect_batch(curves)
    changed = results.filter(results.column("change_detected")).column("tightening_id").to_pylist()
    fig = plot_detectors(curves, results, changed[0])
    OUT.mkdir(parents=True, exist_ok=True)
    path = OUT / "demo_detectors.png"
    fig.savefig(path, dpi=70)
    return path


FIGURES = {"demo_tightening": demo_tightening, "demo_detectors": demo_detectors, "simulated_vs_real": simulated_vs_real}

if __name__ == "__main__":
    for name in sys.argv[1:] or list(FIGURES):
        print(FIGURES[name]())
