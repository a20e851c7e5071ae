"""Reading plant files; the format follows from the extension.

``.toml`` (primary, see docs/plant-format.md), ``.json`` (same schema), ``.map`` (MovingAI
grid) and ``.nodes`` (the thesis' compass node list).
"""

from __future__ import annotations

from pathlib import Path

from ..errors import TopologyError
from ..model import Plant
from .compass import load_nodes
from .movingai import Scenario, load_map, load_scenarios, read_cells
from .structured import dump_json, dump_toml, from_dict, load_json, load_toml, to_dict

LOADERS = {".toml": load_toml, ".json": load_json, ".nodes": load_nodes}


def load(path: str | Path, cell_size: float = 1.0) -> Plant:
    """Load a plant file of any supported format; TopologyError naming the file on any problem."""
    path = Path(path)
    if path.is_dir():
        raise TopologyError("a folder, not a plant file", str(path))
    suffix = path.suffix.lower()
    if suffix == ".map":
        return load_map(path, cell_size)
    loader = LOADERS.get(suffix)
    if loader is None:
        known = ", ".join(sorted([*LOADERS, ".map"]))
        raise TopologyError(
            f"unknown plant file type {suffix or '(none)'!r}; known: {known}", str(path)
        )
    return loader(path)


__all__ = [
    "Scenario",
    "dump_json",
    "dump_toml",
    "from_dict",
    "load",
    "load_scenarios",
    "read_cells",
    "to_dict",
]
