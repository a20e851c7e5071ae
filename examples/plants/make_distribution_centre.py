"""Write ``distribution-centre.toml``: a plant modelled on the food distribution centre of the
order-allocation study (docs/plant-format.md): 87 m x 72 m, free-driving pallet shuttles at
up to 1.5 m/s, transfer stations on the four walls, a one-way ring lane round the hall and
cross aisles of two one-way lanes through it.

The layout (north at the top; in the file y grows downwards, positions in metres):

                  receiving                             control
                   21       22       23       24         71
     NW >-----------S----+-+-S--------S--------S-+-+------S----+-+----> NE
        ^           P-^ v-P              P-^ v-P          ^ v      v hrl 31
        ^           P-^ v-P              P-^ v-P          ^ v      v hrl 32
        ^  C        P-^ v-P  C           P-^ v-P          ^ v      v
        <<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<<< v hrl 33
        >>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>>> v
  62    ^  C        P-^ v-P  C           P-^ v-P          ^ v      v hrl 34
  61    ^           P-^ v-P              P-^ v-C          ^ v      v hrl 35
     SW <----S--------S-+-+---S-------S--------S-+-+-----S-+-+----< SE
            54       53      52      51       43      42      41
                    picking                        depalletising

  S: a transfer station (61 and 62: empty pallets, 31-35: the high-bay warehouse's five
  aisles, each beside the lane); C: the five chargers, two off each lane of the middle
  aisle H and one off the southbound lane of V2; P: parking places; > v < ^: one-way
  lanes. The cross aisles V1 (x = 28 | 32), V2 (52 | 56), V3 (70 | 74) and H (y = 34 | 41)
  each have a northbound (eastbound) and a southbound (westbound) lane.

* The ring lane is one-way and runs clockwise as drawn: east along the north wall, south
  along the east wall (the high-bay warehouse, its five aisles' transfer points), west
  along the south wall, north along the west wall. The main goods flows follow it:
  receiving -> hrl -> depalletising / picking -> empty pallets.
* The cross aisles give the ways back upstream (depalletising -> hrl, picking -> hrl) and
  short cuts, so every node can reach every other (the routable graph is strongly
  connected). Each is a dual carriageway driven on the left like the ring, so no lane in
  the hall is two-way: vehicles never meet head-on on a lane, only queue behind each other.
* A transfer station sits at the end of a two-way spur, 6 m off the ring lane towards the
  wall: lane junction J -> approach node A (3 m) -> station S (3 m). The station and its
  approach form a single-vehicle area named after the station, so a shuttle docking or
  backing out never meets another one in the spur, while the lane itself stays free.
* 4 m upstream of every junction J a second spur, 4 m long, leads to the station's queue
  node (role "queue"): a shuttle whose station is occupied waits there, off the lane.
* Cluster zones (zone = the unit's function id): the lane nodes from a unit's first queue
  junction to its last station junction, with the unit's queue and approach nodes; the
  chargers' zone is their five junctions.
* Five chargers (function 8) and nineteen parking places (idle positions) on 3 m spurs off
  the aisles' lanes. Lane nodes are at least 3 m apart.

Node ids: stations function * 10 + k (receiving 21-24, hrl 31-35, depalletising 41-43,
picking 51-54, empty pallets 61-62, control 71), chargers 81-85, a station's queue node
100 + its id, its approach node 200 + its id, parking places 301-319, lane and aisle nodes
from 401 on (the ring clockwise from the north-west corner, then the aisles). No entry or
exit: the work is transport orders between stations, not recipes.

The file is written by this code alone (no randomness): tests/test_distribution_centre.py
re-runs the script and compares bytes.

    python examples/plants/make_distribution_centre.py [--out FILE]
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from pathlib import Path

DEFAULT_OUT = Path(__file__).with_name("distribution-centre.toml")
WIDTH, HEIGHT = 87.0, 72.0
MAX_SPEED = 1.5  # m/s, on every lane
FUNCTIONS = {
    2: "receiving",
    3: "hrl",
    4: "depalletising",
    5: "picking",
    6: "empty_pallets",
    7: "control",
    8: "charging",
}
CHARGING = 8

# The ring lane: the lane position (y of the north and south sides, x of the west and east
# ones) of each side; its corners are where they meet.
NORTH_Y, SOUTH_Y, WEST_X, EAST_X = 9.0, 63.0, 9.0, 78.0
# The cross aisles are dual carriageways of two one-way lanes, driven on the left like the
# ring (its stations lie to the left of its traffic). So a shuttle leaving a south-wall
# station finds the northbound lane of an aisle at or downstream of its junction, and one
# coming east along H meets the high-bay stations below it. The lanes meet the ring lane at
# station or queue junctions where they can, so no lane node crowds another. The middle
# aisle H: the y of its eastbound lane and of its westbound lane.
H_EAST, H_WEST = 34.0, 41.0
PARKING_Y = (15.0, 23.0, 30.0, 45.0, 53.0)  # parking junctions on a vertical aisle's lanes
# the vertical aisles: x of the northbound lane, x of the southbound lane, the y of the
# parking junctions on them
V_AISLES = ((28.0, 32.0, PARKING_Y), (52.0, 56.0, PARKING_Y), (70.0, 74.0, ()))
CHARGER_X = (16.0, 40.0)  # junctions on both lanes of the middle aisle, a charger off each
# The fifth charger, in the parking row of the southbound lane of V2 (its last parking
# junction): 17 shuttles need more than four over a shift (docs/fleet-config.md, "Enough
# chargers?").
SOUTH_CHARGER = ((56.0, 53.0), (1.0, 0.0))
QUEUE_GAP = 4.0  # queue junction this far upstream of the station junction
APPROACH, STATION, QUEUE = 3.0, 6.0, 4.0  # spur lengths off the lane
CHARGER_SPUR = PARKING_SPUR = 3.0
MIN_GAP = 3.0  # nodes along a lane at least this far apart (room to stop, room for a label)

# side -> (direction of travel, unit vector towards the wall)
SIDES = {
    "north": ((1.0, 0.0), (0.0, -1.0)),
    "east": ((0.0, 1.0), (1.0, 0.0)),
    "south": ((-1.0, 0.0), (0.0, 1.0)),
    "west": ((0.0, -1.0), (-1.0, 0.0)),
}
# (function, side, lane positions of the station junctions in the order of the ids)
UNITS = (
    (2, "north", (22.0, 32.0, 42.0, 52.0)),
    (7, "north", (64.0,)),
    (3, "east", (16.0, 25.0, 34.0, 45.0, 54.0)),
    (4, "south", (70.0, 61.0, 52.0)),
    (5, "south", (42.0, 32.0, 24.0, 15.0)),
    (6, "west", (55.0, 46.0)),
)


@dataclass
class Node:
    id: int
    name: str
    x: float
    y: float
    role: str = "transit"
    functions: tuple[int, ...] = ()
    queue_for: int | None = None
    zone: int | None = None
    area: str | None = None


@dataclass
class Layout:
    """The plant as it is made: nodes by id, edges as (kind, from, to) with kind "ring",
    "aisle" or "spur", and the lane and aisle nodes by position."""

    nodes: dict[int, Node]
    edges: list[tuple[str, int, int]]
    lane: dict[tuple[float, float], int]

    def add(self, node: Node) -> int:
        assert node.id not in self.nodes, f"node id {node.id} used twice"
        self.nodes[node.id] = node
        return node.id

    def spur(self, lane: tuple[float, float], node: Node) -> int:
        """A node off the lane, joined to the lane node at ``lane`` by a two-way segment."""
        self.edges.append(("spur", self.lane[lane], self.add(node)))
        return node.id


def lane_point(side: str, position: float) -> tuple[float, float]:
    """The point of the ring lane at ``position`` along ``side`` (x or y)."""
    if side in ("north", "south"):
        return position, NORTH_Y if side == "north" else SOUTH_Y
    return WEST_X if side == "west" else EAST_X, position


def moved(point: tuple[float, float], vector: tuple[float, float], d: float) -> tuple[float, float]:
    return point[0] + d * vector[0], point[1] + d * vector[1]


def on_side(side: str, point: tuple[float, float]) -> bool:
    """Whether a point lies on that side of the ring lane (corners lie on two)."""
    x, y = point
    if side in ("north", "south"):
        return y == (NORTH_Y if side == "north" else SOUTH_Y) and WEST_X <= x <= EAST_X
    return x == (WEST_X if side == "west" else EAST_X) and NORTH_Y <= y <= SOUTH_Y


def station_junctions() -> list[tuple[int, str, float, float, int]]:
    """(function, side, junction position, queue junction position, station id) of every
    transfer station, in the order of UNITS."""
    out, made = [], dict.fromkeys(FUNCTIONS, 0)
    for function, side, junctions in UNITS:
        travel = SIDES[side][0]
        along = travel[0] + travel[1]  # +1 or -1: the lane position grows or falls
        for position in junctions:
            made[function] += 1
            sid = function * 10 + made[function]
            out.append((function, side, position, position - along * QUEUE_GAP, sid))
    return out


def lane_points() -> list[list[tuple[float, float]]]:
    """The nodes of the ring lane in driving order from the north-west corner round to it
    again, then those of each aisle (the vertical ones north to south, H west to east)."""
    corners = [(WEST_X, NORTH_Y), (EAST_X, NORTH_Y), (EAST_X, SOUTH_Y), (WEST_X, SOUTH_Y)]
    junctions = [
        lane_point(side, p) for _f, side, *positions, _sid in station_junctions() for p in positions
    ]
    aisles = []
    for north_x, south_x, ys in V_AISLES:
        stops = sorted((NORTH_Y, H_EAST, H_WEST, SOUTH_Y, *ys))
        aisles += [[(north_x, y) for y in reversed(stops)], [(south_x, y) for y in stops]]
    crossings = sorted((WEST_X, EAST_X, *CHARGER_X, *(x for a in V_AISLES for x in a[:2])))
    aisles += [[(x, H_WEST) for x in reversed(crossings)], [(x, H_EAST) for x in crossings]]
    points = set(corners + junctions + [p for aisle in aisles for p in aisle])
    ring = []
    for side, (travel, _wall) in SIDES.items():
        side_points = sorted(
            (p for p in points if on_side(side, p)),
            key=lambda p: p[0] * travel[0] + p[1] * travel[1],
        )
        ring += side_points[:-1]  # the corner at its end starts the next side
    lanes = [ring + ring[:1], *aisles]
    for lane in lanes:
        for a, b in zip(lane, lane[1:], strict=False):
            assert math.dist(a, b) >= MIN_GAP, f"{a} and {b} are too close"
    return lanes


def build() -> Layout:
    layout = Layout({}, [], {})
    lanes = lane_points()
    next_id = 401
    for kind, points in zip(["ring"] + ["aisle"] * (len(lanes) - 1), lanes, strict=True):
        for x, y in points:
            if (x, y) not in layout.lane:
                layout.lane[(x, y)] = layout.add(Node(next_id, f"lane-{x:g}-{y:g}", x, y))
                next_id += 1
        ids = [layout.lane[p] for p in points]
        layout.edges += [(kind, a, b) for a, b in zip(ids, ids[1:], strict=False)]
    for function, side, position, queue_position, sid in station_junctions():
        wall = SIDES[side][1]
        name = f"{FUNCTIONS[function].replace('_', '-')}-{sid % 10}"
        junction, queue_junction = lane_point(side, position), lane_point(side, queue_position)
        approach = Node(200 + sid, f"{name}-approach", *moved(junction, wall, APPROACH))
        approach.zone, approach.area = function, name
        layout.spur(junction, approach)
        layout.add(Node(sid, name, *moved(junction, wall, STATION), "station", (function,)))
        layout.nodes[sid].area = name
        layout.edges.append(("spur", approach.id, sid))
        queue = Node(100 + sid, f"{name}-queue", *moved(queue_junction, wall, QUEUE), "queue")
        queue.queue_for, queue.zone = sid, function
        layout.spur(queue_junction, queue)
    chargers = [
        ((x, y), (0.0, side)) for x in CHARGER_X for y, side in ((H_EAST, -1.0), (H_WEST, 1.0))
    ]
    for k, (junction, direction) in enumerate([*chargers, SOUTH_CHARGER], start=1):
        place = moved(junction, direction, CHARGER_SPUR)
        layout.spur(junction, Node(80 + k, f"charger-{k}", *place, "charger", (CHARGING,)))
        layout.nodes[layout.lane[junction]].zone = CHARGING
    parking = [
        ((x, y), (side, 0.0))
        for south_x, north_x, ys in V_AISLES
        for y in ys
        for x, side in ((south_x, -1.0), (north_x, 1.0))
        if (x, y) != SOUTH_CHARGER[0]
    ]
    for k, (junction, direction) in enumerate(parking, start=1):
        place = moved(junction, direction, PARKING_SPUR)
        layout.spur(junction, Node(300 + k, f"parking-{k}", *place, "parking"))
    _mark_zones(layout)
    assert all(0 <= n.x <= WIDTH and 0 <= n.y <= HEIGHT for n in layout.nodes.values())
    return layout


def _mark_zones(layout: Layout) -> None:
    """A unit's zone on the ring lane: from its first queue junction to its last station
    junction, with the ends of the aisles between them."""
    ranges: dict[tuple[int, str], list[float]] = {}
    for function, side, position, queue_position, _sid in station_junctions():
        ranges.setdefault((function, side), []).extend((position, queue_position))
    for (function, side), positions in ranges.items():
        for point, node in layout.lane.items():
            along = point[0] if side in ("north", "south") else point[1]
            if on_side(side, point) and min(positions) <= along <= max(positions):
                assert layout.nodes[node].zone is None, f"{point} lies in two zones"
                layout.nodes[node].zone = function


def _value(value: object) -> str:
    """The TOML spelling of a value of this file: floats rounded to centimetres, strings
    without quotes or backslashes in them (names of our own making)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, tuple):
        return "[" + ", ".join(map(_value, value)) + "]"
    if isinstance(value, float):
        return repr(round(value, 2))
    if isinstance(value, str):
        return f'"{value}"'
    return str(value)


def _table(pairs: dict[str, object]) -> str:
    return (
        "{ "
        + ", ".join(f"{k} = {_value(v)}" for k, v in pairs.items() if v not in (None, ()))
        + " }"
    )


def toml_text(layout: Layout) -> str:
    nodes = layout.nodes
    lines = [
        "# Written by make_distribution_centre.py, whose docstring explains the layout: change",
        "# the script and re-run it rather than editing this file.",
        "",
        'name = "distribution-centre"',
        "",
        *(f'functions.{f} = "{name}"' for f, name in FUNCTIONS.items()),
        "",
        "nodes = [",
    ]

    def section(title: str, ids: list[int]) -> None:
        lines.append(f"  # ----- {title}")
        for i in ids:
            n = nodes[i]
            lines.append(
                "  "
                + _table(
                    {
                        "id": n.id,
                        "name": n.name,
                        "x": n.x,
                        "y": n.y,
                        "role": None if n.role == "transit" else n.role,
                        "functions": n.functions,
                        "queue_for": n.queue_for,
                        "zone": n.zone,
                        "area": n.area,
                    }
                )
                + ","
            )

    for function, name in FUNCTIONS.items():
        stations = sorted(i for i, n in nodes.items() if n.functions == (function,))
        if function == CHARGING:
            section(f"chargers, function {function}", stations)
            continue
        places = [i for s in stations for i in (s, 200 + s, 100 + s)]
        section(f"{name}, function {function}: station, approach, queue", places)
    section("parking places", sorted(i for i, n in nodes.items() if n.role == "parking"))
    section("lane and aisle nodes", sorted(layout.lane.values()))
    lines += ["]", "", "edges = ["]
    titles = {
        "ring": "the ring lane, one-way: east on the north wall, south, west, north",
        "aisle": "the cross aisles, two one-way lanes each, driven on the left",
        "spur": "spurs to stations, queues, chargers and parking places, two-way",
    }
    for kind, title in titles.items():
        lines.append(f"  # ----- {title}")
        for _kind, a, b in (e for e in layout.edges if e[0] == kind):
            length = math.dist((nodes[a].x, nodes[a].y), (nodes[b].x, nodes[b].y))
            directed = True if kind in ("ring", "aisle") else None
            edge = {
                "from": a,
                "to": b,
                "length": length,
                "directed": directed,
                "max_speed": MAX_SPEED,
            }
            lines.append(f"  {_table(edge)},")
    lines += ["]", ""]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="file to write")
    args = parser.parse_args()
    args.out.write_text(toml_text(build()), encoding="utf-8")


if __name__ == "__main__":
    main()
