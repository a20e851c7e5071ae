"""A controller runs for months: no record appended to once per event may grow with the run
time. Each keeps its newest entries (``plc_runtime.recent.RecentList``) and an exact count
of all of them; what the summary, tags, web views and drawing report stays exact.

The capacities are lowered here so a short run passes them; the runs are on the virtual
clock, scan by scan."""

from __future__ import annotations

import csv
from collections.abc import Iterator
from dataclasses import dataclass
from types import SimpleNamespace

import pytest
from fleet_scenarios import ONE_DRILL
from fleet_scenarios import run as run_checked
from test_fleet_deadlock import head_on_config

import blocks.traffic.deadlock as deadlock
import fleet.program
import vehicles.agv
import vehicles.monitor
from blocks.traffic.deadlock import DeadlockEvent
from fleet.config import parse_config
from fleet.program import FleetProgram
from fleet.report import summary, write_csv
from fleet.web.views import fleet_counters
from plc_runtime.clock import VirtualClock
from topology import model_plant
from topology.draw import HEATMAP_ABOVE, render, segment_usage
from topology.model import Edge, Node, Plant
from vehicles.agv import AGV
from vehicles.fleet import Fleet
from vehicles.monitor import ConflictMonitor

# ----- a fleet run: driven routes, segment usage, recipe runs ---------------------------

TWO_DRILLS = ONE_DRILL + "\n[[vehicles]]\nid = 2\nstart = 10\n"
RUN_S = 120.0


@dataclass
class Run:
    program: FleetProgram
    csv_rows: list[dict[str, str]]
    result: dict


def drill_run(tmp_path) -> Run:
    cfg = parse_config(TWO_DRILLS)
    cfg.watchdog = 5.0  # behaviour, not wall time: a busy machine must not fault a scan
    program = FleetProgram(cfg, clock=VirtualClock())
    try:
        program.rt.start()
        program.rt.step(round(RUN_S / cfg.cycle_time))
    finally:
        program.close()
    path = write_csv(program, tmp_path / f"recipes-{id(program)}.csv")
    with path.open(encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    return Run(program, rows, summary(program, 1.0))


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> Iterator[tuple[Run, Run]]:
    """The same run twice: with the capacities of a real controller (nothing dropped in two
    minutes) and with capacities of a few entries."""
    tmp = tmp_path_factory.mktemp("bounded")
    whole = drill_run(tmp)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(fleet.program, "DRIVEN_NODES_KEPT", 4)
        patch.setattr(fleet.program, "RUNS_KEPT", 1)
        small = drill_run(tmp)
    yield whole, small


def test_the_short_run_passes_the_lowered_capacities(runs):
    whole, small = runs
    assert whole.program.completed.total == len(whole.program.completed) >= 3
    for v in (1, 2):
        assert len(whole.program.recorder.driven[v]) > 2 * 4
    assert len(small.program.completed) < small.program.completed.total


def test_the_recorder_keeps_the_newest_nodes_of_each_vehicle(runs):
    whole, small = runs
    for v in (1, 2):
        full, kept = whole.program.recorder.driven[v], small.program.recorder.driven[v]
        assert 4 <= len(kept) <= 8
        assert kept == full[-len(kept) :]
        assert kept.total == len(full)


def test_the_heat_map_counts_every_segment_driven_not_only_the_nodes_kept(runs):
    whole, small = runs
    full = [whole.program.recorder.driven[v] for v in (1, 2)]
    expected = segment_usage(whole.program.cfg.plant, full)
    assert expected and whole.program.recorder.usage == expected
    assert small.program.recorder.usage == expected
    # the drawing takes the count handed over instead of counting the few nodes kept
    plant = small.program.cfg.plant
    walks = {f"AGV {k}": (small.program.recorder.driven[1 + k % 2], []) for k in range(21)}
    assert len(walks) > HEATMAP_ABOVE
    picture = render(plant, vehicles=walks, usage=small.program.recorder.usage)
    assert picture.mode == "heatmap" and picture.usage == expected
    assert render(plant, vehicles=walks).usage != expected  # what the kept nodes alone give


def test_recipe_runs_are_counted_exactly_and_the_csv_holds_the_newest(runs):
    whole, small = runs
    completed = small.program.completed
    assert 1 <= len(completed) <= 2
    total = whole.program.completed.total
    assert completed.total == total == sum(s.rounds_done for s in small.program.jobs.values())
    assert [(r.vehicle, r.round) for r in completed] == [
        (r.vehicle, r.round) for r in whole.program.completed[-len(completed) :]
    ]
    assert small.result["recipes_completed"] == total == whole.result["recipes_completed"]
    assert fleet_counters(small.program)["recipes_completed"] == total
    image = small.program.rt.image
    assert image.read("fleet.recipes_completed") == total
    assert image.read("fleet.total.recipes") == total
    rounds = {(int(r["vehicle"]), int(r["round"])) for r in small.csv_rows}
    assert rounds == {(r.vehicle, r.round) for r in completed}


# ----- deadlock records --------------------------------------------------------------------


def test_deadlock_records_are_kept_newest_and_every_one_is_logged_once(monkeypatch):
    """The corridor without a siding: eight back-offs and one livelock in 90 s."""
    monkeypatch.setattr(deadlock, "EVENTS_KEPT", 2)
    p = FleetProgram(head_on_config(False))
    try:
        run_checked(p, 90)
    finally:
        p.close()
    records = p.resolver.events
    assert records.total > 2 * 2 and 2 <= len(records) <= 4
    logged = p.events.counts["deadlock"] + p.events.counts["livelock"]
    assert logged == records.total
    assert records.total == p.resolver.resolved + p.resolver.unresolved


def test_the_summary_shows_the_newest_100_deadlock_records():
    cfg = parse_config(ONE_DRILL)
    p = FleetProgram(cfg, clock=VirtualClock())
    p.close()
    for k in range(150):  # as the resolver appends them, oldest first
        p.resolver.events.append(DeadlockEvent(float(k), (1, 2), 2, 5))
    shown = summary(p, 1.0)["deadlock_events"]
    assert len(shown) == 100
    assert [e["time_s"] for e in shown] == [float(k) for k in range(50, 150)]


# ----- the simulator: nodes reached, conflicts seen ----------------------------------------


def test_a_simulated_vehicle_keeps_its_newest_nodes_reached(monkeypatch):
    monkeypatch.setattr(vehicles.agv, "DRIVEN_KEPT", 3)
    plant = model_plant()
    agv = AGV(1, plant, 6)
    reached = [6]
    for _ in range(10):  # along the middle row and back: 6 -> 7 -> 6 -> ...
        to = 7 if agv.node == 6 else 6
        assert agv.command((to,))
        while agv.node != to:
            agv.step(0.01)
        reached.append(to)
    assert agv.driven.total == len(reached) == 11
    assert 3 <= len(agv.driven) <= 6 and agv.driven == reached[-len(agv.driven) :]


def test_the_conflict_monitor_keeps_its_newest_conflicts_and_counts_all(monkeypatch):
    monkeypatch.setattr(vehicles.monitor, "EVENTS_KEPT", 2)
    simulated = Fleet(model_plant(), {1: 0, 2: 10})
    monitor = ConflictMonitor(simulated)
    second = simulated.vehicles[2]
    for _ in range(7):  # vehicle 2 put onto vehicle 1's node and back: a new conflict each time
        second.node = 0
        monitor.check()
        second.node = 10
        monitor.check()
    assert monitor.node == monitor.events.total == 7
    assert 2 <= len(monitor.events) <= 4
    assert all(e.kind == "node" and e.vehicles == (1, 2) for e in monitor.events)


# ----- what an entry holds: the plant's int for its node, not one of its own -------------


def far_ids_plant() -> Plant:
    """Three nodes in a row with ids past the ints Python shares (-5..256)."""
    ids = (1000, 1001, 1002)
    nodes = [Node(n, x=float(k)) for k, n in enumerate(ids)]
    return Plant.build(nodes, [Edge(1000, 1001, 1.0), Edge(1001, 1002, 1.0)])


def fresh(node: int) -> int:
    """An int equal to ``node`` but a new object, as one decoded from a frame is."""
    return int(str(node))


def test_a_simulated_vehicles_nodes_reached_share_the_plants_ints():
    plant = far_ids_plant()
    agv = AGV(1, plant, plant.nodes[0].id)
    for to in (1001, 1002, 1001, 1000):
        assert agv.command((fresh(to),))
        while agv.node != to:
            agv.step(0.01)
    assert list(agv.driven) == [1000, 1001, 1002, 1001, 1000]
    assert all(n is plant.node(n).id for n in agv.driven)


def test_the_recorders_driven_nodes_share_the_plants_ints():
    plant = far_ids_plant()
    control = SimpleNamespace(current=None)
    recorder = fleet.program.FleetRecorder({1: control}, plant)  # type: ignore[dict-item]
    for node in (1000, 1001, 1002, 1001):
        control.current = fresh(node)
        recorder.cycle(None)  # type: ignore[arg-type]  # the recorder reads no context
        recorder.cycle(None)  # type: ignore[arg-type]  # standing still adds no entry
    assert list(recorder.driven[1]) == [1000, 1001, 1002, 1001]
    assert all(n is plant.node(n).id for n in recorder.driven[1])
    assert recorder.usage == {(1000, 1001): 1, (1001, 1002): 2}
