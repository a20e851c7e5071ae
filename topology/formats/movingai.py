"""MovingAI 2D grid benchmark maps (.map) and scenarios (.scen), the standard format of the
multi-agent path-finding community (Sturtevant, "Benchmarks for Grid-Based Pathfinding").

A map becomes a 4-connected grid graph: '.' and 'G' are passable, '@', 'O', 'T' and 'W'
blocked (other letters of the full format, S for swamp, are rejected rather than guessed).
Node id of cell (x, y) is ``y * width + x`` with (0, 0) the top-left cell and x the column,
so ids match the coordinates in .scen files. Every segment is ``cell_size`` long.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import TopologyError
from ..grid import grid_plant
from ..model import Plant
from .structured import read_text

PASSABLE = set(".G")
BLOCKED = set("@OTW")


def load_map(path: Path, cell_size: float = 1.0) -> Plant:
    source = str(path)
    if not (isinstance(cell_size, int | float) and cell_size > 0):
        raise TopologyError(f"cell size must be > 0, got {cell_size!r}", source)
    lines = read_text(path).splitlines()
    header: dict[str, str] = {}
    row = 0
    for row, line in enumerate(lines):
        if line.strip() == "map":
            break
        parts = line.split()
        if len(parts) != 2 or parts[0] not in ("type", "height", "width"):
            raise TopologyError(
                f"expected 'type', 'height W', 'width W' or 'map', got {line!r}",
                source,
                f"line {row + 1}",
            )
        header[parts[0]] = parts[1]
    else:
        raise TopologyError("no 'map' line: not a MovingAI map", source)
    try:
        height, width = int(header["height"]), int(header["width"])
    except (KeyError, ValueError):
        raise TopologyError("header needs integer 'height' and 'width'", source, "line 1") from None
    if height < 1 or width < 1:
        raise TopologyError(
            f"height and width must be >= 1, got {height} x {width}", source, "line 1"
        )
    grid = lines[row + 1 : row + 1 + height]
    if len(grid) != height:
        raise TopologyError(
            f"truncated: {len(grid)} of {height} rows", source, f"line {row + 1 + len(grid)}"
        )
    passable = []
    for y, text in enumerate(grid):
        where = f"line {row + 2 + y}"
        if len(text) != width:
            raise TopologyError(f"row has {len(text)} cells, expected {width}", source, where)
        for x, cell in enumerate(text):
            if cell not in PASSABLE and cell not in BLOCKED:
                raise TopologyError(f"unknown cell {cell!r} at column {x + 1}", source, where)
        passable.append([cell in PASSABLE for cell in text])
    return grid_plant(np.array(passable, dtype=bool), cell_size, name=path.stem, source=source)


@dataclass(frozen=True)
class Scenario:
    start: int  # node id (y * width + x)
    goal: int
    optimal_octile: float  # the file's optimal length: 8-connected, NOT the 4-connected distance


def load_scenarios(path: Path) -> list[Scenario]:
    source = str(path)
    lines = read_text(path).splitlines()
    if not lines or not lines[0].startswith("version"):
        raise TopologyError("expected 'version 1' on the first line", source, "line 1")
    scenarios = []
    for number, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        parts = line.split("\t")
        try:
            _bucket, _map, width, _height, sx, sy, gx, gy, optimal = parts
            w = int(width)
            scenarios.append(Scenario(int(sy) * w + int(sx), int(gy) * w + int(gx), float(optimal)))
        except ValueError:
            raise TopologyError(
                "expected 9 tab-separated fields", source, f"line {number}"
            ) from None
    return scenarios
