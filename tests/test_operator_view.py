"""What the operator sees: the event log (fed by every source of change), the dashboard at
80 columns, the liveness warning at start, and recipes refused because a vehicle would
"complete" a step without moving."""

from __future__ import annotations

from pathlib import Path

import pytest
from fleet_scenarios import make_config, run
from rich.console import Console
from test_fleet_deadlock import head_on_config

from fleet import liveness
from fleet.cli import main
from fleet.config import DEFAULT_CONFIG, Blockade, load_config, parse_config
from fleet.dashboard import dashboard
from fleet.orders_config import OrdersConfig
from fleet.program import FleetProgram
from fleet.report import summary
from plc_runtime.errors import ConfigError, StartupError
from topology import grid, model_plant
from vehicles.fleet import Faults


@pytest.fixture
def programs():
    made: list[FleetProgram] = []
    yield made
    for p in made:
        p.close()


def default_program(programs) -> FleetProgram:
    cfg = load_config()
    cfg.watchdog = 5.0
    p = FleetProgram(cfg)
    programs.append(p)
    return p


def kinds(p: FleetProgram) -> list[str]:
    return [e.kind for e in p.events.events]


def test_blockades_from_any_source_are_events(programs):
    p = default_program(programs)
    p.rt.start()
    p.rt.run(duration=1)
    p.blockades.block(8, 13)  # as an operator command would
    p.rt.step()
    assert kinds(p)[-1] == "blockade" and p.events.events[-1].text == "segment 8-13 closed"
    p.blockades.unblock(8, 13)
    p.rt.step()
    assert kinds(p)[-1] == "reopened"
    # the configured schedule closes 7-8 at 120 s and reopens it at 300 s
    p.rt.run(duration=300)
    texts = [e.text for e in p.events.events if e.kind in ("blockade", "reopened")]
    assert "segment 7-8 closed" in texts and "segment 7-8 open again" in texts
    assert p.events.counts["blockade"] == 2 and p.events.counts["reopened"] == 2


def test_replans_and_a_silent_vehicle_are_events(programs):
    p = default_program(programs)
    p.rt.start()
    p.rt.run(duration=300)
    replans = sum(c.replans for c in p.controls.values())
    assert p.events.counts["replan"] == replans > 0
    # vehicle 3 stops talking: it goes stale, which the operator is told about
    p.fleet.faults[3] = Faults(dead_after=p.fleet.time)
    p.rt.run(duration=3)
    stale = [e for e in p.events.events if e.kind == "vehicle" and e.vehicle == 3]
    assert stale and stale[-1].text.endswith("-> stale")


def test_a_vehicle_silent_from_the_start_is_an_event_and_so_is_its_first_status(programs):
    """Every vehicle starts offline, which is no news; one still unheard of once the stale
    time (0.5 s) has passed is, and its first status later is a recovery."""
    p = default_program(programs)
    p.fleet.faults[3] = Faults(dead_after=0.0)
    p.rt.start()
    p.rt.run(duration=2)
    silent = [e for e in p.events.events if e.kind == "vehicle"]
    assert [(e.vehicle, e.text) for e in silent] == [
        (3, "offline: no status received since the start")
    ]
    assert 0.5 < silent[0].time_s < 0.6
    del p.fleet.faults[3]
    p.rt.run(duration=2)
    back = [e for e in p.events.events if e.kind == "recovered"]
    assert [(e.vehicle, e.text.split(" -> ")[0]) for e in back] == [(3, "offline")]


def test_deadlocks_and_unbreakable_cycles_are_events(programs):
    for siding, kind in ((True, "deadlock"), (False, "livelock")):
        p = FleetProgram(head_on_config(siding))
        try:
            run(p, 90)
            assert kind in kinds(p)
            assert p.events.counts[kind] == sum(
                1 for e in p.resolver.events if (e.backed_off is None) == (kind == "livelock")
            )
        finally:
            p.close()


def test_the_event_log_is_bounded(programs):
    p = default_program(programs)
    p.rt.start()
    for _ in range(3000):
        p.events.add(0.0, "replan", 1, "x")
    assert len(p.events.events) == 1000 and p.events.counts["replan"] >= 3000


def render(program: FleetProgram, width: int) -> list[str]:
    console = Console(width=width, record=True, force_terminal=False, color_system=None)
    console.print(dashboard(program, 100_000, width=width))
    return console.export_text().splitlines()


@pytest.mark.parametrize("width", [80, 120])
def test_the_dashboard_fits_the_terminal(programs, width):
    p = default_program(programs)
    p.rt.start()
    p.rt.run(duration=150)  # past the blockade at 120 s: the event log has lines
    lines = render(p, width)
    assert max(len(line) for line in lines) <= width
    text = "\n".join(lines)
    for header in ("agv", "state", "node", "tgt", "step"):
        assert f" {header} " in text
    # one line per vehicle: no cell wrapped
    rows = [line for line in lines if line.startswith("│") and line.split("│")[1].strip() in "1234"]
    assert len(rows) == 4
    assert "events (newest last)" in text and "segment 7-8 closed" in text


def test_the_dashboard_fits_80_columns_with_many_vehicles(programs):
    plant = grid(14, 14)
    ids = [n.id for n in plant.nodes]
    stations = ids[1::7][:8]
    cfg = make_config(
        plant,
        {v: ids[v * 3] for v in range(1, 31)},
        {"a": [1, 2]},
        {1: stations[:4], 2: stations[4:]},
    )
    p = FleetProgram(cfg)
    programs.append(p)
    p.rt.start()
    p.rt.run(duration=5)
    lines = render(p, 80)
    assert max(len(line) for line in lines) <= 80
    vehicle_rows = [line for line in lines if line.startswith("│ ") and line[2:5].strip().isdigit()]
    assert len(vehicle_rows) == 30  # one line each, nothing wrapped


def test_a_config_outside_the_liveness_condition_is_warned_about(tmp_path, capsys):
    assert main(["run", "--duration", "1", "--out", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    assert "warning: default.toml does not meet the liveness condition" in err
    assert "4 vehicles on 25 nodes" in err and "one-way segments" in err


def test_a_config_inside_the_liveness_condition_is_not_warned_about(tmp_path, capsys):
    cfg = tmp_path / "ok.toml"
    cfg.write_text(
        """
[plant]
sample = "warehouse"

[stations.clusters]
1 = [46, 91]
2 = [184, 229]

[[recipes]]
name = "shuttle"
functions = [1, 2]

[[vehicles]]
id = 1
start = 322

[[vehicles]]
id = 2
start = 367
"""
    )
    assert main(["run", str(cfg), "--duration", "1", "--out", str(tmp_path / "o")]) == 0
    assert "liveness" not in capsys.readouterr().err
    assert liveness.violations(load_config(cfg)) == []


def test_each_clause_of_the_liveness_condition_is_checked():
    cfg = load_config(DEFAULT_CONFIG)
    found = liveness.violations(cfg)
    assert any(v.startswith("one-way segments") for v in found)
    assert any("not 2-connected: losing node 9" in v for v in found)
    assert "function(s) 1, 6 offered by one station only" in found
    cfg.blockades[0] = type(cfg.blockades[0])(7, 8, 10.0, None)
    assert "a blockade that never reopens" in liveness.violations(cfg)


@pytest.mark.parametrize(
    ("vehicles", "nodes", "clause"),
    [
        (
            1,
            4,
            "1 vehicle on 4 nodes, more than 1 vehicle per 10 nodes (at least 10 nodes for 1 vehicle)",
        ),
        (
            4,
            25,
            "4 vehicles on 25 nodes, more than 1 vehicle per 10 nodes (at least 40 nodes for 4 vehicles)",
        ),
        (3, 30, None),
    ],
)
def test_the_share_of_vehicles_says_how_many_nodes_they_need(vehicles, nodes, clause):
    """A small plant is told the size its fleet needs, not that it takes "at most 0"."""
    from topology import Edge, Node, Plant

    ring = Plant.build(
        [Node(0, role="entry", functions=(0,))]
        + [Node(k, role="station", functions=(2,)) for k in (1, 2)]
        + [Node(k) for k in range(3, nodes)],
        [Edge(k, (k + 1) % nodes, 1.0) for k in range(nodes)],
    )
    cfg = load_config(DEFAULT_CONFIG)
    cfg.plant, cfg.starts = ring, {v: v - 1 for v in range(1, vehicles + 1)}
    found = [v for v in liveness.violations(cfg) if "nodes" in v and "vehicle" in v]
    assert found == ([clause] if clause else [])


def test_time_window_traffic_needs_a_parking_position_per_order_vehicle():
    """That mode pushes nobody aside: an idle vehicle that cannot park may block a way."""
    cfg = load_config(
        Path(__file__).resolve().parent.parent / "examples" / "distribution-centre.toml"
    )
    parking = len(cfg.plant.with_role("parking"))
    assert parking >= len(cfg.order_vehicles) > 0
    assert not any("parking" in v for v in liveness.violations(cfg))  # reactive
    cfg.traffic = "time_windows"
    assert not any("parking" in v for v in liveness.violations(cfg))
    cfg.dispatch.park = False
    found = [v for v in liveness.violations(cfg) if "parking" in v]
    assert found == [
        f"time-window traffic moves no idle vehicle aside, and 0 parking position(s) for "
        f"{len(cfg.order_vehicles)} vehicles taking orders: an idle vehicle may stand on "
        "another's only way"
    ]


def test_articulation_points_match_an_independent_count():
    nx = pytest.importorskip("networkx")
    from topology import Edge, Node, Plant, model_plant, warehouse

    ring = Plant.build(
        [Node(k, x=float(k), y=0.0) for k in range(12)],
        [Edge(k, (k + 1) % 12, 0.0 if k in (4, 5, 6) else 1.0) for k in range(12)],
    )  # segments of length 0 still join their nodes: no cut node in a ring
    for plant in (model_plant(), warehouse(), grid(6, 6), ring):
        g = nx.Graph()
        g.add_nodes_from(plant.ids.tolist())
        src, dst, _ = plant.arcs
        g.add_edges_from(zip(plant.ids[src].tolist(), plant.ids[dst].tolist(), strict=True))
        assert liveness.articulation_points(plant) == sorted(nx.articulation_points(g))


ONE_STATION = """
[plant]
sample = "model-plant"

[stations.clusters]
3 = [16]

[[recipes]]
name = "mill"
functions = [3]

[[vehicles]]
id = 1
start = 0
"""


def test_a_step_completed_without_moving_is_refused():
    with pytest.raises(ConfigError) as err:
        parse_config(ONE_STATION, "one.toml")
    text = str(err.value)
    assert text.startswith("one.toml: vehicles: vehicle 1: step 1")
    assert "only station 16 offers it" in text and "without moving" in text


def one_way_plant(tmp_path: Path) -> Path:
    """A two-way ring 1-2-3-4 with a saw at 2 and a weld at 4; node 5 is reached from 1 by a
    one-way segment and leads nowhere; the paint station 6 is reached from 3 by a one-way
    segment and leads nowhere either."""
    nodes = [(1, 0, 0, "transit", None), (2, 1, 0, "station", 2), (3, 1, 1, "transit", None)]
    nodes += [(4, 0, 1, "station", 3), (5, -1, 0, "transit", None), (6, 2, 1, "station", 4)]
    text = 'name = "one-way"\n[functions]\n2 = "saw"\n3 = "weld"\n4 = "paint"\n'
    for n, x, y, role, f in nodes:
        text += f'[[nodes]]\nid = {n}\nx = {x}\ny = {y}\nrole = "{role}"\n'
        text += f"functions = [{f}]\n" if f else ""
    for a, b, one_way in [(1, 2, 0), (2, 3, 0), (3, 4, 0), (4, 1, 0), (1, 5, 1), (3, 6, 1)]:
        text += f"[[edges]]\nfrom = {a}\nto = {b}\nlength = 1.0\n"
        text += "directed = true\n" if one_way else ""
    path = tmp_path / "one-way.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "start, functions, says",
    [
        (
            5,
            [2, 3],
            "vehicle 1: step 1 of its recipe sequence needs function 2, and no station "
            "offering it can be reached from its start node 5",
        ),
        (
            1,
            [4, 2],
            "vehicle 1: step 2 of its recipe sequence needs function 2, and no station "
            "offering it can be reached from any station of step 1",
        ),
    ],
)
def test_a_vehicle_that_one_way_segments_keep_from_its_work_is_refused(
    tmp_path, capsys, start, functions, says
):
    """A vehicle whose start (or a station it must visit) has only one-way segments leading
    away from the stations it needs next would report no route for the whole run, which
    would then end as if all were well: the configuration is refused, naming the vehicle,
    the step and the node."""
    plant = one_way_plant(tmp_path)
    cfg = tmp_path / "fleet.toml"
    cfg.write_text(
        f'[plant]\nfile = "{plant.name}"\n[[recipes]]\nname = "r"\nfunctions = {functions}\n'
        f"[[vehicles]]\nid = 1\nstart = {start}\n"
    )
    assert main(["run", str(cfg), "--cycles", "1", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert (
        err[-1] == f"plc-runtime: error: {cfg}: vehicles: {says} (one-way segments lead "
        "away): the vehicle could never complete it"
    )
    assert not (tmp_path / "o").exists()


def test_a_vehicle_taking_orders_that_reaches_no_station_is_refused(tmp_path, capsys):
    plant = one_way_plant(tmp_path)
    orders = tmp_path / "orders.csv"
    orders.write_text("id,get,put\na,2,4\n")
    cfg = tmp_path / "fleet.toml"
    vehicles = "".join(f"[[vehicles]]\nid = {v}\nstart = {n}\n" for v, n in [(1, 1), (2, 5)])
    cfg.write_text(f'[plant]\nfile = "{plant.name}"\n[orders]\nfile = "orders.csv"\n{vehicles}')
    assert main(["run", str(cfg), "--cycles", "1", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err == (
        f"plc-runtime: error: {cfg}: vehicles: vehicle 2: no station can be reached from its "
        "start node 5 (one-way segments lead away from every one): it could take no order"
    )


def test_a_vehicle_taking_orders_is_judged_by_the_stations_orders_name(tmp_path):
    """Orders name stations (role "station"), which need no function: a vehicle that can
    reach them is accepted though the plant has a one-way dead end and no function."""
    plant = one_way_plant(tmp_path)
    text = plant.read_text().split("[[nodes]]", 1)[1]  # without [functions] and functions = []
    lines = (x for x in text.splitlines() if not x.startswith("functions ="))
    plant.write_text('name = "one-way"\n[[nodes]]' + "\n".join(lines))
    (tmp_path / "orders.csv").write_text("id,get,put\na,2,4\n")
    cfg = tmp_path / "fleet.toml"
    cfg.write_text(
        f'[plant]\nfile = "{plant.name}"\n[orders]\nfile = "orders.csv"\n'
        "[[vehicles]]\nid = 1\nstart = 1\n"
    )
    assert liveness.stranded_starts(load_config(cfg)) == []


def test_a_vehicle_that_reaches_its_stations_over_one_way_segments_is_accepted(tmp_path):
    plant = one_way_plant(tmp_path)
    text = f'[plant]\nfile = "{plant.name}"\n[[recipes]]\nname = "r"\nfunctions = [2, 3]\n'
    for start in (1, 3):
        path = tmp_path / "fleet.toml"
        path.write_text(text + f"[[vehicles]]\nid = 1\nstart = {start}\n")
        assert liveness.stranded_starts(load_config(path)) == []


def test_a_single_round_of_a_one_function_recipe_is_accepted():
    cfg = parse_config(ONE_STATION + "\n[sequencer]\nrounds = 1\n", "one.toml")
    assert cfg.rounds == 1


def test_two_programs_in_one_process_each_drive_their_own_fleet(programs):
    """Both on the configured in-process channel 'agv', each would read the other's
    vehicles; the second gets a channel of its own, and each runs as it runs alone."""
    examples = Path(DEFAULT_CONFIG).parent.parent / "examples"

    def made() -> FleetProgram:
        cfg = load_config(examples / "workshop.toml")
        p = FleetProgram(cfg)
        programs.append(p)
        return p

    alone = made()
    alone.rt.start()
    alone.rt.run(duration=60)
    expected = [(r["node"], r["rounds"]) for r in alone.vehicle_rows()]
    alone.close()
    a, b = made(), made()
    assert (a.bus_channel, b.bus_channel) == ("agv", "agv~2")
    a.rt.start()
    with pytest.warns(RuntimeWarning, match="watchdog interrupt not available"):
        b.rt.start()  # (one SIGALRM per process: b's watchdog checks after each scan)
    for _ in range(round(60 / a.cfg.cycle_time)):
        a.rt.step()
        b.rt.step()
    for p in (a, b):
        assert [(r["node"], r["rounds"]) for r in p.vehicle_rows()] == expected
        assert p.reservation.refused_reports == 0
    b.close()
    again = made()  # a's channel is still taken, b's is free again
    assert again.bus_channel == "agv~2"
    broken = load_config(examples / "workshop.toml")
    broken.traffic = "no such mode"
    with pytest.raises(ConfigError):
        FleetProgram(broken)  # a program that was never built holds no channel
    assert made().bus_channel == "agv~3"


def test_a_fleet_program_starts_once(programs):
    """After a stop the vehicles stood where the safe state stopped them, not where the
    program's holds and routes say: a restart would drive on stale holds, so it is refused
    with the reason, and a new program takes over."""
    p = default_program(programs)
    p.rt.start()
    p.rt.run(duration=5)
    p.rt.stop()
    with pytest.raises(StartupError, match="a fleet program starts once: after stop"):
        p.rt.start()
    assert p.rt.state == "FAULT"


@pytest.mark.parametrize(
    ("change", "says"),
    [
        (lambda c: setattr(c, "traffic", "timewindows"), "test: traffic: must be one of"),
        (lambda c: setattr(c, "astar_budget", 0), "test: astar_budget: must be a number >= 1"),
        (lambda c: c.starts.update({2: 0}), "test: starts: vehicle 2: node 0 is already vehicle 1"),
        (lambda c: c.starts.update({2: 999}), "test: starts: vehicle 2: node 999 is not in the"),
        (
            lambda c: c.starts.update({0: 5}),
            "test: starts: vehicle ids are integers 1..1008, got 0",
        ),
        (lambda c: c.vehicle_recipes.update({1: ["nope"]}), "vehicle 1: unknown recipe 'nope'"),
        (lambda c: c.clusters.pop(3), "recipes: 'r' needs function 3, which no station provides"),
        (
            lambda c: c.blockades.append(Blockade(3, 999, 5.0, None)),
            "test: blockades[0]: model-plant: no routable segment between nodes 3 and 999",
        ),
        (lambda c: setattr(c, "starts", [0, 10]), "test: starts: must be a dict, got list"),
        (
            lambda c: c.vehicle_recipes.pop(2),
            "test: vehicle_recipes: vehicle 2 has no recipes, takes no orders (order_vehicles) and no",
        ),
        (
            lambda c: c.clusters.update({3: [17, 999]}),
            "test: clusters: function 3: station 999 is not a node of the plant",
        ),
        (
            lambda c: setattr(c, "orders", OrdersConfig()),
            "test: orders: given, but no vehicle takes orders: every [[vehicles]] entry names "
            "its recipes; leave recipes out of those that should take orders",
        ),
        (
            lambda c: c.order_vehicles.append(7),
            "test: order_vehicles: vehicle 7 has no start",
        ),
    ],
    ids=[
        "traffic",
        "budget",
        "same-start",
        "no-node",
        "id-0",
        "recipe",
        "function",
        "blockade",
        "starts-list",
        "no-job",
        "station-not-in-plant",
        "orders-nobody",
        "order-vehicle-no-start",
    ],
)
def test_a_configuration_built_in_code_is_checked_as_a_file_is(change, says):
    """A FleetConfig made or changed in code gets the file's checks when the program is
    built: a typo is an error naming the field, not a silent fallback or a KeyError."""
    cfg = make_config(model_plant(), {1: 0, 2: 10}, {"r": [2, 3]}, {2: [15, 16], 3: [17, 18]})
    change(cfg)
    with pytest.raises(ConfigError) as caught:
        FleetProgram(cfg)
    assert says in str(caught.value)


def test_the_summary_of_a_program_not_started_yet(programs):
    """Nothing ran: no vehicle online, no cycle, and no error from a link not opened."""
    p = default_program(programs)
    result = summary(p, wall_s=0.0)
    assert result["state"] == "STOP" and result["cycles"] == 0
    assert result["drivers"]["can"]["online"] == 0


@pytest.mark.parametrize(
    ("functions", "rounds", "refused"),
    [([2, 1, 1], 1, True), ([2, 1], 0, False), ([1], 0, False)],
    ids=["twice-in-one-recipe", "exit-then-next-round", "exit-only-laps"],
)
def test_the_same_exit_twice_is_a_lap_only_across_a_recipes_end(
    tmp_path, functions, rounds, refused
):
    """The workshop's exit 1 has a return lane to the entry: a recipe that ends there drives
    it, so the next recipe's exit step is a lap. Within one recipe the second exit step
    would be completed where the vehicle stands."""
    examples = Path(DEFAULT_CONFIG).parent.parent / "examples"
    text = (
        f'[plant]\nfile = "{examples / "plants" / "workshop.toml"}"\n'
        f"[sequencer]\nrounds = {rounds}\n[stations.clusters]\n1 = [1]\n2 = [20]\n"
        f'[[recipes]]\nname = "r"\nfunctions = {functions}\n[[vehicles]]\nid = 1\nstart = 0\n'
    )
    if refused:
        with pytest.raises(ConfigError, match="would complete the step without moving"):
            parse_config(text, "w.toml")
    else:
        assert parse_config(text, "w.toml").recipes["r"].functions == tuple(functions)
