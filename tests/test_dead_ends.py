"""Dead ends (topology/dead_ends.py), and why the time-window planner keeps vehicles out of
one another vehicle is bound for: waiting in a station's spur, a vehicle can only come out
through the node in front of it, where the vehicle sent to that station stops and waits for
it to leave."""

import importlib.util
import sys
from pathlib import Path

import numpy as np

from fleet.program import FleetProgram
from topology import Edge, Node, Plant, kiva
from topology.dead_ends import NO_POCKET, dead_end_pockets, pocket_entries

ROOT = Path(__file__).resolve().parent.parent
spec = importlib.util.spec_from_file_location("bench_allocation", ROOT / "bench" / "allocation.py")
allocation = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = allocation
spec.loader.exec_module(allocation)


def plant_of(edges: list[tuple[int, int]], one_way: set[tuple[int, int]] = frozenset()) -> Plant:
    ids = sorted({n for e in edges for n in e})
    nodes = [Node(n, f"n{n}", float(n), float(n % 3)) for n in ids]
    return Plant.build(
        nodes, [Edge(a, b, 1.0, bidirectional=(a, b) not in one_way) for a, b in edges]
    )


def pockets_by_id(plant: Plant) -> dict[int, set[int]]:
    pocket = dead_end_pockets(plant)
    out: dict[int, set[int]] = {}
    for i, root in enumerate(pocket.tolist()):
        if root != NO_POCKET:
            out.setdefault(int(plant.ids[root]), set()).add(int(plant.ids[i]))
    return out


def test_spurs_and_sidings_off_a_ring_are_pockets_named_by_the_node_next_to_the_ring():
    # a one-way ring 1-2-3-4, a two-node spur 2-10-11 with a branch 10-12, a siding 4-20,
    # and a second siding 4-30 off the same ring node: each its own pocket
    ring = [(1, 2), (2, 3), (3, 4), (4, 1)]
    p = plant_of([*ring, (2, 10), (10, 11), (10, 12), (4, 20), (4, 30)], one_way=set(ring))
    assert pockets_by_id(p) == {10: {10, 11, 12}, 20: {20}, 30: {30}}
    pocket = dead_end_pockets(p)
    entries = pocket_entries(p, pocket)
    src, dst, _ = p.arcs
    into = {
        int(p.ids[root]): sorted((int(p.ids[src[a]]), int(p.ids[dst[a]])) for a in arcs)
        for root, arcs in entries.items()
    }
    # only the arc from the ring into each pocket: closing it closes the whole pocket
    assert into == {10: [(2, 10)], 20: [(4, 20)], 30: [(4, 30)]}


def test_a_plant_without_a_cycle_and_a_grid_have_no_pockets():
    line = plant_of([(1, 2), (2, 3), (3, 4)])
    assert pockets_by_id(line) == {}  # no part of a line is more of a dead end than another
    assert (dead_end_pockets(kiva()) == NO_POCKET).all()


def test_a_tree_beside_a_ring_is_no_pocket_of_it():
    # two separate parts: a ring with a spur, and a line of their own
    p = plant_of([(1, 2), (2, 3), (3, 1), (3, 9), (5, 6), (6, 7)])
    assert pockets_by_id(p) == {9: {9}}


def mouths(plant: Plant) -> dict[int, int]:
    """Pocket root index -> the index of the node in front of it."""
    src, dst, _ = plant.arcs
    pocket = dead_end_pockets(plant)
    return {root: int(src[arcs[0]]) for root, arcs in pocket_entries(plant, pocket).items()}


def test_on_the_distribution_centre_no_vehicle_waits_in_a_spur_another_is_sent_into():
    """The seed's plant on time-window traffic (dhht, 17 vehicles, 150 orders at once): a
    vehicle waiting for the lane ahead was planned aside into a station's spur (its
    approach, part of the station's area), and the vehicle given that station drove to the
    node in front of the spur and waited for the area to clear; the one inside could only
    leave through that node. Both waited for ever, and the lane behind them filled (the
    benchmark's run stopped at 43 of 150 orders). An independent watch, every second: no
    vehicle stands in a dead end it is not bound for while a vehicle bound for that dead
    end stands in front of it, for more than a minute; and the orders go on being
    finished."""
    case = allocation.Case("fleet", "dhht", 17, 1, 150, traffic="time_windows")
    cfg = allocation.load_config(allocation.CONFIG)
    allocation.first_vehicles(cfg, 17)
    cfg.dispatch.strategy, cfg.traffic, cfg.watchdog = "dhht", "time_windows", 5.0
    cfg.battery.enabled = False
    orders = allocation.orders_for(case, cfg)
    plant = cfg.plant
    pocket, mouth = dead_end_pockets(plant), mouths(plant)
    index = plant.index
    path = Path(allocation.tempfile.mkdtemp()) / "orders.csv"
    allocation.write_orders(path, orders)
    cfg.orders.file, cfg.orders.generator, cfg.orders.lead_s = path, None, 1e9
    program = FleetProgram(cfg)
    facing: dict[tuple[int, int], int] = {}  # (inside, in front) -> seconds so far
    longest = 0
    try:
        program.rt.start()
        per_s = round(1.0 / cfg.cycle_time)
        for _ in range(600):
            program.rt.run(cycles=per_s)
            now = {}
            for v, inside in program.controls.items():
                if inside.current is None:
                    continue
                root = int(pocket[index[inside.current]])
                goal = inside.goal
                if root == NO_POCKET or (goal is not None and pocket[index[goal]] == root):
                    continue
                for w, other in program.controls.items():
                    bound = other.goal is not None and pocket[index[other.goal]] == root
                    if w != v and bound and other.current == int(plant.ids[mouth[root]]):
                        now[(v, w)] = facing.get((v, w), 0) + 1
            facing = now
            longest = max([longest, *facing.values()])
        finished = program.orders.book.counts()["FINISHED"]
        conflicts = program.monitor.head_on + program.monitor.node + program.monitor.area
    finally:
        program.close()
        path.unlink()
        path.parent.rmdir()
    assert longest <= 60, longest
    assert conflicts == 0
    # 31 finished in these 600 s; 21 when two vehicles faced each other from 312 s on
    assert finished >= 25, finished
    assert np.count_nonzero(pocket != NO_POCKET) == 81  # every station spur and siding
