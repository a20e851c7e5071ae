"""Fleets of more than 126 vehicles: a CAN bus carries vehicle ids 1..126 (7 bits), so a
larger fleet runs on several buses, 126 vehicles to a bus in id order. A configuration
names one channel per bus, comma-separated; the in-process virtual bus makes as many as
the ids need; the simulated vehicles of ``plc-runtime vehicles`` split the same way."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import can
import pytest
from netns import realtime_run, run_isolated, unavailable
from pymodbus.client import ModbusTcpClient

from fleet.cli import main
from fleet.config import link_problem, load_config
from fleet.program import FleetProgram
from fleet.tags import HOLDING_BASE, STATE_CODES, vehicle_word
from io_drivers.can_bus import bus_of, bus_options, by_bus
from io_drivers.modbus_server import ModbusServer
from io_drivers.protocol import MAX_VEHICLE_ID, STATUS
from plc_runtime.errors import ConfigError
from topology import warehouse
from vehicles.runner import default_starts, run_fleet

WAREHOUSE = Path(__file__).resolve().parent.parent / "examples" / "warehouse.toml"


def warehouse_config(tmp_path: Path, count: int, bus: str = "", battery: str = "") -> Path:
    """examples/warehouse.toml with ``count`` vehicles, ids 1..count."""
    text = WAREHOUSE.read_text(encoding="utf-8")
    text = text[: text.index("# 15 vehicles along the top border row")]
    text = text.replace('[bus]\ninterface = "virtual"\n', "")
    starts = default_starts(warehouse(), count)
    for v, node in starts.items():
        text += f"[[vehicles]]\nid = {v}\nstart = {node}\n"
        if v == 135 and battery:
            text += f"battery = {battery}\n"
        text += "\n"
    path = tmp_path / "fleet.toml"
    path.write_text(text + bus, encoding="utf-8")
    return path


def test_ids_split_126_to_a_bus_in_id_order():
    assert [bus_of(v) for v in (1, 126, 127, 252, 253)] == [
        (0, 1),
        (0, 126),
        (1, 1),
        (1, 126),
        (2, 1),
    ]
    assert by_bus({1: "a", 127: "b", 130: "c"}) == {0: {1: "a"}, 1: {1: "b", 4: "c"}}
    # udp_multicast: each bus after the first on a port of its own, at both ends of the link
    assert [bus_options("udp_multicast", k) for k in (0, 1, 2)] == [
        {},
        {"port": 43114},
        {"port": 43115},
    ]
    assert bus_options("socketcan", 1) == {}


def test_a_fleet_of_140_runs_on_two_in_process_buses(tmp_path):
    """Vehicles 127..140 are ids 1..14 of a second virtual bus: their frames, their
    battery, their moves; the independent monitor watches both buses as one plant."""
    cfg = load_config(warehouse_config(tmp_path, 140, battery="55"))
    cfg.watchdog = 5.0
    p = FleetProgram(cfg)
    try:
        assert [len(f.vehicles) for f in p.fleets] == [126, 14]
        assert round(p.fleets[1].vehicles[9].battery.percent) == 55  # vehicle 135
        every = p.simulated_vehicles()  # by fleet-wide id, the second bus's included
        assert sorted(every) == list(range(1, 141)) and every[135] is p.fleets[1].vehicles[9]
        assert all(every[v].node == cfg.starts[v] for v in every)
        starts = {v: f.vehicles[v].node for f in p.fleets[1:] for v in f.vehicles}
        p.rt.start()
        p.rt.run(cycles=round(30 / cfg.cycle_time))
        assert p.rt.state == "RUN", p.rt.fault_reason
        moved = [v for v, node in starts.items() if p.fleets[1].vehicles[v].driven != [node]]
        assert len(moved) >= 5, moved  # (9: the others wait their turn)
        assert all(p.controls[v].state != "offline" for v in range(127, 141))
        assert p.monitor.head_on == 0 and p.monitor.node == 0
    finally:
        p.close()


def test_an_hmi_reads_and_holds_every_vehicle_of_a_large_fleet_over_modbus(tmp_path):
    """The marker area is served whole: vehicle 140's words are holding registers past
    2047, read like vehicle 1's; its hold is writable, its status words are not; a
    register past the marker area is no address at all."""
    cfg = load_config(warehouse_config(tmp_path, 140))
    cfg.watchdog = 5.0
    p = FleetProgram(cfg)
    server = ModbusServer(port=0)
    p.rt.add_driver(server)
    client = None
    try:
        p.rt.start()
        client = ModbusTcpClient("127.0.0.1", port=server.port, timeout=2.0, retries=0)
        assert client.connect()
        p.rt.run(cycles=round(10 / cfg.cycle_time))
        node_hr = HOLDING_BASE + vehicle_word(140, "node")
        assert node_hr > 2047
        node, state = client.read_holding_registers(node_hr, count=2).registers
        control = p.controls[140]
        assert (node, state) == (control.current, STATE_CODES[control.state])
        hold_hr = HOLDING_BASE + vehicle_word(140, "hold")
        assert not client.write_register(hold_hr, 1).isError()
        p.rt.step()
        assert control.hold and p.rt.image.read("agv140.held") is True
        refused = client.write_register(node_hr, 3)
        assert refused.isError() and refused.exception_code == 2
        past = HOLDING_BASE + p.rt.image.sizes["M"] // 2
        assert client.read_holding_registers(past - 1, count=1).registers == [0]
        beyond = client.read_holding_registers(past, count=1)
        assert beyond.isError() and beyond.exception_code == 2
        assert p.rt.image.read("agv140.node") == control.current
    finally:
        if client is not None:
            client.close()
        p.close()


@pytest.mark.parametrize(
    ("bus", "message"),
    [
        (
            '[bus]\ninterface = "socketcan"\nchannel = "vcan0"\n',
            "bus.channel: vehicle 140 needs 2 buses (126 vehicles a bus: ids 1..126 on the "
            "first channel, 127..252 on the second, ...), and 'vcan0' names 1",
        ),
        ('[bus]\ninterface = "socketcan"\nchannel = "vcan0,"\n', "bus.channel: an empty channel"),
        (
            '[bus]\ninterface = "modbus"\nchannel = "127.0.0.1:65400"\n',
            "vehicle 140 would serve on port 65540, past 65535",
        ),
    ],
)
def test_a_link_that_cannot_carry_the_fleet_is_named(tmp_path, bus, message):
    with pytest.raises(ConfigError, match=re.escape(message)):
        load_config(warehouse_config(tmp_path, 140, bus))


def test_two_channels_carry_the_fleet(tmp_path):
    cfg = load_config(
        warehouse_config(tmp_path, 140, '[bus]\ninterface = "socketcan"\nchannel = "vcan0,vcan1"\n')
    )
    assert cfg.bus_channel == "vcan0,vcan1"
    assert link_problem("socketcan", "vcan0", 126) is None


def test_run_and_vehicles_name_a_bus_too_few_for_the_fleet(tmp_path, capsys):
    path = warehouse_config(tmp_path, 140)
    assert main(["run", str(path), "--bus", "socketcan:vcan0", "--vehicles", "external"]) == 2
    err = capsys.readouterr().err
    assert "--bus socketcan:vcan0: vehicle 140 needs 2 buses" in err and len(err.splitlines()) == 1
    code = main(
        [
            "vehicles",
            "--plant",
            "warehouse",
            "--count",
            "130",
            "--bus",
            "udp_multicast:239.74.163.2",
        ]
    )
    assert code == 2
    assert "vehicle 130 needs 2 buses" in capsys.readouterr().err
    code = main(
        ["vehicles", "--plant", "warehouse", "--count", "130", "--modbus-base-port", "65450"]
    )
    assert code == 2
    assert capsys.readouterr().err == (
        "plc-runtime: error: --modbus-base-port 65450: vehicle 130 would serve on port 65580, "
        "past 65535: give a lower base port\n"
    )


def test_simulated_vehicles_split_over_the_channels_given():
    """run_fleet with 130 vehicles on two channels: vehicle 130 reports as id 4 on the
    second, and the result names each bus's fleet with the offset of its ids."""
    listener = can.Bus(interface="virtual", channel="split-b", receive_own_messages=False)
    try:
        fleets = run_fleet(
            warehouse(), default_starts(warehouse(), 130), "virtual", "split-a,split-b", 0.01, 0.3
        )
        senders = set()
        while (msg := listener.recv(timeout=0)) is not None:
            if STATUS < msg.arbitration_id <= STATUS + MAX_VEHICLE_ID:
                senders.add(msg.arbitration_id - STATUS)
    finally:
        listener.shutdown()
    assert [(offset, len(f.vehicles)) for offset, f in fleets] == [(0, 126), (126, 4)]
    assert senders == {1, 2, 3, 4}


@pytest.mark.skipif(unavailable() is not None, reason=unavailable() or "")
def test_a_realtime_run_of_130_vehicles_on_two_multicast_buses(tmp_path):
    """Wall clock, the vehicles a child process (``plc-runtime vehicles``, started by the
    run) on two udp_multicast groups inside a private network namespace: both links carry
    frames, vehicles of the second bus are planned and driven, and the vehicles' monitor,
    watching both buses as one plant, counts no conflict."""
    text = warehouse_config(tmp_path, 130).read_text(encoding="utf-8")
    path = tmp_path / "fleet.toml"
    path.write_text(text.replace("watchdog_ms = 150", "watchdog_ms = 5000"), encoding="utf-8")
    summary = realtime_run(
        f"{path} --duration 15 --bus udp_multicast:239.74.163.9,239.74.163.10 "
        f"--out {tmp_path / 'out'}"
    )
    drivers = summary["drivers"]
    assert drivers["can0"]["frames_in"] > 0 and drivers["can1"]["frames_in"] > 0, drivers
    # each bus hears only its own vehicles (udp_multicast: a port of its own; on one port the
    # first bus heard vehicle 127 as a second vehicle 1, out of sequence, and the second
    # bus's vehicles turned suspect)
    assert all(d["unknown_vehicle"] == 0 and d["out_of_sequence"] == 0 for d in drivers.values())
    second = [summary["vehicles"][str(v)] for v in range(127, 131)]
    assert all(v["state"] not in ("offline", "suspect") and v["plans"] >= 1 for v in second), second


GROUPS_SCRIPT = """
import json, can
from io_drivers.can_bus import open_can_bus

def frame(n):
    return can.Message(arbitration_id=n, data=b"x", is_extended_id=False)

def heard(bus):
    message = bus.recv(0.3)
    return None if message is None else message.arbitration_id

first = open_can_bus("udp_multicast", "239.74.163.21")
second = open_can_bus("udp_multicast", "239.74.163.22")
peer = open_can_bus("udp_multicast", "239.74.163.22")
plain = can.Bus(interface="udp_multicast", channel="239.74.163.22", receive_own_messages=False)
first.send(frame(1))
out = {"second": heard(second), "plain": heard(plain)}
peer.send(frame(2))
out["second_from_peer"] = heard(second)
for bus in (first, second, peer, plain):
    bus.shutdown()
print(json.dumps(out))
"""


@pytest.mark.skipif(unavailable() is not None, reason=unavailable() or "")
def test_two_multicast_groups_on_one_port_are_two_buses(tmp_path):
    """Two fleets on one machine over udp_multicast, each on its own group and the same
    port: a bus hears its own group only (a python-can bus opened without that hears the
    other group's frame, which is why open_can_bus sets it)."""
    script = tmp_path / "groups.py"
    script.write_text(GROUPS_SCRIPT, encoding="utf-8")
    root = Path(__file__).resolve().parent.parent
    result = run_isolated(f"env PYTHONPATH={root} {sys.executable} {script}", timeout=60)
    assert result.returncode == 0, result.stderr
    heard = json.loads(result.stdout)
    assert heard == {"second": None, "plain": 1, "second_from_peer": 2}


def test_without_a_bus_a_fleet_takes_any_id():
    """Each vehicle its own Modbus server (no bus): ids past 126 are simulated as they are;
    on a CAN bus an id stays 7 bits."""
    from vehicles.fleet import Fleet

    plant = warehouse()
    starts = default_starts(plant, 130)
    assert max(Fleet(plant, starts, None).vehicles) == 130
    bus = can.Bus(interface="virtual", channel="seven-bits", receive_own_messages=False)
    try:
        with pytest.raises(ValueError, match="vehicle ids are 1..126, got 127"):
            Fleet(plant, starts, bus)
    finally:
        bus.shutdown()
