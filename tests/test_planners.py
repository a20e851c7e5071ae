"""A planner of one's own for the time-window traffic: registered, run on the whole fleet
program, and kept from doing harm: what it gets wrong is refused and counted, never booked,
and the fleet's safety holds whatever it returns."""

from __future__ import annotations

import itertools
import math
import operator

import pytest
from test_tw_traffic import kiva_config, run_checked, tw_config

from blocks.routing.heuristic import distances_to
from blocks.traffic import planners
from blocks.traffic.planners import (
    PlanRequest,
    WindowView,
    planner_names,
    register_planner,
    vetted,
)
from blocks.traffic.sipp import AGV_TURNS, ArcGeometry, TimedPlan
from blocks.traffic.time_windows import TimeWindowTable
from fleet.config import load_config
from fleet.program import FleetProgram
from plc_runtime.errors import ConfigError
from topology import Edge, Node, Plant


@pytest.fixture(autouse=True)
def no_planner_left_behind():
    """Each test registers its own planners; none outlives it."""
    before = dict(planners.PLUGGED)
    planners.PLUGGED.clear()
    yield
    planners.PLUGGED.clear()
    planners.PLUGGED.update(before)


def shortest_then_timed(request: PlanRequest):
    """Route first (the shortest route over the open arcs), then schedule: its earliest
    timing through the free windows."""
    route = yield from request.shortest_route()
    return None if route is None else (yield from request.timed(route))


def done(run):
    """Run a generator to its end: its return value."""
    try:
        while True:
            next(run)
    except StopIteration as stop:
        return stop.value


def free_flow(request: PlanRequest, speed_up: float = 1.0) -> TimedPlan | None:
    """The shortest route timed as if the vehicle were alone (turns and speed limits kept,
    ``speed_up`` times faster): a plan that ignores every other vehicle."""
    route = done(request.shortest_route())
    if route is None:
        return None
    arrive, depart, heading = [request.start_s], [], request.heading
    for a, b in zip(route, route[1:], strict=False):
        direction = request._direction(a, b)
        depart.append(arrive[-1] + request.turns.between(heading, direction))
        arrive.append(depart[-1] + request.travel_s(a, b) / speed_up)
        heading = direction
    depart.append(arrive[-1] + request.hold_s)
    return TimedPlan(request.vehicle, tuple(route), tuple(arrive), tuple(depart), 0.0)


# ----- the plan check, on a small plant ----------------------------------------------------


def tee() -> Plant:
    """0 - 1 - 2 - 3 along x (1 m apart, 2 -> 3 limited to 0.5 m/s), and 4 above 1."""
    nodes = [Node(k, f"n{k}", float(k), 0.0) for k in range(4)] + [Node(4, "n4", 1.0, 1.0)]
    edges = [Edge(0, 1, 1.0), Edge(1, 2, 1.0), Edge(2, 3, 1.0, max_speed=0.5), Edge(1, 4, 1.0)]
    return Plant.build(nodes, edges, name="tee")


def request_on(plant: Plant, table: TimeWindowTable, start: int, goal: int, **kw) -> PlanRequest:
    fields = dict(
        vehicle=1,
        start=start,
        goal=goal,
        start_s=10.0,
        heading=(1.0, 0.0),
        speed=1.0,
        turns=AGV_TURNS,
        hold_s=4.0,
        horizon_s=math.inf,
        until_s=math.inf,
        plant=plant,
        windows=WindowView(table),
        allowed=[True] * plant.n_arcs,
        to_goal=distances_to(plant, [goal])[0],
        weights=None,
        geometry=ArcGeometry(plant),
    )
    fields.update(kw)
    return PlanRequest(**fields)


def fault(plan, request, table) -> str | None:
    return vetted(plan, request, math.inf, request.start_s, table)[1]


def test_a_plan_timed_through_the_windows_passes_the_check():
    plant, table = tee(), TimeWindowTable(0.5)
    request = request_on(plant, table, 0, 3)
    plan = done(request.timed(done(request.shortest_route())))
    assert plan.nodes == (0, 1, 2, 3)
    # 1 s a metre, 2 s on the limited arc; no turn (it faces along the line)
    assert plan.arrive == (10.0, 11.0, 12.0, 14.0) and plan.depart[-1] == 18.0
    assert fault(plan, request, table) is None
    assert fault(free_flow(request), request, table) is None


def test_a_timed_route_waits_for_a_vehicle_booked_before_it():
    plant, table = tee(), TimeWindowTable(0.5)
    table.book(2, [(2, 9.0, 13.0)], [])  # vehicle 2 stands on node 2 until 13 s
    request = request_on(plant, table, 0, 3)
    plan = done(request.timed([0, 1, 2, 3]))
    assert plan.arrive[2] >= 13.5 - 1e-9  # the gap after vehicle 2 leaves
    assert fault(plan, request, table) is None
    assert "meets vehicle 2's window" in fault(free_flow(request), request, table)


def raising():
    """A lazy field that fails half-way."""
    yield 0
    raise RuntimeError("lazy")


class Sneaky(int):
    """An int that says it is another one when converted."""

    def __int__(self):
        return 4


def line(nodes, arrive, depart, vehicle=1) -> TimedPlan:
    return TimedPlan(vehicle, nodes, arrive, depart, 0.0)


GOOD = ((0, 1, 2), (10.0, 11.0, 12.0), (10.0, 11.0, 16.0))  # 0 -> 1 -> 2, at top speed


@pytest.mark.parametrize(
    ("plan", "reason"),
    [
        (line(*GOOD, vehicle=2), "a plan for vehicle 2, not 1"),
        (line((1, 2), (10.0, 11.0), (10.0, 15.0)), "it starts at node 1, not at 0"),
        (line((0, 1), (10.0, 11.0), (10.0, 15.0)), "it ends at node 1, not at the goal 2"),
        (line((0, 1, 2), (9.0, 10.0, 11.0), (9.0, 10.0, 15.0)), "starts at 9 s, not at 10 s"),
        (line((0, 2), (10.0, 12.0), (10.0, 15.0)), "no open arc from node 0 to node 2"),
        (line((0, 1, 2), (10.0, 10.5, 11.5), (10.0, 10.5, 15.0)), "drives 0 -> 1 in 0.5 s"),
        (
            line((0, 1, 4, 1, 2), (10, 11, 12, 14, 16), (10, 11, 14, 15, 20)),
            "it turns on node 1 in 0 s, under 1 s",
        ),
        (line((0, 1, 2), (10.0, 11.0, 12.0), (10.0, 10.5, 15.0)), "before it arrives"),
        (line((0, 1, 2), (10.0, math.nan, 12.0), (10.0, 11.0, 15.0)), "must be finite"),
        (line((0, 1, 2), (10.0, 11.0, 12.0), (10.0, 11.0, math.nan)), "last departure must be"),
        (line((), (), ()), "of one length, at least 1"),
        (line(5, (10.0,), (11.0,)), "a malformed plan (TypeError"),
        (line((0, 1, 2), ("10", 11.0, 12.0), (10.0, 11.0, 15.0)), "must be numbers"),
        (line((0, 1.0, 2), GOOD[1], GOOD[2]), "node ids (integers)"),
        (line((0, True, 2), GOOD[1], GOOD[2]), "node ids (integers)"),
        (line(GOOD[0], GOOD[1], (10.0, 11.0, 10**400)), "a malformed plan (OverflowError"),
        (line((0, Sneaky(1), 2), GOOD[1], GOOD[2]), "no open arc from node 0 to node 4"),
        (line((0, 1) * 60 + (2,), (10.0,) * 121, (10.0,) * 121), "a plan of more than 100 nodes"),
        (line(itertools.count(), GOOD[1], GOOD[2]), "a plan of more than 100 nodes"),
        (line(raising(), GOOD[1], GOOD[2]), "a malformed plan (RuntimeError: lazy"),
    ],
)
def test_what_is_wrong_with_a_plan_is_named(plan, reason):
    plant, table = tee(), TimeWindowTable(0.5)
    request = request_on(plant, table, 0, 2)
    assert fault(line(*GOOD), request, table) is None
    assert reason in fault(plan, request, table)


def test_a_route_longer_than_a_plan_may_be_is_not_timed():
    plant, table = tee(), TimeWindowTable(0.5)
    request = request_on(plant, table, 0, 2)
    assert done(request.timed([0, 1] * 50 + [2])) is None  # 101 nodes: one too many
    assert done(request.timed(itertools.chain([0, 1] * 60, [2]))) is None
    assert done(request.timed([0, 1] * 49 + [2])) is not None  # back and forth, 99 nodes
    assert done(request.timed([0, 1, 2])) is not None


def test_the_arc_speed_limit_holds_for_a_plan():
    plant, table = tee(), TimeWindowTable(0.5)
    plan = line((0, 1, 2, 3), (10.0, 11.0, 12.0, 13.0), (10.0, 11.0, 12.0, 17.0))
    assert "drives 2 -> 3 in 1 s, under the 2 s" in fault(
        plan, request_on(plant, table, 0, 3), table
    )


def test_what_is_booked_is_what_was_checked():
    """Numpy ids and times are booked as plain ints and floats, claimed on departure."""
    import numpy as np

    plant, table = tee(), TimeWindowTable(0.5)
    request = request_on(plant, table, 0, 2)
    plan = TimedPlan(
        np.int64(1),
        np.array([0, 1, 2]),
        np.array([10.0, 11.0, 12.0]),
        (10.0, 11.0, np.float32(16)),
        "x",
    )
    booked, reason = vetted(plan, request, math.inf, 10.0, table)
    assert reason is None
    assert booked.nodes == (0, 1, 2) and all(type(n) is int for n in booked.nodes)
    assert booked.claims == (10.0, 10.0, 11.0) and booked.depart == (10.0, 11.0, 16.0)


def test_a_closed_arc_is_no_way():
    plant, table = tee(), TimeWindowTable(0.5)
    closed = [True] * plant.n_arcs
    closed[plant.arc_index[(1, 2)][0]] = False
    request = request_on(plant, table, 0, 3, allowed=closed)
    assert done(request.shortest_route()) is None and done(request.timed([0, 1, 2, 3])) is None
    plan = TimedPlan(1, (0, 1, 2, 3), (10.0, 11.0, 12.0, 14.0), (10.0, 11.0, 12.0, 18.0), 0.0)
    assert "no open arc from node 1 to node 2" in fault(plan, request, table)


def test_only_windows_claimed_before_the_horizon_are_checked():
    """Steps claimed after the round's horizon are not booked (nor released), so a
    conflict there is the next round's to resolve, as with the built-in search."""
    plant, table = tee(), TimeWindowTable(0.5)
    table.book(2, [(3, 12.0, 30.0)], [])
    request = request_on(plant, table, 0, 3)
    plan = free_flow(request)  # on node 3 from its departure from node 2 at 12 s
    assert "meets vehicle 2" in vetted(plan, request, 12.5, 10.0, table)[1]
    assert vetted(plan, request, 11.5, 10.0, table)[1] is None


# ----- registration and configuration ------------------------------------------------------


def test_a_planner_is_registered_under_a_new_name_once():
    register_planner("route_first", shortest_then_timed)
    assert planner_names() == ("sipp", "route_first")
    register_planner("route_first", shortest_then_timed)  # the same one again: no change
    with pytest.raises(ValueError, match="registered already"):
        register_planner("route_first", lambda request: iter(()))
    register_planner("route_first", free_flow, replace=True)
    for name in ("sipp", "not a name", ""):
        with pytest.raises(ValueError, match="needs a new name"):
            register_planner(name, shortest_then_timed)
    with pytest.raises(TypeError, match="not callable"):
        register_planner("route_second", 3)


def test_an_unknown_planner_is_a_configuration_error_naming_the_field(tmp_path):
    path = tw_config(tmp_path, '\n[time_windows]\nplanner = "route_first"\n')
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    message = str(exc.value)
    assert str(path) in message and "time_windows.planner: must be one of sipp" in message
    assert "register_planner" in message
    register_planner("route_first", shortest_then_timed)
    assert load_config(path).time_windows.planner == "route_first"
    cfg = load_config(tw_config(tmp_path))
    cfg.time_windows.planner = "route_second"  # in code: checked when the program is built
    with pytest.raises(ConfigError, match="time_windows.planner: must be one of"):
        FleetProgram(cfg)


# ----- on the whole program ----------------------------------------------------------------


def test_a_route_first_planner_drives_a_kiva_fleet_without_conflict():
    """30 vehicles on RHCR's kiva map (1,300 nodes), every plan from the planner of one's
    own; every round checked (its windows keep the rules, its order can be executed to the
    end) and the independent monitor after every cycle."""
    register_planner("route_first", shortest_then_timed)
    cfg = kiva_config(30)
    cfg.time_windows.planner = "route_first"
    p, seen = run_checked(cfg, 120)
    tw = p.traffic
    assert tw.refused == 0 and tw.refused_reason is None, tw.refused_reason
    assert tw.plans > 30 and seen["swaps"] > 20
    assert len(p.completed) >= 15
    assert p.monitor.head_on == p.monitor.node == 0


def hostile(request: PlanRequest):
    """A planner whose every vehicle gets a different mistake (by its id), and some none."""
    kind = request.vehicle % 8
    if kind == 1:
        raise RuntimeError("boom")
    if kind == 2:
        return [request.start]  # not a generator
    return _hostile_run(request, kind)


def _hostile_run(request: PlanRequest, kind: int):
    yield
    if kind == 3:
        raise KeyError("mid-run")
    if kind == 4:
        return TimedPlan(
            request.vehicle,
            (request.start, request.goal),
            (request.start_s, 1.0),
            (request.start_s, math.inf),
            0.0,
        )  # a jump to the goal
    if kind == 5:
        return free_flow(request, speed_up=3.0)  # faster than the vehicle drives
    if kind == 6:
        return free_flow(request)  # ignores every other vehicle
    if kind == 7:
        return "a plan"
    return (yield from shortest_then_timed(request))  # kind 0: a proper planner


def test_a_hostile_planner_costs_its_own_plans_not_the_fleets_safety():
    """40 vehicles on kiva with a planner that raises, returns no generator or no plan,
    jumps, drives too fast or ignores the others. What it gets wrong is refused and
    counted; every round still keeps the rules and can be executed to the end, the
    monitor counts no conflict, the runtime never faults, and the vehicles planned
    properly (and those whose free-flow plans happen to be free) complete tasks."""
    register_planner("hostile", hostile)
    cfg = kiva_config(40)
    cfg.time_windows.planner = "hostile"
    p, _seen = run_checked(cfg, 120)
    tw = p.traffic  # (run_checked asserted the runtime in RUN after every cycle)
    assert tw.refused >= 20 and tw.refused_reason.startswith("vehicle ")
    assert p.monitor.head_on == p.monitor.node == 0
    done = {r.vehicle for r in p.completed}
    assert any(v % 8 == 0 for v in done)
    assert not any(v % 8 in (1, 2, 3, 4, 5, 7) for v in done)


def test_a_planner_that_never_returns_is_cut_off_and_the_round_goes_on(monkeypatch):
    """A planner that yields for ever would hold up every vehicle after it in the round:
    it is refused after the work limit, and the others are planned."""
    monkeypatch.setattr(planners, "WORK_LIMIT_MIN", 2_000)
    monkeypatch.setattr(planners, "WORK_LIMIT_PER_NODE", 1)

    def endless_for_one(request: PlanRequest):
        units, deaf = 0, True
        while request.vehicle == 1:
            try:
                yield
            except GeneratorExit:
                # deaf to the program's close at the limit (its 2000th unit), once; the
                # collector's close of this or of an unfinished run is heard
                if units < 1_999 or not deaf:
                    raise
                deaf = False
            units += 1
        return (yield from shortest_then_timed(request))

    register_planner("endless", endless_for_one)
    cfg = kiva_config(10)
    cfg.time_windows.planner = "endless"
    p, _seen = run_checked(cfg, 60)
    tw = p.traffic
    assert tw.refused >= 1
    assert tw.refused_reason == (
        "vehicle 1: the planner took 2000 units of work without a plan (and on closing "
        "raised RuntimeError: generator ignored GeneratorExit)"
    )
    assert {r.vehicle for r in p.completed} - {1}
    assert 1 not in {r.vehicle for r in p.completed}


def test_a_planner_that_answers_at_once_keeps_the_rounds_estimate_sound(monkeypatch):
    """A round sizes itself by the work of the latest searches; a planner that returns
    without a unit of work must not bring that estimate to nothing (it divides by it)."""
    from blocks.traffic import tw_traffic

    monkeypatch.setattr(tw_traffic, "FIRST_WORK_ESTIMATE", 1e-300)

    def at_once(request: PlanRequest):
        return None
        yield  # a generator all the same

    register_planner("at_once", at_once)
    cfg = kiva_config(10)
    cfg.time_windows.planner = "at_once"
    p, seen = run_checked(cfg, 60)  # the runtime in RUN after every cycle
    assert p.traffic.failed > 250 and p.traffic._work_per_search > 0.5


def test_the_summary_counts_refused_plans(tmp_path, capsys):
    import json

    from fleet.cli import main

    register_planner("hostile", hostile)
    path = tw_config(tmp_path, '\n[time_windows]\nplanner = "hostile"\n')
    out = tmp_path / "o"
    assert main(["run", str(path), "--duration", "60", "--json", "--out", str(out)]) == 0
    traffic = json.loads(capsys.readouterr().out)["traffic"]
    assert traffic["refused_plans"] > 0 and traffic["refused_reason"].startswith("vehicle ")


def test_what_a_planner_is_given_cannot_change_what_the_others_are_given():
    """The distances to a goal are the heuristic table's row, and the open arcs and their
    weights the round's lists, shared by every search: a planner gets them read-only."""
    tried = []

    def meddler(request: PlanRequest):
        for change in (
            lambda: operator.setitem(request.to_goal, 0, -1.0),
            lambda: operator.setitem(request.allowed, 0, False),
        ):
            try:
                change()
            except (TypeError, ValueError):
                tried.append(request.vehicle)
        return (yield from shortest_then_timed(request))

    register_planner("meddler", meddler)
    cfg = kiva_config(10)
    cfg.time_windows.planner = "meddler"
    p, _seen = run_checked(cfg, 30)
    assert len(tried) >= 40 and p.traffic.refused == 0, p.traffic.refused_reason
    row = p.table.row(p.cfg.clusters[2][0])
    assert float(row.min()) >= 0.0


def test_a_vehicle_that_finds_no_plan_round_after_round_is_reported_stranded():
    """Route first on 60 kiva vehicles jams: plans are made, dropped for vehicles they box
    in (give way), and fail again. A vehicle whose every round ends without a plan is
    reported (FAULT event, summary ``traffic.stranded``) after ``wait_occupied_s``,
    however many plans it was given and lost meanwhile."""
    register_planner("route_first", shortest_then_timed)
    cfg = kiva_config(60)
    cfg.time_windows.planner = "route_first"
    p = FleetProgram(cfg)
    try:
        p.rt.start()
        p.rt.run(duration=75)
        tw = p.traffic
        assert tw.give_ways > 100 and tw.stranded_at
        assert any(e.kind == "vehicle" and "FAULT" in e.text for e in p.events.events)
    finally:
        p.close()
