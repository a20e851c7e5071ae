"""Transport orders on the running fleet program: the life cycle end to end, the entry point
for orders at run time, unroutable orders, charging, parking, and a property over random
order sets: every reachable order finishes exactly once, no vehicle's battery runs empty,
and the independent monitor counts no conflict."""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_operator_view import one_way_plant
from test_suspect_vehicles import free_node, move_by_hand

from blocks.dispatch.orders import OrderError, OrderState, TransportOrder
from fleet import liveness, order_system
from fleet.config import first_vehicles, parse_config
from fleet.program import FleetProgram
from fleet.report import summary, write_drawing
from fleet.tags import ACK_DONE, ACK_REFUSED
from fleet.web.views import FleetCopy, render_vehicles
from plc_runtime.errors import ConfigError, StartupError
from vehicles.fleet import Faults

WORKSHOP = Path(__file__).resolve().parent.parent / "examples" / "plants" / "workshop.toml"
STATIONS = list(range(20, 30))  # the workshop's ten stations


def config(orders_csv: str, tmp_path: Path, vehicles=((1, 0), (2, 11), (3, 14)), extra: str = ""):
    (tmp_path / "orders.csv").write_text(orders_csv, encoding="utf-8")
    cars = "".join(f"[[vehicles]]\nid = {v}\nstart = {s}\n" for v, s in vehicles)
    text = f"""
[plant]
file = "{WORKSHOP}"
[runtime]
cycle_time_ms = 50
watchdog_ms = 5000
[orders]
file = "orders.csv"
lead_s = 60
[dispatch]
strategy = "two_stage"
buffer_s = 10
get_s = 5
put_s = 5
{extra}
{cars}"""
    return parse_config(text, "orders-test.toml", tmp_path)


def run(p: FleetProgram, seconds: float) -> None:
    for _ in range(round(seconds / p.cfg.cycle_time)):
        p.rt.step()
        assert p.rt.state == "RUN", p.rt.fault_reason


def start(cfg, made) -> FleetProgram:
    p = FleetProgram(cfg)
    made.append(p)
    p.rt.start()
    return p


ORDERS = """id,get,put,start_s,end_s
o1,20,29,0,300
o2,22,27,0,300
o3,24,21,10,400
o4,26,23,20,400
o5,28,25,30,500
"""


@pytest.mark.parametrize("strategy", ["nearest_idle", "dhht", "two_stage"])
def test_every_order_runs_its_life_cycle_and_sections_with_each_strategy(
    strategy, tmp_path, made, monkeypatch
):
    cfg = config(ORDERS, tmp_path)
    cfg.dispatch.strategy = strategy
    p = start(cfg, made)
    run(p, 240)
    book = p.orders.book
    assert book.counts()["FINISHED"] == 5
    for order in book:
        states = [s for _t, s in order.history]
        assert states[:3] == [OrderState.RAW, OrderState.DISPATCHABLE, OrderState.BEING_PROCESSED]
        assert states[-1] is OrderState.FINISHED
        times = [t for t, _s in order.history]
        assert times == sorted(times)
        assert {"Get", "Go_To_Put", "Put"} <= set(order.sections)
        assert all(len(t) == 2 and t[0] <= t[1] for t in order.sections.values())
        assert order.sections["Get"][0] >= order.start_s
    assert sum(r.orders_done for r in p.orders.runners.values()) == 5
    use = summary(p, 1.0)["station_utilisation"]  # every Get and Put dwell, 5 s each
    assert sum(row["visits"] for row in use.values()) == 10
    assert sum(row["busy_s"] for row in use.values()) == pytest.approx(50.0, abs=0.5)
    assert p.monitor.head_on == 0 and p.monitor.node == 0
    # with nothing left to do, the vehicles park (two parking places) or stand aside
    assert sum(r.phase == "parked" for r in p.orders.runners.values()) == 2
    for v, r in p.orders.runners.items():  # each on a place of its own, held by it
        if r.phase == "parked":
            assert p.orders.claims.holder.get(r.current) == v
    drawn = []  # the drawing's title counts the orders, not the (absent) recipes
    monkeypatch.setattr("topology.draw.draw", lambda plant, path, **kw: drawn.append(kw) or path)
    write_drawing(p, tmp_path / "routes.png")
    assert drawn[0]["title"] == "workshop: 3 AGVs, 5 orders in 240 s"


def test_no_scan_walks_the_whole_order_book(tmp_path, made, monkeypatch):
    """A long run's book holds every order it ever had (a million, mostly final): the scan
    looks at the orders that changed, never at all of them. dhht counts each Get station's
    orders as they come, and its rates are the book's all the same."""
    from blocks.dispatch.orders import OrderBook

    cfg = config(ORDERS, tmp_path)
    cfg.dispatch.strategy = "dhht"
    p = start(cfg, made)

    def walked(_book):
        raise AssertionError("a scan walked the whole order book")

    with monkeypatch.context() as m:
        m.setattr(OrderBook, "__iter__", walked)
        run(p, 240)
    assert p.orders.book.counts()["FINISHED"] == 5
    counted = p.orders.dispatcher._supply  # what its last round's rates came from
    assert counted == Counter(o.get for o in p.orders.book)


def test_orders_come_and_go_at_run_time_through_the_entry_point(tmp_path, made):
    # one configured order, released only much later (lead 60 s before its start)
    p = start(config("id,get,put,start_s\no-later,20,25,5000\n", tmp_path), made)
    run(p, 2)
    done = p.orders.submit(TransportOrder("late", 20, 25))
    bad = p.orders.submit(TransportOrder("bad", 20, 20))
    unknown = p.orders.submit(TransportOrder("nowhere", 20, 3))
    before = p.orders.book.counts()
    run(p, 0.1)
    assert done.result(0).state is OrderState.DISPATCHABLE or done.result(0).assigned
    with pytest.raises(OrderError, match="field 'put'"):
        bad.result(0)
    with pytest.raises(OrderError, match="node 3 is not a Get/Put station"):
        unknown.result(0)
    assert len(p.orders.book) == 1  # the bad ones changed nothing
    dup = p.orders.submit(TransportOrder("late", 21, 25))
    run(p, 0.1)
    with pytest.raises(OrderError, match="already used"):
        dup.result(0)
    assert before["RAW"] == 0
    # an id the configuration will release later is taken: refused now, not at release
    taken = p.orders.submit(TransportOrder("o-later", 20, 25))
    run(p, 0.1)
    with pytest.raises(OrderError, match="configured order not released yet"):
        taken.result(0)
    withdrawn = p.orders.submit(TransportOrder("gone", 22, 27))
    run(p, 0.1)
    assert withdrawn.result(0)
    w = p.orders.withdraw("gone")
    run(p, 0.1)
    assert w.result(0).state is OrderState.WITHDRAWN
    run(p, 120)
    assert p.orders.book.get("late").state is OrderState.FINISHED
    assert p.orders.book.get("gone").state is OrderState.WITHDRAWN
    assert not any(
        r.active is not None and r.active.id == "gone" for r in p.orders.runners.values()
    )


def test_a_load_is_never_taken_before_the_orders_start_time(tmp_path, made):
    # two_stage gives the order once the estimated arrival is not before its start, and the
    # estimate here is far too slow (0.1 m/s): the vehicle is there long before 60 s
    cfg = config(
        "id,get,put,start_s\nlater,20,29,60\n",
        tmp_path,
        vehicles=((1, 3),),
        extra="mean_speed = 0.1",
    )
    p = start(cfg, made)
    run(p, 200)
    order = p.orders.book.get("later")
    assert order.state is OrderState.FINISHED
    assert order.sections["Get"][0] >= 60.0
    assert order.sections["Get_Queue"][0] < 60.0  # it waited for the start time


def test_an_order_a_blockade_cuts_off_waits_and_is_driven_once_it_reopens(tmp_path, made):
    """Both segments to station 20 (its only links) are closed from 0 s to 150 s. An order
    from station 20 is not ended for good (closing a segment for a moment must not destroy
    a backlog): it waits, counted as cut off, no vehicle gets it while the station is cut
    off, and it is driven once the segments reopen."""
    links = sorted({b for (a, b) in config(ORDERS, tmp_path).plant.arc_index if a == 20})
    extra = "".join(f"[[blockades]]\nfrom = 20\nto = {b}\nat_s = 0\nuntil_s = 150\n" for b in links)
    cfg = config("id,get,put,start_s\nx,20,29,30\nok,22,27,30\n", tmp_path, extra=extra)
    p = start(cfg, made)
    run(p, 120)
    x = p.orders.book.get("x")
    assert x.state is OrderState.DISPATCHABLE and x.assigned is None  # no vehicle got it
    assert p.orders.dispatcher.cut_off == 1
    assert p.orders.book.get("ok").state is OrderState.FINISHED
    run(p, 200)
    assert x.state is OrderState.FINISHED and p.orders.dispatcher.cut_off == 0


def test_an_order_set_aside_that_is_taken_and_given_back_is_not_lost(tmp_path, made):
    """A round that began before an order was set aside may still give it out, and the
    vehicle give it back: the order must be checked again, not stay out of the pool once
    its station is reachable again."""
    links = sorted({b for (a, b) in config(ORDERS, tmp_path).plant.arc_index if a == 20})
    extra = "".join(f"[[blockades]]\nfrom = 20\nto = {b}\nat_s = 0\nuntil_s = 150\n" for b in links)
    p = start(config("id,get,put\nx,20,29\n", tmp_path, extra=extra), made)
    run(p, 60)
    x, book = p.orders.book.get("x"), p.orders.book
    assert p.orders.dispatcher.cut_off == 1
    book.transition(x, OrderState.BEING_PROCESSED, 60.0, "taken by a round begun before")
    book.transition(x, OrderState.DISPATCHABLE, 60.0, "given back")
    run(p, 30)
    assert x.state is OrderState.DISPATCHABLE and p.orders.dispatcher.cut_off == 1
    run(p, 250)
    assert x.state is OrderState.FINISHED


def test_orders_a_blockade_cuts_off_do_not_keep_the_others_from_being_given_out(tmp_path, made):
    """1,100 urgent orders wait at station 20, which a blockade cuts off; rounds pass over
    at most 1,000 orders they cannot give out before they stop looking. Set aside, those
    orders do not keep the least urgent order elsewhere from being driven; they are all
    counted as cut off, and none ended."""
    rows = "".join(f"c{k},20,25,5\n" for k in range(1100)) + "ok,22,27,0\n"
    links = sorted({b for (a, b) in config(ORDERS, tmp_path).plant.arc_index if a == 20})
    extra = "".join(f"[[blockades]]\nfrom = 20\nto = {b}\nat_s = 0\n" for b in links)
    p = start(config("id,get,put,priority\n" + rows, tmp_path, extra=extra), made)
    run(p, 200)
    assert p.orders.book.get("ok").state is OrderState.FINISHED
    assert p.orders.dispatcher.cut_off == 1100
    assert p.orders.book.counts()["DISPATCHABLE"] == 1100


def test_an_order_no_vehicle_could_ever_drive_is_unroutable_and_reported(tmp_path, made):
    """On the plant as built (one-way segments, no blockade), station 6 leads nowhere: an
    order from it can never be driven, and is ended UNROUTABLE with the reason."""
    plant = one_way_plant(tmp_path)
    (tmp_path / "orders.csv").write_text("id,get,put\nx,6,2\nok,2,4\n")
    text = f'[plant]\nfile = "{plant.name}"\n[runtime]\ncycle_time_ms = 50\n'
    text += '[orders]\nfile = "orders.csv"\n[[vehicles]]\nid = 1\nstart = 1\n'
    p = start(parse_config(text, "one-way.toml", tmp_path), made)
    run(p, 60)
    x = p.orders.book.get("x")
    assert x.state is OrderState.UNROUTABLE and x.assigned is None
    assert x.reason == "no route from Get station 6 to Put station 2"
    assert p.orders.book.get("ok").state is OrderState.FINISHED
    assert p.rt.image.read("fleet.orders.failed") == 1  # what an HMI shows
    assert p.rt.image.read("fleet.orders.finished") == 1


def carrying_a_with_b_next(tmp_path: Path, made):
    """two_stage, one vehicle: order A's load on board (to its Put), order B its next one."""
    cfg = config("id,get,put,start_s\n", tmp_path, vehicles=((1, 0),))
    p = start(cfg, made)
    run(p, 1)
    p.orders.submit(TransportOrder("A", 20, 24))
    p.orders.submit(TransportOrder("B", 29, 27))
    runner = p.orders.runners[1]
    assert p.rt.run_until(
        lambda: runner.next is not None and runner.phase == "to_put", max_cycles=4000
    )
    return cfg, p, runner


def test_without_next_orders_a_busy_vehicle_is_given_work_only_once_free(tmp_path, made):
    """``next_order = false``: where the default gives the carrying vehicle its next order
    (above), B waits in the pool until A is delivered, and is then driven."""
    cfg = config("id,get,put,start_s\n", tmp_path, vehicles=((1, 0),), extra="next_order = false")
    assert cfg.dispatch.next_order is False
    p = start(cfg, made)
    run(p, 1)
    p.orders.submit(TransportOrder("A", 20, 24))
    p.orders.submit(TransportOrder("B", 29, 27))
    p.rt.step()  # (submitted orders enter the book in the next scan)
    runner, a, b = p.orders.runners[1], p.orders.book.get("A"), p.orders.book.get("B")
    for _ in range(4000):
        p.rt.step()
        assert runner.next is None
        if a.state is OrderState.FINISHED:
            break
    assert a.state is OrderState.FINISHED and b.state is OrderState.DISPATCHABLE
    assert p.rt.run_until(lambda: b.state is OrderState.FINISHED, max_cycles=4000)
    taken = [t for t, state, *_ in b.history if state is OrderState.BEING_PROCESSED]
    assert taken[0] >= a.finished_s


def test_the_two_stage_options_are_checked(tmp_path):
    with pytest.raises(ConfigError, match=r"dispatch\.next_order: expected true/false, got 'no'"):
        config("id,get,put\n", tmp_path, extra='next_order = "no"')
    with pytest.raises(ConfigError, match=r"dispatch\.bottleneck_s: .*-5"):
        config("id,get,put\n", tmp_path, extra="bottleneck_s = -5")
    assert config("id,get,put\n", tmp_path, extra="bottleneck_s = 60").dispatch.bottleneck_s == 60


def test_a_next_order_a_blockade_cuts_off_goes_back_and_is_reported(tmp_path, made):
    """two_stage: a vehicle carries its active order and holds a next one when a blockade
    cuts the next order's Get station off. The next order must not stay with the vehicle
    (which would drive for a station it cannot reach): it goes back to the pool, where it
    waits, counted as cut off; the active order is delivered. Once the blockade is lifted
    the next order is driven too."""
    cfg, p, runner = carrying_a_with_b_next(tmp_path, made)
    links = sorted({b for (a, b) in cfg.plant.arc_index if a == 29})
    for b in links:
        p.blockades.block(29, b)
    run(p, 120)
    a, b = p.orders.book.get("A"), p.orders.book.get("B")
    assert a.state is OrderState.FINISHED
    assert b.state is OrderState.DISPATCHABLE and "cut off by a blockade" in b.reason
    assert b.assigned is None and runner.next is None and runner.active is None
    assert p.orders.dispatcher.cut_off == 1
    for c in links:
        p.blockades.unblock(29, c)
    run(p, 120)
    assert b.state is OrderState.FINISHED and p.orders.dispatcher.cut_off == 0


def test_a_section_over_its_estimate_sends_every_next_order_back_for_a_new_round(tmp_path, made):
    """two_stage, two vehicles each carrying an order with a next one. An operator holds
    vehicle 1 on its way to the Put station until that section has taken more than 1.3
    times its estimate: the plan both next orders were given on no longer holds, so both go
    back to the pool in that scan, and new rounds give them out again once vehicle 1 is
    released (B names it). Every order is delivered, without a conflict."""
    cfg = config("id,get,put,start_s\n", tmp_path, vehicles=((1, 0), (2, 11)))
    p = start(cfg, made)
    run(p, 1)
    for oid, get, put, vehicle in (("A", 20, 24, 1), ("B", 29, 27, 1), ("C", 22, 26, 2)):
        p.orders.submit(TransportOrder(oid, get, put, vehicle=vehicle))
    p.orders.submit(TransportOrder("D", 21, 25, vehicle=2))
    runners, d, book = p.orders.runners, p.orders.dispatcher, p.orders.book
    assert p.rt.run_until(
        lambda: all(r.next is not None and r.phase == "to_put" for r in runners.values()),
        max_cycles=6000,
    )
    a, taken_back = runners[1].active, d.reassigned
    nexts = [r.next.id for r in runners.values()]
    p.rt.image.write("agv1.hold", 1)
    assert p.rt.run_until(lambda: (a.id, "Go_To_Put") in d._deviated, max_cycles=2000)
    assert not runners[1].arrived  # (held on the way: the section is not over)
    assert d.reassigned == taken_back + 2
    # both taken back in that scan (and maybe given out again in it)
    (scan_s,) = {
        [at for at, state in book.get(oid).history if state is OrderState.DISPATCHABLE][-1]
        for oid in nexts
    }
    assert p.rt.clock_time - scan_s < 2 * p.cfg.cycle_time
    # (the estimate as the scan saw it: the fleet's measured speed changes as trips end)
    estimate = d.estimates.travel(a.get, a.put)
    assert 0 < estimate < math.inf
    assert scan_s - a.sections["Go_To_Put"][0] > 1.3 * estimate
    p.rt.image.write("agv1.hold", 0)  # (a held vehicle takes no order: B waits for it)
    assert p.rt.run_until(
        lambda: all(book.get(oid).state is OrderState.BEING_PROCESSED for oid in nexts),
        max_cycles=100,
    )
    run(p, 300)
    assert all(book.get(oid).state is OrderState.FINISHED for oid in "ABCD")
    assert (p.monitor.head_on, p.monitor.node, p.monitor.area) == (0, 0, 0)


@pytest.mark.parametrize("which", ["next", "active"])
def test_an_order_withdrawn_in_the_scan_a_blockade_cuts_it_off_stays_withdrawn(
    which, tmp_path, made
):
    """An operator closes the segments round a station and withdraws the order bound for
    it at one quiet point (as the web API can). The withdrawal is applied at the start of
    the next scan and the dispatcher's blockade check runs in the same scan, before the
    vehicle's own: it must not hand the withdrawn order back to the pool (an illegal
    WITHDRAWN -> DISPATCHABLE that faulted the runtime and stopped every vehicle)."""
    cfg, p, runner = carrying_a_with_b_next(tmp_path, made)
    order = runner.next if which == "next" else runner.active
    station = order.get if which == "next" else order.put
    for a, b in sorted(cfg.plant.arc_index):
        if station in (a, b):
            p.blockades.block(a, b)
    withdrawal = p.orders.withdraw(order.id)
    run(p, 60)  # (run() asserts the runtime stays in RUN)
    assert withdrawal.result(0).state is OrderState.WITHDRAWN
    assert order.state is OrderState.WITHDRAWN
    assert runner.next is None or runner.next.id != order.id
    assert runner.active is None or runner.active.id != order.id


def test_a_next_order_is_given_back_when_the_charge_falls_below_good(tmp_path, made):
    """The dispatcher gave a next order while the charge allowed it; on the way the charge
    reads far lower (to 8 %, below critical). Once the active order is delivered the
    vehicle goes charging and the next order goes back to the pool, not onto an empty
    battery."""
    _, p, runner = carrying_a_with_b_next(tmp_path, made)
    agv = p.fleet.vehicles[1]
    agv.battery.charge_as = 0.08 * agv.battery.params.capacity_as
    assert p.rt.run_until(lambda: runner.active is None, max_cycles=4000)
    run(p, 60)
    assert p.orders.book.get("A").state is OrderState.FINISHED
    b = p.orders.book.get("B")
    assert b.state is OrderState.DISPATCHABLE and b.assigned is None
    assert runner.phase in ("to_charger", "charging") and runner.min_battery == 8


def test_a_load_left_on_board_by_a_withdrawn_order_waits_for_the_operator(tmp_path, made):
    """two_stage: vehicle 1 carries order A's load and holds B as its next order when A is
    withdrawn. The load is still on its deck, so it must not drive for B's Get with it: B
    goes back to the pool, and the vehicle takes no order (the only vehicle: B waits) until
    an operator has taken the load off and acknowledged the vehicle through its tag. Then
    it takes B and delivers it. A withdrawal while it loads leaves the load on board too."""
    _, p, runner = carrying_a_with_b_next(tmp_path, made)
    assert runner.load == "A" and not runner.load_left  # on board, for its own order
    p.orders.withdraw("A")
    run(p, 120)
    book = p.orders.book
    a, b = book.get("A"), book.get("B")
    assert a.state is OrderState.WITHDRAWN and runner.load == "A" and runner.load_left
    assert b.state is OrderState.DISPATCHABLE and b.assigned is None and "load on board" in b.reason
    assert runner.active is None and runner.next is None
    left = [e for e in p.events.events if "left on board" in e.text]
    assert [(e.vehicle, e.kind) for e in left] == [(1, "vehicle")]
    assert "order A" in left[0].text and "agv1.ack" in left[0].text
    # what the HTTP API and the operator page show of it
    (view,) = render_vehicles(FleetCopy(p).of([1]))
    assert view["load"] == "A" and view["order"] is None
    assert summary(p, 1.0)["vehicles"]["1"]["load"] == "A"
    # pushed by hand elsewhere meanwhile, it is suspect too: one acknowledge confirms one
    # thing, where it stands first (the usual acknowledge must not confirm a load unseen)
    move_by_hand(p, 1, free_node(p))
    run(p, 1)
    assert p.controls[1].suspect
    p.rt.image.write("agv1.ack", 1)
    run(p, 1)
    assert p.rt.image.read("agv1.ack_result") == ACK_DONE
    assert not p.controls[1].suspect and runner.load_left
    p.rt.image.write("agv1.ack", 2)  # as an HMI would, once the load is off
    run(p, 120)
    assert p.rt.image.read("agv1.ack_result") == ACK_DONE
    assert any(
        e.kind == "recovered" and "load of order A taken off" in e.text for e in p.events.events
    )
    assert runner.load == "" and book.get("B").state is OrderState.FINISHED
    assert book.get("B").history[-1][0] > left[0].time_s + 120  # not a moment before
    # nothing left to confirm: a new ack value is refused, and says why
    p.rt.image.write("agv1.ack", 3)
    run(p, 0.1)
    assert p.rt.image.read("agv1.ack_result") == ACK_REFUSED
    assert p.events.events[-1].text == "acknowledge refused: not suspect, and no load left on board"


def test_a_load_being_loaded_when_its_order_is_withdrawn_stays_on_board(tmp_path, made):
    """Withdrawn while the vehicle loads at its Get station: the load is (partly) on board,
    so the vehicle takes no order until the operator confirms it was taken off."""
    cfg = config("id,get,put,start_s\n", tmp_path, vehicles=((1, 0),))
    p = start(cfg, made)
    run(p, 1)
    p.orders.submit(TransportOrder("A", 20, 24))
    runner = p.orders.runners[1]
    assert p.rt.run_until(lambda: runner.phase == "get", max_cycles=4000)
    p.orders.withdraw("A")
    p.orders.submit(TransportOrder("B", 29, 27))
    run(p, 60)
    assert runner.load_left and runner.load == "A" and runner.active is None
    assert p.orders.book.get("B").state is OrderState.DISPATCHABLE


@pytest.mark.parametrize("dead_s", [8, 14])
def test_a_vehicle_out_of_service_gives_its_orders_up(dead_s, tmp_path, made):
    """Vehicle 1 falls silent for good: at 8 s driving empty to station 20 (released into
    it), at 14 s loading there. A minute later it gives its orders up: one not picked up
    goes back to the pool, where it waits while the station stays held by the silent
    vehicle (nobody queues for it for ever); one with the load on board fails. Its next
    order goes to another vehicle, and its other claims are freed."""
    extra = (  # (into [dispatch], the table config() ends with; no recomputing of next
        # orders on a late section, so vehicle 1 still holds its next order when it gives up)
        "out_of_service_s = 30\ndeviation = 100\n"
        f"[faults]\n[[faults.vehicles]]\nid = 1\ndead_after_s = {dead_s}\n"
    )
    p = start(config(ORDERS, tmp_path, extra=extra), made)
    run(p, dead_s + 29)
    held_next = p.orders.runners[1].next
    run(p, 300 - dead_s - 29)
    book, runner = p.orders.book, p.orders.runners[1]
    assert p.controls[1].state == "stale"
    assert runner.active is None and runner.next is None
    o1 = book.get("o1")
    assert o1.state is (OrderState.FAILED if dead_s == 14 else OrderState.DISPATCHABLE)
    assert "vehicle 1 out of service" in o1.reason
    given_up = [t for t, state in o1.history if state is o1.state][-1]
    assert dead_s + 30 <= given_up < dead_s + 32  # silent, then stale within a second
    assert all(len(times) == 2 for times in o1.sections.values())  # none left open
    assert {o.id for o in book if o.state is OrderState.FINISHED} == {"o2", "o3", "o4", "o5"}
    if dead_s == 14:  # it held o5 as its next order until it gave up
        assert held_next is not None and held_next.id == "o5"
        assert book.get("o5").assigned != 1
    assert all(r.active is None for r in p.orders.runners.values())  # nobody waits for 20
    held = {place for place, v in p.orders.claims.holder.items() if v == 1}
    assert held == ({20} if dead_s == 14 else set())
    # loading when it fell silent: that load stays on board, for the operator to confirm
    assert runner.load_left == (dead_s == 14) and runner.load == ("o1" if dead_s == 14 else "")
    assert p.monitor.head_on == 0 and p.monitor.node == 0


def test_an_order_withdrawn_in_the_scan_its_vehicle_gives_it_up_stays_withdrawn(tmp_path, made):
    """Vehicle 1, loading at station 20, falls silent; the operator withdraws its order
    just as the vehicle's out-of-service time runs out: giving its orders up must not
    touch the withdrawn one (WITHDRAWN -> FAILED faulted the runtime)."""
    extra = "out_of_service_s = 30\n[faults]\n[[faults.vehicles]]\nid = 1\ndead_after_s = 14\n"
    p = start(config(ORDERS, tmp_path, extra=extra), made)
    runner = p.orders.runners[1]
    assert p.rt.run_until(lambda: runner.out_since_ns is not None, max_cycles=round(60 / 0.05))
    order = runner.active
    assert order is not None and runner.phase in ("get", "to_put")
    runner.out_since_ns -= runner.out_of_service_ns  # it gives up in the next scan
    withdrawal = p.orders.withdraw(order.id)
    run(p, 5)
    assert p.orders.runners[1].claims.out_of_service == {1}  # it did give up
    assert withdrawal.result(0).state is OrderState.WITHDRAWN
    assert order.state is OrderState.WITHDRAWN and runner.active is None


@pytest.mark.parametrize(
    ("strategy", "more", "pinned"),
    [
        ("nearest_idle", 0, False),
        ("dhht", 0, False),
        ("two_stage", 0, False),
        ("dhht", 150, False),
        ("dhht", 150, True),
    ],
)
def test_an_order_at_a_station_out_of_service_does_not_starve_the_others(
    strategy, more, pinned, tmp_path, made
):
    """Vehicle 1 falls silent driving into station 20 and gives o1 up; o1 then waits, the
    most urgent order, for a station nobody can use. It must not take a round's free
    vehicle every round: vehicle 2 drives the later orders, which need other stations.
    Nor may ``more`` orders for that station, more urgent than the rest and more than a
    round's pool takes (100), fill the pool: a round passes over them; nor as many for
    other stations that name the silent vehicle as theirs (``pinned``)."""
    extra = "out_of_service_s = 30\n[faults]\n[[faults.vehicles]]\nid = 1\ndead_after_s = 8\n"
    cfg = config("id,get,put,start_s,end_s\no1,20,29,0,300\n", tmp_path, ((1, 0), (2, 11)), extra)
    cfg.dispatch.strategy = strategy
    p = start(cfg, made)
    run(p, 100)
    assert p.orders.book.get("o1").state is OrderState.DISPATCHABLE
    for k in range(more):
        get, put, vehicle = (22, 25, 1) if pinned else (20, 25, None)
        p.orders.submit(TransportOrder(f"s{k}", get, put, 0.0, 5000.0, 5, vehicle))
    for k, (get, put) in enumerate([(22, 27), (24, 21), (26, 23)]):
        p.orders.submit(TransportOrder(f"n{k}", get, put, 0.0, 5000.0))
    run(p, 400)
    book = p.orders.book
    assert [book.get(f"n{k}").state for k in range(3)] == [OrderState.FINISHED] * 3
    assert book.get("o1").state is OrderState.DISPATCHABLE  # station 20 is still held


def test_a_vehicle_back_from_an_outage_on_its_charger_charges_there(tmp_path, made):
    """Silent for 90 s while charging on the workshop's only charger, it gave its claims
    up but that of the charger it stands on; back, it charges there again (it used to
    wait for a free charger, its own not counting as one)."""
    extra = "[battery]\ngood = 35\nsufficient = 40\nfull = 60\n"
    cfg = config("id,get,put\n", tmp_path, vehicles=((1, 0), (2, 11)), extra=extra)
    cfg.battery.start = {1: 30.0, 2: 90.0}
    p = start(cfg, made)
    runner = p.orders.runners[1]
    assert p.rt.run_until(lambda: runner.phase == "charging", max_cycles=round(300 / 0.05))
    charger = runner.current
    p.fleet.faults[1] = Faults(dead_after=p.fleet.time)
    run(p, 90)
    assert runner.phase == "idle" and p.orders.claims.holder.get(charger) == 1
    p.fleet.faults.pop(1)
    run(p, 20)
    assert runner.phase == "charging" and runner.place == charger == runner.current


def test_a_low_battery_vehicle_finishes_its_order_then_charges_and_comes_back(tmp_path, made):
    extra = "[battery]\ngood = 35\nsufficient = 36\nfull = 42\n"
    cfg = config("id,get,put\na,20,29\nb,22,27\n", tmp_path, vehicles=((1, 0),), extra=extra)
    cfg.battery.start = {1: 40.0}
    p = start(cfg, made)
    runner, agv = p.orders.runners[1], p.fleet.vehicles[1]
    assert p.rt.run_until(lambda: runner.active is not None, max_cycles=200)
    first = runner.active.id
    # on its way the battery reads low (an older battery than the controller assumed)
    agv.battery.charge_as = 0.34 * agv.battery.params.capacity_as
    assert p.rt.run_until(lambda: runner.phase == "charging", max_cycles=round(300 / 0.05))
    # it finished the order it had, took no other, and went to the charger
    assert p.orders.book.get(first).state is OrderState.FINISHED
    other = "b" if first == "a" else "a"
    assert p.orders.book.get(other).state is OrderState.DISPATCHABLE
    assert p.cfg.plant.node(runner.current).role == "charger"
    # the first order seemed to use 6 %: it charges until 42 % (42 - 6 >= 35), about 500 s
    # at 30 A, then takes the other order
    run(p, 700)
    assert runner.charges == 1 and runner.charging_s > 400
    assert p.orders.book.get(other).state is OrderState.FINISHED
    assert runner.min_battery == 34


@settings(
    max_examples=6,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(
    pairs=st.lists(
        st.tuples(st.sampled_from(STATIONS), st.sampled_from(STATIONS)).filter(
            lambda t: t[0] != t[1]
        ),
        min_size=1,
        max_size=12,
    ),
    starts=st.lists(st.integers(0, 120), min_size=12, max_size=12),
    strategy=st.sampled_from(["nearest_idle", "dhht", "two_stage"]),
    fleet=st.integers(1, 3),
    charge=st.floats(38.0, 100.0),
)
def test_every_reachable_order_finishes_once_and_no_battery_runs_empty(
    pairs, starts, strategy, fleet, charge, tmp_path_factory
):
    tmp = tmp_path_factory.mktemp("orders")
    rows = "".join(f"o{k},{g},{q},{starts[k]}\n" for k, (g, q) in enumerate(pairs))
    vehicles = ((1, 0), (2, 11), (3, 14))[:fleet]
    cfg = config("id,get,put,start_s\n" + rows, tmp, vehicles=vehicles)
    cfg.dispatch.strategy = strategy
    cfg.battery.start = {v: charge for v, _s in vehicles}
    p = FleetProgram(cfg)
    try:
        p.rt.start()
        deadline = 200 + 60 * len(pairs)
        done = p.rt.run_until(
            lambda: p.orders.book.counts()["FINISHED"] == len(pairs),
            max_cycles=round(deadline / cfg.cycle_time),
        )
        counts = p.orders.book.counts()
        assert done, counts
        assert sum(r.orders_done for r in p.orders.runners.values()) == len(pairs)  # once each
        assert all(r.min_battery > 0 for r in p.orders.runners.values())
        assert all(a.battery.percent > 0 for a in p.fleet.vehicles.values())
        assert p.monitor.head_on == 0 and p.monitor.node == 0
    finally:
        p.close()


def _loop() -> str:
    """A loop of eight nodes: Get station 2 with a queue place (9), Put station 4 without
    one, no parking."""
    nodes = [  # id, x, y, extra keys
        (0, 0, 0, 'role = "entry"\nfunctions = [0]'),
        (1, 1, 0, ""),
        (2, 2, 0, 'role = "station"\nfunctions = [2]'),
        (3, 3, 0, ""),
        (4, 3, 1, 'role = "station"\nfunctions = [3]'),
        (5, 0, 1, 'role = "exit"\nfunctions = [1]'),
        (6, 1, 1, ""),
        (7, 2, 1, ""),
        (9, 2, -1, 'role = "queue"\nqueue_for = 2'),
    ]
    edges = ((0, 1), (1, 2), (2, 3), (3, 4), (4, 7), (7, 6), (6, 5), (5, 0), (1, 6), (1, 9))
    return (
        'name = "loop"\n[functions]\n0 = "entry"\n1 = "exit"\n2 = "get"\n3 = "put"\n'
        + "".join(
            f"[[nodes]]\nid = {n}\nx = {x}.0\ny = {y}.0\n{extra}\n" for n, x, y, extra in nodes
        )
        + "".join(f"[[edges]]\nfrom = {a}\nto = {b}\nlength = 1.0\n" for a, b in edges)
    )


LOOP = _loop()


def test_a_vehicle_pushed_onto_a_station_it_waits_for_is_served_there(tmp_path, made):
    """Put station 4 has no queue place and the loop no parking, so a loaded vehicle
    refused its claim waits on the lane, where the deadlock resolver may push it on, onto
    the station. The claim's holder, behind it, can then never get there: the vehicle on
    the station takes the claim, and the holder is next. Checked after every scan; before,
    the three stood for good from 75 s on with 2 of the 6 orders done. (The last order may
    still wait: with nowhere to park, idle vehicles stand on the loop.)"""
    (tmp_path / "loop.toml").write_text(LOOP, encoding="utf-8")
    (tmp_path / "orders.csv").write_text(
        "id,get,put,start_s,end_s\n" + "".join(f"o{k},2,4,0,600\n" for k in range(6)),
        encoding="utf-8",
    )
    cars = "".join(f"[[vehicles]]\nid = {v}\nstart = {s}\n" for v, s in ((1, 0), (2, 6), (3, 3)))
    text = f"""
[plant]
file = "loop.toml"
[runtime]
cycle_time_ms = 50
watchdog_ms = 5000
[routing]
traffic = "reactive"
[orders]
file = "orders.csv"
[dispatch]
get_s = 5
put_s = 5
[battery]
enabled = false
{cars}"""
    p = start(parse_config(text, "loop-fleet.toml", tmp_path), made)
    claims = p.orders.claims
    for _ in range(round(300 / p.cfg.cycle_time)):
        p.rt.step()
        for v, runner in p.orders.runners.items():
            order = runner.active
            if runner.phase in ("get_queue", "put_queue") and runner.arrived:
                station = order.get if runner.phase == "get_queue" else order.put
                if runner.current == station:
                    assert claims.holder.get(station) == v, (p.rt.clock.now_ns(), v)
    states = [p.orders.book.get(f"o{k}").state for k in range(6)]
    assert states.count(OrderState.FINISHED) >= 5, states
    s = summary(p, 1.0)
    assert s["head_on_conflicts"] == s["node_conflicts"] == s["area_conflicts"] == 0


def loop_config(tmp_path: Path, battery: str = "", vehicle_1: str = ""):
    (tmp_path / "loop.toml").write_text(LOOP, encoding="utf-8")
    (tmp_path / "orders.csv").write_text("id,get,put\no1,2,4\n", encoding="utf-8")
    text = f"""
[plant]
file = "loop.toml"
[orders]
file = "orders.csv"
{battery}
[[recipes]]
name = "lap"
functions = [2, 3]
[[vehicles]]
id = 1
start = 0
{vehicle_1}
[[vehicles]]
id = 2
start = 6
"""
    return parse_config(text, "loop-fleet.toml", tmp_path)


def test_a_fleet_cut_down_to_its_recipe_vehicles_is_refused(tmp_path):
    """Its orders would be dropped without a word: nobody would take them."""
    cfg = loop_config(tmp_path, vehicle_1='recipes = ["lap"]')
    assert cfg.order_vehicles == [2]
    with pytest.raises(ConfigError) as caught:
        first_vehicles(cfg, 1)
    assert str(caught.value) == (
        "--vehicles-count 1: the first 1 vehicles of loop-fleet.toml all run recipes, so "
        "nobody would take its transport orders (vehicles 2 do)"
    )
    assert sorted(cfg.starts) == [1, 2]  # unchanged


def test_an_order_file_checked_against_the_plant_names_the_line(tmp_path, made):
    cfg = config("id,get,put\nok,20,29\nbad,20,99\n", tmp_path)
    with pytest.raises(ConfigError) as caught:
        made.append(FleetProgram(cfg))
    assert str(caught.value) == (
        f"orders-test.toml: orders.file: {tmp_path / 'orders.csv'}:3: order 'bad': field "
        "'put': node 99 is not a Get/Put station"
    )


def test_an_order_for_a_vehicle_vehicles_count_left_out_blames_the_option(tmp_path, made):
    """The configuration has vehicle 3; ``--vehicles-count 2`` dropped it."""
    cfg = config("id,get,put,vehicle\nok,20,29,1\nlate,22,27,3\n", tmp_path)
    first_vehicles(cfg, 2)
    with pytest.raises(ConfigError) as caught:
        made.append(FleetProgram(cfg))
    assert str(caught.value) == (
        f"--vehicles-count 2: orders-test.toml: orders.file: {tmp_path / 'orders.csv'}:3: "
        "order 'late': field 'vehicle': there is no vehicle 3, since the option keeps only "
        "the first 2 vehicles"
    )


@pytest.mark.parametrize(("battery", "warned"), [("", True), ("[battery]\nenabled = false", False)])
def test_order_vehicles_with_batteries_need_a_charger(tmp_path, battery, warned):
    """Else a vehicle below 'good' takes no order and can never recharge."""
    found = liveness.violations(loop_config(tmp_path, battery))
    clause = (
        "batteries on and no charger (role 'charger'): a vehicle below the 'good' threshold "
        "takes no order and cannot recharge"
    )
    assert (clause in found) is warned


def test_requests_to_a_closed_program_end_at_once_with_the_reason(tmp_path, made):
    """A script that closed its program must not wait for ever for a scan: the requests
    still waiting and the later ones end with the reason, and a start is refused."""
    p = start(config(ORDERS, tmp_path), made)
    waiting = p.orders.submit(TransportOrder("w", 20, 24))
    p.close()
    with pytest.raises(RuntimeError, match="closed before the scan"):
        waiting.result(0)
    with pytest.raises(RuntimeError, match="the fleet program is closed"):
        p.orders.submit(TransportOrder("x", 20, 24)).result(0)
    with pytest.raises(StartupError, match="this fleet program was closed"):
        p.rt.start()


def test_a_request_to_a_stopped_program_ends_at_once(tmp_path, made):
    """A fleet program starts once: after a stop no scan answers, so a request says so."""
    p = start(config(ORDERS, tmp_path), made)
    run(p, 1)
    p.rt.stop()
    with pytest.raises(RuntimeError, match="is in STOP and starts once: no scan will answer"):
        p.orders.submit(TransportOrder("late", 20, 24)).result(0)


def test_requests_waiting_for_the_scan_are_bounded(tmp_path, made, monkeypatch):
    monkeypatch.setattr(order_system, "MAX_WAITING", 3)
    p = start(config(ORDERS, tmp_path), made)
    taken = [p.orders.submit(TransportOrder(f"q{k}", 20, 24)) for k in range(3)]
    with pytest.raises(RuntimeError, match="3 requests wait for the scan already"):
        p.orders.submit(TransportOrder("q3", 20, 24)).result(0)
    run(p, p.cfg.cycle_time)
    assert [f.result(0).state for f in taken] == [OrderState.DISPATCHABLE] * 3
    assert p.orders.submit(TransportOrder("q3", 20, 24))  # room again


DC = Path(__file__).resolve().parent.parent / "examples" / "distribution-centre.toml"


def dc_program(made, tmp_path, vehicles: int, orders: list[TransportOrder], **battery):
    """The distribution centre's program with its first ``vehicles`` and these orders only."""
    from blocks.dispatch.order_file import write_orders
    from fleet.config import load_config

    cfg = load_config(DC)
    first_vehicles(cfg, vehicles)
    cfg.watchdog = 5.0
    cfg.battery.enabled = bool(battery)
    for key, value in battery.items():
        setattr(cfg.battery, key, value)
    write_orders(tmp_path / "orders.csv", orders)
    cfg.orders.file, cfg.orders.generator, cfg.orders.lead_s = tmp_path / "orders.csv", None, 1e9
    return start(cfg, made)


def test_closing_the_segment_a_loaded_vehicle_is_on_does_not_fail_its_order(tmp_path, made):
    """The vehicle is partway along a segment, its load on board, when an operator closes
    that segment. It drives on to the segment's end (released to it), from where its Put
    station is still reachable: the order is delivered, not failed as cut off."""
    p = dc_program(made, tmp_path, 1, [TransportOrder("o1", 21, 31, 0.0)])
    agv, runner = p.fleet.vehicles[1], p.orders.runners[1]
    assert p.rt.run_until(
        lambda: runner.phase == "to_put" and agv.target is not None and agv.progress > 1.0,
        max_cycles=round(600 / 0.05),
    )
    a, b = agv.node, agv.target
    p.blockades.block(a, b, both_ways=True)
    run(p, 300)
    order = p.orders.book.get("o1")
    assert order.state is OrderState.FINISHED, order.reason
    assert not runner.load_left


def test_a_vehicle_waiting_for_a_charger_does_not_wait_on_the_station_it_served(tmp_path, made):
    """Every charger is taken when vehicle 6's charge falls below good during its Put:
    it waits for a charger, but off the station and its single-vehicle area, so vehicle 7,
    bound for the same station, is served meanwhile (chargers free up only after an hour)."""
    starts = {1: 30.0, 2: 30.0, 3: 30.0, 4: 30.0, 5: 30.0, 6: 80.0, 7: 90.0}
    chargers = (1, 2, 3, 4, 5)  # at 30 %: they take the plant's five chargers
    orders = [
        TransportOrder("o1", 21, 71, 0.0, vehicle=6),
        TransportOrder("o2", 22, 71, 300.0, vehicle=7),
    ]
    p = dc_program(made, tmp_path, 7, orders, start=starts)
    assert len(p.cfg.plant.with_role("charger")) == len(chargers)
    r6 = p.orders.runners[6]
    assert p.rt.run_until(lambda: r6.phase == "put", max_cycles=round(600 / 0.05))
    battery = p.fleet.vehicles[6].battery
    battery.charge_as = 0.33 * battery.params.capacity_as
    o2 = p.orders.book.get("o2")
    assert p.rt.run_until(lambda: o2.state is OrderState.FINISHED, max_cycles=round(900 / 0.05))
    assert r6.phase == "to_charger" and r6.current not in r6._area(71)
    assert all(p.orders.runners[v].phase == "charging" for v in chargers)
    assert p.monitor.head_on == 0 and p.monitor.node == 0 and p.monitor.area == 0


def close_round(p: FleetProgram, nodes: set[int]) -> None:
    """Close every segment into and out of ``nodes``: they are cut off."""
    for a, b in sorted(p.cfg.plant.arc_index):
        if nodes & {a, b}:
            p.blockades.block(a, b)


@pytest.mark.parametrize("traffic", ["reactive", "time_windows"])
@pytest.mark.parametrize("when", ["to_get", "get"])
def test_an_order_whose_put_station_is_cut_off_before_its_put_leg_does_not_hang(
    when, traffic, tmp_path, made
):
    """The Put station is cut off while the vehicle drives to the Get station, or during
    the Get dwell (its load on board from then on). Not picked up, the order goes back to
    the pool to wait for the segments; picked up, it fails with its load left on board.
    Either way the vehicle leaves the Get station, and the next order there is served: the
    order hung in BEING_PROCESSED, the vehicle on the Get station, for ever."""
    cfg = config("id,get,put\n", tmp_path, vehicles=((1, 0), (2, 14)))
    cfg.traffic = traffic
    p = start(cfg, made)
    run(p, 1)
    p.orders.submit(TransportOrder("A", 20, 24, vehicle=1))
    runner = p.orders.runners[1]
    assert p.rt.run_until(lambda: runner.phase == when, max_cycles=4000)
    close_round(p, {24})
    run(p, 0.1)
    a = p.orders.book.get("A")
    if when == "get":
        assert (a.state, a.reason) == (OrderState.FAILED, "Put station 24 cut off by a blockade")
        assert runner.load_left
    else:
        assert a.state is OrderState.DISPATCHABLE and a.assigned is None
    p.orders.submit(TransportOrder("B", 20, 29, vehicle=2))
    run(p, 0.1)
    b = p.orders.book.get("B")
    assert p.rt.run_until(lambda: b.state is OrderState.FINISHED, max_cycles=round(600 / 0.05))
    assert p.monitor.head_on == p.monitor.node == p.monitor.area == 0


@pytest.mark.parametrize("closed", [{18}, {18, 19}])
def test_a_vehicle_without_work_parks_where_it_can_get_and_frees_its_station(
    closed, tmp_path, made
):
    """A blockade cuts off the nearest parking place (or both): the vehicle that served
    station 20 parks at one it can reach, or, with none, waits aside; either way it leaves
    the station for the next vehicle. It headed for the place cut off and stood on the
    station for ever."""
    p = start(config("id,get,put\n", tmp_path, vehicles=((1, 0), (2, 14))), made)
    close_round(p, closed)
    run(p, 1)
    p.orders.submit(TransportOrder("A", 22, 20, vehicle=1))
    run(p, 0.1)
    a, runner = p.orders.book.get("A"), p.orders.runners[1]
    assert p.rt.run_until(lambda: a.state is OrderState.FINISHED, max_cycles=4000)
    run(p, 20)
    assert runner.place not in closed
    p.orders.submit(TransportOrder("B", 20, 25, vehicle=2))
    run(p, 0.1)
    b = p.orders.book.get("B")
    assert p.rt.run_until(lambda: b.state is OrderState.FINISHED, max_cycles=round(600 / 0.05))
    if closed == {18}:
        assert runner.place == 19 and runner.phase == "parked"
    assert p.orders.claims.holder.get(20) != 1


@pytest.mark.parametrize("when", ["before", "on_the_way"])
def test_a_vehicle_that_must_charge_goes_to_a_charger_it_can_reach(when, tmp_path, made):
    """The nearest charger is cut off (before the vehicle chose it, or on its way there);
    three others are free. It charges at one it can reach: it drove towards the one cut
    off for ever, until its battery was empty."""
    p = dc_program(made, tmp_path, 1, [], start={1: 30.0})
    runner, start_node = p.orders.runners[1], p.cfg.starts[1]
    nearest = min(p.cfg.plant.with_role("charger"), key=lambda c: p.orders.distance(start_node, c))
    if when == "before":
        close_round(p, {nearest})
    else:
        assert p.rt.run_until(lambda: runner.place == nearest, max_cycles=200)
        run(p, 2)
        assert runner.phase == "to_charger" and runner.current != nearest
        close_round(p, {nearest})
    assert p.rt.run_until(lambda: runner.phase == "charging", max_cycles=round(600 / 0.05))
    assert runner.place != nearest and runner.current == runner.place
    assert p.orders.claims.holder.get(nearest) is None


def test_a_strategy_of_ones_own_is_registered_and_dispatches(tmp_path, made, monkeypatch):
    """A researcher's allocation on the whole program: registered under a name, chosen as
    the built-in ones are; an unknown name is a configuration error naming the key."""
    from blocks.dispatch import strategies
    from blocks.dispatch.strategies import Assignment, register_strategy

    monkeypatch.setattr(strategies, "PLUGGED", {})
    seen = []

    def farthest_idle(vehicles, orders, distance):
        free, out = list(vehicles), []
        for order in orders:
            if not free:
                break
            best = max(free, key=lambda c: distance(c.node, order.get))
            seen.append((order.id, [c.vehicle for c in free]))
            yield
            free.remove(best)
            out.append(Assignment(best.vehicle, order))
        return out

    cfg = config("id,get,put\n", tmp_path, vehicles=((1, 0), (2, 14)))
    cfg.dispatch.strategy = "farthest_idle"
    with pytest.raises(ConfigError, match="dispatch.strategy: must be one of .*register_strategy"):
        FleetProgram(cfg)
    register_strategy("farthest_idle", farthest_idle)
    with pytest.raises(ValueError, match="needs a new name"):
        register_strategy("two_stage", farthest_idle)
    p = start(cfg, made)
    run(p, 1)
    distances = {v: p.orders.distance(p.cfg.starts[v], 20) for v in (1, 2)}
    farther = max(distances, key=distances.get)
    assert distances[farther] > distances[3 - farther]
    p.orders.submit(TransportOrder("A", 20, 24))
    run(p, 2)
    order = p.orders.book.get("A")
    assert seen and order.assigned == farther
    assert p.rt.run_until(lambda: order.state is OrderState.FINISHED, max_cycles=round(600 / 0.05))


def test_a_plugged_strategys_mistakes_are_refused_and_named_not_the_fleets_end(
    tmp_path, made, monkeypatch
):
    """A researcher's strategy that is no generator is refused when registered; one that
    hands out what no vehicle can take (a vehicle that does not exist, a tuple, an order
    not in the book, an order intended for another vehicle) loses those assignments,
    counted and named in the summary, while its good ones are applied and the fleet runs
    on (one bad id faulted the whole runtime)."""
    from blocks.dispatch import strategies
    from blocks.dispatch.strategies import Assignment, register_strategy

    monkeypatch.setattr(strategies, "PLUGGED", {})

    def careless(vehicles, orders, distance):
        yield
        first = orders[0]
        mine = next(c.vehicle for c in vehicles)
        return [
            Assignment(99, first),
            (mine, first),
            Assignment([mine], first),
            Assignment(mine, TransportOrder("stranger", 20, 24)),
            Assignment(np.int64(mine), first),  # a numpy id is an id
            Assignment(mine, first),  # the same order again
            *[Assignment(mine, o) for o in orders if o.vehicle not in (None, mine)],
        ]

    register_strategy("careless", careless)
    with pytest.raises(ValueError, match="registered already.*replace=True"):
        register_strategy("careless", lambda *a: (yield))
    cfg = config("id,get,put\n", tmp_path, vehicles=((1, 0), (2, 14)))
    cfg.dispatch.strategy = "careless"
    p = start(cfg, made)
    run(p, 1)
    p.orders.submit(TransportOrder("A", 20, 24))
    p.orders.submit(TransportOrder("B", 22, 27, vehicle=2))
    run(p, 3)
    d = p.orders.dispatcher
    assert p.orders.book.get("A").assigned in (1, 2)  # the good assignment was applied
    assert d.refused >= 5
    assert d.refused_reason == (
        "dispatch strategy 'careless': vehicle 99 is not a vehicle that takes orders"
    )
    # B is intended for vehicle 2: the strategy gives it to vehicle 1 whenever 1 is first
    for _ in range(round(300 / p.cfg.cycle_time)):
        run(p, p.cfg.cycle_time)
        assert p.orders.book.get("B").assigned in (None, 2)
    assert p.orders.book.get("A").state is OrderState.FINISHED
    dispatch = summary(p, 0.0)["dispatch"]
    assert dispatch["refused"] == d.refused and "vehicle 99" in dispatch["refused_reason"]


def test_a_plugged_strategy_that_is_no_generator_is_refused_round_by_round(
    tmp_path, made, monkeypatch
):
    """A function returning its list at once is no round the dispatcher can spread over
    scans, one that raises or never ends no round at all: each round is refused with the
    reason, and the fleet runs on (an exception faulted the runtime); a wrapper that
    returns a built-in strategy's generator is a strategy like any other."""
    from blocks.dispatch import dispatcher, strategies
    from blocks.dispatch.strategies import Assignment, nearest_idle, register_strategy

    monkeypatch.setattr(strategies, "PLUGGED", {})

    def raising(vehicles, orders, distance):
        yield
        raise ValueError("oops in the strategy\nsecond line")

    def endless(vehicles, orders, distance):
        while True:
            yield

    register_strategy("listing", lambda v, o, d: [Assignment(v[0].vehicle, o[0])])
    register_strategy("wrapped", lambda v, o, d: nearest_idle(v, o, d))
    register_strategy("raising", raising)
    register_strategy("endless", endless)
    reasons = {
        "listing": "it returned list, not a generator (it yields after each evaluation and "
        "returns its Assignment list)",
        "raising": "it raised ValueError: oops in the strategy",
        "endless": "its round did not end after 100,000 evaluations",
    }
    monkeypatch.setattr(dispatcher, "PLUGGED_ROUND_MIN", 100_000)
    for name, finished in (
        ("listing", False),
        ("wrapped", True),
        ("raising", False),
        ("endless", False),
    ):
        cfg = config("id,get,put\n", tmp_path, vehicles=((1, 0),))
        cfg.dispatch.strategy = name
        p = start(cfg, made)
        run(p, 1)
        p.orders.submit(TransportOrder("A", 20, 24))
        run(p, 120)
        d = p.orders.dispatcher
        assert p.rt.state == "RUN", p.rt.fault_reason
        assert (p.orders.book.get("A").state is OrderState.FINISHED) is finished, name
        if not finished:
            assert d.refused >= 1 and d.refused_reason == (
                f"dispatch strategy {name!r}: {reasons[name]}"
            )
        p.close()  # one runtime at a time: the next one's watchdog needs SIGALRM


def test_a_queue_place_cut_off_on_the_way_is_given_up_for_another(tmp_path, made):
    """A vehicle heads for its station's queue place while another is served there; a
    blockade cuts the queue place off. It gives the place up and waits elsewhere off the
    lanes: it kept heading for it and waited on the one-way ring, blocking it."""
    p = dc_program(made, tmp_path, 3, [])
    p.orders.submit(TransportOrder("A", 21, 31, vehicle=1))
    p.orders.submit(TransportOrder("B", 21, 32, vehicle=2))
    runners = p.orders.runners.values()
    queue = p.cfg.plant.queues[21][0]
    assert p.rt.run_until(
        lambda: any(r.target == queue and r.current != queue for r in runners), max_cycles=20000
    )
    waiting = next(r for r in runners if r.target == queue)
    close_round(p, {queue})
    run(p, 1)
    assert waiting.target != queue and p.orders.claims.holder.get(queue) is None
    assert waiting.target in p.cfg.plant.with_role("parking", "queue")
    order = waiting.active
    assert p.rt.run_until(lambda: order.state.final, max_cycles=20000)
    assert order.state is OrderState.FINISHED
    assert (p.monitor.head_on, p.monitor.node, p.monitor.area) == (0, 0, 0)


def test_the_hmi_phase_word_of_an_order_vehicle_shows_its_phase(tmp_path, made):
    """An HMI reads an order vehicle's phase in ``agvN.phase`` (it read 0, "start", in
    every phase), and its finished orders in ``agvN.rounds``."""
    from fleet.tags import PHASE_CODES, shown_phase

    p = start(config("id,get,put\no1,20,24\no2,22,27\n", tmp_path, vehicles=((1, 0),)), made)
    runner, seen, before = p.orders.runners[1], set(), "idle"
    for _ in range(round(300 / p.cfg.cycle_time)):
        run(p, p.cfg.cycle_time)
        word = p.rt.image.read("agv1.phase")
        seen.add(word)
        # the phase of this scan, or of the one before if it changed after the word's copy
        assert word in (PHASE_CODES[shown_phase(runner)], PHASE_CODES[before])
        before = shown_phase(runner)
    assert {PHASE_CODES[f] for f in ("to_get", "get", "to_put", "put")} <= seen
    assert min(seen) >= PHASE_CODES["idle"]  # an order vehicle's codes only
    assert p.rt.image.read("agv1.rounds") == runner.orders_done == 2


def test_the_hmi_order_words_count_the_book_by_state(tmp_path, made):
    """An HMI reads the orders waiting, under way, finished, failed and withdrawn in the
    fleet's words; they follow the book within a scan."""
    csv = "id,get,put\no1,20,24\no2,22,27\no3,24,21\no4,26,23\n"
    p = start(config(csv, tmp_path, vehicles=((1, 0), (2, 11))), made)
    words = ("waiting", "active", "finished", "failed", "withdrawn")

    def from_book() -> tuple[int, ...]:
        n = p.orders.book.counts()
        return (
            n["DISPATCHABLE"] + n["RAW"],
            n["BEING_PROCESSED"],
            n["FINISHED"],
            n["FAILED"] + n["UNROUTABLE"],
            n["WITHDRAWN"],
        )

    seen, before = set(), from_book()
    for k in range(round(400 / p.cfg.cycle_time)):
        if k == 20:
            p.orders.withdraw("o4")
        run(p, p.cfg.cycle_time)
        shown = tuple(p.rt.image.read(f"fleet.orders.{w}") for w in words)
        assert shown in (from_book(), before)  # this scan's, or the last if it changed after
        seen.add(shown)
        before = from_book()
    assert shown == from_book() == (0, 0, 3, 0, 1)
    assert any(s[0] > 0 for s in seen) and any(s[1] > 0 for s in seen)
