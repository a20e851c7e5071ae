"""Sample plants shipped with the package: ``model-plant``, ``warehouse``, ``grid`` and ``kiva``.

``model_plant()`` reconstructs the thesis' 25-node plant (Hochschule Muenchen, 2016): a 3 x 5
matrix of crossings (a 2 x 4 matrix of lanes), the entry (node 0) as the middle crossing of
the left edge and the exit (node 24) behind the right edge, nine stations on the outer lanes
grouped into function clusters. The outer lanes are one-way (top left to right, bottom right
to left, the left edge upwards through station 23), so every station exit is directed; the
middle row and the vertical lanes are two-way overtaking lanes. A return lane from the exit
back to the entry exists for driving but routing ignores it. Final targets: the nine
stations and the exit (10). Lengths in metres.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .grid import grid_plant
from .model import Edge, Node, Plant

FUNCTIONS = {0: "entry", 1: "exit", 2: "drill", 3: "mill", 4: "paint", 5: "inspect", 6: "wash"}
LANE = 1.0  # horizontal distance between crossings
RUNG = 0.8  # vertical distance between crossings


def model_plant() -> Plant:
    crossing: dict[tuple[int, int], int] = {}
    nodes = [Node(0, "entry", 0.0, RUNG, "entry", (0,))]
    crossing[(0, 1)] = 0
    next_id = 1
    for r in range(3):
        for c in range(5):
            if (c, r) == (0, 1):
                continue
            crossing[(c, r)] = next_id
            nodes.append(Node(next_id, f"x{c}{r}", c * LANE, r * RUNG))
            next_id += 1
    edges: list[Edge] = []
    clusters = {15: 2, 16: 3, 17: 4, 18: 5, 19: 5, 20: 4, 21: 3, 22: 2, 23: 6}
    # top lane, one-way left to right, a station in every segment
    for c in range(4):
        s = 15 + c
        nodes.append(
            Node(
                s, f"{FUNCTIONS[clusters[s]]}-top", (c + 0.5) * LANE, 0.0, "station", (clusters[s],)
            )
        )
        edges.append(
            Edge(
                crossing[(c, 0)], s, LANE / 2, bidirectional=False, port_source="E", port_target="W"
            )
        )
        edges.append(
            Edge(
                s,
                crossing[(c + 1, 0)],
                LANE / 2,
                bidirectional=False,
                port_source="E",
                port_target="W",
            )
        )
    # bottom lane, one-way right to left
    for c in range(4):
        s = 22 - c
        nodes.append(
            Node(
                s,
                f"{FUNCTIONS[clusters[s]]}-bottom",
                (c + 0.5) * LANE,
                2 * RUNG,
                "station",
                (clusters[s],),
            )
        )
        edges.append(
            Edge(
                crossing[(c + 1, 2)],
                s,
                LANE / 2,
                bidirectional=False,
                port_source="W",
                port_target="E",
            )
        )
        edges.append(
            Edge(
                s, crossing[(c, 2)], LANE / 2, bidirectional=False, port_source="W", port_target="E"
            )
        )
    # left edge: upwards through station 23; down to the bottom-left crossing two-way
    nodes.append(Node(23, "wash", 0.0, RUNG / 2, "station", (6,)))
    edges.append(Edge(0, 23, RUNG / 2, bidirectional=False, port_source="N", port_target="S"))
    edges.append(
        Edge(23, crossing[(0, 0)], RUNG / 2, bidirectional=False, port_source="N", port_target="S")
    )
    edges.append(Edge(0, crossing[(0, 2)], RUNG, port_source="S", port_target="N"))
    # middle row and the other vertical lanes: two-way overtaking lanes
    for c in range(4):
        edges.append(
            Edge(crossing[(c, 1)], crossing[(c + 1, 1)], LANE, port_source="E", port_target="W")
        )
    for c in range(1, 5):
        for r in range(2):
            edges.append(
                Edge(crossing[(c, r)], crossing[(c, r + 1)], RUNG, port_source="S", port_target="N")
            )
    # exit and the return lane routing ignores
    nodes.append(Node(24, "exit", 5 * LANE, RUNG, "exit", (1,)))
    edges.append(
        Edge(crossing[(4, 1)], 24, LANE, bidirectional=False, port_source="E", port_target="W")
    )
    edges.append(
        Edge(24, 0, 7 * LANE, bidirectional=False, port_source="S", port_target="W", routable=False)
    )
    return Plant.build(
        sorted(nodes, key=lambda n: n.id), edges, name="model-plant", functions=FUNCTIONS
    )


def warehouse(
    width: int = 46,
    height: int = 33,
    shelf_length: int = 10,
    border: int = 4,
    cell_size: float = 1.0,
) -> Plant:
    """A fulfilment-centre layout: rows of shelf blocks (``shelf_length`` x 1 cells) with
    one-cell aisles between them, an open border of ``border`` cells on the left and right
    with picking stations (function 2) on the outermost columns every third row, chargers in
    the four corners. The default 33 x 46 instance matches the size of the fulfilment map used
    in lifelong multi-agent path-finding papers."""
    if width < 2 * border + shelf_length or height < 5:
        raise ValueError(
            f"warehouse {width}x{height} too small for shelves of {shelf_length} and border {border}"
        )
    passable = np.ones((height, width), dtype=bool)
    for y in range(2, height - 2, 2):  # shelf rows, every other row, aisles between
        x = border + 1
        while x + shelf_length <= width - border - 1:
            passable[y, x : x + shelf_length] = False
            x += shelf_length + 1
    roles: dict[int, tuple[str, tuple[int, ...]]] = {}
    for y in range(1, height - 1, 3):
        roles[y * width] = ("station", (2,))
        roles[y * width + width - 1] = ("station", (2,))
    for corner in (0, width - 1, (height - 1) * width, height * width - 1):
        roles[corner] = ("charger", ())
    return grid_plant(
        passable, cell_size, roles, name=f"warehouse-{height}x{width}", functions={2: "pick"}
    )


def grid(
    width: int = 32,
    height: int = 32,
    obstacles: float = 0.1,
    seed: int = 0,
    stations: int = 8,
    cell_size: float = 1.0,
) -> Plant:
    """A W x H grid with a seeded random fraction of blocked cells and ``stations`` random
    station cells (function 2). Obstacles may cut cells off: validation then warns."""
    if not 0 <= obstacles < 1:
        raise ValueError(f"obstacles must be a fraction in [0, 1), got {obstacles!r}")
    rng = np.random.default_rng(seed)
    passable = rng.random((height, width)) >= obstacles
    free = np.flatnonzero(passable.ravel())
    chosen = rng.choice(free, size=min(stations, len(free)), replace=False) if len(free) else []
    roles = {int(i): ("station", (2,)) for i in chosen}
    return grid_plant(
        passable,
        cell_size,
        roles,
        name=f"grid-{width}x{height}-{seed}",
        functions={2: "pick"} if roles else {},
    )


KIVA_WIDTH, KIVA_HEIGHT = 46, 33
KIVA_SHELF_COLUMNS = ((7, 16), (18, 27), (29, 38))  # inclusive: three shelf blocks per band
KIVA_HOME_COLUMNS = (1, 2, 4, 5, 40, 41, 43, 44)


def kiva() -> Plant:
    """The "kiva" fulfilment map of RHCR (Li et al., "Lifelong Multi-Agent Path Finding in
    Large-Scale Warehouses"), cell for cell: the reference map of lifelong MAPF results, so a
    throughput measured on it compares with the published ones directly, which the
    ``warehouse`` sample (same size, a layout of its own) does not allow.

    33 rows x 46 columns of 1 m cells. Every fourth row (0, 4, .., 32) is open; the three rows
    between two open rows form a band: its middle row holds three shelf blocks of ten cells
    (columns 7-16, 18-27, 29-38; blocked), the rows above and below them are the shelves'
    endpoints (stations, function 2 "pick"), and columns 1-2, 4-5, 40-41 and 43-44 of all three
    band rows are the robots' home cells (parking). Everything else is open floor. 8 bands:
    480 endpoints, 240 shelf cells, 192 home cells, 1278 passable cells.

    Its long lanes are highways (:func:`kiva_highways`): the cells are RHCR's, every lane
    stays two-way, and routing only prices driving against a lane's direction higher."""
    passable = np.ones((KIVA_HEIGHT, KIVA_WIDTH), dtype=bool)
    roles: dict[int, tuple[str, tuple[int, ...]]] = {}
    for top in range(0, KIVA_HEIGHT - 1, 4):  # the open row above each band
        for row in (top + 1, top + 2, top + 3):
            for first, last in KIVA_SHELF_COLUMNS:
                if row == top + 2:
                    passable[row, first : last + 1] = False
                else:
                    for x in range(first, last + 1):
                        roles[row * KIVA_WIDTH + x] = ("station", (2,))
            for x in KIVA_HOME_COLUMNS:
                roles[row * KIVA_WIDTH + x] = ("parking", ())
    grid = grid_plant(
        passable,
        1.0,
        roles,
        name=f"kiva-{KIVA_HEIGHT}x{KIVA_WIDTH}",
        functions={2: "pick"},
    )
    return Plant.build(
        grid.nodes, kiva_highways(grid.edges), name=grid.name, functions=grid.functions
    )


KIVA_OPEN_COLUMNS = (0, 3, 6, 17, 28, 39, 42, 45)  # the columns open from top to bottom


def kiva_highways(edges: tuple[Edge, ...]) -> list[Edge]:
    """The kiva grid's edges with a preferred direction on every long lane, parallel lanes
    alternating, like the one-way streets of a city grid (the "highways" of Cohen et al.,
    2015): the rows along the shelves (every row but the shelves' own) east, west, east, ...
    from the top, the open columns south, north, south, ... from the left. Crowded
    vehicles then mostly follow each other instead of meeting head-on; the short spurs
    into the shelf faces and home cells keep no direction."""
    rows = [r for r in range(KIVA_HEIGHT) if r % 4 != 2]
    east = {r: k % 2 == 0 for k, r in enumerate(rows)}
    south = {c: k % 2 == 0 for k, c in enumerate(KIVA_OPEN_COLUMNS)}
    out = []
    for e in edges:
        (ra, ca), (rb, cb) = divmod(e.source, KIVA_WIDTH), divmod(e.target, KIVA_WIDTH)
        if ra == rb and ra in east:
            forward = (cb > ca) == east[ra]
        elif ca == cb and ca in south:
            forward = (rb > ra) == south[ca]
        else:
            out.append(e)
            continue
        if forward:
            out.append(replace(e, highway=True))
        else:
            out.append(
                replace(
                    e,
                    source=e.target,
                    target=e.source,
                    port_source=e.port_target,
                    port_target=e.port_source,
                    highway=True,
                )
            )
    return out


SAMPLES = {"model-plant": model_plant, "warehouse": warehouse, "grid": grid, "kiva": kiva}
