"""Highways: two-way lanes with a preferred direction, priced by both traffic modes.

A highway edge stays drivable both ways; driving against it costs ``highway_factor`` times
its length (reactive A*: that much extra per arc; time-window searches: that factor on the
travel time). The plant format reads and writes the key, validation refuses it where it
means nothing, and on a ring a vehicle takes the long way round with the lanes rather than
the short way against them, in both modes, only while the factor makes that cheaper."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from fleet_scenarios import make_config, run

from blocks.traffic.reservation import ReservationMatrix
from blocks.traffic.tw_traffic import TimeWindowTraffic
from fleet.config import DEFAULT_CONFIG, parse_config
from fleet.program import FleetProgram
from plc_runtime.errors import ConfigError
from topology import Edge, Node, Plant
from topology.errors import TopologyError
from topology.formats.structured import from_dict, to_dict

M = 12  # ring nodes


def ring(highways: bool = True) -> Plant:
    """A ring of 12 nodes 1 m apart, its lanes preferred k -> k + 1 (anticlockwise), the
    only station at node 7: 7 steps with the lanes from node 0, 5 steps against them."""
    nodes = [
        Node(k, f"r{k}", 2 * math.cos(2 * math.pi * k / M), 2 * math.sin(2 * math.pi * k / M))
        for k in range(M)
    ]
    nodes[7] = Node(7, "r7", nodes[7].x, nodes[7].y, "station", (2,))
    edges = [Edge(k, (k + 1) % M, 1.0, highway=highways) for k in range(M)]
    return Plant.build(nodes, edges, name="ring", functions={2: "a"})


def test_against_highway_marks_the_reverse_arc_of_each_highway_edge():
    plant = Plant.build(
        [Node(0, "", 0, 0), Node(1, "", 1, 0), Node(2, "", 2, 0), Node(3, "", 3, 0)],
        [
            Edge(0, 1, 1.0, highway=True),
            Edge(1, 2, 1.0),
            Edge(3, 2, 1.0, highway=True),
            Edge(2, 0, 2.0, bidirectional=False),
        ],
    )
    src, dst, _ = plant.arcs
    against = {
        (int(plant.ids[u]), int(plant.ids[v]))
        for u, v, a in zip(src, dst, plant.against_highway, strict=True)
        if a
    }
    assert against == {(1, 0), (2, 3)}
    assert (
        plant.fingerprint
        != Plant.build(
            plant.nodes,
            [
                Edge(e.source, e.target, e.length, bidirectional=e.bidirectional)
                for e in plant.edges
            ],
        ).fingerprint
    )


def test_the_plant_format_reads_and_writes_highways():
    plant = ring()
    document = json.loads(json.dumps(to_dict(plant)))
    assert all(edge["highway"] is True for edge in document["edges"])
    again = from_dict(document, "ring.json")
    assert again.fingerprint == plant.fingerprint
    assert "highway" not in to_dict(ring(highways=False))["edges"][0]


@pytest.mark.parametrize(
    "change, message",
    [
        ({"highway": "yes"}, "highway"),
        ({"highway": True, "directed": True}, "highway on a directed edge"),
        ({"highway": True, "routable": False}, "highway on an edge that is not routable"),
        ({"highway": True, "from": 3, "to": 2}, "highway undone by edges[3]"),
        ({"from": 3, "to": 2}, "lets vehicles drive 3 -> 2 at no extra cost"),
        ({"from": 2, "to": 3}, "highway undone by edges[3]"),
        ({"from": 3, "to": 2, "directed": True}, "highway undone by edges[3]"),
    ],
)
def test_a_bad_highway_names_the_edge_and_what_is_wrong(change, message):
    document = to_dict(ring(highways=False))
    document["edges"][2]["highway"] = True  # 2 -> 3
    document["edges"][3].update(change)  # 3 -> 4
    with pytest.raises(TopologyError) as caught:
        from_dict(document, "ring.json")
    text = str(caught.value)
    assert "ring.json" in text and "edges[3]" in text and message in text


def test_an_edge_beside_a_highway_that_cannot_undo_it_is_accepted():
    """A one-way edge the preferred way, or one that is not routable, leaves the way back
    priced."""
    for change in ({"from": 2, "to": 3, "directed": True}, {"from": 3, "to": 2, "routable": False}):
        document = to_dict(ring(highways=False))
        document["edges"][2]["highway"] = True  # 2 -> 3
        document["edges"][3].update(change)
        plant = from_dict(document, "ring.json")
        assert plant.against_highway.sum() == 1


def test_reactive_routes_pay_the_factor_against_a_highway_only():
    plant = ring()
    reservation = ReservationMatrix(plant, [1], highway_factor=4.0)
    out = reservation.penalties_for(1, np.zeros(plant.n_arcs))
    _, _, length = plant.arcs
    assert np.allclose(out, np.where(plant.against_highway, 3.0 * length, 0.0))
    assert plant.against_highway.sum() == M
    with pytest.raises(ValueError, match="highway_factor"):
        ReservationMatrix(plant, [1], highway_factor=0.5)


def test_the_factor_is_read_from_the_routing_table_and_checked():
    text = DEFAULT_CONFIG.read_text()
    assert parse_config(text, "fleet.toml").highway_factor == 3.0
    changed = text.replace("[routing]\n", "[routing]\nhighway_factor = 1.5\n", 1)
    assert parse_config(changed, "fleet.toml").highway_factor == 1.5
    bad = text.replace("[routing]\n", "[routing]\nhighway_factor = 0.5\n", 1)
    with pytest.raises(ConfigError) as caught:
        parse_config(bad, "fleet.toml")
    assert "fleet.toml" in str(caught.value) and "highway_factor" in str(caught.value)


def drive_to_station(traffic: str, factor: float, highways: bool = True) -> list[int]:
    cfg = make_config(
        ring(highways),
        {1: 0},
        {"a": [2]},
        {2: [7]},
        processing_s=1.0,
        cycle_time=0.05,
        rounds=1,
        traffic=traffic,
        highway_factor=factor,
    )
    program = FleetProgram(cfg)
    try:
        run(program, 40)
    finally:
        program.close()
    assert program.completed, "the vehicle never reached its station"
    driven = program.recorder.driven[1]
    return driven[: driven.index(7) + 1]


@pytest.mark.parametrize("traffic", ["reactive", "time_windows"])
def test_a_vehicle_goes_round_with_the_lanes_while_that_is_cheaper(traffic):
    with_lanes = list(range(8))  # 7 m with the lanes
    against = [0, 11, 10, 9, 8, 7]  # 5 m against them
    assert drive_to_station(traffic, 3.0) == with_lanes  # 7 < 5 x 3
    assert drive_to_station(traffic, 1.0) == against  # the factor 1 ignores highways
    assert drive_to_station(traffic, 3.0, highways=False) == against
    assert drive_to_station(traffic, 1.3) == against  # 7 > 5 x 1.3: the short way still


def test_time_window_searches_get_the_factor_on_arcs_against_a_highway():
    cfg = make_config(ring(), {1: 0}, {"a": [2]}, {2: [7]}, traffic="time_windows")
    program = FleetProgram(cfg)
    try:
        traffic: TimeWindowTraffic = program.traffic
        weights = traffic._arc_weights()
        assert weights == [3.0 if a else 1.0 for a in program.cfg.plant.against_highway]
        traffic.path_heat = True
        heat = [1.0 + (arc % 3) / 2 for arc in range(len(weights))]
        traffic._heat = lambda: heat
        assert traffic._arc_weights() == [h * w for h, w in zip(heat, weights, strict=True)]
    finally:
        program.close()
    plain = make_config(ring(highways=False), {1: 0}, {"a": [2]}, {2: [7]}, traffic="time_windows")
    program = FleetProgram(plain)
    try:
        assert program.traffic._arc_weights() is None
    finally:
        program.close()


def test_the_web_api_shows_which_edges_are_highways():
    from fleet.web.models import PlantOut
    from fleet.web.views import plant as plant_view

    body = PlantOut.model_validate(plant_view(ring(), [])).model_dump()
    assert [(e["a"], e["b"], e["highway"]) for e in body["edges"]] == [
        (k, (k + 1) % M, True) for k in range(M)
    ]
    plain = PlantOut.model_validate(plant_view(ring(highways=False), [])).model_dump()
    assert not any(e["highway"] for e in plain["edges"])


def test_the_route_command_prices_highways_as_the_fleet_does(capsys):
    from fleet.cli import main as cli
    from fleet.route import find_route
    from topology import kiva

    plant = kiva()
    west_on_row_0 = list(range(40, 29, -1))  # row 0 prefers east: 10 m against it
    along_row_1 = find_route(plant, 40, 30)  # the fleet's default factor, 3
    assert along_row_1["route"][1] == 86 and along_row_1["cost"] == 12.0
    assert find_route(plant, 40, 30, highway_factor=1.0)["route"] == west_on_row_0
    assert cli(["route", "kiva", "--from", "40", "--to", "30", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["highway_factor"] == 3.0
    with pytest.raises(SystemExit) as refused:  # the argument parser refuses it
        cli(["route", "kiva", "--from", "40", "--to", "30", "--highway-factor", "0.5"])
    assert refused.value.code == 2
    assert "--highway-factor: must be a finite number >= 1: '0.5'" in capsys.readouterr().err


def test_a_drawing_shows_each_highway_direction_with_a_faint_arrow():
    from matplotlib.colors import to_rgb

    from topology.draw import HIGHWAY_ARROW, render

    def heads(plant):
        picture = render(plant)
        faint = [p for p in picture.axes.patches if p.get_facecolor()[:3] == to_rgb(HIGHWAY_ARROW)]
        return [p._posA_posB for p in faint]  # (tail, tip) of each arrow head

    arrows = heads(ring())
    assert len(arrows) == M
    for (x0, y0), (x1, y1) in arrows:
        # k -> k + 1 runs anticlockwise in the file, clockwise as drawn (y points down)
        assert x0 * y1 - y0 * x1 < 0
    assert heads(ring(highways=False)) == []
