"""Dependencies point one way, so the folder list shows the architecture.

    plc_runtime  <-  blocks.standard  <-  blocks.routing  <-  blocks.traffic  <-  blocks.jobs
                                                        blocks.traffic  <-  blocks.dispatch
    topology     <-  blocks.routing, blocks.traffic, blocks.jobs, blocks.dispatch, vehicles
    plc_runtime  <-  io_drivers  <-  vehicles
    everything   <-  fleet (the application: configuration, program assembly, reports, CLI)

The soft-PLC (``plc_runtime``) and the plant model (``topology``) import nothing else of
ours; no package but the application imports the application.
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("plc_runtime", "topology", "blocks", "io_drivers", "vehicles", "fleet")

# what each layer may import of ours (itself always)
ALLOWED = {
    "plc_runtime": set(),
    "topology": set(),
    "blocks.standard": {"plc_runtime"},
    "blocks.routing": {"plc_runtime", "topology", "blocks.standard"},
    "blocks.traffic": {"plc_runtime", "topology", "blocks.standard", "blocks.routing"},
    "blocks.jobs": {
        "plc_runtime",
        "topology",
        "blocks.standard",
        "blocks.routing",
        "blocks.traffic",
    },
    "blocks.dispatch": {
        "plc_runtime",
        "topology",
        "blocks.standard",
        "blocks.routing",
        "blocks.traffic",
    },
    "io_drivers": {"plc_runtime"},
    "vehicles": {"plc_runtime", "topology", "io_drivers"},
    "fleet": {"plc_runtime", "topology", "blocks", "io_drivers", "vehicles"},
}


def layer_of(module: str) -> str | None:
    """The most specific layer a dotted module name belongs to."""
    best = None
    for layer in ALLOWED:
        if module == layer or module.startswith(layer + "."):
            if best is None or len(layer) > len(best):
                best = layer
    return best


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports_of(path: Path) -> set[str]:
    """Every module of ours that ``path`` imports, relative imports resolved."""
    package = module_name(path).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
                names = [f"{module}.{a.name}" for a in node.names] if not node.module else []
                found |= {module, *names}
            elif node.module:
                found.add(node.module)
    return {m for m in found if m.split(".")[0] in PACKAGES}


def sources() -> list[Path]:
    return sorted(p for package in PACKAGES for p in (ROOT / package).rglob("*.py"))


def allowed_for(layer: str, target: str) -> bool:
    if layer_of(target) == layer:
        return True
    return any(target == a or target.startswith(a + ".") for a in ALLOWED[layer]) or (
        # a package's __init__ (``blocks``) is a namespace, not a layer of its own
        target in {"blocks"}
    )


@pytest.mark.parametrize("path", sources(), ids=lambda p: str(p.relative_to(ROOT)))
def test_imports_follow_the_layers(path):
    layer = layer_of(module_name(path))
    if layer is None:  # blocks/__init__.py: documentation only
        assert not imports_of(path), path
        return
    wrong = sorted(t for t in imports_of(path) if not allowed_for(layer, t))
    assert not wrong, f"{path.relative_to(ROOT)} ({layer}) imports {wrong}"


def test_every_module_belongs_to_a_layer():
    stray = [p for p in sources() if layer_of(module_name(p)) is None and p.name != "__init__.py"]
    assert not stray


def test_the_soft_plc_has_no_application_inside():
    """Nothing under plc_runtime/ names an AGV concept: it is a generic runtime."""
    for path in (ROOT / "plc_runtime").rglob("*.py"):
        text = path.read_text().lower()
        for word in ("vehicle", "agv", "recipe", "fleet"):
            assert word not in text, f"{path.relative_to(ROOT)} mentions {word!r}"


def test_the_checker_catches_wrong_arrows():
    """The rule can fail: upward and sideways imports are reported."""
    assert not allowed_for("plc_runtime", "blocks.standard")
    assert not allowed_for("blocks.routing", "blocks.traffic.reservation")
    assert not allowed_for("vehicles", "fleet.program")
    assert not allowed_for("io_drivers", "topology")
    assert allowed_for("blocks.jobs", "blocks.routing.heuristic")
