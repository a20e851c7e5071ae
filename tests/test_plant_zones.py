"""Queue nodes, cluster zones and single-vehicle areas in the plant model and its formats."""

import json

import pytest

from topology import ROLES, Edge, Node, Plant, TopologyError, load, model_plant
from topology.draw import ROLE_STYLE
from topology.formats import dump_json, dump_toml

# entry 0 - 1 - 2 - exit 3 along a line; stations 10 (drill) and 11 (mill) on spurs off 1
# and 2 with approach nodes 20 and 21; queue 30 waits for 10, queues 31 and 32 for 11.
NODES = [
    Node(0, "entry", 0.0, 0.0, "entry", (0,)),
    Node(1, "", 2.0, 0.0, zone=2),
    Node(2, "", 4.0, 0.0, zone=3),
    Node(3, "exit", 6.0, 0.0, "exit", (1,)),
    Node(20, "drill-approach", 2.0, 1.0, zone=2, area="drill"),
    Node(10, "drill", 2.0, 2.0, "station", (2,), area="drill"),
    Node(21, "mill-approach", 4.0, 1.0, zone=3, area="mill"),
    Node(11, "mill", 4.0, 2.0, "station", (3,), area="mill"),
    Node(30, "drill-queue", 1.0, 1.0, "queue", queue_for=10, zone=2),
    Node(31, "mill-queue-1", 3.0, 1.0, "queue", queue_for=11, zone=3),
    Node(32, "mill-queue-2", 5.0, 1.0, "queue", queue_for=11),
]
EDGES = [
    Edge(0, 1, 2.0),
    Edge(1, 2, 2.0),
    Edge(2, 3, 2.0),
    Edge(1, 20, 1.0),
    Edge(20, 10, 1.0),
    Edge(2, 21, 1.0),
    Edge(21, 11, 1.0),
    Edge(0, 30, 1.5),
    Edge(1, 31, 1.5),
    Edge(2, 32, 1.5),
]
FUNCTIONS = {0: "entry", 1: "exit", 2: "drill", 3: "mill"}


def cell() -> Plant:
    return Plant.build(NODES, EDGES, "cell", FUNCTIONS)


def test_queues_zones_and_areas():
    plant = cell()
    assert plant.queues == {10: (30,), 11: (31, 32)}
    assert plant.zones == {
        0: frozenset({0}),
        1: frozenset({3}),
        2: frozenset({1, 10, 20, 30}),  # the station is in its own zone unmarked
        3: frozenset({2, 11, 21, 31}),
    }
    assert plant.areas == {"drill": (20, 10), "mill": (21, 11)}
    assert plant.with_role("queue") == [30, 31, 32]
    assert 30 not in plant.targets  # a queue is a place to wait, not a route's default end
    summary = plant.summary()
    assert summary["roles"]["queue"] == 3
    assert summary["queues"] == {10: [30], 11: [31, 32]}
    assert summary["zones"][2] == [1, 10, 20, 30]
    assert summary["areas"] == {"drill": [20, 10], "mill": [21, 11]}


def test_without_marks_a_zone_is_the_units_stations():
    plant = model_plant()
    assert plant.queues == {} and plant.areas == {}
    assert plant.zones[2] == frozenset(plant.stations_for(2)) == frozenset({15, 22})


@pytest.mark.parametrize("suffix,dump", [(".toml", dump_toml), (".json", dump_json)])
def test_round_trip_through_files(tmp_path, suffix, dump):
    plant = cell()
    path = tmp_path / f"cell{suffix}"
    path.write_text(dump(plant))
    again = load(path)
    assert again.nodes == plant.nodes and again.edges == plant.edges
    assert again.fingerprint == plant.fingerprint
    assert (again.queues, again.zones, again.areas) == (plant.queues, plant.zones, plant.areas)


def test_json_null_means_not_set(tmp_path):
    doc = json.loads(dump_json(cell()))
    doc["nodes"][1].update(zone=None, area=None, queue_for=None)
    path = tmp_path / "cell.json"
    path.write_text(json.dumps(doc))
    node = load(path).node(1)
    assert (node.zone, node.area, node.queue_for) == (None, None, None)


@pytest.mark.parametrize(
    "change",
    [
        {"zone": 3},
        {"area": "other"},
        {"zone": None},
    ],
)
def test_fingerprint_sees_zones_and_areas(change):
    plant = cell()
    nodes = [n if n.id != 20 else Node(**{**_fields(n), **change}) for n in NODES]
    assert Plant.build(nodes, EDGES, "cell", FUNCTIONS).fingerprint != plant.fingerprint


def test_fingerprint_sees_queues():
    nodes = [n if n.id != 32 else Node(**{**_fields(n), "queue_for": 10}) for n in NODES]
    assert Plant.build(nodes, EDGES, "cell", FUNCTIONS).fingerprint != cell().fingerprint


def _fields(node: Node) -> dict:
    return {name: getattr(node, name) for name in Node.__slots__}


def test_every_role_is_drawn():
    assert set(ROLE_STYLE) == set(ROLES)


# ----- errors: the file, the node, the field, what is wrong ---------------------------------
BASE = """
[functions]
2 = "drill"

[[nodes]]
id = 0
role = "entry"

[[nodes]]
id = 1
x = 1.0
role = "station"
functions = [2]

[[nodes]]
id = 5
x = 0.5
y = 1.0
{extra}

[[edges]]
from = 0
to = 1
length = 1.0

[[edges]]
from = 0
to = 5
length = 1.2
"""


@pytest.mark.parametrize(
    "extra,message",
    [
        ('role = "queue"', "nodes[2] (id 5): a queue node needs queue_for = <id of the station"),
        (
            "queue_for = 1",
            "nodes[2] (id 5): queue_for is only for queue nodes, this one has role 'transit'",
        ),
        ('role = "queue"\nqueue_for = "1"', "nodes[2]: queue_for must be an integer, got '1'"),
        (
            'role = "queue"\nqueue_for = 9',
            "nodes[2] (id 5): queue_for names node 9, which is not in the plant",
        ),
        (
            'role = "queue"\nqueue_for = 0',
            "nodes[2] (id 5): queue_for names node 0, whose role is 'entry': "
            "a queue waits for a station",
        ),
        (
            'role = "queue"\nqueue_for = 1\nfunctions = [2]',
            "nodes[2] (id 5): a queue node cannot provide functions",
        ),
        ("zone = 7", "nodes[2] (id 5): zone 7 is not a function of the plant (its functions: 2)"),
        ("zone = 2.0", "nodes[2]: zone must be an integer, got 2.0"),
        ('area = ""', "nodes[2] (id 5): area must be a non-empty name, got ''"),
        ('area = "  "', "nodes[2] (id 5): area must be a non-empty name, got '  '"),
        ("area = 3", "nodes[2]: area must be a string, got 3"),
        ("areas = 3", "nodes[2]: unknown key(s): areas"),
    ],
)
def test_errors_name_file_node_and_field(tmp_path, extra, message):
    path = tmp_path / "plant.toml"
    path.write_text(BASE.format(extra=extra))
    with pytest.raises(TopologyError) as err:
        load(path)
    assert str(err.value).startswith(f"{path}: {message}")


def test_base_plant_of_the_error_cases_is_valid(tmp_path):
    path = tmp_path / "plant.toml"
    path.write_text(BASE.format(extra='role = "queue"\nqueue_for = 1\nzone = 2\narea = "a"'))
    plant = load(path)
    assert plant.queues == {1: (5,)} and plant.zones[2] == {1, 5} and plant.areas == {"a": (5,)}


@pytest.mark.parametrize(
    "node,message",
    [
        (
            Node(5, role="queue", queue_for=True),
            "queue_for must be a node id 0..2147483647, got True",
        ),
        (Node(5, role="queue", queue_for=-1), "queue_for must be a node id 0..2147483647, got -1"),
        (
            Node(5, role="queue", queue_for=[1]),
            "queue_for must be a node id 0..2147483647, got [1]",
        ),
        (Node(5, zone=-2), "zone must be a function id 0..2147483647, got -2"),
        (Node(5, zone=[2]), "zone must be a function id 0..2147483647, got [2]"),
        (Node(5, area=3), "area must be a non-empty name, got 3"),
    ],
)
def test_plants_built_in_code_are_checked_too(node, message):
    nodes = [Node(0, role="entry"), Node(1, role="station", functions=(2,)), node]
    edges = [Edge(0, 1, 1.0), Edge(0, 5, 1.0)]
    with pytest.raises(TopologyError) as err:
        Plant.build(nodes, edges, source="code")
    assert str(err.value) == f"code: nodes[2] (id 5): {message}"
