"""The data-contract page and the README stay true to the code."""

from __future__ import annotations

import importlib.util
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


def test_contract_table_is_generated_from_result_columns() -> None:
    """docs/data-contract.md's result table is what docs/make_data_contract.py writes from
    tightscan.result_columns(): run that script after changing a column."""
    spec = importlib.util.spec_from_file_location("make_data_contract", ROOT / "docs" / "make_data_contract.py")
    assert spec is not None and spec.loader is not None
    generator = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(generator)
    committed = (ROOT / "docs" / "data-contract.md").read_text()
    assert committed == generator.generated_page(committed), "run: .venv/bin/python docs/make_data_contract.py"
    for c in tightscan.result_columns():
        assert f"| `{c.name}` |" in generator.result_table() and c.meaning.replace("|", "\\|") in committed


def test_readme_states_the_two_commands_first() -> None:
    text = (ROOT / "README.md").read_text()
    first, second = text.index("make demo"), text.index("make test")
    assert first < second
