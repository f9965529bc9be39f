"""ISO metric thread geometry for ``mu_tot`` at level 2 when a table names its threads (a
``thread`` column such as ``"M10"`` or ``"M10x1.25"``) instead of giving ``pitch_mm``, ``d2_mm``
and ``dkm_mm``.

The rows are the engine's table itself (``crates/tightscan-core/src/physics/thread.rs``,
``ISO_METRIC_THREADS``: ISO 261/724 pitches, d2 = d - 0.649519 P, Dkm = (dw + dh) / 2 from the
head's bearing diameter and the clearance hole), read through the binding, so that diagnose and
``detect_batch`` read a designation the same way from one table.

>>> [round(v, 4) for v in thread_geometry("M10") or ()]
[1.5, 9.0257, 12.815]
>>> (thread_geometry("m10 x 1,25") or (0.0,))[0], thread_geometry("M7") is None
(1.25, True)
"""

from __future__ import annotations

from .._core import thread_geometry as _engine_thread_geometry


def thread_geometry(designation: object) -> tuple[float, float, float] | None:
    """``(pitch_mm, d2_mm, dkm_mm)`` of an ISO metric designation (``"M8"``: the coarse thread;
    ``"M8x1"``, ``"m8 X 1,0"``: the fine one), or None when it is not in the table or not a
    string."""
    if not isinstance(designation, str):
        return None
    return _engine_thread_geometry(designation)
