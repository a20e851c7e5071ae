"""MovingAI 2D grid benchmark maps (.map) and scenarios (.scen), the standard format of the
multi-agent path-finding community (Sturtevant, "Benchmarks for Grid-Based Pathfinding").

A map becomes a 4-connected grid graph: '.', 'G' and 'S' (swamp, passable from ground) are
passable, '@', 'O', 'T' and 'W' (water, not passable from ground) blocked; 'E' is passable
too, as the League of Robot Runners' maps write their emitter cells (and 'S' their service
cells) in this format. Any other letter is refused rather than guessed.
Node id of cell (x, y) is ``y * width + x`` with (0, 0) the top-left cell and x the column,
so ids match the coordinates in .scen files. Every segment is ``cell_size`` long.

The cells are read as one array (a 1024 x 1024 map is a million cells), and a map with more
passable cells than a plant may have nodes is refused before any node is made.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import TopologyError
from ..grid import grid_plant
from ..model import Plant
from ..validate import escaped_name
from .numbers import parse_float, parse_int, shown
from .structured import read_text, text_lines

PASSABLE = ".GSE"
BLOCKED = "@OTW"
HEADER_KEYS = ("type", "height", "width")
SCENARIO_FIELDS = (
    "bucket",
    "map",
    "width",
    "height",
    "start x",
    "start y",
    "goal x",
    "goal y",
    "optimal length",
)


# A cell of a kilometre is far beyond any plant's grid; it keeps every coordinate of the
# largest map within the plant model's limits.
MAX_CELL_SIZE_M = 1000.0


def load_map(path: str | Path, cell_size: float = 1.0) -> Plant:
    path = Path(path)
    source = str(path)
    if not (
        isinstance(cell_size, int | float)
        and not isinstance(cell_size, bool)
        and math.isfinite(cell_size)
        and 0 < cell_size <= MAX_CELL_SIZE_M
    ):
        raise TopologyError(
            f"cell size must be a number > 0 and at most {MAX_CELL_SIZE_M:g} m, got {cell_size!r}",
            source,
        )
    passable = read_cells(path)
    return grid_plant(passable, cell_size, name=escaped_name(path.stem), source=source)


def read_cells(path: str | Path) -> np.ndarray:
    """The map's cells as a (height, width) array, True where passable: for programs that
    work on the grid itself (arrays in, arrays out) with the same checks as ``load_map``."""
    path = Path(path)
    source = str(path)
    lines = text_lines(read_text(path))
    header, row = _header(lines, source)
    height, width = header["height"], header["width"]
    grid = lines[row + 1 : row + 1 + height]
    if len(grid) != height:
        raise TopologyError(
            f"truncated: {len(grid)} of {height} rows", source, f"line {row + 1 + len(grid)}"
        )
    for y, text in enumerate(grid):
        if len(text) != width:
            raise TopologyError(
                f"row has {len(text)} cells, expected {width}", source, f"line {row + 2 + y}"
            )
    _check_nothing_after(lines, row + 1 + height, height, source)
    cells = np.frombuffer("".join(grid).encode("utf-32-le"), dtype="<u4").reshape(height, width)
    passable = np.isin(cells, [ord(c) for c in PASSABLE])
    known = passable | np.isin(cells, [ord(c) for c in BLOCKED])
    if not known.all():
        y, x = np.unravel_index(int(np.argmin(known)), known.shape)
        raise TopologyError(
            f"unknown cell {chr(cells[y, x])!r} at column {x + 1}", source, f"line {row + 2 + y}"
        )
    return passable


def _check_nothing_after(lines: list[str], end: int, height: int, source: str) -> None:
    """Only blank lines may follow the rows: a line more is a row the header does not
    count (a wrong height, or two maps in one file), and reading the map without it would
    drive vehicles on a plant other than the one written down."""
    for number, line in enumerate(lines[end:], start=end + 1):
        if line.strip():
            raise TopologyError(
                f"text after the {height} row(s) that 'height {height}' declares: "
                f"{shown(line)}; only blank lines may follow the map",
                source,
                f"line {number}",
            )


def _header(lines: list[str], source: str) -> tuple[dict[str, int], int]:
    """The height and width, and the index of the 'map' line."""
    header: dict[str, int] = {}
    seen: dict[str, int] = {}
    for row, line in enumerate(lines):
        where = f"line {row + 1}"
        if line.strip() == "map":
            missing = [key for key in ("height", "width") if key not in header]
            if missing:
                raise TopologyError(
                    f"header needs integer 'height' and 'width': no {' and no '.join(missing)} "
                    "line before 'map'",
                    source,
                    where,
                )
            return header, row
        parts = line.split()
        if len(parts) != 2 or parts[0] not in HEADER_KEYS:
            raise TopologyError(
                f"expected 'type', 'height H', 'width W' or 'map', got {shown(line)}",
                source,
                where,
            )
        key, value = parts
        if key in seen:
            raise TopologyError(f"'{key}' given twice (first on line {seen[key]})", source, where)
        seen[key] = row + 1
        if key == "type":
            continue
        number = parse_int(value)
        if number is None:
            raise TopologyError(
                f"header needs integer 'height' and 'width' (ASCII digits), got {key} {shown(value)}",
                source,
                where,
            )
        if number < 1:
            raise TopologyError(f"height and width must be >= 1, got {key} {number}", source, where)
        header[key] = number
    raise TopologyError("no 'map' line: not a MovingAI map", source)


@dataclass(frozen=True)
class Scenario:
    start: int  # node id (y * width + x)
    goal: int
    optimal_octile: float  # the file's optimal length: 8-connected, NOT the 4-connected distance


def load_scenarios(path: str | Path) -> list[Scenario]:
    """The scenarios of a .scen file; TopologyError naming the file, line and field of any
    value that is not what the format says (a coordinate outside its map would name another
    cell: x = 40 on a 32-wide map is a cell of the next row)."""
    path = Path(path)
    source = str(path)
    lines = text_lines(read_text(path))
    if not lines or not lines[0].startswith("version"):
        raise TopologyError("expected 'version 1' on the first line", source, "line 1")
    scenarios = []
    for number, line in enumerate(lines[1:], start=2):
        if line.strip():
            scenarios.append(_scenario(line, source, f"line {number}"))
    return scenarios


def _scenario(line: str, source: str, where: str) -> Scenario:
    parts = line.split("\t")
    if len(parts) != len(SCENARIO_FIELDS):
        raise TopologyError(
            f"expected {len(SCENARIO_FIELDS)} tab-separated fields "
            f"({', '.join(SCENARIO_FIELDS)}), got {len(parts)}",
            source,
            where,
        )
    values = dict(zip(SCENARIO_FIELDS, parts, strict=True))
    if not values["map"].strip():
        raise TopologyError("map: the map file name is empty", source, where)
    numbers: dict[str, int] = {}
    for field in ("bucket", "width", "height"):
        value = parse_int(values[field])
        low = 0 if field == "bucket" else 1
        if value is None or value < low:
            raise TopologyError(
                f"{field} must be an integer >= {low}, got {shown(values[field])}", source, where
            )
        numbers[field] = value
    for field, size in (("x", "width"), ("y", "height")):
        for end in ("start", "goal"):
            name = f"{end} {field}"
            value = parse_int(values[name])
            if value is None or not 0 <= value < numbers[size]:
                raise TopologyError(
                    f"{name} must be an integer 0..{numbers[size] - 1} (the map {size} is "
                    f"{numbers[size]}), got {shown(values[name])}",
                    source,
                    where,
                )
            numbers[name] = value
    optimal = parse_float(values["optimal length"].strip())
    if optimal is None or optimal < 0:
        raise TopologyError(
            f"optimal length must be a finite number >= 0, got {shown(values['optimal length'])}",
            source,
            where,
        )
    width = numbers["width"]
    return Scenario(
        numbers["start y"] * width + numbers["start x"],
        numbers["goal y"] * width + numbers["goal x"],
        optimal,
    )
