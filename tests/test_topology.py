"""Plant model, file formats and validation."""

import copy
import json
import math
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from topology import (
    Edge,
    Node,
    Plant,
    TopologyError,
    grid,
    load,
    load_scenarios,
    model_plant,
    read_cells,
    warehouse,
)
from topology.formats import dump_json, dump_toml

MOVINGAI = Path(__file__).resolve().parents[2] / "shared" / "data" / "movingai"


def test_model_plant_matches_the_thesis():
    plant = model_plant()
    assert plant.n == 25 and len(plant.targets) == 10 and plant.warnings == ()
    assert plant.node(0).role == "entry" and plant.node(24).role == "exit"
    assert sorted(plant.stations_for(2)) == [15, 22]  # a function cluster of two stations
    return_lane = [e for e in plant.edges if not e.routable]
    assert [(e.source, e.target) for e in return_lane] == [(24, 0)]
    assert (24, 0) not in plant.arc_index  # routing ignores it
    station_exits = [e for e in plant.edges if plant.node(e.source).role == "station"]
    assert station_exits and all(not e.bidirectional for e in station_exits)


@pytest.mark.parametrize("make", [model_plant, warehouse, lambda: grid(12, 9, 0.2, seed=5)])
@pytest.mark.parametrize("suffix,dump", [(".toml", dump_toml), (".json", dump_json)])
def test_round_trip_through_files(tmp_path, make, suffix, dump):
    plant = make()
    path = tmp_path / f"plant{suffix}"
    path.write_text(dump(plant))
    again = load(path)
    assert again.fingerprint == plant.fingerprint
    assert (
        again.nodes == plant.nodes
        and again.edges == plant.edges
        and again.functions == plant.functions
    )


def test_warehouse_is_the_fulfilment_size():
    plant = warehouse()
    assert plant.name == "warehouse-33x46" and plant.n > 1000
    assert len(plant.with_role("station")) == 22 and plant.warnings == ()


def test_grid_is_seeded():
    assert grid(20, 20, 0.3, seed=1).fingerprint == grid(20, 20, 0.3, seed=1).fingerprint
    assert grid(20, 20, 0.3, seed=1).fingerprint != grid(20, 20, 0.3, seed=2).fingerprint


def test_movingai_ids_follow_the_benchmark(tmp_path):
    path = tmp_path / "tiny.map"
    path.write_text("type octile\nheight 3\nwidth 4\nmap\n..@.\n.T..\nG...\n")
    plant = load(path, cell_size=0.5)
    assert sorted(plant.ids.tolist()) == [0, 1, 3, 4, 6, 7, 8, 9, 10, 11]
    assert plant.node(6).x == 1.0 and plant.node(6).y == 0.5  # cell (2, 1)
    assert (0, 1) in plant.arc_index and (1, 2) not in plant.arc_index and (3, 7) in plant.arc_index
    assert plant.csr[0, 1] == 0.5


def test_movingai_reads_the_robot_runners_cells(tmp_path):
    """The League of Robot Runners writes its maps in this format with E (emitter) and S
    (service) cells, both free; S is also MovingAI's swamp, passable from ground. W (water)
    stays blocked."""
    path = tmp_path / "warehouse_small.map"
    path.write_text("type octile\nheight 2\nwidth 5\nmap\n@.E@S\n.EW..\n")
    cells = read_cells(path)
    assert cells.tolist() == [
        [False, True, True, False, True],
        [True, True, False, True, True],
    ]
    plant = load(path)
    assert sorted(plant.ids.tolist()) == [1, 2, 4, 5, 6, 8, 9]
    assert (1, 2) in plant.arc_index and (4, 9) in plant.arc_index and (2, 7) not in plant.arc_index


@pytest.mark.parametrize(
    "text,message",
    [
        ("type octile\nheight 2\nwidth 3\nmap\n...\n", "truncated: 1 of 2 rows"),
        ("type octile\nheight 1\nwidth 3\nmap\n..\n", "line 5: row has 2 cells, expected 3"),
        ("type octile\nheight 1\nwidth 3\nmap\n.X.\n", "line 5: unknown cell 'X' at column 2"),
        ("type octile\nheight 1\nwidth 3\nmap\n.e.\n", "line 5: unknown cell 'e' at column 2"),
        # a form feed or a line separator is a stray character, not the end of a row
        (
            "type octile\nheight 2\nwidth 3\nmap\n.\x0c.\n...\n",
            r"line 5: unknown cell '\\x0c' at column 2",
        ),
        (
            "type octile\nheight 2\nwidth 3\nmap\n...\n.\u2028.\n",
            r"line 6: unknown cell '\\u2028' at col",
        ),
        ("type octile\rheight 1\rwidth 3\rmap\r...\r", "line 1: expected 'type'"),
        ("height x\nwidth 3\nmap\n", "integer 'height' and 'width'"),
        ("hello\n", "line 1: expected 'type'"),
    ],
)
def test_movingai_errors_name_the_line(tmp_path, text, message):
    path = tmp_path / "bad.map"
    path.write_text(text)
    with pytest.raises(TopologyError, match=message) as err:
        load(path)
    assert str(path) in str(err.value)


@pytest.mark.skipif(not MOVINGAI.exists(), reason="shared MovingAI data not present")
def test_shared_movingai_map_and_scenarios():
    from scipy.sparse.csgraph import dijkstra

    plant = load(MOVINGAI / "random-32-32-10.map")
    rows = (MOVINGAI / "random-32-32-10.map").read_text().splitlines()[4:]
    assert plant.n == sum(row.count(".") + row.count("G") for row in rows)
    for scen in load_scenarios(MOVINGAI / "random-32-32-10-random-1.scen")[:50]:
        x, y = scen.start % 32, scen.start // 32
        assert rows[y][x] in ".G"  # ids match the scenario coordinates
        four = dijkstra(plant.csr, indices=plant.idx(scen.start))[plant.idx(scen.goal)]
        assert four >= scen.optimal_octile - 1e-6  # 4-connected is never shorter than octile


def test_compass_node_list(tmp_path):
    path = tmp_path / "thesis.nodes"
    path.write_text(
        "# id  N d   E d     S d     W d\n"
        "0   -1 0   1 1.0   -1 0    -1 0   role=entry functions=0\n"
        "1   -1 0   2 1.0    3 0.8   0 1.0\n"
        "2   -1 0   -1 0    -1 0     1 1.0  role=station functions=2+3 name=drill\n"
        "3    1 0.8  4 2.5  -1 0    -1 0\n"
        "4   -1 0   -1 0    -1 0    -1 0    role=exit\n"
    )
    plant = load(path)
    both = {(e.source, e.target): e for e in plant.edges}
    assert (
        both[(0, 1)].bidirectional
        and both[(0, 1)].port_source == "E"
        and both[(0, 1)].port_target == "W"
    )
    assert both[(1, 3)].bidirectional and both[(1, 3)].length == 0.8
    assert not both[(3, 4)].bidirectional  # listed from one end only: one-way
    assert plant.node(2).functions == (2, 3) and plant.node(2).name == "drill"
    assert plant.node(1).x == 1.0 and plant.node(3).y == 0.8  # laid out from the ports


@pytest.mark.parametrize(
    "text,message",
    [
        ("0 -1 0 1 1.0 -1 0\n", "line 1: expected id and 4 x"),
        ("0 -1 0 7 1.0 -1 0 -1 0\n", "line 1: port E of node 0: unknown node 7"),
        ("0 -1 0 -1 0 -1 0 -1 0\n0 -1 0 -1 0 -1 0 -1 0\n", "line 2: node 0 is listed twice"),
        ("0 -1 x -1 0 -1 0 -1 0\n", "line 1: ids must be integers"),
        ("0 -1 0 -1 0 -1 0 -1 0 colour=red\n", "unknown option"),
    ],
)
def test_compass_errors_name_the_line(tmp_path, text, message):
    path = tmp_path / "bad.nodes"
    path.write_text(text)
    with pytest.raises(TopologyError, match=message):
        load(path)


def plant_toml(nodes: str, edges: str, extra: str = "") -> str:
    return extra + nodes + edges


NODES = '[[nodes]]\nid = 0\nrole = "entry"\n[[nodes]]\nid = 1\n[[nodes]]\nid = 2\nrole = "station"\nfunctions = [2]\n'


@pytest.mark.parametrize(
    "text,message",
    [
        (
            NODES + "[[edges]]\nfrom = 0\nto = 9\nlength = 1\n",
            r"edges\[0\] \(0 -> 9\): unknown node 9",
        ),
        (
            "edges = []\n" + NODES + "[[nodes]]\nid = 1\n",
            r"nodes\[3\] \(id 1\): duplicate node id 1",
        ),
        (
            NODES + "[[edges]]\nfrom = 0\nto = 1\nlength = -1\n",
            r"length must be a finite number >= 0 \(at most 1e\+12\), got -1",
        ),
        (
            NODES + "[[edges]]\nfrom = 0\nto = 1\nlength = nan\n",
            r"length must be a finite number >= 0 \(at most 1e\+12\), got nan",
        ),
        (
            NODES + "[[edges]]\nfrom = 0\nto = 1\nlength = inf\n",
            r"length must be a finite number >= 0 \(at most 1e\+12\), got inf",
        ),
        (NODES + "[[edges]]\nfrom = 1\nto = 1\nlength = 1\n", "self loop"),
        (
            NODES + '[[edges]]\nfrom = 0\nto = 1\nlength = 1\nports = ["E", "W"]\n'
            '[[edges]]\nfrom = 0\nto = 2\nlength = 1\nports = ["E", "W"]\n',
            r"edges\[1\] \(0 -> 2\): port E of node 0 is already used by edges\[0\]",
        ),
        (
            '[functions]\n7 = "polish"\n' + NODES + "[[edges]]\nfrom = 0\nto = 2\nlength = 1\n",
            "function 7 \\(polish\\) is provided by no station",
        ),
        (
            NODES + "[[edges]]\nfrom = 0\nto = 1\nlength = 1\n",
            "target 2 cannot be reached from entry 0",
        ),
        (
            NODES + '[[edges]]\nfrom = 0\nto = "one"\nlength = 1\n',
            "to must be an integer, got 'one'",
        ),
        (
            "edges = []\n" + NODES.replace('role = "station"', 'role = "stacion"'),
            "unknown role 'stacion'",
        ),
        (
            "edges = []\n[[nodes]]\nid = 0\nfunctions = [3]\n",
            "a transit node cannot provide functions",
        ),
        (
            NODES + "[[edges]]\nfrom = 0\nto = 2\nlength = 1\nspeed = 3\n",
            "unknown key\\(s\\): speed",
        ),
        ("nodes = 3\nedges = []\n", "'nodes' must be a list"),
        ("[[nodes]\n", "invalid TOML"),
    ],
)
def test_validation_errors_name_file_and_item(tmp_path, text, message):
    path = tmp_path / "plant.toml"
    path.write_text(text)
    with pytest.raises(TopologyError, match=message) as err:
        load(path)
    assert str(err.value).startswith(str(path))


def test_unreachable_from_some_node_is_a_warning():
    nodes = [Node(0, role="entry"), Node(1), Node(2, role="station", functions=(2,)), Node(3)]
    edges = [
        Edge(0, 2, 1.0, bidirectional=False),
        Edge(2, 1, 1.0),
        Edge(1, 3, 1.0, bidirectional=False),
    ]
    plant = Plant.build(nodes, edges)  # builds: the entry reaches the station
    assert plant.warnings == ("target 2 cannot be reached from 1 node(s), e.g. 3",)


_LINE = [Node(0, role="entry"), Node(1), Node(2, role="station", functions=(2,))]


@pytest.mark.parametrize(
    ("extra", "warnings"),
    [
        (  # a copy-pasted line, its length edited
            Edge(0, 1, 1.5),
            (
                "edges[2] joins nodes 0 and 1 both ways, as edges[0] does: only the shorter is "
                "ever driven: drop the other, or give it its own speed limit",
            ),
        ),
        (  # the same two-way lane written the other way round
            Edge(1, 0, 1.0),
            ("edges[2] joins nodes 0 and 1 both ways, as edges[0] does: a copy? drop one of them",),
        ),
        (Edge(1, 0, 1.0, bidirectional=False), ()),  # one way beside a two-way lane
        (Edge(2, 1, 1.0, routable=False), ()),  # the other way of a one-way lane
        (Edge(1, 2, 1.0, routable=False), ()),  # a return lane beside a one-way lane
        (Edge(0, 1, 1.5, max_speed=2.0), ()),  # a parallel lane, faster on purpose
    ],
)
def test_an_edge_that_repeats_another_is_a_warning(extra, warnings):
    """Routing drives only the shorter of two routable edges on the same nodes and
    directions at one speed limit: a copy is accepted, named with the edge it repeats, by
    their places in the file."""
    edges = [Edge(0, 1, 1.0), Edge(1, 2, 1.0, bidirectional=False), extra]
    assert Plant.build(_LINE, edges).warnings == warnings


@pytest.mark.parametrize(
    "content",
    [
        b"\x00\x01\x02\xff binary",
        b"\xff\xfe\xfa",
        b"",
        b'{"nodes": [',
        b"[1, 2, 3]",
        b'{"nodes": [{"id": 0}], "edges": [1]}',
    ],
)
def test_garbage_files_give_one_clear_error(tmp_path, content):
    for suffix in (".toml", ".json", ".map", ".nodes"):
        path = tmp_path / f"garbage{suffix}"
        path.write_bytes(content)
        try:
            load(path)
        except TopologyError as exc:
            assert str(path) in str(exc) and "\n" not in str(exc)
        else:
            assert content == b"" and suffix == ".nodes"  # an empty node list is an empty plant


def test_plant_files_saved_with_a_byte_order_mark_load(tmp_path):
    """A BOM (as editors on Windows write UTF-8) is no part of the text in any format, and
    the lines of errors are counted as without it."""
    examples = Path(__file__).parent.parent / "examples" / "plants"
    thesis = tmp_path / "thesis.nodes"
    thesis.write_text(
        "0 -1 0 1 1.0 -1 0 -1 0 role=entry functions=0\n"
        "1 -1 0 -1 0 -1 0 0 1.0 role=exit functions=1\n"
    )
    json_plant = tmp_path / "plant.json"
    json_plant.write_text(json.dumps(small_plant()))
    for original in (examples / "workshop.toml", examples / "random-32-32.map", thesis, json_plant):
        marked = tmp_path / f"bom{original.suffix}"
        marked.write_bytes(b"\xef\xbb\xbf" + original.read_bytes())
        assert load(marked).fingerprint == load(original).fingerprint
    marked = tmp_path / "bom.map"
    marked.write_bytes(b"\xef\xbb\xbftype octile\nheight 1\nwidth 2\nmap\n.x\n")
    with pytest.raises(TopologyError, match="line 5"):
        load(marked)


def test_unknown_extension_and_missing_file(tmp_path):
    with pytest.raises(TopologyError, match="unknown plant file type '.yaml'"):
        load(tmp_path / "plant.yaml")
    with pytest.raises(TopologyError, match="cannot read plant file"):
        load(tmp_path / "missing.toml")


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(st.integers(0, 12), st.integers(0, 12), st.floats(0, 50)), max_size=30),
    st.booleans(),
)
def test_fingerprint_changes_with_routing_relevant_edits(pairs, directed):
    nodes = [Node(i) for i in range(13)]
    edges = [Edge(a, b, w, bidirectional=not directed) for a, b, w in pairs if a != b]
    plant = Plant.build(nodes, edges)
    extra = Plant.build(nodes, (*edges, Edge(0, 12, 1.0)))
    assert plant.fingerprint != extra.fingerprint
    assert Plant.build(nodes, edges).fingerprint == plant.fingerprint
    assert all(math.isfinite(w) for w in plant.arcs[2])


@pytest.mark.parametrize(
    "name,content,message",
    [
        (
            "big.json",
            '{"nodes": [{"id": 0, "x": 1' + "0" * 400 + '}], "edges": []}',
            r"x must be a finite number within ±1e\+12 m, got 1000",
        ),
        (  # (finite, but the plant's extent 2e308 is not: its drawing failed at a run's end)
            "far.json",
            '{"nodes": [{"id": 0, "x": 1e308}, {"id": 1, "x": -1e308}], "edges": []}',
            r"x must be a finite number within ±1e\+12 m, got 1e\+308",
        ),
        ("digits.json", '{"nodes": [{"id": 1' + "0" * 5000 + '}], "edges": []}', "unreadable JSON"),
        ("deep.json", "[" * 100_000, "unreadable JSON"),
        ("deep.toml", "x = " + "[" * 100_000, "unreadable TOML"),
        (
            "id.toml",
            "edges = []\n[[nodes]]\nid = 9223372036854775807\n",
            "node id must be an integer 0..2147483647",
        ),
        (
            "long.toml",
            "[[nodes]]\nid = 0\n[[nodes]]\nid = 1\n[[edges]]\nfrom = 0\nto = 1\nlength = 1e308\n",
            r"at most 1e\+12",
        ),
        ("empty.toml", "nodes = []\nedges = []\n", "the plant has no nodes"),
        ("zero.map", "type octile\nheight 0\nwidth 4\nmap\n", "height and width must be >= 1"),
    ],
)
def test_hostile_files_give_one_clear_error(tmp_path, name, content, message):
    path = tmp_path / name
    path.write_text(content)
    with pytest.raises(TopologyError, match=message) as err:
        load(path)
    assert len(str(err.value)) < 300 and str(path) in str(err.value)


def test_fingerprint_ignores_int_versus_float_lengths():
    nodes = [Node(0), Node(1)]
    assert (
        Plant.build(nodes, [Edge(0, 1, 1)]).fingerprint
        == Plant.build(nodes, [Edge(0, 1, 1.0)]).fingerprint
    )


def test_drawing_must_be_png(tmp_path):
    from topology.draw import draw

    with pytest.raises(TopologyError, match="give a file name ending in .png"):
        draw(model_plant(), tmp_path / "plant.svg")


SMALL_PLANT = {
    "name": "line",
    "functions": {"0": "entry", "1": "exit"},
    "nodes": [
        {"id": 0, "role": "entry", "functions": [0]},
        {"id": 1, "role": "exit", "functions": [1], "x": 1.0},
    ],
    "edges": [{"from": 0, "to": 1, "length": 1.0}],
}


def small_plant(**changes) -> dict:
    """SMALL_PLANT with top-level keys replaced, and node keys given as ``node_<key>``
    (set on node 1)."""
    plant = copy.deepcopy(SMALL_PLANT)
    for key, value in changes.items():
        if key.startswith("node_"):
            plant["nodes"][1][key.removeprefix("node_")] = value
        else:
            plant[key] = value
    return plant


@pytest.mark.parametrize(
    "changes,where,message",
    [
        ({"name": "\ud800"}, ": name: ", r"'\\ud800': character 1 \(U\+D800\) is a lone surrogate"),
        (
            {"name": "a\x00b\x1b[31mred"},
            ": name: ",
            r"character 2 \(U\+0000\) is a control character",
        ),
        ({"node_name": "drill\ud83d"}, ": nodes[1] (id 1): ", r"\(U\+D83D\) is a lone surrogate"),
        ({"node_name": "\x1b[2J"}, ": nodes[1] (id 1): ", r"name '\\x1b\[2J': character 1"),
        ({"node_name": "ab\ncd"}, ": nodes[1] (id 1): ", r"\(U\+000A\) is a control character"),
        (
            {"node_area": "dr\u202eill"},
            ": nodes[1] (id 1): ",
            r"area .* \(U\+202E\) is a bidirectional control",
        ),
        ({"node_name": "a\u2028b"}, ": nodes[1] (id 1): ", r"\(U\+2028\) is a line separator"),
        ({"name": "x" * 100_000}, ": name: ", r"\(100002 characters\) is too long: a name has at"),
        (
            {"functions": {"0": "entry", "1": "ex\x9bit"}},
            ": functions: ",
            r"name of function 1 'ex\\x9bit': character 3 \(U\+009B\) is a control character",
        ),
    ],
    ids=[
        "surrogate-plant-name",
        "nul-and-escape-plant-name",
        "surrogate-node-name",
        "escape-node-name",
        "newline-node-name",
        "bidi-override-area",
        "line-separator-node-name",
        "megabyte-plant-name",
        "c1-csi-function-name",
    ],
)
def test_names_must_be_printable_text(tmp_path, changes, where, message):
    """A name reaches terminals, drawings and the operator page: no escape sequence, no
    text reordered or hidden, nothing that cannot be written as UTF-8."""
    path = tmp_path / "plant.json"
    path.write_text(json.dumps(small_plant(**changes)), encoding="ascii")  # \u escapes
    with pytest.raises(TopologyError, match=message) as err:
        load(path)
    text = str(err.value)
    assert text.startswith(f"{path}{where}")
    assert text.isprintable() and text.encode("utf-8")  # safe to print: every character escaped


def test_names_in_any_script_are_fine_but_not_control_characters(tmp_path):
    """Letters of any script, spaces and emoji (with the zero-width joiner) are names; the
    same check refuses an escape sequence in a .nodes file and in a plant built in code."""
    name = "Bohrstation Süd 北 ‍🧑‍🔧 می‌خواهم"
    assert load_json_plant(tmp_path, small_plant(name=name, node_name=name)).name == name
    # marks that set digits beside Hebrew or Arabic, a soft hyphen, a word joiner, a flag
    # made of tag characters, a byte order mark: invisible, but they move nothing
    for name in (
        "תחנה \u200e3",
        "محطة\u200f 3",
        "\u061cمحطة",
        "Lager\u00adhalle",
        "A\u2060B",
        "\U0001f3f4\U000e0067\U000e0062\U000e0073\U000e0063\U000e0074\U000e007f",
        "\ufeffhall",
    ):
        assert load_json_plant(tmp_path, small_plant(node_name=name)).nodes[1].name == name
    path = tmp_path / "thesis.nodes"
    path.write_text(
        "0 -1 0 1 1.0 -1 0 -1 0 role=entry functions=0\n"
        "1 -1 0 -1 0 -1 0 0 1.0 role=exit functions=1 name=\x1b]0;pwned\x07\n"
    )
    with pytest.raises(TopologyError, match=r"line 2: name '\\x1b\]0;pwned\\x07'"):
        load(path)
    with pytest.raises(TopologyError, match=r"nodes\[0\] \(id 4\): name must be a string, got 7"):
        Plant.build([Node(4, name=7)], [])
    with pytest.raises(TopologyError, match="name: the plant's name 'x\\\\ty'"):
        Plant.build([Node(4)], [], name="x\ty")


def load_json_plant(tmp_path: Path, plant: dict) -> Plant:
    path = tmp_path / "plant.json"
    path.write_text(json.dumps(plant))
    return load(path)


@pytest.mark.parametrize(
    "name,content",
    [
        ("keys.json", '{"nodes": [{"id": 0, "\\u001b[31m": 1}], "edges": []}'),
        ("keys.toml", 'edges = []\n"\\u001b[2J" = 1\n[[nodes]]\nid = 0\n'),
    ],
    ids=["json-node-key", "toml-top-level-key"],
)
def test_unknown_keys_are_shown_escaped(tmp_path, name, content):
    path = tmp_path / name
    path.write_text(content)
    with pytest.raises(TopologyError, match=r"unknown (top-level )?key\(s\): '\\x1b\[") as err:
        load(path)
    assert "\x1b" not in str(err.value)


@pytest.mark.parametrize(
    "content,where,message",
    [
        (
            '{"name":"x","name":"y","nodes":[],"edges":[]}',
            "line 1, column 13",
            "duplicate key 'name' in one object \\(first on line 1, column 2\\)",
        ),
        (
            '{\n "nodes": [\n  {"id": 0, "role": "entry"},\n  {"id": 1,\n   "id": 5}\n ],\n'
            ' "edges": []\n}\n',
            "line 5, column 4",
            "duplicate key 'id' in one object \\(first on line 4, column 4\\)",
        ),
        (  # a key spelled with an escape is the same key
            '{"nodes": [], "edges": [], "n\\u006fdes": [{"id": 1}]}',
            "line 1, column 28",
            "duplicate key 'nodes' in one object \\(first on line 1, column 2\\)",
        ),
        (  # deeper than the locating reader's stack: the key is still named
            '{"nodes": [], "edges": ' + "[" * 600 + '{"a": 1, "a": 2}' + "]" * 600 + "}",
            None,
            "duplicate key 'a' in one object$",
        ),
    ],
    ids=["top-level", "node-on-another-line", "escaped-spelling", "nested-600-deep"],
)
def test_json_duplicate_keys_are_refused(tmp_path, content, where, message):
    """JSON readers keep the last of two equal keys without a word; a plant file says one
    thing once."""
    path = tmp_path / "plant.json"
    path.write_text(content)
    with pytest.raises(TopologyError, match=message) as err:
        load(path)
    prefix = f"{path}: {where}: " if where else f"{path}: "
    assert str(err.value).startswith(prefix)


def test_movingai_only_blank_lines_follow_the_rows(tmp_path):
    path = tmp_path / "junk.map"
    path.write_text("type octile\nheight 1\nwidth 3\nmap\n...\n\nthis is junk text!!\n@@@@\n")
    with pytest.raises(TopologyError) as err:
        load(path)
    assert str(err.value) == (
        f"{path}: line 7: text after the 1 row(s) that 'height 1' declares: "
        "'this is junk text!!'; only blank lines may follow the map"
    )
    path.write_text("type octile\nheight 1\nwidth 3\nmap\n...\n\n  \n")
    assert load(path).n == 3


def test_a_plant_named_after_its_file_escapes_what_a_name_may_not_hold(tmp_path):
    """A map or node list takes its name from the file's name, which nobody wrote as a
    name: a tab or a byte that is not UTF-8 there is escaped, not refused."""
    text = (Path(__file__).parent.parent / "examples/plants/random-32-32.map").read_text()
    path = tmp_path / "lager\udce4\tost.map"  # a file name in Latin-1, and a tab
    path.write_text(text)
    assert load(path).name == "lager\\udce4\\tost"
    assert load(tmp_path / "lager\udce4\tost.map").name.isprintable()


@pytest.mark.parametrize(
    ("options", "error"),
    [
        ("functions=5", "line 4 (id 1): a transit node cannot provide functions"),
        ("role=entyr", "line 4 (id 1): unknown role 'entyr'"),
    ],
)
def test_a_nodes_file_names_the_line_of_a_node_the_plant_checks_refuse(tmp_path, options, error):
    """The checks of the plant as a whole name a node by its place in the list; a .nodes
    file is lines, so its line is named."""
    path = tmp_path / "n.nodes"
    path.write_text(
        "# id N dN E dE S dS W dW\n0 -1 0 1 1.0 -1 0 -1 0 role=entry\n\n"
        f"1 -1 0 -1 0 -1 0 0 1.0 {options}\n"
    )
    with pytest.raises(TopologyError) as err:
        load(path)
    assert str(err.value).startswith(f"{path}: {error}")
