"""End-to-end protection of the vehicle messages: CRC, counters, confirmation of positions,
the compiled codec, the Modbus link's checks, fault injection, and a fleet under faults."""

from __future__ import annotations

import itertools
import random

import can
import cantools
import pytest
from fleet_helpers import Dispatcher, record

from io_drivers.can_driver import (
    CLEAR,
    FAULT,
    LINK_JUMP_SHIFT,
    ONLINE,
    STALE,
    CanDriver,
    frames_per_tick,
)
from io_drivers.e2e import (
    ACCEPTED,
    OUT_OF_SEQUENCE,
    REPEATED,
    RESYNC,
    CounterCheck,
    crc8,
)
from io_drivers.modbus_vehicles import ModbusVehicleLink
from io_drivers.protocol import (
    BATTERY_UNKNOWN,
    DBC_PATH,
    INFO,
    NO_NODE,
    ROUTE,
    STATUS,
    Codec,
    CorruptFrame,
    Heartbeat,
    Info,
    RouteCommand,
    Status,
    StopGo,
)
from io_drivers.vehicle_records import VehicleRecords
from plc_runtime import ProcessImage, Runtime, VirtualClock
from topology import model_plant
from vehicles.cosim import CoSimulation
from vehicles.fleet import Faults, Fleet
from vehicles.modbus_endpoint import VehicleModbusEndpoints

_channels = itertools.count()
MESSAGES = [
    Status(3, 17, 4, "DRIVING", 0.42, 5, False, True, 9),
    Info(3, 88, 7),
    RouteCommand(3, 11, (6, 7, 8)),
    StopGo(127, True, 4),
    Heartbeat(0, 15),
]


# ----- the CRC ---------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("data", "crc"),
    [  # AUTOSAR Specification of CRC Routines, CRC-8 SAE J1850 check values
        ("00 00 00 00", 0x59),
        ("F2 01 83", 0x37),
        ("0F AA 00 55", 0x79),
        ("00 FF 55 11", 0xB8),
        ("33 22 55 AA BB CC DD EE FF", 0xCB),
        ("92 6B 55", 0x8C),
        ("FF FF FF FF", 0x74),
        ("31 32 33 34 35 36 37 38 39", 0x4B),  # "123456789": the CRC catalogue's check
    ],
)
def test_crc8_matches_the_published_sae_j1850_vectors(data, crc):
    assert crc8(bytes.fromhex(data)) == crc


@pytest.mark.parametrize("message", MESSAGES, ids=lambda m: type(m).__name__)
def test_every_change_of_a_single_byte_is_rejected(message):
    codec = Codec()
    frame_id, data = codec.encode(message)
    assert codec.decode(frame_id, data) == message
    for at in range(len(data)):
        for value in range(256):
            if value == data[at]:
                continue
            corrupt = bytearray(data)
            corrupt[at] = value
            with pytest.raises(CorruptFrame):
                codec.decode(frame_id, bytes(corrupt))


def test_a_frame_under_another_frame_id_fails_its_crc():
    codec = Codec()
    frame_id, data = codec.encode(MESSAGES[0])
    for other in [*range(STATUS + 1, STATUS + 127), *range(ROUTE + 1, ROUTE + 127)]:
        if other != frame_id:
            with pytest.raises(CorruptFrame):
                codec.decode(other, data)


# ----- the compiled codec ----------------------------------------------------------------------
@pytest.mark.parametrize(
    "name", ["StopGo", "VehicleStatus", "RouteCommand", "VehicleInfo", "Heartbeat"]
)
def test_compiled_codec_equals_cantools_on_random_frames(name):
    message = cantools.database.load_file(str(DBC_PATH)).get_message_by_name(name)
    layout = Codec().layouts[message.frame_id]
    assert layout.signals == tuple(s.name for s in message.signals)
    rng = random.Random(name)
    for _ in range(500):
        data = bytes(rng.randrange(256) for _ in range(message.length))
        expected = message.decode(data, decode_choices=False, scaling=True)
        assert dict(zip(layout.signals, layout.unpack(data), strict=True)) == expected
        raws = [rng.randrange(1 << s.length) for s in message.signals]
        values = [raw * s.scale + s.offset for raw, s in zip(raws, message.signals, strict=True)]
        signals = dict(zip(layout.signals, values, strict=True))
        assert layout.pack(*values) == message.encode(signals, scaling=True, strict=False)


def test_the_compiled_pack_refuses_a_value_wider_than_its_signal():
    layout = Codec().layouts[ROUTE]
    with pytest.raises(ValueError, match="RouteCommand"):
        layout.pack(0, 16, 1, 5, 6, 7)  # a counter of 16 does not fit 4 bits


def test_a_dbc_layout_the_compiler_does_not_support_is_refused_at_startup(tmp_path):
    dbc = tmp_path / "agv.dbc"
    dbc.write_text(DBC_PATH.read_text().replace("SG_ go : 12|1@1+", "SG_ go : 12|1@0+"))
    with pytest.raises(ValueError, match="agv.dbc: StopGo.go: only unsigned little-endian"):
        Codec(dbc)
    dbc.write_text(
        DBC_PATH.read_text().replace(
            'SG_ counter : 8|4@1+ (1,0) [0|15] "" AGV\n SG_ go',
            'SG_ counter : 8|3@1+ (1,0) [0|7] "" AGV\n SG_ go',
        )
    )
    with pytest.raises(ValueError, match="StopGo: must begin with crc"):
        Codec(dbc)


# ----- the counter -----------------------------------------------------------------------------
def test_counter_check_accepts_steps_up_to_three_and_counts_what_was_lost():
    check = CounterCheck()
    assert [check.check(1, c) for c in (14, 15, 0, 3)] == [ACCEPTED] * 4  # wraps at 16
    assert check.counters == {"repeated": 0, "lost": 2, "out_of_sequence": 0, "resyncs": 0}
    assert check.check(2, 9) == ACCEPTED  # another data id has its own reference


def test_counter_check_drops_repeated_and_out_of_sequence_frames_and_keeps_the_reference():
    check = CounterCheck()
    check.check(1, 5)
    assert check.check(1, 5) == REPEATED
    assert check.check(1, 12) == OUT_OF_SEQUENCE  # a stale or foreign frame ...
    assert check.check(1, 4) == OUT_OF_SEQUENCE  # ... an old one ...
    assert check.check(1, 6) == ACCEPTED  # ... the sender's next frame is still accepted
    assert check.counters == {"repeated": 1, "lost": 0, "out_of_sequence": 2, "resyncs": 0}


def test_a_sender_that_jumped_and_continues_is_resynchronised():
    check = CounterCheck()
    check.check(1, 5)
    assert check.check(1, 11) == OUT_OF_SEQUENCE  # a restarted sender's first frame
    assert check.check(1, 12) == RESYNC  # it continues from there: follow it
    assert check.check(1, 13) == ACCEPTED
    assert check.counters["resyncs"] == 1 and check.counters["out_of_sequence"] == 1


def test_a_second_sender_with_the_same_id_is_found_at_its_first_two_frames_in_a_row():
    check = CounterCheck()
    verdicts = []
    for a, b in zip(range(1, 7), range(9, 15), strict=True):  # A at 1, 2, ...; B at 9, 10, ...
        verdicts += [check.check(1, a), check.check(1, b)]  # interleaved: B's are dropped
    assert RESYNC not in verdicts and check.counters["out_of_sequence"] == 6
    assert check.check(1, 15) == RESYNC  # B sends two in a row (an event is sent twice)


def test_a_false_frame_out_of_the_window_never_resynchronises_the_real_sender():
    for false in range(16):
        check = CounterCheck()
        check.check(1, 0)
        verdicts = [check.check(1, false)] + [check.check(1, c) for c in range(1, 40)]
        if false not in (1, 2, 3):  # outside the window: dropped, the real frames go on
            assert verdicts[1:] == [ACCEPTED] * 39 and check.counters["resyncs"] == 0


# ----- the vehicle records: confirmation and flags ---------------------------------------------
def records(stale_after_ns=10**9):
    image = ProcessImage(sizes={"I": 2048, "Q": 2048})
    return image, VehicleRecords(image, [3], 1024, 1024, stale_after_ns=stale_after_ns)


def inputs(image, recs, now_ns):
    recs.refresh_flags(now_ns)
    image.copy_in()
    base = record(3)
    return (
        image.read(f"%IW{base // 2}"),
        image.read(f"%IW{base // 2 + 1}"),
        image.read(f"%IB{base + 4}"),
        image.read(f"%IB{base + 7}"),
    )


def test_a_position_applies_only_when_two_consecutive_statuses_agree():
    image, recs = records()
    recs.received(Status(3, 17, NO_NODE, "IDLE", 0.0, 1), 0)
    assert inputs(image, recs, 0) == (0, 0, 0, 0)  # one report: not online, no position
    recs.received(Status(3, 17, 4, "IDLE", 0.0, 2), 1)
    assert inputs(image, recs, 1) == (17, 4, 0, ONLINE)
    recs.received(Status(3, 99, 98, "DRIVING", 0.5, 3, False, True), 2)  # one false frame
    assert inputs(image, recs, 2) == (17, 4, 1, ONLINE)  # its state is taken, not its position
    recs.received(Status(3, 17, 4, "IDLE", 0.0, 4), 3)
    recs.received(Status(3, 17, 4, "IDLE", 0.0, 5), 4)
    assert inputs(image, recs, 4) == (17, 4, 0, ONLINE) and recs.counters["unconfirmed"] == 1
    recs.received(Status(3, 17, 4, "DRIVING", 0.3, 6, False, True), 5)  # the clear bit ...
    assert inputs(image, recs, 5)[3] == ONLINE
    recs.received(Status(3, 17, 4, "DRIVING", 0.4, 7, False, True), 6)  # ... when repeated
    assert inputs(image, recs, 6)[3] == ONLINE | CLEAR


def test_a_fault_is_taken_at_once_and_staleness_follows_confirmed_positions():
    image, recs = records(stale_after_ns=100)
    recs.received(Status(3, 17, NO_NODE, "IDLE", 0.0, 1), 0)
    recs.received(Status(3, 17, NO_NODE, "IDLE", 0.0, 2), 0)
    recs.received(Status(3, 18, NO_NODE, "FAULT", 0.0, 3, True), 50)  # unconfirmed position
    assert inputs(image, recs, 50) == (17, NO_NODE, 6, ONLINE | FAULT)
    for t in (120, 140, 160):  # statuses that never agree keep nothing fresh
        recs.received(Status(3, t, NO_NODE, "IDLE", 0.0, t % 16), t)
    # ... and the fault stands: no two consecutive frames said it was over
    assert inputs(image, recs, 160)[3] == STALE | FAULT


def jumps(n: int) -> int:
    return (n % 8) << LINK_JUMP_SHIFT


def test_every_counter_jump_counts_so_none_hides_behind_an_earlier_one():
    image, recs = records()
    recs.received(Status(3, 17, NO_NODE, "IDLE", 0.0, 1), 0)
    recs.received(Status(3, 17, NO_NODE, "IDLE", 0.0, 2), 0, resync=True)
    assert inputs(image, recs, 0)[3] == ONLINE | jumps(1)
    recs.received(Status(3, 17, NO_NODE, "IDLE", 0.0, 3), 1)
    assert inputs(image, recs, 1)[3] == ONLINE | jumps(1)  # the count stays
    recs.received_info(Info(3, 50, 1), resync=True)  # an info frame's counter jumped too
    recs.received(Status(3, 17, NO_NODE, "IDLE", 0.0, 9), 2, resync=True)  # in the same tick
    assert inputs(image, recs, 2)[3] == ONLINE | jumps(3)  # two jumps in one tick: both seen


def test_a_fault_ends_only_when_two_consecutive_frames_say_so():
    image, recs = records()
    recs.received(Status(3, 17, NO_NODE, "IDLE", 0.0, 1), 0)
    recs.received(Status(3, 17, NO_NODE, "FAULT", 0.0, 2, True), 0)
    assert inputs(image, recs, 0)[3] == ONLINE | FAULT
    recs.received(Status(3, 17, NO_NODE, "IDLE", 0.0, 3), 1)  # one frame (a spoof?) says no
    assert inputs(image, recs, 1)[3] == ONLINE | FAULT
    recs.received(Status(3, 17, NO_NODE, "FAULT", 0.0, 4, True), 2)
    recs.received(Status(3, 17, NO_NODE, "IDLE", 0.0, 6), 3)  # not consecutive
    recs.received(Status(3, 17, NO_NODE, "IDLE", 0.0, 8), 3)
    assert inputs(image, recs, 3)[3] == ONLINE | FAULT
    recs.received(Status(3, 17, NO_NODE, "IDLE", 0.0, 9), 4)  # 8 and 9: confirmed
    assert inputs(image, recs, 4)[3] == ONLINE


def test_the_battery_reads_unknown_until_the_first_info_frame_not_empty():
    image, recs = records()
    base = record(3)
    image.copy_in()
    assert image.read(f"%IB{base + 5}") == BATTERY_UNKNOWN  # a lost first frame is no 0 %
    recs.received_info(Info(3, 0, 1))
    image.copy_in()
    assert image.read(f"%IB{base + 5}") == 0  # a real empty battery reads 0


def test_a_battery_jump_applies_only_when_the_next_info_frame_repeats_it():
    """One forged or garbled info frame (it passed the checks) must not set the level the
    charging policy learns an order's consumption from."""
    image, recs = records()
    base = record(3)

    def level():
        image.copy_in()
        return image.read(f"%IB{base + 5}")

    recs.received_info(Info(3, 97, 1))
    assert level() == 97  # the first is taken
    recs.received_info(Info(3, 0, 2))  # one frame: not taken
    assert level() == 97 and recs.counters["unconfirmed"] == 1
    recs.received_info(Info(3, 96, 3))  # a step from the level taken: taken
    assert level() == 96
    for counter, battery in enumerate((95, 94, 96, 98), start=4):  # driving, then charging
        recs.received_info(Info(3, battery, counter))
        assert level() == battery
    recs.received_info(Info(3, 10, 8))  # a real failure: the next frame repeats it
    assert level() == 98
    recs.received_info(Info(3, 9, 9))
    assert level() == 9 and recs.counters["unconfirmed"] == 2


# ----- the CAN driver ----------------------------------------------------------------------------
def driver_runtime(vehicles):
    channel = f"e2e-{next(_channels)}"
    bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    driver = CanDriver(vehicles, interface="virtual", channel=channel)
    rt = Runtime(cycle_time=0.010, clock=VirtualClock())
    rt.add_driver(driver)
    rt.add_task("program", [Dispatcher({})])
    rt.start()
    return rt, driver, bus


def send(bus, codec, message):
    frame_id, data = codec.encode(message)
    bus.send(can.Message(arbitration_id=frame_id, data=data, is_extended_id=False))


def test_a_counter_jump_raises_the_jump_count_in_the_record():
    rt, driver, bus = driver_runtime([1])
    codec = Codec()
    flags = f"%IB{record(1) + 7}"
    try:
        for counter in (1, 2, 9, 10, 11):  # 9: the sender jumped; 10 continues from it
            send(bus, codec, Status(1, 5, NO_NODE, "IDLE", 0.0, counter))
            rt.step()
        stats = driver.stats()
        assert stats["out_of_sequence"] == 1 and stats["resyncs"] == 1
        assert rt.image.read(flags) == ONLINE | jumps(1)
        for counter in (12, 13, 4, 5):  # another jump, right after
            send(bus, codec, Status(1, 5, NO_NODE, "IDLE", 0.0, counter))
            rt.step()
        assert rt.image.read(flags) == ONLINE | jumps(2)
    finally:
        rt.stop()
        bus.shutdown()


def test_stop_go_is_repeated_every_second_with_a_new_counter():
    rt, driver, bus = driver_runtime([2])
    codec = Codec()
    try:
        rt.image.write(f"%QB{record(2) + 6}", 0x80)  # go
        rt.step(250)  # 2.5 s
        got = []
        while (msg := bus.recv(timeout=0)) is not None:
            message = codec.decode(msg.arbitration_id, msg.data)
            if isinstance(message, StopGo):
                got.append(message)
        assert [m.counter for m in got] == [1, 2, 3] and all(m.go for m in got)
    finally:
        rt.stop()
        bus.shutdown()


def test_spoofed_frames_never_move_a_vehicle_in_the_image():
    """A foreign node sends well-formed statuses with random vehicles, nodes and counters;
    whatever the image shows of a vehicle's position was true of it at some time."""
    plant = model_plant()
    channel = f"spoof-{next(_channels)}"
    fleet_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    faults = {1: Faults(spoof_rate=0.25), 2: Faults(spoof_rate=0.25, corrupt_rate=0.1)}
    fleet = Fleet(plant, {1: 0, 2: 11}, fleet_bus, faults=faults, seed=11)
    driver = CanDriver([1, 2], interface="virtual", channel=channel)
    rt = Runtime(cycle_time=0.010, clock=VirtualClock())
    rt.add_driver(driver)
    rt.add_task("program", [Dispatcher({1: [0, 6, 7, 8, 9, 24], 2: [11, 22, 10, 0, 6]})])
    rt.add_task("plant", [CoSimulation(fleet)], priority=9)
    truth = {1: set(), 2: set()}
    rt.start()
    try:
        for _ in range(6000):
            for v, agv in fleet.vehicles.items():
                truth[v].add((agv.node, agv.clear))
            rt.step()
            for v in (1, 2):
                flags = rt.image.read(f"%IB{record(v) + 7}")
                if flags & ONLINE:
                    shown = (rt.image.read(f"%IW{record(v) // 2}"), bool(flags & CLEAR))
                    assert shown in truth[v], (v, shown)
        stats = driver.stats()
    finally:
        rt.stop()
        fleet_bus.shutdown()
    assert fleet.counters["spoofed"] > 200 and fleet.counters["corrupted"] > 0
    assert stats["crc_errors"] == fleet.counters["corrupted"]
    assert stats["out_of_sequence"] + stats["repeated"] > 0 and stats["unconfirmed"] > 0
    assert fleet.vehicles[1].driven == [0, 6, 7, 8, 9, 24]
    assert fleet.vehicles[2].driven == [11, 22, 10, 0, 6]


# ----- fault injection ---------------------------------------------------------------------------
def test_a_corrupted_frame_differs_in_one_byte_and_every_one_fails_its_crc():
    plant = model_plant()
    clean = Fleet(plant, {1: 0, 2: 11}, seed=4)
    corrupt = Fleet(plant, {1: 0, 2: 11}, faults={1: Faults(corrupt_rate=1.0)}, seed=4)
    codec = Codec()
    for _ in range(100):
        clean.step(0.01)
        corrupt.step(0.01)
        for frame_id in (STATUS + 1, INFO + 1):
            a, b = clean.frames[frame_id], corrupt.frames[frame_id]
            assert sum(x != y for x, y in zip(a, b, strict=True)) == 1
            with pytest.raises(CorruptFrame):
                codec.decode(frame_id, b)
        assert corrupt.frames[STATUS + 2] == clean.frames[STATUS + 2]  # vehicle 2 is fine
    assert corrupt.counters["sent"] == clean.counters["sent"] and corrupt.counters["corrupted"] > 0


def test_a_vehicle_obeys_a_stop_whatever_its_counter_but_a_go_only_in_sequence():
    fleet = Fleet(model_plant(), {1: 0})
    codec = Codec()

    def deliver(message):
        fleet.receive(*codec.encode(message))

    deliver(StopGo(1, False, 5))
    deliver(StopGo(1, True, 5))  # repeated counter: dropped
    assert not fleet.vehicles[1].go and fleet.counters["repeated"] == 1
    deliver(StopGo(1, True, 6))
    deliver(StopGo(1, False, 6))  # repeated, but a stop
    assert not fleet.vehicles[1].go
    deliver(RouteCommand(1, 3, (6,)))
    fleet.vehicles[1].route.clear()
    deliver(RouteCommand(1, 3, (6,)))  # a resend of the same command: not a new route
    assert list(fleet.vehicles[1].route) == [] and fleet.counters["repeated"] == 3
    _, data = codec.encode(RouteCommand(1, 4, (6, 7)))
    fleet.receive(ROUTE + 1, bytes([data[0] ^ 1]) + data[1:])
    assert fleet.counters["crc_errors"] == 1 and list(fleet.vehicles[1].route) == []
    fleet.step(0.01)
    assert codec.decode(STATUS + 1, fleet.frames[STATUS + 1]).route_ack == 3


# ----- the Modbus link ---------------------------------------------------------------------------
def test_modbus_registers_carry_the_same_protection_both_ways():
    """The vehicles' registers (written by a fleet with faults) through the link's checks
    into the image; the link's command frames through the vehicle's checks into the fleet.
    No network: the server's register callbacks and the link's worker steps are called."""
    fleet = Fleet(model_plant(), {1: 0}, faults={1: Faults(corrupt_rate=0.2)}, seed=5)
    endpoints = VehicleModbusEndpoints(fleet)
    read, write = endpoints._reader(1), endpoints._writer(1)
    image = ProcessImage()
    link = ModbusVehicleLink({1: ("127.0.0.1", 1)}, poll_period=60.0, timeout=0.01)
    link.open(image)
    try:
        fleet.announce()
        for k in range(800):
            endpoints.apply()
            fleet.step(0.01)
            endpoints.publish()
            registers = read("ir", 0, 11)
            link._check(1, STATUS + 1, registers[:8])
            link._check(1, INFO + 1, registers[8:])
            link.read_inputs(image, k * 10_000_000)
            if k == 10:  # the controller's route and go, as the worker writes them
                image.published_outputs.view("<u2")[record(1) // 2] = 6
                image.published_outputs.bytes[record(1) + 6] = 0x80 | 1
                image.published_outputs.bytes[record(1) + 7] = 1
                link.write_outputs(image, k * 10_000_000)
                frames = link._commands.pop(1)
                assert write("hr", 0, frames["route"] + frames["stop_go"]) is None
        image.copy_in()
        stats = link.stats()
        assert fleet.counters["corrupted"] > 0 and stats["crc_errors"] > 0
        assert stats["crc_errors"] <= fleet.counters["corrupted"]  # some were overwritten unread
        assert image.read(f"%IW{record(1) // 2}") == 6 == fleet.vehicles[1].node
        assert image.read(f"%IB{record(1) + 7}") & ONLINE
        # a corrupted command frame is refused by the vehicle
        _, data = Codec().encode(StopGo(1, False, 9))
        write("hr", 8, [data[0] ^ 0x40, data[1]])
        endpoints.apply()
        assert fleet.counters["crc_errors"] == 1 and fleet.vehicles[1].go
        assert write("hr", 8, [256, 0]) is not None  # a register carries one byte
    finally:
        link.close()


# ----- a fleet under faults ----------------------------------------------------------------------
def test_the_default_job_under_corruption_and_spoofing_sees_only_true_positions():
    """The default job with every vehicle's frames lost, corrupted and spoofed: the vehicle
    records only ever show positions the vehicles really had, and nothing collides."""
    from fleet.config import load_config
    from fleet.program import FleetProgram

    cfg = load_config(None)
    cfg.watchdog = 5.0
    program = FleetProgram(cfg)
    fleet = program.fleet
    for v in fleet.vehicles:
        fleet.faults[v] = Faults(drop_rate=0.02, corrupt_rate=0.05, spoof_rate=0.05)
    truth = {v: set() for v in fleet.vehicles}
    rt = program.rt
    try:
        rt.start()
        for _ in range(round(60 / cfg.cycle_time)):
            for v, agv in fleet.vehicles.items():
                truth[v].add((agv.node, agv.clear))
            rt.step()
            for v in fleet.vehicles:
                flags = rt.image.read(f"%IB{record(v) + 7}")
                if flags & ONLINE:
                    shown = (rt.image.read(f"%IW{record(v) // 2}"), bool(flags & CLEAR))
                    assert shown in truth[v], (v, shown)
        stats = rt.stats.to_dict()["drivers"]["can"]
    finally:
        program.close()
    assert program.monitor.head_on == 0 and program.monitor.node == 0, program.monitor.events
    assert fleet.counters["corrupted"] > 0 and fleet.counters["spoofed"] > 0
    assert stats["crc_errors"] == fleet.counters["corrupted"] and stats["unconfirmed"] > 0


# ----- the vehicle side ---------------------------------------------------------------------------
def test_a_resync_on_the_vehicle_side_never_starts_a_vehicle_or_gives_it_a_route():
    """Replayed old frames (or a restarted controller) make the vehicle's check resync: the
    new reference is taken, but only a stop is obeyed from such a frame."""
    codec = Codec()
    fleet = Fleet(model_plant(), {1: 0})
    agv = fleet.vehicles[1]

    def deliver(message):
        fleet.receive(*codec.encode(message))

    for k in range(1, 12):
        deliver(StopGo(1, k != 11, k))  # ... go 10, then stop 11
    deliver(StopGo(1, False, 4))  # a replayed old pair: stop 4 (a stop is always obeyed) ...
    deliver(StopGo(1, True, 5))  # ... and go 5, which the check resyncs to
    assert agv.go is False and fleet.counters["resyncs"] == 1
    deliver(StopGo(1, True, 6))  # the next frame in the window: a go again
    assert agv.go is True
    for k in range(1, 10):
        deliver(RouteCommand(1, k, (6,)))
        agv.route.clear()
    deliver(RouteCommand(1, 3, (6,)))  # replays of old commands 3 and 4
    deliver(RouteCommand(1, 4, (6,)))
    assert list(agv.route) == [] and fleet.counters["resyncs"] == 2
    for _ in range(300):
        fleet.step(0.01)
    assert agv.driven == [0]  # it did not move


def test_an_empty_route_command_cancels_the_route_aboard():
    codec = Codec()
    fleet = Fleet(model_plant(), {1: 0})
    agv = fleet.vehicles[1]
    fleet.receive(*codec.encode(RouteCommand(1, 1, (6, 7))))
    assert list(agv.route) == [6, 7]
    fleet.receive(*codec.encode(RouteCommand(1, 2, ())))
    assert list(agv.route) == [] and agv.target is None
    for _ in range(300):
        fleet.step(0.01)
    assert agv.driven == [0]


# ----- a flooded bus ---------------------------------------------------------------------------
def test_a_flood_of_valid_frames_is_read_a_bounded_number_per_tick_in_order():
    """More frames than the cap: each tick reads exactly the cap, the rest waits (deferred),
    and nothing is lost or reordered, so the last position is the last one sent."""
    channel = f"flood-{next(_channels)}"
    sender = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    image = ProcessImage({"I": 4096, "Q": 4096})
    driver = CanDriver([1, 2], channel=channel, max_frames=40)
    driver.open(image)
    codec = Codec()
    try:
        for k in range(100):  # vehicle 1 and 2 in turn, each counter in sequence
            v = 1 + k % 2
            frame_id, data = codec.encode(Status(v, k, NO_NODE, "IDLE", 0.0, (k // 2 + 1) % 16))
            sender.send(can.Message(arbitration_id=frame_id, data=data, is_extended_id=False))
        for tick, (read, deferred) in enumerate(((40, 1), (80, 2), (100, 2))):
            driver.read_inputs(image, tick)
            assert driver.counters["frames_in"] == read and driver.counters["deferred"] == deferred
        assert driver.checks.counters["out_of_sequence"] == 0
        assert driver.counters["crc_errors"] == 0
        # the newest status of each vehicle is the last one sent
        assert driver.records.status[1].current_node == 98
        assert driver.records.status[2].current_node == 99
    finally:
        driver.close()
        sender.shutdown()


@pytest.mark.parametrize(
    ("cycle_s", "vehicles", "period_s", "frames"),
    [
        (0.010, 4, 0.1, 100),  # the default job: what a 1 Mbit/s bus carries in 10 ms
        (0.050, 126, 0.1, 500),  # a full bus at 50 ms
        (0.010, 126, 0.001, 5040),  # vehicles reporting every ms: their own traffic first
        (0.001, 1, 0.1, 32),  # never fewer than the floor
    ],
)
def test_the_per_tick_cap_is_what_a_bus_carries_or_the_fleet_sends(
    cycle_s, vehicles, period_s, frames
):
    assert frames_per_tick(cycle_s, vehicles, period_s) == frames


def test_the_fleet_program_caps_each_bus_by_its_cycle():
    from fleet.config import load_config
    from fleet.program import FleetProgram

    cfg = load_config()
    program = FleetProgram(cfg)
    try:
        (driver,) = [d for d in program.rt.drivers if isinstance(d, CanDriver)]
        assert driver.max_frames == frames_per_tick(cfg.cycle_time, 4, cfg.status_period_s)
        assert driver.max_frames == 100  # 10 ms cycle
    finally:
        program.close()
