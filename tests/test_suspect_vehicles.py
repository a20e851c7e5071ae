"""Plausibility: a vehicle reporting a position it was never given (pushed by hand, a wrong
tag read, a forged frame that got through) is suspect: stopped, its holds kept, nothing of
it applied, visible everywhere; it returns to service by the documented rule (reporting a
node it holds for ``RECOVER_S``) or by an operator's acknowledge through its tag."""

from __future__ import annotations

import json

import can
import pytest

from blocks.traffic.vehicle_control import RECOVER_S
from fleet.config import load_config
from fleet.dashboard import dashboard
from fleet.program import FleetProgram
from fleet.report import summary
from fleet.tags import ACK_DONE, ACK_REFUSED
from io_drivers.protocol import NO_NODE, STATUS, Codec, RouteCommand, Status


@pytest.fixture
def program():
    cfg = load_config()
    cfg.watchdog = 5.0
    p = FleetProgram(cfg)
    p.rt.start()
    yield p
    p.close()


def move_by_hand(p: FleetProgram, vehicle: int, node: int) -> None:
    """What an operator with a pallet jack does: the vehicle stands at ``node`` now."""
    agv = p.fleet.vehicles[vehicle]
    agv.node, agv.target, agv.progress, agv.speed = node, None, 0.0, 0.0
    agv.route.clear()
    agv.driven.append(node)


def standing(p: FleetProgram, vehicle: int, limit_s: float = 120.0) -> None:
    """Run until ``vehicle`` stands at a node with nothing released (processing, waiting)."""
    agv, control = p.fleet.vehicles[vehicle], p.controls[vehicle]
    done = p.rt.run_until(
        lambda: agv.target is None and not control.released and control.current is not None,
        max_cycles=round(limit_s / p.cfg.cycle_time),
    )
    assert done


def free_node(p: FleetProgram) -> int:
    """A node nobody holds, stands on, or plans to pass: somewhere out of everyone's way."""
    used = {int(p.cfg.plant.ids[n]) for h in p.reservation.holds.values() for n in h}
    used |= {n for c in p.controls.values() for n in c.planned}
    used |= {a.node for a in p.fleet.vehicles.values()}
    # a crossing on the lanes (from a dead end or the exit there may be no way on)
    return next(
        n.id for n in reversed(p.cfg.plant.nodes) if n.id not in used and n.role == "transit"
    )


def test_a_vehicle_moved_by_hand_is_suspect_stopped_and_keeps_its_holds(program):
    p = program
    program.rt.run(duration=20)
    standing(p, 2)
    before = p.reservation.held_by(2)
    away = free_node(p)
    move_by_hand(p, 2, away)
    p.rt.run(duration=1)
    c = p.controls[2]
    assert c.state == "suspect" and c.suspect and c.suspect_events == 1
    assert c.suspect_reason.startswith(f"reports node {away}, never released to it")
    assert p.reservation.held_by(2) == before  # nothing applied
    assert p.fleet.vehicles[2].go is False  # the stop command reached it
    assert p.rt.image.read("agv2.suspect") is True
    assert p.rt.image.read("agv2.state") == 9  # "suspect" in the state codes
    events = [e for e in p.events.events if e.vehicle == 2 and e.kind == "vehicle"]
    assert events[-1].text.endswith(f"-> suspect: {c.suspect_reason}")
    result = json.loads(json.dumps(summary(p, wall_s=1.0)))
    assert result["suspect_vehicles"] == {"2": c.suspect_reason}
    assert result["vehicles"]["2"]["state"] == "suspect"
    assert result["refused_reports"] > 0 and result["suspect_events"] == 1
    # it does not come back by itself while it reports a node it was never given
    p.rt.run(duration=2 * RECOVER_S)
    assert c.suspect
    screen = dashboard(p, None, width=80)
    assert screen is not None


def test_an_operator_acknowledge_moves_its_holds_to_where_it_stands(program):
    p = program
    p.rt.run(duration=20)
    standing(p, 2)
    away = free_node(p)
    move_by_hand(p, 2, away)
    p.rt.run(duration=1)
    assert p.controls[2].suspect
    p.rt.image.write("agv2.ack", 1)  # as an HMI would, through the quiet point
    p.rt.run(duration=0.1)
    c = p.controls[2]
    assert not c.suspect and c.state != "suspect"
    assert p.rt.image.read("agv2.ack_result") == ACK_DONE
    assert p.reservation.held_by(2)[0] == p.cfg.plant.index[away]
    assert any(e.kind == "recovered" and "acknowledged" in e.text for e in p.events.events)
    # back in service: it goes on with its recipes, and nobody meets anybody
    rounds = p.sequencers[2].stations_visited
    p.rt.run(duration=120)
    assert p.sequencers[2].stations_visited > rounds
    assert p.monitor.head_on == 0 and p.monitor.node == 0
    # the same ack value again does nothing (a retried write is not a second acknowledge)
    p.rt.image.write("agv2.ack", 1)
    p.rt.run(duration=0.1)
    assert p.rt.image.read("agv2.ack_result") == ACK_DONE


def test_acknowledging_a_vehicle_that_is_not_suspect_is_refused(program):
    p = program
    p.rt.run(duration=5)
    p.rt.image.write("agv3.ack", 7)
    p.rt.run(duration=0.1)
    assert p.rt.image.read("agv3.ack_result") == ACK_REFUSED
    assert p.events.events[-1].text == "acknowledge refused: not suspect"


def test_a_flood_of_refused_acknowledges_does_not_push_other_events_out(program):
    """A client that writes ``ack`` again and again (a new value every scan) is refused
    every time, but logged once a minute per vehicle and reason: the bounded log keeps
    the events before the flood, and the next logged refusal says how many were left out."""
    p = program
    p.blockades.block(7, 8)
    p.rt.run(duration=5)
    before = list(p.events.events)
    assert [e.text for e in before] == ["segment 7-8 closed"]
    for k in range(1, 2001):  # 100 s at 20 scans a second, three vehicles
        for v in (1, 2, 3):
            p.rt.image.write(f"agv{v}.ack", k % 60000 + 1)
        p.rt.run(duration=0.05)
        assert p.rt.image.read("agv3.ack_result") == ACK_REFUSED
    refusals = [e for e in p.events.events if e.text.startswith("acknowledge refused")]
    assert len(refusals) == 6  # 3 vehicles, at 5 s and at 65 s
    assert all(e in p.events.events for e in before)
    assert refusals[-1].text == (
        "acknowledge refused: not suspect (1199 more like it left out since 5 s)"
    )
    assert p.events.left_out == 3 * 2000 - 6
    assert p.events.counts["vehicle"] == 3 * 2000  # every refusal counted


def test_put_back_where_it_belongs_it_returns_to_service_by_itself(program):
    p = program
    p.rt.run(duration=20)
    standing(p, 1)
    home = p.fleet.vehicles[1].node
    move_by_hand(p, 1, free_node(p))
    p.rt.run(duration=1)
    assert p.controls[1].suspect
    move_by_hand(p, 1, home)  # the operator pushes it back
    p.rt.run(duration=RECOVER_S / 2)
    assert p.controls[1].suspect  # not yet: the rule wants RECOVER_S of consistent reports
    p.rt.run(duration=RECOVER_S)
    assert not p.controls[1].suspect
    visited = p.sequencers[1].stations_visited
    p.rt.run(duration=120)
    assert p.sequencers[1].stations_visited > visited
    assert p.monitor.head_on == 0 and p.monitor.node == 0


def test_a_vehicle_suspect_on_its_return_lane_drives_the_rest_of_the_lane(program):
    """A restarted vehicle link (its counter jumps) on the way back to the entry: once it
    recovers it drives on along the fixed lane, from where it stands, and starts its next
    recipe (a return lane is not planned, so it must be adopted again)."""
    p = program
    v = next(
        v
        for v in sorted(p.sequencers)
        if p.rt.run_until(
            lambda v=v: p.sequencers[v].phase == "returning" and p.controls[v].route,
            max_cycles=round(300 / p.cfg.cycle_time),
        )
    )
    seq, control = p.sequencers[v], p.controls[v]
    round_before = seq.rounds_done
    p.fleet._counter[STATUS + v] = (p.fleet._counter[STATUS + v] + 8) % 16  # a restart
    assert p.rt.run_until(lambda: control.suspect, max_cycles=200)
    assert control.suspect_reason.startswith("link: message counter jumped")
    assert p.rt.run_until(lambda: not control.suspect, max_cycles=round(10 / p.cfg.cycle_time))
    assert p.rt.run_until(
        lambda: seq.rounds_done > round_before or seq.phase != "returning",
        max_cycles=round(120 / p.cfg.cycle_time),
    ), f"vehicle {v} stuck at {control.current}: {control.state}, route {control.route}"


def jump_counter(p: FleetProgram, vehicle: int) -> None:
    """The vehicle's status counter jumps, as after a restart of its controller."""
    p.fleet._counter[STATUS + vehicle] = (p.fleet._counter[STATUS + vehicle] + 8) % 16


def test_a_second_jump_right_after_the_first_is_seen_and_restarts_the_recovery(program):
    p = program
    p.rt.run(duration=20)
    standing(p, 2)
    c = p.controls[2]
    jump_counter(p, 2)
    assert p.rt.run_until(lambda: c.suspect, max_cycles=100)
    p.rt.run(duration=RECOVER_S - 0.2)
    assert c.suspect
    jump_counter(p, 2)  # just before it would have recovered: the recovery starts again
    p.rt.run(duration=0.4)
    assert c.suspect and c.suspect_events == 1
    jump_counter(p, 2)
    p.rt.step()
    jump_counter(p, 2)  # two jumps one scan apart
    p.rt.run(duration=RECOVER_S - 0.3)
    assert c.suspect  # the last jump counts from when it was seen
    # ... and once the link is quiet it recovers by the rule: never stuck
    assert p.rt.run_until(lambda: not c.suspect, max_cycles=round(2 * RECOVER_S / p.cfg.cycle_time))
    assert c.suspect_events == 1


def clear_on_a_segment(p: FleetProgram) -> int:
    """Run until a vehicle has left its node and is well short of the next one: the node
    behind it is free for others, the one ahead held by it."""
    for _ in range(round(120 / p.cfg.cycle_time)):
        p.rt.step()
        for v, agv in p.fleet.vehicles.items():
            left = p.reservation.cleared[v] == p.cfg.plant.index[agv.node]  # reported clear
            if left and agv.target is not None and agv.length - agv.progress > 0.4:
                return v
    raise AssertionError("no vehicle drove a segment")


@pytest.fixture(params=["reactive", "time_windows"])
def either_traffic(request):
    cfg = load_config()
    cfg.watchdog = 5.0
    cfg.traffic = request.param
    p = FleetProgram(cfg)
    p.rt.start()
    yield p
    p.close()


def test_acknowledging_a_vehicle_suspect_on_a_segment_keeps_the_node_it_drives_to(
    either_traffic,
):
    """A vehicle whose link restarted while it drove a segment (clear of the node behind
    it) is suspect, stopped on the segment. An operator's acknowledge confirms what its
    holds already say: the node ahead stays its own (given to it, the node behind would
    free the one it stands in front of for the next vehicle), and it drives on, also with
    time-window traffic (where it stood "planning" for good: its old plan was kept whole,
    though it had dropped it)."""
    p = either_traffic
    v = clear_on_a_segment(p)
    agv, c = p.fleet.vehicles[v], p.controls[v]
    ahead = agv.target
    jump_counter(p, v)
    assert p.rt.run_until(lambda: c.suspect, max_cycles=100)
    held = p.cfg.plant.index[ahead]
    assert agv.target == ahead and held in p.reservation.held_by(v)
    p.rt.image.write(f"agv{v}.ack", 1)
    p.rt.step()
    assert p.rt.image.read(f"agv{v}.ack_result") == ACK_DONE
    assert not c.suspect and held in p.reservation.held_by(v)
    assert p.rt.run_until(lambda: agv.node == ahead, max_cycles=round(10 / p.cfg.cycle_time))
    arrived = len(agv.driven)
    p.rt.run(duration=60)
    assert len(agv.driven) >= arrived + 5  # on with its recipes
    assert (p.monitor.head_on, p.monitor.node, p.monitor.area) == (0, 0, 0)
    assert not any(c.suspect for c in p.controls.values())


def pushed_onto_a_free_segment(p: FleetProgram):
    """Vehicle 3, once it stands, pushed by hand onto the start of a segment between two
    nodes nobody holds or stands on, towards the second: (the simulated vehicle, its control,
    the two node ids); the caller sets how far along it is."""
    plant = p.cfg.plant
    p.rt.run(duration=10)
    standing(p, 3)
    agv, c = p.fleet.vehicles[3], p.controls[3]
    x = free_node(p)
    used = {a.node for a in p.fleet.vehicles.values()} | {
        int(plant.ids[n]) for h in p.reservation.holds.values() for n in h
    }
    t = next(b for (a, b) in plant.arc_index if a == x and b not in used)
    agv.node, agv.target, agv.speed, agv.turn_left = x, t, 0.0, 0.0
    agv.length = float(agv._lengths[(x, t)].length)
    agv.route.clear()
    agv.driven.append(x)
    return agv, c, x, t


def test_acknowledging_a_vehicle_pushed_past_a_node_holds_it_for_the_node_ahead(program):
    """Pushed by hand onto a segment it was never released, past the crossing of the node
    behind it (its report: that node, clear of it, the next one ahead), a vehicle is
    suspect. The operator confirms it: it is held for the node ahead, not for the node it
    has left, and sent on to it."""
    p = program
    plant = p.cfg.plant
    agv, c, x, t = pushed_onto_a_free_segment(p)
    agv.progress = 2 * agv.params.length + 0.1  # its rear off the crossing of x
    assert agv.clear and agv.progress < agv.length
    p.rt.run(duration=1)
    assert c.suspect
    p.rt.image.write("agv3.ack", 1)
    p.rt.step()
    assert p.rt.image.read("agv3.ack_result") == ACK_DONE
    assert p.reservation.held_by(3) == [plant.index[t]]
    for _ in range(round(20 / p.cfg.cycle_time)):
        p.rt.step()
        held = {int(plant.ids[n]) for n in p.reservation.held_by(3)}
        assert not agv.go or agv.target is None or agv.target in held, (agv.target, held)
    assert t in agv.driven[agv.driven.index(x) :] and not c.suspect
    assert p.monitor.head_on == 0 and p.monitor.node == 0


@pytest.mark.parametrize("cancel_lost", [False, True])
def test_an_acknowledge_cancels_the_route_the_vehicle_still_carries(program, cancel_lost):
    """Pushed by hand while it was driving, the vehicle still carries the route it had
    from its old place. An operator's acknowledge moves its holds to where it stands; the
    old route is cancelled before it may go again, so it drives only what it is released.
    The first command after the acknowledge may be lost on the link: the vehicle then still
    reports the old route's next node, which the controller claims for it if it is free
    (else it keeps it stopped and repeats the command), so what it drives stays held."""
    p = program
    plant = p.cfg.plant
    p.rt.run(duration=10)
    found = None
    for _ in range(20_000):
        p.rt.step()
        for v, agv in p.fleet.vehicles.items():
            if agv.target is None or not agv.route:
                continue
            used = {a.node for a in p.fleet.vehicles.values()}
            used |= {a.target for a in p.fleet.vehicles.values()}
            used |= {n for c in p.controls.values() for n in c.planned}
            for x in plant.ids.tolist():
                if (
                    (x, agv.route[0]) in agv._lengths
                    and x not in used
                    and p.reservation.holder_of(plant.index[x]) is None
                ):
                    found = (v, x)
                    break
            if found:
                break
        if found:
            break
    v, x = found
    agv, c = p.fleet.vehicles[v], p.controls[v]
    carried = list(agv.route)
    agv.node, agv.target, agv.progress, agv.speed, agv.turn_left = x, None, 0.0, 0.0, 0.0
    agv.driven.append(x)  # the route on board is left as it was
    p.rt.run(duration=1)
    assert c.suspect and list(agv.route) == carried
    if cancel_lost:  # the first route command for v after the acknowledge never arrives
        receive, lost = p.fleet.receive, []

        def losing(frame_id, data):
            message = Codec().decode(frame_id, data)
            if isinstance(message, RouteCommand) and message.vehicle == v and not lost:
                lost.append(message)
                return
            receive(frame_id, data)

        p.fleet.receive = losing
    p.rt.image.write(f"agv{v}.ack", 1)
    for _ in range(round(5 / p.cfg.cycle_time)):
        p.rt.step()
        # once it may go, whatever it carries or drives to was released to it after the
        # acknowledge (the frames reach it a tick after the program acted: until then it
        # is still stopped)
        held = {int(plant.ids[n]) for n in p.reservation.held_by(v)}
        aboard = set(agv.route) | ({agv.target} if agv.target is not None else set())
        assert not agv.go or aboard <= held, (aboard, held)
    p.rt.run(duration=30)
    assert p.rt.image.read(f"agv{v}.ack_result") == ACK_DONE
    assert c.suspect_events == 1, c.suspect_reason  # it never drove what it was not given
    assert not c.foreign_route and len(agv.driven) > 1 + agv.driven.index(x)  # it drove on
    if cancel_lost:
        assert lost  # (a command after the acknowledge was lost)
    assert p.monitor.head_on == 0 and p.monitor.node == 0


def test_a_vehicle_braked_on_a_segment_it_was_not_released_finishes_it_once_held(program):
    """A vehicle stands on a segment towards a node nobody released to it (braked there when
    a controller before a restart stopped, or pushed by hand there): after the operator's
    acknowledge its released route is empty, yet it reports that node as its next. The
    node is free, so it is claimed for it and the vehicle finishes the segment, held all
    the way, instead of standing there for ever or driving on into a node it does not
    hold."""
    p = program
    plant = p.cfg.plant
    agv, c, x, t = pushed_onto_a_free_segment(p)
    agv.progress = 0.1
    p.rt.run(duration=1)
    assert c.suspect
    p.rt.image.write("agv3.ack", 1)
    for _ in range(round(20 / p.cfg.cycle_time)):
        p.rt.step()
        held = {int(plant.ids[n]) for n in p.reservation.held_by(3)}
        assert not agv.go or agv.target is None or agv.target in held, (agv.target, held)
    assert p.rt.image.read("agv3.ack_result") == ACK_DONE
    assert t in agv.driven[agv.driven.index(x) :] and not c.foreign_route and not c.suspect
    assert p.monitor.head_on == 0 and p.monitor.node == 0


def test_a_vehicle_braked_towards_a_node_another_holds_waits_stopped_and_is_reported(program):
    """The same, but the node ahead is held by a vehicle standing there (on hold): the
    braked vehicle stays stopped (go off) and the event log says why once it has lasted;
    when the other has gone, the node is claimed for it and it finishes the segment."""
    p = program
    plant = p.cfg.plant
    p.rt.run(duration=10)
    standing(p, 2)
    p.rt.image.write("agv2.hold", 1)
    t = p.fleet.vehicles[2].node
    used = {a.node for a in p.fleet.vehicles.values()} | {
        int(plant.ids[n]) for h in p.reservation.holds.values() for n in h
    }
    x = next(a for (a, b) in sorted(plant.arc_index) if b == t and a not in used)
    agv, c = p.fleet.vehicles[3], p.controls[3]
    agv.node, agv.target, agv.progress, agv.speed, agv.turn_left = x, t, 0.1, 0.0, 0.0
    agv.route.clear()
    agv.driven.append(x)
    p.rt.run(duration=1)
    assert c.suspect and agv.speed == 0.0
    braked_at = agv.progress  # (it rolled on a little until the stop reached it)
    p.rt.image.write("agv3.ack", 1)
    for _ in range(round(5 / p.cfg.cycle_time)):
        p.rt.step()
        assert agv.progress == braked_at
    assert c.foreign_route and not c.suspect
    told = [e.text for e in p.events.events if e.vehicle == 3 and "not released" in e.text]
    assert told == [
        f"stopped at node {x}: it reports a next node it was not released (a route it still "
        "carries); the command is repeated"
    ]
    p.rt.image.write("agv2.hold", 0)
    assert p.rt.run_until(lambda: t in agv.driven[agv.driven.index(x) :], round(120 / 0.05))
    assert any(e.vehicle == 3 and e.kind == "recovered" for e in p.events.events)
    assert p.monitor.head_on == 0 and p.monitor.node == 0


def test_a_report_of_a_node_not_in_the_plant_makes_it_suspect_not_faulty(program):
    """A status that passes the link's checks (a forged frame with the right CRC and
    counter, or a vehicle configured for another plant) names node 60000: nothing in it can
    be checked, so the vehicle is stopped as suspect with the reason, the image shows no
    node rather than the forged one, and it returns to service only by the usual rule."""
    p = program
    p.rt.run(duration=20)
    standing(p, 2)
    before = p.reservation.held_by(2)
    codec = Codec()
    forger = can.Bus(interface="virtual", channel=p.bus_channel)
    try:
        counter = p.fleet._counter[STATUS + 2] + 1  # the counter of its last frame, and on
        for k in range(2):  # two consecutive statuses agree: the link takes the position
            fid, data = codec.encode(Status(2, 60000, 60001, "DRIVING", 0.0, (counter + k) % 16))
            forger.send(can.Message(arbitration_id=fid, data=data, is_extended_id=False))
        p.fleet._counter[STATUS + 2] = (counter + 1) % 16  # the real vehicle goes on after them
        c = p.controls[2]
        assert p.rt.run_until(lambda: c.suspect, max_cycles=20)
    finally:
        forger.shutdown()
    assert c.state == "suspect" and c.suspect_reason == "reports node 60000, not in the plant"
    assert p.reservation.held_by(2) == before
    assert p.rt.image.read("agv2.node") == NO_NODE and p.rt.image.read("agv2.next") == NO_NODE
    assert p.rt.image.read("agv2.suspect") is True
    p.rt.step()
    assert p.fleet.vehicles[2].go is False  # stopped
    # the true reports resume: back in service by the rule, and on with its recipes
    assert p.rt.run_until(lambda: not c.suspect, max_cycles=round(3 * RECOVER_S / p.cfg.cycle_time))
    assert p.rt.image.read("agv2.node") == p.fleet.vehicles[2].node
    visited = p.sequencers[2].stations_visited
    p.rt.run(duration=120)
    assert p.sequencers[2].stations_visited > visited
    assert p.monitor.head_on == 0 and p.monitor.node == 0


@pytest.mark.parametrize("traffic", ["reactive", "time_windows"])
@pytest.mark.parametrize("fault", ["dead_after", "stall_after"])
def test_a_vehicle_that_stops_for_good_mid_route_is_driven_round(traffic, fault):
    """Vehicle 2 falls silent (stale) or stalls (fault) on its way into the middle of a
    grid, keeping the node ahead of it; vehicle 1's shortest way crosses that node. It must
    replan round it after its wait, not wait for ever because the node's holder is
    "driving": one out of service makes no way, whatever it holds."""
    from fleet_scenarios import make_config
    from test_tw_traffic import grid_with_stations

    from vehicles.fleet import Faults

    plant = grid_with_stations(7, 5, set(), {(3, 0): 2, (6, 2): 3})
    cell = {(int(n.x), int(n.y)): n.id for n in plant.nodes}
    cfg = make_config(
        plant,
        {1: cell[(3, 4)], 2: cell[(0, 2)]},
        {"a": [2], "b": [3]},
        {2: [cell[(3, 0)]], 3: [cell[(6, 2)]]},
        vehicle_recipes={1: ["a"], 2: ["b"]},
        strategy="nearest",
        processing_s=1.0,
        cycle_time=0.05,
        rounds=1,
        traffic=traffic,
        watchdog=10.0,
    )
    p = FleetProgram(cfg)
    try:
        p.rt.start()
        p.rt.image.write("agv1.hold", 1)  # vehicle 1 sets off once vehicle 2 has stopped
        stopped_at = None
        for _ in range(round(60 / cfg.cycle_time)):
            p.rt.step()
            assert p.rt.state == "RUN", p.rt.fault_reason
            if stopped_at is None and p.fleet.vehicles[2].target == cell[(3, 2)]:
                stopped_at = p.fleet.time
                p.fleet.faults[2] = Faults(**{fault: stopped_at})
                p.rt.image.write("agv1.hold", 0)
        assert stopped_at is not None
        assert p.controls[2].state == ("stale" if fault == "dead_after" else "fault")
        assert cell[(3, 2)] in [int(plant.ids[n]) for n in p.reservation.holds[2]]
        assert [r.vehicle for r in p.completed] == [1]
        assert p.monitor.head_on == 0 and p.monitor.node == 0
    finally:
        p.close()
