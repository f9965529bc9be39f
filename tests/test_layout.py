"""The layout keeps its promises (docs/architecture.md): dependencies between the core crate's
layers point one way, the architecture page and the README name every module, and the status
codes of the data contract are the engine's."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / "crates" / "tightscan-core" / "src"

# Which layers each layer may use (besides itself and the shared `error` and `sample`).
ALLOWED = {
    "engine": {"detectors", "physics"},
    "detectors": set(),
    "physics": set(),
    "simulate": {"physics"},
}
LAYERS = set(ALLOWED)


def _code_lines(path: Path) -> list[str]:
    """Lines of Rust code, doc and line comments dropped (doc links may point anywhere)."""
    return [line for line in path.read_text().splitlines() if not line.lstrip().startswith("//")]


def test_core_layers_depend_one_way() -> None:
    offences = []
    for layer, allowed in ALLOWED.items():
        for path in sorted((CORE / layer).rglob("*.rs")):
            for number, line in enumerate(_code_lines(path), 1):
                for used in re.findall(r"crate::([a-z_]+)", line):
                    if used in LAYERS and used != layer and used not in allowed:
                        offences.append(f"{path.relative_to(ROOT)}:{number} uses {used}")
    assert not offences, offences


def test_shared_modules_use_no_layer() -> None:
    for name in ("error.rs", "sample.rs"):
        used = {u for line in _code_lines(CORE / name) for u in re.findall(r"crate::([a-z_]+)", line)}
        assert not used & LAYERS, (name, used)


def test_no_core_module_uses_python() -> None:
    manifest = (ROOT / "crates" / "tightscan-core" / "Cargo.toml").read_text()
    assert "pyo3" not in manifest


def test_architecture_page_names_every_core_module() -> None:
    page = (ROOT / "docs" / "architecture.md").read_text()
    missing = []
    for path in sorted(CORE.rglob("*.rs")):
        rel = path.relative_to(CORE).as_posix()
        if rel in ("lib.rs",) or rel.endswith("/mod.rs") and rel.count("/") > 1:
            continue
        # Named by its path within its layer (`engine/decision.rs`) or, inside a listed folder,
        # by its file name (`friction.rs` in the physics line).
        if rel not in page and f"`{path.name}`" not in page and path.name not in page:
            missing.append(rel)
    assert not missing, missing


def test_readme_layout_names_the_layers() -> None:
    readme = (ROOT / "README.md").read_text()
    layout = readme.split("## Layout", 1)[1]
    for folder in ("engine/", "detectors/", "physics/", "simulate/", "diagnose/", "docs/architecture.md"):
        assert folder in layout, folder


def test_contract_status_codes_are_the_engines() -> None:
    status_rs = (CORE / "engine" / "status.rs").read_text()
    codes = re.findall(r'=> "([a-z_]+)",', status_rs.split("pub fn code", 1)[1].split("pub fn is_ok", 1)[0])
    contract = (ROOT / "docs" / "data-contract.md").read_text().split("### Status codes", 1)[1]
    listed = re.findall(r"^\| `([a-z_]+)` \|", contract.split("## The result table", 1)[0], flags=re.M)
    assert codes and listed == codes, (listed, codes)
