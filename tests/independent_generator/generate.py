"""Entry point: draw the tightenings, simulate them in batches, build the tables."""

from __future__ import annotations

import pyarrow as pa

from .config import GeneratorConfig
from .engine import CurveData, simulate_batch
from .params import draw_tightening, operator_table
from .record import curves_table, truth_table

BATCH = 512
"""Tightenings stepped together (memory and speed only: results do not depend on it)."""


def generate(config: GeneratorConfig) -> tuple[pa.Table, pa.Table]:
    """Simulate ``config.n`` tightenings: ``(curves, truth)``.

    ``curves``: nested layout of docs/data-contract.md (``tightening_id``, ``angle``,
    ``torque``, ``time``, ``speed``, ``clamp_force`` when enabled, ``strategy``, ``thread``,
    ``target_torque``, ``operator`` with operators, ``joint_stiffness`` when asked).
    ``truth``: one row per tightening (see :data:`independent_generator.record.TRUTH_SCHEMA`);
    every angle in it is in the coordinates of the ``angle`` channel."""
    operators = operator_table(config)
    drawn = [draw_tightening(config, i, operators) for i in range(config.n)]
    tights = [d[0] for d in drawn]
    curves: list[CurveData] = []
    for start in range(0, config.n, BATCH):
        part = drawn[start:start + BATCH]
        curves.extend(simulate_batch(config, [d[0] for d in part], [d[1] for d in part], [d[2] for d in part]))
    return curves_table(config, tights, curves), truth_table(config, tights, curves, operators)
