"""The AGV simulator and the CAN driver, co-simulated on the virtual clock over a virtual bus."""

import gc
import itertools
import re
from collections import deque

import can
import pytest
from fleet_helpers import Dispatcher, record

from io_drivers.can_bus import BusOpenError, open_can_bus
from io_drivers.can_driver import FAULT, GO_BIT, LINK_JUMPS, ONLINE, STALE, CanDriver
from io_drivers.protocol import (
    ALL_VEHICLES,
    NO_NODE,
    STATE_CODE,
    Codec,
    RouteCommand,
    Status,
    StopGo,
)
from plc_runtime import Runtime, StartupError, VirtualClock
from topology import model_plant
from vehicles.agv import AGV
from vehicles.cosim import CoSimulation
from vehicles.fleet import Faults, Fleet

_channels = itertools.count()

# these tests are about the bus, not the watchdog: a busy machine must not fault them
WIDE_WATCHDOG = 5.0


def cosim(starts, routes, faults=None, seed=0, cycles=3000):
    plant = model_plant()
    channel = f"cosim-{next(_channels)}"
    fleet_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    fleet = Fleet(plant, starts, fleet_bus, faults=faults, seed=seed)
    driver = CanDriver(starts.keys(), interface="virtual", channel=channel)
    rt = Runtime(cycle_time=0.010, clock=VirtualClock(), watchdog=WIDE_WATCHDOG)
    rt.add_driver(driver)
    rt.add_task("program", [Dispatcher(routes)], priority=0)
    rt.add_task("plant", [CoSimulation(fleet)], priority=9)
    trace = []
    rt.start()
    try:
        for _ in range(cycles):
            rt.step()
            trace.append(
                tuple(
                    (v, a.node, a.target, round(a.progress, 9), a.state)
                    for v, a in fleet.vehicles.items()
                )
            )
        stats = rt.stats.to_dict()["drivers"]["can"]
        image = {
            v: [rt.image.read(f"%IW{record(v) // 2}"), rt.image.read(f"%IB{record(v) + 7}")]
            for v in starts
        }
    finally:
        rt.stop()
        fleet_bus.shutdown()
    return fleet, trace, stats, image


def test_vehicles_drive_their_released_routes_over_can():
    routes = {1: [0, 6, 7, 8, 9, 24], 2: [11, 22, 10]}
    fleet, _trace, stats, image = cosim({1: 0, 2: 11}, routes)
    assert fleet.vehicles[1].driven == [0, 6, 7, 8, 9, 24]
    assert fleet.vehicles[2].driven == [11, 22, 10]
    assert fleet.vehicles[1].state == "WAITING_FOR_ROUTE"  # stopped at the exit's centre
    assert image[1] == [24, ONLINE] and image[2] == [10, ONLINE | 0]
    assert stats["malformed"] == 0 and stats["frames_in"] > 0 and stats["stale"] == []


def test_cosimulation_is_deterministic_with_the_same_seed():
    faults = {1: Faults(drop_rate=0.2, corrupt_rate=0.05)}
    args = ({1: 0, 2: 11}, {1: [0, 6, 7, 8, 9, 24], 2: [11, 22, 10, 0, 6]})
    a = cosim(*args, faults=faults, seed=7, cycles=1500)
    b = cosim(*args, faults=faults, seed=7, cycles=1500)
    assert a[1] == b[1] and a[2] == b[2]
    c = cosim(*args, faults=faults, seed=8, cycles=1500)
    assert c[2] != a[2]  # another seed loses other frames


def test_without_a_next_node_the_vehicle_stops_at_the_node_centre():
    plant = model_plant()
    agv = AGV(1, plant, 0)
    assert agv.command((6,))
    reached = sum(agv.step(0.01) for _ in range(1000))
    assert reached == 1 and agv.node == 6 and agv.speed == 0.0 and agv.target is None
    assert agv.state == "WAITING_FOR_ROUTE"


def test_turns_take_time_and_straight_passes_do_not():
    plant = model_plant()
    straight, turn = AGV(1, plant, 0), AGV(2, plant, 0)
    straight.command((6, 7))  # 0 -> 6 -> 7 along the middle row
    turn.command((6, 2))  # 0 -> 6 then up: a 90 degree turn at 6
    steps = {}
    for agv in (straight, turn):
        for k in range(1, 2000):
            agv.step(0.01)
            if agv.node != 6 and agv.tag_reads == 2:
                steps[agv.vehicle] = k
                break
    # 1.8 m vs 1.8 m of driving, but the turn stops the vehicle and costs turn_90 = 1 s
    assert steps[2] - steps[1] >= 100


def test_front_sensor_stops_the_follower_until_the_lane_is_clear():
    fleet = Fleet(model_plant(), {1: 6, 2: 0})  # no bus: commands given directly
    leader, follower = fleet.vehicles[1], fleet.vehicles[2]
    leader.command((7, 8))  # the leader stops at 8 ...
    follower.command((6, 7, 8, 9))  # ... where the follower wants to pass
    for _ in range(3000):
        fleet.step(0.01)
    assert leader.node == 8 and leader.target is None
    assert follower.target == 8 and follower.speed == 0.0 and follower.blocked_ahead
    # stopped short of the leader by its own length plus the sensor's free space
    assert (
        follower.length - follower.progress
        >= follower.params.length
        + follower.params.sensor_range
        - 0.005  # one 10 ms step: the sensor is sampled
    )
    leader.command((9, 24))  # the lane clears: the follower resumes
    for _ in range(3000):
        fleet.step(0.01)
    assert leader.driven[-1] == 24 and follower.driven[-2:] == [8, 9]


def test_random_delays_stop_a_vehicle_for_a_while_and_end_after_the_faults_are_gone():
    straight = (7, 8, 9, 24)
    plain = Fleet(model_plant(), {1: 6})
    plain.vehicles[1].command(straight)
    delayed = Fleet(model_plant(), {1: 6}, faults={1: Faults(delay_rate=0.5, delay_s=(2.0, 3.0))})
    delayed.vehicles[1].command(straight)
    t_plain = t_delayed = None
    for k in range(4000):
        plain.step(0.01)
        delayed.step(0.01)
        if k == 500:
            delayed.faults.clear()  # a delay under way still ends
        if t_plain is None and plain.vehicles[1].driven[-1] == 24:
            t_plain = plain.time
        if t_delayed is None and delayed.vehicles[1].driven[-1] == 24:
            t_delayed = delayed.time
    assert delayed.counters["delays"] >= 1
    assert delayed.vehicles[1].paused_until is None
    assert t_plain is not None and t_delayed is not None
    assert t_delayed >= t_plain + 2.0  # at least one stop of 2-3 s on the way


def test_battery_drains_while_driving_and_charges_on_a_charger():
    from topology import warehouse

    plant = warehouse()
    charger = plant.with_role("charger")[0]
    agv = AGV(1, plant, charger)
    agv.battery.charge_as = 100_000.0
    for _ in range(1000):
        agv.step(0.1)
    assert agv.state == "CHARGING" and agv.battery.charge_as == pytest.approx(100_000 + 30 * 100)
    far = AGV(2, plant, 1)
    far.command((2, 3))
    before = far.battery.charge_as
    for _ in range(100):
        far.step(0.1)
    assert before - far.battery.charge_as > 7.0 * 5  # at least b0 over the drive


def test_dead_vehicle_is_flagged_stale_and_nothing_crashes():
    faults = {2: Faults(dead_after=2.0)}
    fleet, _trace, stats, image = cosim(
        {1: 0, 2: 11}, {1: [0, 6, 7], 2: [11, 22, 10]}, faults=faults, cycles=600
    )
    assert stats["stale"] == [2] and image[2][1] == STALE
    assert image[1][1] == ONLINE


def test_lossy_and_corrupting_links_are_survived():
    faults = {1: Faults(drop_rate=0.05, corrupt_rate=0.05)}
    fleet, _trace, stats, image = cosim(
        {1: 0}, {1: [0, 6, 7, 8, 9, 24]}, faults=faults, seed=3, cycles=3000
    )
    assert fleet.counters["dropped"] > 0 and fleet.counters["corrupted"] > 0
    assert stats["crc_errors"] == fleet.counters["corrupted"]  # every one counted, not applied
    assert stats["lost"] > 0  # counter steps over dropped and corrupted frames
    assert fleet.vehicles[1].driven == [0, 6, 7, 8, 9, 24]  # the route still completes
    # three frames lost in a row look like a counter jump: the link may count one
    assert image[1][0] == 24 and image[1][1] & ~LINK_JUMPS == ONLINE


def test_faults_are_reported():
    faults = {1: Faults(stall_after=1.0)}
    fleet, _trace, _stats, image = cosim({1: 0}, {1: [0, 6, 7, 8]}, faults=faults, cycles=300)
    assert fleet.vehicles[1].state == "FAULT" and image[1][1] == ONLINE | FAULT


def test_malformed_frames_and_unknown_ids_are_counted(tmp_path):
    channel = f"bad-{next(_channels)}"
    noise = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    driver = CanDriver([1], interface="virtual", channel=channel)
    rt = Runtime(cycle_time=0.010, clock=VirtualClock(), watchdog=WIDE_WATCHDOG)
    rt.add_driver(driver)
    rt.add_task("program", [Dispatcher({})])
    rt.start()
    codec = Codec()
    good_id, good = codec.encode(Status(1, 5, NO_NODE, "IDLE", 0.0, 1))
    _, again = codec.encode(Status(1, 5, NO_NODE, "IDLE", 0.0, 2))
    layout = codec.layouts[0x100]
    state_15 = bytearray(layout.pack(0, 3, 15, 5, NO_NODE, 0, 0, 0, 0.0))  # a valid CRC ...
    state_15[0] = codec.crc(good_id, state_15)  # ... over an out-of-range state
    frames = [
        (good_id, good[:5]),  # wrong length
        (good_id, bytes(state_15)),  # state 15: out of range
        (0x300, bytes(8)),  # unknown id
        (0x105, good),  # vehicle 1's frame under the id of vehicle 5: the CRC's data id differs
        (0x102, codec.encode(Status(2, 1, 2, "IDLE", 0.0, 1))[1]),  # a vehicle we do not manage
        (good_id, good),
        (good_id, again),  # the position repeated: confirmed
    ]
    for frame_id, data in frames:
        noise.send(can.Message(arbitration_id=frame_id, data=data, is_extended_id=False))
    noise.send(can.Message(arbitration_id=0x1FFFFFF, data=b"x", is_extended_id=True))
    # a valid frame's bytes as CAN FD: not a frame of this classic-CAN protocol
    noise.send(can.Message(arbitration_id=good_id, data=good, is_extended_id=False, is_fd=True))
    rt.step()
    stats = driver.stats()
    assert stats["malformed"] == 2 and stats["unknown_id"] == 3 and stats["unknown_vehicle"] == 1
    assert stats["crc_errors"] == 1 and stats["frames_in"] == 3
    assert rt.state == "RUN" and rt.image.read(f"%IW{record(1) // 2}") == 5
    rt.stop()
    noise.shutdown()


def test_the_vehicles_obey_classic_can_frames_only_and_read_a_bus_worth_a_step():
    """A command as a CAN FD frame is not the protocol's, and is ignored; a flood waiting
    on a bus without a bit rate (virtual, UDP) is read what 1 Mbit/s carries in a step, so
    one step cannot stall on it, and nothing of it is lost: the next steps read the rest."""
    channel = f"fd-{next(_channels)}"
    controller = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    fleet = Fleet(model_plant(), {1: 0}, can.Bus(interface="virtual", channel=channel))
    fleet.step(0.01)
    codec = Codec()
    frame_id, data = codec.encode(RouteCommand(1, 1, (6,)))
    controller.send(
        can.Message(arbitration_id=frame_id, data=data, is_extended_id=False, is_fd=True)
    )
    for _ in range(20):
        fleet.step(0.01)
    assert fleet.vehicles[1].route == deque() and fleet.vehicles[1].target is None
    assert fleet.counters["ignored"] == 1
    for _ in range(250):  # 0.01 s of a 1 Mbit/s bus carries 100 frames
        controller.send(can.Message(arbitration_id=0x7FF, data=b"x", is_extended_id=True))
    fleet.step(0.01)
    assert fleet.counters["ignored"] == 1 + 100
    fleet.step(0.01)
    fleet.step(0.01)
    assert fleet.counters["ignored"] == 1 + 250
    controller.send(can.Message(arbitration_id=frame_id, data=data, is_extended_id=False))
    for _ in range(20):
        fleet.step(0.01)
    assert fleet.vehicles[1].driven[-1] == 6 or fleet.vehicles[1].target == 6
    fleet.bus.shutdown()
    controller.shutdown()


def test_a_broadcast_go_starts_no_vehicle_and_a_broadcast_stop_stops_them_all():
    """The broadcast id is the controller's last word (everyone stops); a go is always a
    vehicle's own, so a single frame, however valid, cannot set a held fleet off."""
    fleet = Fleet(model_plant(), {1: 0, 2: 10}, None)
    codec = Codec()
    for v in (1, 2):
        fleet.receive(*codec.encode(StopGo(v, False, 1)))
    fleet.receive(*codec.encode(StopGo(ALL_VEHICLES, True, 1)))
    assert [a.go for a in fleet.vehicles.values()] == [False, False]
    assert fleet.counters["ignored"] == 1
    for v in (1, 2):
        fleet.receive(*codec.encode(StopGo(v, True, 2)))
    fleet.receive(*codec.encode(StopGo(ALL_VEHICLES, False, 2)))
    assert [a.go for a in fleet.vehicles.values()] == [False, False]


def test_driver_sends_route_commands_on_sequence_change_and_stops_everyone_on_close():
    channel = f"cmd-{next(_channels)}"
    listener = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    driver = CanDriver([3], interface="virtual", channel=channel)
    rt = Runtime(cycle_time=0.010, clock=VirtualClock(), watchdog=WIDE_WATCHDOG)
    rt.add_driver(driver)
    rt.add_task("program", [Dispatcher({})])
    rt.start()
    base = record(3)
    rt.image.write_many(
        {
            f"%QW{base // 2}": 6,
            f"%QW{base // 2 + 1}": 7,
            f"%QB{base + 6}": GO_BIT | 2,
            f"%QB{base + 7}": 1,
        }
    )
    rt.step(3)
    rt.stop()
    codec = Codec()
    got = []
    while (msg := listener.recv(timeout=0)) is not None:
        got.append(codec.decode(msg.arbitration_id, msg.data))
    routes = [m for m in got if isinstance(m, RouteCommand)]
    # once, not every cycle; at stop the safe state (all outputs 0) goes out before the
    # driver closes: the route is cancelled (no nodes) and the vehicle stopped
    assert routes == [RouteCommand(3, 1, (6, 7)), RouteCommand(3, 0, ())]
    stops = [m for m in got if type(m).__name__ == "StopGo"]
    assert stops[0].vehicle == 3 and stops[0].go  # go bit set from the first scan
    assert (stops[-2].vehicle, stops[-2].go) == (3, False)  # the safe state
    assert stops[-1].vehicle == 127 and not stops[-1].go  # closing the driver stops everyone
    assert got.index(stops[-2]) < got.index(routes[-1])  # the stop before the cancel
    listener.shutdown()


def test_bad_interface_is_a_clear_startup_error():
    rt = Runtime(cycle_time=0.010, clock=VirtualClock(), watchdog=WIDE_WATCHDOG)
    rt.add_driver(CanDriver([1], interface="no-such-interface", channel="x"))
    rt.add_task("program", [Dispatcher({})])
    with pytest.raises(
        StartupError, match="driver can: cannot open: CAN interface 'no-such-interface'"
    ):
        rt.start()
    rt.stop()


@pytest.mark.parametrize(
    ("interface", "cause"),
    [
        ("socketcand", "TypeError: SocketCanDaemonBus.__init__() missing"),  # no host, port
        ("neousys", "Neousys WDT_DIO Can driver missing"),  # no vendor library
    ],
)
def test_an_interface_that_cannot_open_is_one_error(interface, cause, caplog):
    """Each python-can interface fails in its own way; both ends of the link report one
    error naming interface, channel and cause (the controller at start, the vehicles'
    process as its exit line), and the half-made bus does not log a second line."""
    with pytest.raises(BusOpenError) as error:
        open_can_bus(interface, "0")
    assert str(error.value).startswith(f"CAN interface {interface!r} channel '0': {cause}")
    gc.collect()
    assert "not properly shut down" not in caplog.text
    rt = Runtime(cycle_time=0.010, clock=VirtualClock(), watchdog=WIDE_WATCHDOG)
    rt.add_driver(CanDriver([1], interface=interface, channel="0"))
    rt.add_task("program", [Dispatcher({})])
    with pytest.raises(StartupError, match=re.escape(f"cannot open: CAN interface {interface!r}")):
        rt.start()
    rt.stop()
    gc.collect()
    assert "not properly shut down" not in caplog.text


def test_state_codes_match_the_dbc():
    assert STATE_CODE["FAULT"] == 6 and STATE_CODE["IDLE"] == 0


def test_battery_failure_is_a_reported_fault():
    faults = {1: Faults(battery_failure_after=0.5)}
    fleet, _trace, _stats, image = cosim({1: 0}, {1: [0, 6, 7, 8]}, faults=faults, cycles=300)
    agv = fleet.vehicles[1]
    assert agv.state == "FAULT" and agv.battery.percent == 0.0 and agv.speed == 0.0
    assert image[1][1] == ONLINE | FAULT


def test_oncoming_vehicles_stop_instead_of_passing_through_each_other():
    fleet = Fleet(model_plant(), {1: 6, 2: 7})
    fleet.vehicles[1].command((7,))
    fleet.vehicles[2].command((6,))
    for _ in range(1000):
        fleet.step(0.01)
    a, b = fleet.vehicles[1], fleet.vehicles[2]
    assert a.driven == [6] and b.driven == [7]  # nobody got through: a head-on standoff
    assert a.speed == b.speed == 0.0 and a.blocked_ahead and b.blocked_ahead
    assert a.progress + b.progress + a.params.length + b.params.length <= a.length + 1e-9


def test_a_new_direction_during_a_turn_costs_its_own_turn_time():
    agv = AGV(1, model_plant(), 0)
    agv.command((6, 7))
    while agv.node != 7:
        agv.step(0.01)
    agv.command((3,))  # at 7, heading east: north is a 90 degree turn
    agv.step(0.01)
    assert agv.turn_left == pytest.approx(1.0)  # the turn began in this step
    agv.command((6,))  # changed before setting off: back west is a 180 degree turn
    assert agv.turn_left == pytest.approx(2.0)


def test_a_route_cancelled_during_a_turn_leaves_the_vehicle_standing_where_it_is():
    """The controller cancels routes (an operator's acknowledge, its safe state on STOP): a
    vehicle turning on the spot then stops turning and waits, where it used to finish the
    turn and set off towards a route it no longer had (IndexError, the process gone)."""
    agv = AGV(1, model_plant(), 0)
    agv.command((6, 7))
    while agv.node != 7:
        agv.step(0.01)
    agv.command((3,))  # a 90 degree turn at 7
    for _ in range(30):
        agv.step(0.01)
    assert 0 < agv.turn_left < 1.0 and agv.state == "DRIVING"
    agv.command(())
    assert agv.turn_left == 0 and agv.state == "WAITING_FOR_ROUTE"
    for _ in range(300):
        agv.step(0.01)
    assert (agv.node, agv.target, agv.driven[-1]) == (7, None, 7)
    agv.command((3,))  # released again: the whole turn, then it drives
    for _ in range(1000):
        agv.step(0.01)
    assert agv.node == 3


def test_failed_sends_are_retried_next_tick():
    channel = f"retry-{next(_channels)}"
    listener = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    driver = CanDriver([3], interface="virtual", channel=channel)
    rt = Runtime(cycle_time=0.010, clock=VirtualClock(), watchdog=WIDE_WATCHDOG)
    rt.add_driver(driver)
    rt.add_task("program", [Dispatcher({})])
    rt.start()
    real_send, failures = driver.bus.send, [1]

    def flaky(msg, timeout=None):
        if failures:
            failures.pop()
            raise can.CanOperationError("transmit buffer full")
        return real_send(msg, timeout)

    driver.bus.send = flaky
    base = record(3)
    rt.image.write_many({f"%QB{base + 6}": GO_BIT})
    rt.step(3)
    codec = Codec()
    got = []
    while (msg := listener.recv(timeout=0)) is not None:
        got.append(codec.decode(msg.arbitration_id, msg.data))
    assert any(type(m).__name__ == "StopGo" and m.vehicle == 3 and m.go for m in got)
    assert driver.counters["send_errors"] == 1
    rt.stop()
    listener.shutdown()


def test_a_vehicle_that_never_reports_becomes_stale():
    channel = f"silent-{next(_channels)}"
    driver = CanDriver([1, 2], interface="virtual", channel=channel)
    rt = Runtime(cycle_time=0.010, clock=VirtualClock(), watchdog=WIDE_WATCHDOG)
    rt.add_driver(driver)
    rt.add_task("program", [Dispatcher({})])
    rt.start()
    rt.step(10)
    assert rt.image.read(f"%IB{record(2) + 7}") == 0 and driver.stats()["stale"] == []  # not yet
    rt.step(60)
    assert rt.image.read(f"%IB{record(2) + 7}") == STALE and driver.stats()["stale"] == [1, 2]
    rt.stop()
