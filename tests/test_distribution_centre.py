"""The sample distribution centre (examples/plants/distribution-centre.toml): what its script
makes, that the CLI accepts and draws it, and that it has what the order-allocation study's
plant has: every unit its stations, every transfer station a queue node and a single-vehicle
area, cluster zones, chargers, parking places off the lanes, a one-way ring lane, and every
node reachable from every other."""

import math
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest
from scipy.sparse.csgraph import connected_components

from fleet.cli import main
from topology import load

PLANTS = Path(__file__).resolve().parent.parent / "examples" / "plants"
PLANT = PLANTS / "distribution-centre.toml"
UNITS = {  # function id -> (name, stations)
    2: ("receiving", 4),
    3: ("hrl", 5),
    4: ("depalletising", 3),
    5: ("picking", 4),
    6: ("empty_pallets", 2),
    7: ("control", 1),
}
CHARGING = 8


@pytest.fixture(scope="module")
def plant():
    return load(PLANT)


def neighbours(plant, node: int) -> set[int]:
    return {e.target for e in plant.edges if e.source == node} | {
        e.source for e in plant.edges if e.target == node
    }


def test_the_file_is_what_its_script_makes(tmp_path):
    out = tmp_path / "distribution-centre.toml"
    subprocess.run(
        [sys.executable, str(PLANTS / "make_distribution_centre.py"), "--out", str(out)],
        check=True,
        timeout=60,
    )
    assert out.read_bytes() == PLANT.read_bytes()


def test_the_cli_validates_and_draws_it(tmp_path, capsys):
    assert main(["plant", "validate", str(PLANT)]) == 0
    out = capsys.readouterr().out
    assert "valid plant 'distribution-centre'" in out and "warning" not in out
    png = tmp_path / "dc.png"
    assert main(["plant", "show", str(PLANT), "--png", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def test_size_and_speed_are_the_studys(plant):
    assert 100 <= plant.n <= 200 and plant.warnings == ()
    xs, ys = plant.positions.T
    assert xs.min() >= 0 and xs.max() <= 87 and ys.min() >= 0 and ys.max() <= 72
    assert {e.max_speed for e in plant.edges} == {1.5}
    for e in plant.edges:  # lengths are the distances: the Euclidean heuristic is exact
        a, b = plant.node(e.source), plant.node(e.target)
        assert e.length == pytest.approx(math.dist((a.x, a.y), (b.x, b.y)), abs=0.01)


def test_every_unit_has_its_stations(plant):
    assert plant.functions == {f: name for f, (name, _n) in UNITS.items()} | {8: "charging"}
    for function, (_name, count) in UNITS.items():
        stations = plant.stations_for(function)
        assert len(stations) == count
        assert all(plant.node(s).role == "station" for s in stations)
    chargers = plant.stations_for(CHARGING)
    assert len(chargers) >= 4 and set(chargers) == set(plant.with_role("charger"))
    assert not plant.with_role("entry") and not plant.with_role("exit")


def test_every_transfer_station_has_a_queue_off_the_lane(plant):
    stations = plant.with_role("station")
    assert len(stations) == sum(n for _name, n in UNITS.values())
    assert set(plant.queues) == set(stations)
    for station, queues in plant.queues.items():
        for queue in queues:
            node = plant.node(queue)
            assert node.role == "queue" and node.queue_for == station
            assert len(neighbours(plant, queue)) == 1  # a spur: nobody drives through it


def test_every_transfer_station_is_a_single_vehicle_area_with_its_approach(plant):
    for station in plant.with_role("station"):
        name = plant.node(station).name
        (approach,) = neighbours(plant, station)  # a spur, entered through its approach
        assert plant.node(station).area == name
        assert set(plant.areas[name]) == {station, approach}
        assert plant.node(approach).role == "transit"
    assert len(plant.areas) == len(plant.with_role("station"))


def test_cluster_zones_hold_each_units_places(plant):
    seen: Counter[int] = Counter()
    for function in [*UNITS, CHARGING]:
        zone = plant.zones[function]
        assert set(plant.stations_for(function)) <= zone
        for station in plant.stations_for(function):
            assert set(plant.queues.get(station, ())) <= zone
        assert len(zone) > len(plant.stations_for(function))  # marked nodes around the unit
        seen.update(zone)
    assert max(seen.values()) == 1  # no node lies in two zones


def test_parking_places_are_off_the_lanes(plant):
    parking = plant.with_role("parking")
    assert len(parking) >= 17
    assert all(len(neighbours(plant, p)) == 1 for p in parking)
    for charger in plant.with_role("charger"):
        assert len(neighbours(plant, charger)) == 1


def test_every_lane_is_one_way_and_the_ring_is_one_cycle(plant):
    lanes = {n.id for n in plant.nodes if n.name.startswith("lane-")}
    # two-way segments only lead into spurs: no two vehicles can meet head-on on a lane
    assert all(
        not (e.source in lanes and e.target in lanes) for e in plant.edges if e.bidirectional
    )
    xs = [plant.node(i).x for i in lanes]
    ys = [plant.node(i).y for i in lanes]
    west, east, north, south = min(xs), max(xs), min(ys), max(ys)
    ring = {
        n.id
        for n in plant.nodes
        if n.id in lanes and (n.x in (west, east) or n.y in (north, south))
    }
    successor = {
        e.source: e.target
        for e in plant.edges
        if not e.bidirectional and e.source in ring and e.target in ring
    }
    assert set(successor) == ring and set(successor.values()) == ring  # in 1, out 1
    start = min(ring)
    node, steps = successor[start], 1
    while node != start:
        node, steps = successor[node], steps + 1
    assert steps == len(ring) >= 40  # a single cycle round the hall


def test_every_node_reaches_every_other(plant):
    assert all(e.routable for e in plant.edges)
    n_components, _labels = connected_components(plant.csr, directed=True, connection="strong")
    assert n_components == 1
