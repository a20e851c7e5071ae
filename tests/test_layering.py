"""Dependencies point one way: the core and topology import nothing of ours."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
OURS = {"plc_runtime", "blocks", "topology", "io_drivers", "vehicles"}


def imported_packages(path: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module.split(".")[0])
    return found & OURS


def sources(package: str, exclude: tuple[str, ...] = ()) -> list[Path]:
    """The package's Python files, minus those with a path part starting with an ``exclude`` prefix."""
    return [
        p
        for p in (ROOT / package).rglob("*.py")
        if not any(
            part.startswith(prefix) for prefix in exclude for part in p.relative_to(ROOT).parts
        )
    ]


# the CLI modules (cli*.py) and program assembly (programs/) are the layer that sees everything
@pytest.mark.parametrize("path", sources("plc_runtime", exclude=("cli", "programs")), ids=str)
def test_runtime_core_imports_only_itself(path):
    assert imported_packages(path) <= {"plc_runtime"}


@pytest.mark.parametrize("path", sources("topology"), ids=str)
def test_topology_imports_nothing_of_ours(path):
    assert imported_packages(path) <= {"topology"}


@pytest.mark.parametrize("package", ["blocks", "io_drivers", "vehicles"])
def test_building_blocks_do_not_reach_into_program_assembly(package):
    for path in sources(package):
        text = path.read_text()
        assert "plc_runtime.cli" not in text and "plc_runtime.programs" not in text, path
