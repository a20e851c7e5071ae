"""ReservationMatrix and the vehicle records as the fleet blocks see them."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from blocks.traffic.records import CLEAR, ONLINE, RecordArea, VehicleRecordsView
from blocks.traffic.reservation import ReservationMatrix
from io_drivers.protocol import Info, Status
from io_drivers.vehicle_records import VehicleRecords
from plc_runtime import ProcessImage
from plc_runtime.context import CycleContext
from plc_runtime.image import ProgramImage
from topology import model_plant


def test_holds_follow_reports_and_the_clear_bit():
    plant = model_plant()
    idx = plant.index
    res = ReservationMatrix(plant, [1, 2])
    res.report(1, idx[6])
    res.claim(1, idx[7])
    res.claim(1, idx[8])
    assert res.may_enter(2, idx[7]) == (False, 1)
    res.report(1, idx[6], clear=True)  # left node 6's crossing zone: 6 is free
    assert res.holder_of(idx[6]) is None and res.held_by(1) == [idx[7], idx[8]]
    res.report(1, idx[6], clear=True)  # repeated periodic status: nothing changes
    assert res.held_by(1) == [idx[7], idx[8]]
    res.report(1, idx[7])  # reached 7
    assert res.held_by(1) == [idx[7], idx[8]]
    res.report(1, idx[8])
    assert res.held_by(1) == [idx[8]] and res.holder_of(idx[7]) is None
    assert res.segments() == []
    res.claim(1, idx[9])
    assert res.segments() == [(8, 9, 1)]
    with pytest.raises(RuntimeError):
        res.claim(2, idx[9])
    assert res.refused_reports == 0


def test_a_report_off_the_vehicles_holds_changes_nothing():
    plant = model_plant()
    idx = plant.index
    res = ReservationMatrix(plant, [1, 2])
    assert res.report(1, idx[6]) and res.report(2, idx[9])  # start positions: free nodes
    res.claim(1, idx[7])
    # a node held by another vehicle: no takeover, nothing freed
    assert res.plausible(2, idx[6]) == "reports node 6, held by vehicle 1 (holds 9)"
    assert not res.report(2, idx[6])
    assert res.held_by(1) == [idx[6], idx[7]] and res.held_by(2) == [idx[9]]
    # a jump to a free node it was never released
    assert "never released to it" in res.plausible(2, idx[13])
    # clear where nothing was released beyond: it cannot have left that node
    assert "nothing was released beyond" in res.plausible(2, idx[9], clear=True)
    assert not res.report(2, idx[9], clear=True) and res.held_by(2) == [idx[9]]
    assert res.refused_reports == 2
    # an operator who looked moves the holds; a node held by another is refused
    assert res.relocate(2, idx[7]) == "node 7 is held by vehicle 1"
    assert res.relocate(2, idx[13]) is None and res.held_by(2) == [idx[13]]
    assert res.holder_of(idx[9]) is None


def test_a_relocation_onto_a_segment_another_vehicle_drives_is_refused():
    """An operator confirms a vehicle on a segment, clear of one end: it is held for the
    other end. Not while another vehicle is on that segment, either way: the two would
    face each other, each holding the node behind the other."""
    plant = model_plant()
    idx = plant.index
    res = ReservationMatrix(plant, [1, 2])
    assert res.report(1, idx[6]) and res.report(2, idx[13])
    res.claim(1, idx[7])
    res.report(1, idx[6], clear=True)  # vehicle 1 on 6 -> 7, clear of 6: holds 7 only
    assert res.held_by(1) == [idx[7]] and res.holder_of(idx[6]) is None
    assert res.relocate(2, idx[6], cleared=idx[7]) == "vehicle 1 is on the segment 7-6"
    assert res.held_by(2) == [idx[13]]  # nothing changed
    assert res.relocate(2, idx[8], cleared=idx[7]) is None  # nobody between 7 and 8
    assert res.held_by(2) == [idx[8]] and res.cleared[2] == idx[7]


def test_oncoming_segment_gets_the_very_high_penalty():
    plant = model_plant()
    idx = plant.index
    res = ReservationMatrix(plant, [1, 2], occupied_penalty=5.0)
    res.report(2, idx[7])
    out = np.zeros(plant.n_arcs)
    res.penalties_for(1, out, oncoming=(idx[6], idx[7]))
    arc = plant.arc_index[(6, 7)][0]
    assert out[arc] == pytest.approx(5.0 + res.oncoming_penalty)
    other_into_7 = plant.arc_index[(8, 7)][0]
    assert out[other_into_7] == 5.0


def test_record_view_reads_what_the_vehicle_link_writes():
    image = ProcessImage(sizes={"I": 2048, "Q": 2048})
    records = VehicleRecords(image, [3, 126], 1024, 1024, stale_after_ns=10**9)
    for counter in (1, 2):  # a position is taken when two consecutive statuses agree
        records.received(Status(3, 17, 4, "DRIVING", 0.42, counter, False, True), 0)
    records.received_info(Info(3, 88, 1))
    records.refresh_flags(0)
    image.copy_in()
    view = VehicleRecordsView([RecordArea(1024, 1024, 126)], {3: (0, 3), 126: (0, 126)})
    view.bind(CycleContext(ProgramImage(image), "t", 10**7))
    rec = view.inputs(3)
    assert (int(rec["current"]), int(rec["next"]), int(rec["battery"]), int(rec["speed"])) == (
        17,
        4,
        88,
        42,
    )
    assert int(rec["flags"]) == ONLINE | CLEAR
    view.write_command(126, (5, 6), True, 9)
    image.copy_out()
    assert records.command(126) == (True, 9, (5, 6))


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_the_planned_flow_is_every_vehicles_route_counted_once(data):
    """Whether a vehicle passes nodes (its route shortened from the front, counted
    incrementally) or gets a new route, the flow is every current route's arcs."""
    plant = model_plant()
    res = ReservationMatrix(plant, [1, 2, 3], contraflow_penalty=3.0)
    neighbors = {u: [v for v, _arc, _len in plant.neighbors[u]] for u in range(plant.n)}
    routes = {1: [], 2: [], 3: []}
    for _ in range(data.draw(st.integers(1, 25))):
        v = data.draw(st.sampled_from([1, 2, 3]))
        if routes[v] and data.draw(st.booleans()):
            route = routes[v][data.draw(st.integers(0, len(routes[v]) - 1)) :]  # passed nodes
        else:
            route = [data.draw(st.integers(0, plant.n - 1))]
            for _ in range(data.draw(st.integers(0, 12))):
                if not neighbors[route[-1]]:
                    break  # a dead end
                route.append(data.draw(st.sampled_from(neighbors[route[-1]])))
        routes[v] = route
        res.plan(v, list(route))
        expected = np.zeros_like(res.flow)
        for r in routes.values():
            for a, b in zip(r, r[1:], strict=False):
                expected[res._arc_of[(a, b)]] += 1
        assert np.array_equal(res.flow, expected)


def test_planned_routes_make_the_opposite_direction_cost_more():
    plant = model_plant()
    idx = plant.index
    res = ReservationMatrix(plant, [1, 2, 3], contraflow_penalty=3.0)
    res.plan(2, [idx[6], idx[7], idx[8]])
    res.plan(3, [idx[6], idx[7]])
    out = np.zeros(plant.n_arcs)
    res.penalties_for(1, out)
    against = plant.arc_index[(7, 6)][0]
    assert out[against] == 6.0  # two routes the other way
    assert out[plant.arc_index[(8, 7)][0]] == 3.0
    assert out[plant.arc_index[(6, 7)][0]] == 0.0  # along the flow: free
    res.penalties_for(2, out)
    assert out[against] == 3.0  # its own route is not held against it
    res.plan(2, [idx[8]])  # it has arrived: its share of the flow is gone
    res.penalties_for(1, out)
    assert out[against] == 3.0 and out[plant.arc_index[(8, 7)][0]] == 0.0


def test_a_configured_start_is_held_before_the_first_report_and_a_forged_one_refused():
    """A vehicle's start node is its own before it reports: it is never released to
    another vehicle, and a first report elsewhere (a forged frame) is implausible, where
    without starts a vehicle holding nothing may report any free node."""
    plant = model_plant()
    i = plant.index
    res = ReservationMatrix(plant, [1, 2], starts={1: 0, 2: 10})
    assert res.holds == {1: [i[0]], 2: [i[10]]}
    assert res.holder[i[0]] == 1 and not res.may_enter(2, i[0])[0]
    assert "never released" in res.plausible(1, i[24])
    assert not res.report(1, i[24]) and res.holds[1] == [i[0]]
    assert res.report(1, i[0]) and res.holds[1] == [i[0]]
    free = ReservationMatrix(plant, [1, 2])
    assert free.report(1, i[24]) and free.holds[1] == [i[24]]
