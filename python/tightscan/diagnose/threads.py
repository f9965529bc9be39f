"""ISO metric thread geometry for ``mu_tot`` at level 2 when a table names its threads (a
``thread`` column such as ``"M10"`` or ``"M10x1.25"``) instead of giving ``pitch_mm``, ``d2_mm``
and ``dkm_mm``.

The rows are those of the engine's table (``crates/tightscan-core/src/physics/thread.rs``,
``ISO_METRIC_THREADS``: ISO 261/724 pitches, d2 = d - 0.649519 P, Dkm = (dw + dh) / 2 from the
head's bearing diameter and the clearance hole), so that diagnose and ``detect_batch`` read a
designation the same way; ``tests/test_grouping_factors.py`` checks the two agree.

>>> [round(v, 4) for v in thread_geometry("M10") or ()]
[1.5, 9.0257, 12.815]
>>> (thread_geometry("m10 x 1,25") or (0.0,))[0], thread_geometry("M7") is None
(1.25, True)
"""

from __future__ import annotations

#: designation -> (nominal diameter, pitch, coarse, dw, dh) [mm]
_ROWS: dict[str, tuple[float, float, bool, float, float]] = {
    "M3": (3.0, 0.5, True, 4.57, 3.4),
    "M4": (4.0, 0.7, True, 5.88, 4.5),
    "M5": (5.0, 0.8, True, 6.88, 5.5),
    "M6": (6.0, 1.0, True, 8.88, 6.6),
    "M8": (8.0, 1.25, True, 11.63, 9.0),
    "M8x1": (8.0, 1.0, False, 11.63, 9.0),
    "M10": (10.0, 1.5, True, 14.63, 11.0),
    "M10x1.25": (10.0, 1.25, False, 14.63, 11.0),
    "M10x1": (10.0, 1.0, False, 14.63, 11.0),
    "M12": (12.0, 1.75, True, 16.63, 13.5),
    "M12x1.5": (12.0, 1.5, False, 16.63, 13.5),
    "M12x1.25": (12.0, 1.25, False, 16.63, 13.5),
    "M14": (14.0, 2.0, True, 19.64, 15.5),
    "M14x1.5": (14.0, 1.5, False, 19.64, 15.5),
    "M16": (16.0, 2.0, True, 22.49, 17.5),
    "M16x1.5": (16.0, 1.5, False, 22.49, 17.5),
    "M18": (18.0, 2.5, True, 25.34, 20.0),
    "M18x1.5": (18.0, 1.5, False, 25.34, 20.0),
    "M20": (20.0, 2.5, True, 28.19, 22.0),
    "M20x1.5": (20.0, 1.5, False, 28.19, 22.0),
    "M22": (22.0, 2.5, True, 31.71, 24.0),
    "M22x1.5": (22.0, 1.5, False, 31.71, 24.0),
    "M24": (24.0, 3.0, True, 33.61, 26.0),
    "M24x2": (24.0, 2.0, False, 33.61, 26.0),
}
D2_PITCH_FACTOR = 0.649519


def thread_geometry(designation: object) -> tuple[float, float, float] | None:
    """``(pitch_mm, d2_mm, dkm_mm)`` of an ISO metric designation (``"M8"``: the coarse thread;
    ``"M8x1"``, ``"m8 X 1,0"``: the fine one), or None when it is not in the table."""
    if not isinstance(designation, str):
        return None
    text = "".join(ch for ch in designation if not ch.isspace()).replace("×", "X").replace("x", "X").replace("m", "M").replace(",", ".")
    if not text.startswith("M"):
        return None
    diameter, _, pitch = text[1:].partition("X")
    try:
        d = float(diameter)
        p = float(pitch) if pitch else None
    except ValueError:
        return None
    for dd, pp, coarse, dw, dh in _ROWS.values():
        if abs(dd - d) < 1e-9 and (coarse if p is None else abs(pp - p) < 1e-9):
            return pp, dd - D2_PITCH_FACTOR * pp, 0.5 * (dw + dh)
    return None
