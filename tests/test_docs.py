"""The data-contract page and the README stay true to the code."""

from __future__ import annotations

from pathlib import Path

import tightscan

ROOT = Path(__file__).resolve().parents[1]


def test_contract_lists_every_result_column_in_order() -> None:
    text = (ROOT / "docs" / "data-contract.md").read_text()
    result_part = text.split("## The result table")[1]
    names = [c.name for c in tightscan.result_columns()]
    positions = [result_part.find(f"| `{n}` |") for n in names]
    assert all(p >= 0 for p in positions), [n for n, p in zip(names, positions) if p < 0]
    assert positions == sorted(positions)


def test_readme_states_the_two_commands_first() -> None:
    text = (ROOT / "README.md").read_text()
    first, second = text.index("make demo"), text.index("make test")
    assert first < second
