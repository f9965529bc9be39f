"""Step 6, report: figures of a diagnosis (residual before and after, evidence) written to a
directory. The figures themselves are :mod:`tightscan.plot`'s, which the HTML report
(``tightscan report --diagnose``) shares."""

from __future__ import annotations

from pathlib import Path

from .result import Diagnosis
from .prepare import PathLike


# ---------------------------------------------------------------------------------------------
# Report


def write_report(diagnosis: Diagnosis, directory: PathLike, prefix: str = "diagnose") -> list[Path]:
    """Figures of a diagnosis: residual before, the evidence, residual after (PNG).

    Needs matplotlib (``pip install 'tightscan[report]'``); the diagnosis itself does not."""
    from ..plot import plot_diagnosis_evidence, plot_diagnosis_residual

    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    paths: list[Path] = []
    for which in ("before", "after"):
        path = out / f"{prefix}-residual-{which}.png"
        plot_diagnosis_residual(diagnosis, which).savefig(path, dpi=110)
        paths.append(path)
    path = out / f"{prefix}-evidence.png"
    plot_diagnosis_evidence(diagnosis).savefig(path, dpi=110)
    paths.append(path)
    return paths
