"""The Modbus TCP server on the process image: map, quiet-point writes, the write
allow-list (the input and output images never writable, the marker area closed unless
opened), exception codes and their log lines, the connection cap and the idle timeout,
the warning for a non-loopback address, an independent client (mbpoll), clean shutdown.
Loopback only, ephemeral ports."""

import itertools
import logging
import shutil
import socket
import struct
import subprocess
import threading
import time
import warnings

import pytest
from conftest import Probe
from pymodbus.client import ModbusTcpClient
from pymodbus.pdu import ExceptionResponse

from fleet.cli import main
from io_drivers.modbus_server import ModbusServer, _ModbusThread, is_loopback, map_entry
from plc_runtime import (
    ConfigError,
    Runtime,
    StartupError,
    TagTable,
    VirtualClock,
    WritesBacklogged,
    parse_address,
)
from plc_runtime import image as image_module
from plc_runtime.throttle import LineThrottle

LOGGER = "io_drivers.modbus_server"
WAIT_S = 30.0  # upper bound for what a busy machine may delay; never reached when it works


def fixture_tags() -> TagTable:
    tags = TagTable()
    tags.add("setpoint", "%MW5", "UINT", writable=True, comment="an HMI sets it")
    tags.add("speed", "%MW2", "UINT", comment="the program writes it: read-only")
    return tags


def runtime(tags: TagTable | None = None) -> Runtime:
    # a server thread runs beside the scans: no watchdog fault because the machine is busy
    return Runtime(cycle_time=0.010, clock=VirtualClock(), watchdog=10.0, tags=tags)


@pytest.fixture
def served():
    def cycle(ctx):
        ctx.image.write("%QW0", ctx.cycle % 65536)  # a value the program owns
        ctx.image.write("%QX4.0", True)  # coil 32 (not inside %QW0: sizes overlap in one memory)
        ctx.image.write("speed", 42)

    rt = runtime(fixture_tags())
    server = ModbusServer(port=0, writable_extra=["%MW0..%MW1"])  # + the writable tag %MW5
    rt.add_driver(server)
    rt.add_task("main", [Probe(cycle)])
    threads_before = threading.active_count()
    rt.start()
    every_line(server._server)
    client = ModbusTcpClient("127.0.0.1", port=server.port, timeout=2.0, retries=0)
    assert client.connect()
    yield rt, server, client
    client.close()
    rt.stop()
    assert threading.active_count() == threads_before  # the server thread is gone


def every_line(thread: _ModbusThread) -> None:
    """Give the server a clock a second later at every look, so that each warning is a line
    of its own (the throttle lets one a second per client through)."""
    ticks = itertools.count(0.0, 1.0)
    thread.clock = lambda: next(ticks)


def exception_code(response):
    assert response.isError() and isinstance(response, ExceptionResponse), response
    return response.exception_code


def image_bytes(rt) -> dict[str, bytes]:
    image = rt.image
    with image._lock:
        return {
            "I": image.inputs.bytes.tobytes(),
            "Q": image.published_outputs.bytes.tobytes(),
            "M": image.markers.bytes.tobytes(),
        }


def test_reads_follow_the_openplc_map(served):
    rt, _server, client = served
    rt.image.write_many({"%IX0.1": True, "%IW3": 777, "%MW3": 4242})
    rt.step(5)
    assert client.read_holding_registers(0, count=1).registers == [4]  # %QW0 after scan 4
    assert client.read_coils(32, count=2).bits[:2] == [True, False]  # %QX4.0, %QX4.1
    assert client.read_discrete_inputs(0, count=3).bits[:3] == [False, True, False]  # %IX0.1
    assert client.read_input_registers(3, count=1).registers == [777]  # %IW3
    assert client.read_holding_registers(1026, count=2).registers == [42, 4242]  # %MW2, %MW3


def test_writes_are_applied_at_the_quiet_point(served):
    rt, server, client = served
    rt.step()
    assert not client.write_register(1024 + 5, 123).isError()  # setpoint, declared writable
    assert not client.write_registers(1024, [7, 8]).isError()  # %MW0, %MW1 together
    assert rt.image.read("%MW0") == 0 and rt.image.pending_writes == 2  # queued, not applied
    rt.step()
    assert rt.image.read("setpoint") == 123
    assert (rt.image.read("%MW0"), rt.image.read("%MW1")) == (7, 8)
    assert client.read_holding_registers(1029, count=1).registers == [123]
    assert server.stats()["writes"] == 2


def test_writes_past_what_the_image_queues_are_busy_until_the_next_scan(served, monkeypatch):
    """A runtime that is not scanning applies no writes: a client writing on would fill the
    memory and make the next scan apply them all. Past the image's queue, exception 06
    (server device busy), nothing queued; after a scan, writes go in again."""
    rt, server, client = served
    monkeypatch.setattr(image_module, "MAX_PENDING", 3)
    for value in (1, 2, 3):
        assert not client.write_register(1024 + 5, value).isError()
    assert exception_code(client.write_registers(1024, [7, 8])) == 6
    assert rt.image.pending_writes == 3 and server.stats()["failures"] == 1
    rt.step()
    assert (rt.image.read("setpoint"), rt.image.read("%MW0")) == (3, 0)
    assert not client.write_registers(1024, [7, 8]).isError()
    rt.step()
    assert (rt.image.read("%MW0"), rt.image.read("%MW1")) == (7, 8)
    with pytest.raises(WritesBacklogged):
        for _ in range(4):
            rt.image.write("%MW0", 1)  # the same rule for every writer of the image


# function code, how to send it, what it aims at; FC22 and FC23 are not served at all
OUTPUT_WRITES = [
    (5, lambda c: c.write_coil(32, False), 2),  # %QX4.0, which the program sets
    (5, lambda c: c.write_coil(0, True), 2),  # %QX0.0 (coil 0 is not %IX0.0 either)
    (15, lambda c: c.write_coils(40, [True] * 3), 2),  # %QX5.0..%QX5.2
    (6, lambda c: c.write_register(0, 999), 2),  # %QW0 (not %IW0)
    (6, lambda c: c.write_register(516, 0x0183), 2),  # %QW516: a route command word
    (16, lambda c: c.write_registers(512, [10, 11, 12, 0x0183]), 2),  # a whole record
    (16, lambda c: c.write_registers(1023, [1, 2]), 2),  # %QW1023 + the writable %MW0
    (22, lambda c: c.mask_write_register(address=0, and_mask=0, or_mask=0xFFFF), 1),
    (
        23,
        lambda c: c.readwrite_registers(read_address=0, read_count=1, write_address=0, values=[1]),
        1,
    ),
    (
        23,
        lambda c: c.readwrite_registers(
            read_address=0, read_count=1, write_address=1024, values=[1]
        ),
        1,
    ),
]


@pytest.mark.parametrize(("fc", "send", "code"), OUTPUT_WRITES)
def test_input_and_output_images_are_never_writable(served, fc, send, code):
    rt, server, client = served
    rt.image.write_many({"%IX0.0": True, "%IW0": 5})  # the field's values
    rt.step(3)
    before = image_bytes(rt)
    assert exception_code(send(client)) == code
    assert rt.image.pending_writes == 0  # nothing of it was queued for the quiet point
    rt.step()
    after = image_bytes(rt)
    assert after["I"] == before["I"] and after["M"] == before["M"]
    assert after["Q"][2:] == before["Q"][2:]  # all but %QW0, the program's scan counter
    assert rt.image.read("%QW0") == 3
    assert server.stats()["writes"] == 0
    assert server.stats()["refused"] == (1 if code == 2 else 0)  # 01: not even looked at


def test_marker_writes_follow_the_allow_list(served, caplog):
    rt, server, client = served
    rt.step()
    caplog.set_level(logging.INFO, logger=LOGGER)
    assert exception_code(client.write_register(1024 + 2, 7)) == 2  # speed: read-only tag
    assert exception_code(client.write_register(1024 + 3, 7)) == 2  # %MW3: nobody opened it
    assert exception_code(client.write_registers(1024, [1, 2, 3])) == 2  # %MW2 in it: whole
    assert rt.image.pending_writes == 0
    reasons = [r.getMessage().split(", ", 1)[1] for r in caplog.records]
    assert reasons == [
        "holding register 1026 (%MW2) is the read-only tag 'speed'",
        "holding register 1027 (%MW3) is not on the write allow-list",
        "holding register 1026 (%MW2) is the read-only tag 'speed'",
    ]
    rt.step()
    assert rt.image.read("speed") == 42 and rt.image.read("%MW0") == 0
    assert server.stats()["refused"] == 3


def test_writable_tags_are_the_default_allow_list():
    tags = TagTable()
    tags.add("setpoint", "%MD4", "UDINT", writable=True, comment="an HMI sets it")
    tags.add("mode", "%MX20.0", "BOOL", writable=True)  # one bit of %MW10
    tags.add("speed", "%MW11", "UINT", comment="measured: read-only for clients")
    rt = runtime(tags)
    server = ModbusServer(port=0)
    rt.add_driver(server)
    rt.add_task("main", [Probe(lambda ctx: ctx.image.write("speed", 42))])
    rt.start()
    client = ModbusTcpClient("127.0.0.1", port=server.port, timeout=2.0, retries=0)
    try:
        assert client.connect()
        assert not client.write_registers(1024 + 8, [0x5678, 0x1234]).isError()  # %MD4
        assert exception_code(client.write_register(1024 + 11, 7)) == 2  # speed
        # a BOOL covers one bit of %MW10: a register write would set the other 15 as well
        assert exception_code(client.write_register(1024 + 10, 1)) == 2
        assert exception_code(client.write_register(1024 + 12, 1)) == 2  # untagged: closed
        rt.step()
        assert rt.image.read("setpoint") == 0x12345678 and rt.image.read("speed") == 42
        assert server.stats()["refused"] == 3
    finally:
        client.close()
        rt.stop()


def test_the_option_opens_named_tags_and_ranges():
    """An HMI set-point the program left read-only is opened by naming it; a range opens
    untagged words."""
    tags = TagTable()
    tags.add("limit", "%MW7", "UINT", comment="read by the program, set by an HMI")
    rt = runtime(tags)
    server = ModbusServer(port=0, writable_extra=[" limit", "%mw100..%MW101"])
    rt.add_driver(server)
    rt.add_task("main", [Probe(lambda ctx: None)])
    rt.start()
    client = ModbusTcpClient("127.0.0.1", port=server.port, timeout=2.0, retries=0)
    try:
        assert client.connect()
        assert not client.write_register(1024 + 7, 300).isError()
        assert not client.write_registers(1024 + 100, [1, 2]).isError()
        assert exception_code(client.write_registers(1024 + 100, [1, 2, 3])) == 2  # %MW102
        rt.step()
        assert rt.image.read("limit") == 300 and rt.image.read("%MW101") == 2
    finally:
        client.close()
        rt.stop()


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ("%QW5", r"writable '%QW5': the output image \(%Q\) is never writable over Modbus"),
        ("%QX0.0", r"writable '%QX0.0': the output image \(%Q\) is never writable"),
        ("%IW3", r"writable '%IW3': the input image \(%I\) is never writable"),
        ("%IX0.1", r"writable '%IX0.1': the input image \(%I\) is never writable"),
        ("%MW64512", r"writable '%MW64512': beyond the Modbus map \(%MW0..%MW64511, hold"),
        ("%MW64500..%MW64530", r"writable '%MW64500..%MW64530': beyond the Modbus map"),
        ("%MW9..%MW3", r"writable '%MW9..%MW3': the range ends before it starts"),
        ("%MW1..%QW3", r"writable '%MW1..%QW3': invalid IEC address .* a range is %MWa..%MWb"),
        ("%MW\u0669\u0660\u0660", r"invalid IEC address '%MW\u0669\u0660\u0660': ASCII letters"),
        ("%MW900..%MW\u0669\u0660\u0669", r"writable '%MW900..%MW\u0669\u0660\u0669': invalid"),
        ("%MW900\n", r"writable '%MW900\\n': invalid IEC address"),
        ("%MW900..%MW909\n", r"writable '%MW900..%MW909\\n': invalid IEC address"),
        ("", r"writable '': expected a tag name, a %M address or %MWa..%MWb"),
    ],
)
def test_addresses_that_cannot_be_opened_are_refused_at_once(entry, message):
    with pytest.raises(ConfigError, match=message):
        ModbusServer(port=0, writable_extra=[entry])
    with pytest.raises(ConfigError, match=message):
        ModbusServer(port=0, writable=[entry])


@pytest.mark.parametrize(
    ("writable", "extra", "message"),
    [
        (None, ["lamp"], r"writable 'lamp' \(%QX0.0\): the output image \(%Q\) is never"),
        (None, ["no_such_tag"], r"writable 'no_such_tag': unknown tag 'no_such_tag'"),
        (None, ["%MW1..%MW3"], r"writable '%MW1..%MW3': covers the read-only tag 'speed'"),
        (None, ["%MB4"], r"writable '%MB4': covers the read-only tag 'speed'"),
        (["button"], [], r"writable 'button' \(%IX0.1\): the input image \(%I\) is never"),
        # the image's marker area is 8192 bytes: %MW0..%MW4095 are served, no more
        (None, ["%MW4096"], r"'%MW4096': beyond the Modbus map \(%MW0..%MW4095, holding regis"),
        (None, ["%MW4000..%MW4100"], r"'%MW4000..%MW4100': beyond the Modbus map \(%MW0..%MW4095"),
    ],
)
def test_tag_entries_are_checked_when_the_runtime_starts(writable, extra, message):
    tags = fixture_tags()
    tags.add("lamp", "%QX0.0", "BOOL")
    tags.add("button", "%IX0.1", "BOOL")
    rt = runtime(tags)
    rt.add_driver(ModbusServer(port=0, writable=writable, writable_extra=extra))
    rt.add_task("main", [Probe(lambda ctx: None)])
    with pytest.raises(StartupError, match=message):
        rt.start()
    rt.stop()


def test_a_writable_tag_in_the_input_or_output_image_is_a_configuration_error():
    tags = TagTable()
    tags.add("target", "%QW5", "UINT", writable=True)
    rt = runtime(tags)
    rt.add_driver(ModbusServer(port=0))
    rt.add_task("main", [Probe(lambda ctx: None)])
    with pytest.raises(StartupError, match=r"writable tag 'target' \(%QW5\): the output image"):
        rt.start()
    rt.stop()
    rt = runtime(tags)
    rt.add_driver(ModbusServer(port=0, writable=[]))  # read-only: the tag is not used
    rt.add_task("main", [Probe(lambda ctx: None)])
    rt.start()
    rt.stop()


@pytest.mark.parametrize(
    ("spec", "line"),
    [
        ("5020", "--modbus: expected HOST:PORT, e.g. 127.0.0.1:5020, got '5020'"),
        ("::1:5020", "--modbus: an IPv6 host goes in brackets, e.g. [::1]:5020, got '::1:5020'"),
        ("[::1:5020", "--modbus: expected HOST:PORT, e.g. 127.0.0.1:5020, got '[::1:5020'"),
    ],
)
def test_a_bad_modbus_address_is_one_line(capsys, spec, line):
    assert main(["run", "--program", "demo", "--modbus", spec, "--cycles", "2"]) == 2
    assert capsys.readouterr().err == f"plc-runtime: error: {line}\n"


def test_the_cli_option_opens_writes_and_reports_bad_entries(capsys, tmp_path):
    assert main(["run", "--program", "demo", "--modbus-writable", "%MW20"]) == 2
    assert "--modbus-writable" in capsys.readouterr().err
    argv = ["run", "--program", "demo", "--modbus", "127.0.0.1:0", "--duration", "0.05"]
    assert main([*argv, "--modbus-writable", "%MW20,%QW5"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "writable '%QW5': the output image (%Q)" in err
    assert main([*argv, "--modbus-writable", "%MW\u0669\u0660\u0660"]) == 2  # Arabic-Indic 900
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'%MW\u0669\u0660\u0660': invalid IEC address" in err
    assert main([*argv, "--modbus-writable", "analog_filtered, %MW20..%MW21"]) == 0
    # the example README and --help give works for either program
    assert main([*argv, "--modbus-writable", "%MW450,%MW900..%MW909"]) == 0
    fleet = ["run", "--modbus", "127.0.0.1:0", "--cycles", "2", "--out", str(tmp_path)]
    assert main([*fleet, "--modbus-writable", "%MW450,%MW900..%MW909"]) == 0
    capsys.readouterr()
    # a bit alone could never be written (clients write whole registers): refused at start
    assert main([*argv, "--modbus-writable", "%MX900.0,%MW900..%MW909"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "writable '%MX900.0': only part of holding register 1474 (%MW450)" in err
    assert main([*argv, "--modbus-writable", ",".join(f"%MX900.{b}" for b in range(8))]) == 2
    capsys.readouterr()
    eight = ",".join(f"%MX{byte}.{b}" for byte in (900, 901) for b in range(8))
    assert main([*argv, "--modbus-writable", eight]) == 0  # together they make %MW450 whole


def test_map_entries_name_where_a_location_is_served():
    cases = {
        "%QX4.1": "coil 33",
        "%IX1.0": "DI 8",  # discrete input
        "%IW3": "IR 3",  # input register
        "%QW7": "HR 7",  # holding register
        "%MW0": "HR 1024",
        "%MD1": "HR 1026..1027",
        "%MX21.0": "HR 1034 bit 8",
        "%MB20": "HR 1034 bits 0-7",
    }
    assert {ref: str(map_entry(parse_address(ref))) for ref in cases} == cases
    assert map_entry(parse_address("%MD1")).table == "holding register"
    assert str(map_entry(parse_address("%MW1024"))) == "HR 2048"  # the marker area is served whole
    assert str(map_entry(parse_address("%MW64511"))) == "HR 65535"
    assert map_entry(parse_address("%MW64512")) is None  # beyond what Modbus addresses
    assert map_entry(parse_address("%QX1024.0")) is None  # beyond coil 8191


def test_a_route_command_record_cannot_be_written(tmp_path):
    """The fleet program's %QW are the vehicles' route commands: one FC16 would drive a
    vehicle past the reservations. Refused, and nothing changes."""
    from fleet.config import load_config
    from fleet.program import AREA_BYTES, FleetProgram

    cfg = load_config()
    cfg.watchdog = 10.0  # a server thread runs beside the scan
    program = FleetProgram(cfg)
    server = ModbusServer(port=0)  # the default: the program's writable tags only
    program.rt.add_driver(server)
    program.rt.start()
    client = ModbusTcpClient("127.0.0.1", port=server.port, timeout=2.0, retries=0)
    try:
        assert client.connect()
        program.rt.run(duration=5)
        first = (AREA_BYTES + 8 * 1) // 2  # vehicle 1's command record: %QW516..%QW519
        record = client.read_holding_registers(first, count=4).registers
        sent = program.controls[1].sequence
        assert record[3] >> 8 == sent > 0  # the high byte of the last word: its sequence
        forged = [10, 11, 12, 0x0183]  # nodes 10, 11, 12, go, sequence 1
        assert exception_code(client.write_registers(first, forged)) == 2
        assert exception_code(client.write_register(first + 3, 0x0183)) == 2
        assert program.rt.image.pending_writes == 0  # nothing queued for the quiet point
        program.rt.step()
        after = client.read_holding_registers(first, count=4).registers
        assert after != forged and after[3] >> 8 == program.controls[1].sequence
        if program.controls[1].sequence == sent:  # the program sent nothing new meanwhile
            assert after == record
        assert server.stats()["refused"] == 2 and server.stats()["writes"] == 0
    finally:
        client.close()
        program.close()


def test_exception_codes(served):
    _rt, _server, client = served
    assert exception_code(client.read_coils(8192, count=1)) == 2
    assert exception_code(client.read_input_registers(1024, count=1)) == 2
    # the marker area (8192 bytes here) ends at holding register 1024 + 4095
    assert exception_code(client.read_holding_registers(5119, count=2)) == 2
    assert exception_code(client.write_register(5120, 1)) == 2
    assert exception_code(client.read_exception_status()) == 1  # FC7: not served
    assert exception_code(client.mask_write_register(address=0)) == 1  # FC22: not served


def test_a_refused_request_is_one_log_line_without_traceback(served, caplog):
    _rt, server, _client = served
    caplog.set_level(logging.DEBUG)  # everything, pymodbus' own logging included
    cases = [  # PDU, what the line says
        (struct.pack(">BHH", 6, 516, 1), "FC6", "exception 02, holding registers 516..516 are"),
        (struct.pack(">BHH", 5, 32, 0xFF00), "FC5", "exception 02, coils 32..32 are %QX4.0"),
        (struct.pack(">BHH", 3, 5119, 2), "FC3", "exception 02, address outside the served"),
        (struct.pack(">B", 7), "FC7", "exception 01, function code not served"),
        (struct.pack(">BHH", 1, 0, 2001), "FC1", "exception 03, count or value out of range"),
    ]
    with socket.create_connection(("127.0.0.1", server.port), timeout=WAIT_S) as sock:
        for tid, (pdu, fc, text) in enumerate(cases):
            caplog.clear()
            sock.sendall(struct.pack(">HHHB", tid, 0, len(pdu) + 1, 1) + pdu)
            reply = sock.recv(64)
            assert reply[7] == pdu[0] | 0x80, reply
            loud = [r for r in caplog.records if r.levelno >= logging.WARNING]
            assert len(loud) == 1, [r.getMessage() for r in loud]
            line = loud[0].getMessage()
            assert line.startswith(f"modbus 127.0.0.1:{server.port}: refused {fc} from 127.0.0.1:")
            assert text in line and "\n" not in line and loud[0].exc_info is None
            assert "Traceback" not in caplog.text
    assert server.stats()["exceptions"] == len(cases)
    caplog.clear()
    with socket.create_connection(("127.0.0.1", server.port), timeout=WAIT_S) as sock:
        sock.sendall(struct.pack(">HHHBBHH", 1, 0x1234, 6, 1, 3, 1024, 1))  # not Modbus/TCP
        assert closed_by_server(sock)
    loud = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(loud) == 1 and "protocol id 4660, not Modbus/TCP's 0" in loud[0]


def test_a_flood_of_refused_requests_is_one_log_line_a_second(served, caplog):
    """A client pipelining refused writes as fast as it can gets every answer, but the log
    one line a second: the rest are counted, and the next line says how many were left
    out. The server's clock is held still, then moved on a second and a half."""
    _rt, server, _client = served
    thread = server._server
    thread.clock = lambda: 1000.0
    caplog.set_level(logging.WARNING, logger=LOGGER)
    flood = b"".join(struct.pack(">HHHBBHH", tid, 0, 6, 1, 6, 0, 1) for tid in range(200))
    with socket.create_connection(("127.0.0.1", server.port), timeout=WAIT_S) as sock:
        sock.sendall(flood)
        replies = receive_exactly(sock, 200 * 9)
        assert all(replies[i * 9 + 7 : i * 9 + 9] == b"\x86\x02" for i in range(200))
        lines = [r.getMessage() for r in caplog.records]
        assert len(lines) == 1 and "refused FC6" in lines[0] and "left out" not in lines[0]
        thread.clock = lambda: 1001.5
        sock.sendall(flood[:12])
        assert receive_exactly(sock, 9)[7:] == b"\x86\x02"
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2 and lines[1].endswith("(199 more from this client left out)")
    assert server.stats()["exceptions"] == 201  # every refusal counted all the same


def test_the_log_throttle_remembers_a_bounded_number_of_clients():
    """Clients come from many addresses: past ``max_keys`` the one quiet longest is
    forgotten (its next line is written at once), so memory stays bounded."""
    lines = LineThrottle(max_keys=2)
    assert [lines.admit(k, 0.0) for k in ("a", "a", "a", "b")] == [0, None, None, 0]
    assert lines.admit("c", 0.5) == 0  # "a" forgotten, with its two left out
    assert (lines.admit("a", 0.6), lines.admit("c", 0.7), lines.admit("c", 1.6)) == (0, None, 1)


def receive_exactly(sock: socket.socket, size: int) -> bytes:
    """``size`` bytes from ``sock`` (its timeout bounds each wait)."""
    data = b""
    while len(data) < size:
        chunk = sock.recv(size - len(data))
        assert chunk, f"connection closed after {len(data)} of {size} bytes"
        data += chunk
    return data


def test_a_failing_callback_is_one_log_line_and_exception_4(caplog):
    def read(area, address, count):
        raise ValueError("the image went away")

    server = _ModbusThread(read, lambda *args: None, "127.0.0.1", 0)
    caplog.set_level(logging.DEBUG)
    port = server.start()
    client = ModbusTcpClient("127.0.0.1", port=port, timeout=2.0, retries=0)
    try:
        assert client.connect()
        assert exception_code(client.read_holding_registers(0, count=1)) == 4
    finally:
        client.close()
        server.stop()
    loud = [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(loud) == 1 and loud[0].exc_info is None
    assert "exception 04, server failure at address 0: ValueError: the image went away" in (
        loud[0].getMessage()
    )
    assert "Traceback" not in caplog.text


@pytest.mark.parametrize("pymodbus_level", [logging.WARNING, logging.CRITICAL])
def test_busy_port_is_a_clear_startup_error(served, caplog, pymodbus_level):
    """The error says why (pymodbus' own exception does not), and nothing else is logged:
    on the command line that is one line. Also with pymodbus' logging turned down, as the
    Modbus vehicle link does for the whole process."""
    _rt, server, _client = served
    other = runtime()
    other.add_driver(ModbusServer(port=server.port))
    other.add_task("main", [Probe(lambda ctx: None)])
    caplog.set_level(logging.WARNING)
    pymodbus_log = logging.getLogger("pymodbus.logging")
    level = pymodbus_log.level
    pymodbus_log.setLevel(pymodbus_level)
    try:
        with pytest.raises(
            StartupError,
            match=f"Modbus server on 127.0.0.1:{server.port}: .*(address already|Address already)",
        ):
            other.start()
    finally:
        pymodbus_log.setLevel(level)
    other.stop()
    assert not [r for r in caplog.records if r.name.startswith("pymodbus")]


# ----- connections ------------------------------------------------------------------------
def read_request(tid: int) -> bytes:
    """FC3, holding register 1024, count 1 (MBAP header + PDU)."""
    return struct.pack(">HHHBBHH", tid, 0, 6, 1, 3, 1024, 1)


def answers(sock: socket.socket, tid: int) -> bool:
    sock.sendall(read_request(tid))
    reply = sock.recv(64)
    return reply[:2] == struct.pack(">H", tid) and reply[7] == 3


def closed_by_server(sock: socket.socket) -> bool:
    """Whether the server closed the connection (EOF or reset) within WAIT_S."""
    sock.settimeout(WAIT_S)
    try:
        return sock.recv(64) == b""
    except ConnectionResetError:
        return True


def wait_until(predicate, what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not predicate():
        assert time.monotonic() < deadline, what
        time.sleep(0.01)


def test_the_17th_connection_is_closed_while_16_stay_open(served, caplog):
    _rt, server, client = served
    client.close()  # the fixture's client would count
    wait_until(lambda: server.connections == 0, "the fixture's client was not released")
    caplog.set_level(logging.INFO, logger=LOGGER)
    sockets = []
    try:
        for i in range(16):
            sockets.append(socket.create_connection(("127.0.0.1", server.port), timeout=WAIT_S))
            assert answers(sockets[-1], i)
        extra = socket.create_connection(("127.0.0.1", server.port), timeout=WAIT_S)
        sockets.append(extra)
        assert closed_by_server(extra)
        assert all(answers(sock, 100 + i) for i, sock in enumerate(sockets[:16]))
        assert server.connections == 16 and server.stats()["connections_refused"] == 1
        refused = [r.getMessage() for r in caplog.records]
        assert len(refused) == 1 and "16 connections open (the limit)" in refused[0]
        sockets[0].close()  # a place frees up
        wait_until(lambda: server.connections == 15, "a closed connection was not released")
        sockets.append(socket.create_connection(("127.0.0.1", server.port), timeout=WAIT_S))
        assert answers(sockets[-1], 200)
    finally:
        for sock in sockets:
            sock.close()


def test_an_idle_connection_is_closed_after_the_timeout(caplog):
    """Only lower bounds are asserted: a busy machine can delay a close, never bring it
    forward. A connection is closed no sooner than the timeout after it opened, or after
    its last answered request (requests 1/4 of the timeout apart keep it open)."""
    timeout = 0.5
    rt = runtime()
    server = ModbusServer(port=0, idle_timeout=timeout)
    rt.add_driver(server)
    rt.add_task("main", [Probe(lambda ctx: None)])
    rt.start()
    caplog.set_level(logging.INFO, logger=LOGGER)
    try:
        opened = time.monotonic()
        with (
            socket.create_connection(("127.0.0.1", server.port), timeout=WAIT_S) as idle,
            socket.create_connection(("127.0.0.1", server.port), timeout=WAIT_S) as busy,
        ):
            answered = []  # when each answered request was sent
            for tid in range(4):
                sent = time.monotonic()
                busy.sendall(read_request(tid))
                if not busy.recv(64):
                    break  # closed already: the machine held this loop back past the timeout
                answered.append(sent)
                time.sleep(timeout / 4)
            assert closed_by_server(busy)
            assert time.monotonic() - max(answered, default=opened) >= timeout
            assert closed_by_server(idle)
            assert time.monotonic() - opened >= timeout
        assert server.stats()["idle_closed"] == 2
        lines = [r.getMessage() for r in caplog.records]
        assert len(lines) == 2 and all("no request for 0.5 s" in line for line in lines)
        wait_until(lambda: server.connections == 0, "closed connections were not released")
    finally:
        rt.stop()


def test_connection_limits_are_checked():
    with pytest.raises(ConfigError, match="max_connections must be 1 or more, not 0"):
        ModbusServer(port=0, max_connections=0)
    with pytest.raises(ConfigError, match="idle_timeout must be positive or None, not -1"):
        ModbusServer(port=0, idle_timeout=-1)


# ----- where it listens ---------------------------------------------------------------------
def test_loopback_addresses():
    assert all(is_loopback(host) for host in ("127.0.0.1", "127.1.2.3", "::1", "localhost"))
    assert not any(is_loopback(host) for host in ("0.0.0.0", "", "::", "192.0.2.1"))


def test_a_non_loopback_address_warns_before_binding(capsys):
    """No listener beyond loopback is opened: the port is taken on 127.0.0.1 by this test,
    so binding 0.0.0.0 to it fails, after the warning."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        rt = runtime()
        rt.add_driver(ModbusServer(host="0.0.0.0", port=port))
        rt.add_task("main", [Probe(lambda ctx: None)])
        with (
            pytest.warns(RuntimeWarning, match=f"on 0.0.0.0:{port}, not a loopback address"),
            pytest.raises(StartupError, match=f"Modbus server on 0.0.0.0:{port}"),
        ):
            rt.start()
        rt.stop()
        argv = ["run", "--program", "demo", "--modbus", f"0.0.0.0:{port}", "--duration", "1"]
        assert main(argv) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith(f"plc-runtime: warning: modbus: Modbus TCP server on 0.0.0.0:{port}")
    assert "no authentication" in err[0] and "docs/security.md" in err[0]
    assert err[1].startswith("plc-runtime: error: ") and len(err) == 2


def test_loopback_does_not_warn():
    server = _ModbusThread(lambda *args: [0], lambda *args: None, "localhost", 0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        server.start()
    server.stop()
    assert not [w for w in caught if "loopback" in str(w.message)]


# ----- other clients ------------------------------------------------------------------------
@pytest.mark.skipif(shutil.which("mbpoll") is None, reason="mbpoll (Debian package) not installed")
def test_interoperates_with_mbpoll(served):
    rt, server, _client = served
    rt.image.write("%MW3", 31337)
    rt.step()
    base = ["mbpoll", "-m", "tcp", "-p", str(server.port), "-a", "1", "-0", "-1", "-o", "2"]

    def mbpoll(*args):
        return subprocess.run(
            [*base, *args], capture_output=True, text=True, timeout=30, check=False
        )

    read = mbpoll("-t", "4", "-r", "1027", "-c", "1", "127.0.0.1")
    assert read.returncode == 0 and "31337" in read.stdout
    write = mbpoll("-t", "4", "-r", "1024", "127.0.0.1", "555")  # %MW0: opened
    assert write.returncode == 0, write.stdout + write.stderr
    rt.step()
    assert rt.image.read("%MW0") == 555
    illegal = mbpoll("-t", "3", "-r", "1024", "-c", "1", "127.0.0.1")
    assert illegal.returncode != 0 and "Illegal data address" in illegal.stdout + illegal.stderr
    refused = mbpoll("-t", "4", "-r", "10", "127.0.0.1", "555")  # %QW10: never writable
    assert refused.returncode != 0 and "Illegal data address" in refused.stdout + refused.stderr


def test_cli_serves_the_image_while_running(tmp_path):
    import json
    import sys
    from pathlib import Path

    with socket.socket() as probe:  # a free loopback port for the CLI
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    script = Path(sys.executable).parent / "plc-runtime"
    proc = subprocess.Popen(
        [
            str(script),
            "run",
            "--program",
            "demo",
            "--realtime",
            "--modbus",
            f"127.0.0.1:{port}",
            "--json",
            "--watchdog",
            "5000",  # a busy machine must not fault a wall-clock run
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert "until Ctrl-C" in proc.stderr.readline()  # running, server listening
        client = ModbusTcpClient("127.0.0.1", port=port, timeout=2.0, retries=0)
        assert client.connect()
        # the demo has no writable tags (its commands are field inputs): %MW10, the filtered
        # analog value it computes, is read-only for clients
        assert exception_code(client.write_register(1024 + 10, 0)) == 2
        reply = client.read_holding_registers(1024, count=1)  # %MW0: the demo's flash counter
        assert not reply.isError()
        client.close()
        proc.send_signal(subprocess.signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0
    assert json.loads(out)["state"] == "RUN"
    with pytest.raises(OSError):
        socket.create_connection(("127.0.0.1", port), timeout=1).close()  # the server is gone


def test_invalid_single_coil_value_is_refused(served):
    rt, server, _client = served
    request = bytes(
        [0, 1, 0, 0, 0, 6, 1, 5, 0, 32, 0x12, 0x34]
    )  # FC5 coil 32 := 0x1234 (only FF00/0000 allowed)
    with socket.create_connection(("127.0.0.1", server.port), timeout=5) as sock:
        sock.sendall(request)
        reply = sock.recv(64)
    assert reply[7:9] == bytes([0x85, 3])  # exception 3: illegal data value
    assert rt.image.pending_writes == 0


@pytest.mark.parametrize(
    "pdu",
    [
        struct.pack(">BHH", 6, 1024, 7) + b"\x00\x00",  # FC6 %MW0 := 7, and two bytes more
        struct.pack(">BHHB", 16, 1024, 1, 2) + struct.pack(">H", 7) + b"\x00",  # one byte more
        struct.pack(">BHH", 3, 1024, 1) + b"\x00",  # a read, one byte more
        struct.pack(">BH", 6, 1024),  # FC6 without its value
    ],
    ids=["fc6-longer", "fc16-longer", "fc3-longer", "fc6-shorter"],
)
def test_a_request_longer_or_shorter_than_its_function_is_refused(served, pdu):
    """pymodbus reads the fields it expects and ignores what follows: a write with bytes
    after its value (a corrupted or crafted frame) was carried out. Now any request of a
    served function whose length is not its function's is exception 3, and nothing is
    written; the connection goes on."""
    rt, server, _client = served
    with socket.create_connection(("127.0.0.1", server.port), timeout=WAIT_S) as sock:
        sock.sendall(frame(5, pdu))
        (answer,) = receive_frames(sock, 1)
        assert answer == frame(5, bytes((pdu[0] | 0x80, 3)))
        assert answers_request(sock, 6)
    rt.step()
    assert rt.image.pending_writes == 0 and rt.image.read("%MW0") == 0


# ----- framing ------------------------------------------------------------------------------
def frame(tid: int, pdu: bytes, unit: int = 1) -> bytes:
    """An MBAP frame: header (transaction id, protocol id 0, length, unit id) + PDU."""
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


def receive_frames(sock: socket.socket, count: int) -> list[bytes]:
    """The next ``count`` answers on ``sock``, cut at their MBAP lengths; nothing more."""
    sock.settimeout(WAIT_S)
    data, frames = b"", []
    while len(frames) < count:
        size = 6 + struct.unpack(">H", data[4:6])[0] if len(data) >= 6 else None
        if size is not None and len(data) >= size:
            frames.append(data[:size])
            data = data[size:]
            continue
        chunk = sock.recv(65536)
        assert chunk, f"closed after {len(frames)} of {count} answers"
        data += chunk
    assert not data, "more bytes than answers"
    return frames


def warnings_logged(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


def answers_request(sock: socket.socket, tid: int) -> bool:
    sock.sendall(read_request(tid))
    return receive_frames(sock, 1)[0][:2] == struct.pack(">H", tid)


# request i of a pipeline: what it asks, what its answer's PDU must be
PIPELINE = [
    (struct.pack(">BHH", 3, 1026, 1), struct.pack(">BBH", 3, 2, 42)),  # speed (%MW2)
    (struct.pack(">BHH", 6, 516, 1), bytes((0x86, 2))),  # %QW516: refused
    (struct.pack(">BHH", 3, 1027, 1), struct.pack(">BBH", 3, 2, 4242)),  # %MW3
]


@pytest.mark.parametrize("count", [2, 10, 60])
def test_pipelined_requests_get_every_answer_in_order(served, caplog, count):
    """Requests sent back to back in one segment, each with its own transaction id: one
    answer each, in request order, each the answer to its own request (a refused write
    among reads does not shift or break the others)."""
    rt, server, _client = served
    rt.image.write("%MW3", 4242)
    rt.step()
    caplog.set_level(logging.INFO, logger=LOGGER)
    cases = [PIPELINE[i % len(PIPELINE)] for i in range(count)]
    with socket.create_connection(("127.0.0.1", server.port), timeout=WAIT_S) as sock:
        sock.sendall(b"".join(frame(1000 + i, pdu) for i, (pdu, _) in enumerate(cases)))
        answers = receive_frames(sock, count)
        assert answers == [frame(1000 + i, want) for i, (_, want) in enumerate(cases)]
        assert answers_request(sock, 7)  # the connection goes on
    refused = warnings_logged(caplog)
    assert len(refused) == sum(want[0] == 0x86 for _, want in cases)
    assert all("refused FC6 " in line and "%QW516" in line for line in refused)


def test_a_burst_beyond_the_backlog_bound_is_answered_in_full(served):
    """3000 requests (36 kB) in one go: the server stops reading while too many wait (TCP
    holds them on the client's side) and answers every one, in order."""
    _rt, server, _client = served
    count = 3000
    requests = b"".join(read_request(i) for i in range(count))
    with socket.create_connection(("127.0.0.1", server.port), timeout=WAIT_S) as sock:
        sender = threading.Thread(target=sock.sendall, args=(requests,))
        sender.start()  # sent while the answers are read: neither side waits on the other
        try:
            answers = receive_frames(sock, count)
        finally:
            sender.join(WAIT_S)
        assert [a[:2] for a in answers] == [struct.pack(">H", i) for i in range(count)]
        assert all(a[7] == 3 for a in answers)


def test_a_client_that_does_not_read_its_answers_is_held_back():
    """It sends requests for 125 registers and reads nothing: once the answers fill the
    transport's send buffer the server takes no more requests and stops reading (the
    client's sends then wait in TCP), instead of buffering answers without bound. Every
    answer arrives once it reads. Both sockets' kernel buffers are made small, so the
    2000 answers (0.5 MB) back up whatever the machine's TCP buffer sizes."""
    server = _ModbusThread(lambda area, address, count: [0] * count, lambda *args: None, port=0)
    server.start()
    count, size = 2000, 9 + 2 * 125
    requests = b"".join(struct.pack(">HHHBBHH", i, 0, 6, 1, 3, 0, 125) for i in range(count))
    sock = socket.socket()
    sender = threading.Thread(target=sock.sendall, args=(requests,))
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        sock.connect(("127.0.0.1", server.port))
        wait_until(lambda: server.connections == 1, "the connection was not counted")
        (conn,) = server._open
        conn.transport.get_extra_info("socket").setsockopt(
            socket.SOL_SOCKET, socket.SO_SNDBUF, 4096
        )
        sender.start()
        wait_until(lambda: conn._writing_paused, "the answers never backed up")
        assert not conn.transport.is_reading()
        assert conn.transport.get_write_buffer_size() <= 64 * 1024 + size  # asyncio's mark
        answers = receive_frames(sock, count)
        assert [a[:2] for a in answers] == [struct.pack(">H", i) for i in range(count)]
        assert all(len(a) == size for a in answers)
    finally:
        sock.close()
        if sender.ident is not None:  # started
            sender.join(WAIT_S)
        server.stop()


@pytest.mark.parametrize("cut", [3, 7, 9])  # inside the header, after it, inside the PDU
def test_a_request_split_over_two_sends_is_answered(served, cut):
    """The first send carries a whole request and the start of the next: the first answer
    shows the server has read that segment, the rest of the second request completes it."""
    _rt, server, _client = served
    second = read_request(2)
    with socket.create_connection(("127.0.0.1", server.port), timeout=WAIT_S) as sock:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.sendall(read_request(1) + second[:cut])
        assert receive_frames(sock, 1)[0][:2] == struct.pack(">H", 1)
        sock.sendall(second[cut:])
        assert receive_frames(sock, 1)[0][:2] == struct.pack(">H", 2)


@pytest.mark.parametrize("behind", [False, True], ids=["first", "behind-a-request"])
@pytest.mark.parametrize(
    ("header", "why"),
    [
        (struct.pack(">HHHB", 1, 0, 0, 1), "MBAP length 0 outside 2..254"),
        (struct.pack(">HHHB", 1, 0, 1, 1), "MBAP length 1 outside 2..254"),
        (struct.pack(">HHHB", 1, 0, 255, 1) + b"\x03", "MBAP length 255 outside 2..254"),
        (struct.pack(">HHHB", 1, 0, 65535, 1), "MBAP length 65535 outside 2..254"),
        (struct.pack(">HHHB", 1, 1, 6, 1), "protocol id 1, not Modbus/TCP's 0"),
    ],
    ids=["length-0", "length-1", "length-255", "length-65535", "protocol-id-1"],
)
def test_a_bad_mbap_header_closes_the_connection_at_once(served, caplog, header, why, behind):
    """Nothing after a bad header can be framed: the connection is closed at once (long
    before the idle timeout) with one line naming the client, and the valid request sent
    behind the header is not answered; a request before it is. Other connections go on."""
    _rt, server, client = served
    caplog.set_level(logging.INFO, logger=LOGGER)
    before = read_request(1) if behind else b""
    with socket.create_connection(("127.0.0.1", server.port), timeout=WAIT_S) as sock:
        peer = f"127.0.0.1:{sock.getsockname()[1]}"
        sock.sendall(before + header + read_request(2))
        if behind:
            assert receive_frames(sock, 1)[0][:2] == struct.pack(">H", 1)
        assert closed_by_server(sock)
    detail = " (unit id + a PDU of 1..253 bytes)" if "length" in why else ""
    assert warnings_logged(caplog) == [
        f"modbus 127.0.0.1:{server.port}: closed connection from {peer}: {why}{detail}"
    ]
    assert client.read_holding_registers(1024, count=1).registers == [0]


@pytest.mark.parametrize("fc", [0x80, 0xC8, 0xFF])
def test_function_codes_128_to_255_get_illegal_function(served, caplog, fc):
    """A request cannot have a code of 128..255 (they mark exception responses): exception
    01, whose function code (fc | 0x80) is the request's own; the line names that code."""
    _rt, server, _client = served
    caplog.set_level(logging.INFO, logger=LOGGER)
    with socket.create_connection(("127.0.0.1", server.port), timeout=WAIT_S) as sock:
        sock.sendall(frame(9, bytes((fc, 0, 0, 0, 1)), unit=5))
        assert receive_frames(sock, 1) == [frame(9, bytes((fc, 1)), unit=5)]
        assert answers_request(sock, 10)  # the connection goes on
    (line,) = warnings_logged(caplog)
    assert f": refused FC{fc} from 127.0.0.1:" in line
    assert line.endswith(
        "exception 01, function codes 128..255 are reserved for exception responses, not requests"
    )


@pytest.mark.parametrize("count", [1, 2, 10])
def test_requests_before_a_half_close_are_all_answered(served, count):
    """A client that sends its requests and shuts its side down (it reads on) gets every
    answer, then the server closes the connection."""
    rt, server, _client = served
    rt.image.write("%MW3", 4242)
    rt.step()
    cases = [PIPELINE[i % len(PIPELINE)] for i in range(count)]
    with socket.create_connection(("127.0.0.1", server.port), timeout=WAIT_S) as sock:
        sock.sendall(b"".join(frame(50 + i, pdu) for i, (pdu, _) in enumerate(cases)))
        sock.shutdown(socket.SHUT_WR)
        answers = receive_frames(sock, count)
        assert answers == [frame(50 + i, want) for i, (_, want) in enumerate(cases)]
        assert sock.recv(1) == b""  # closed after the last answer


def test_a_runtime_s_server_answers_only_between_scans(monkeypatch):
    """While a scan runs (the runtime's between-scans event clear) a request waits; once
    the scan is over it is answered."""
    import io_drivers.modbus_server as module

    monkeypatch.setattr(module, "QUIET_WAIT_S", 60.0)  # only the event lets it go on here
    rt = runtime(fixture_tags())
    server = ModbusServer(port=0)
    rt.add_driver(server)
    rt.add_task("main", [Probe(lambda ctx: None)])
    rt.start()
    try:
        with socket.create_connection(("127.0.0.1", server.port), timeout=WAIT_S) as sock:
            assert answers_request(sock, 1)  # between scans: at once
            rt.between_scans.clear()  # as the runtime does for a scan
            sock.sendall(read_request(2))
            sock.settimeout(0.2)
            with pytest.raises(TimeoutError):
                sock.recv(1)  # held while the "scan" runs
            rt.between_scans.set()
            assert receive_frames(sock, 1)[0][:2] == struct.pack(">H", 2)
    finally:
        rt.between_scans.set()
        rt.stop()


def test_a_server_waiting_for_a_scan_still_stops_at_once(monkeypatch):
    """Stopped while the runtime holds its event clear (a long cycle's quiet lead, or a
    scan that does not end): the server's shutdown does not wait for scans, so stop()
    completes instead of giving up after its join timeout and leaving the runtime up."""
    import io_drivers.modbus_server as module

    monkeypatch.setattr(module, "QUIET_WAIT_S", 60.0)
    rt = runtime(fixture_tags())
    server = ModbusServer(port=0)
    rt.add_driver(server)
    rt.add_task("main", [Probe(lambda ctx: None)])
    rt.start()
    with socket.create_connection(("127.0.0.1", server.port), timeout=WAIT_S) as sock:
        assert answers_request(sock, 1)
        rt.between_scans.clear()
        try:
            rt.stop()  # joins the server's thread for 5 s at most, else TimeoutError
        finally:
            rt.between_scans.set()
    assert rt.state == "STOP" and server.port is None


def test_a_driver_attribute_named_added_to_that_is_no_method_is_left_alone():
    class Logger:
        name = "csvlog"
        added_to = "2026-12-01"  # its own data, not the runtime's hook

        def open(self, image):
            pass

        def read_inputs(self, image, now_ns):
            pass

        def write_outputs(self, image, now_ns):
            pass

        def close(self):
            pass

        def stats(self):
            return {}

    rt = runtime()
    rt.add_driver(Logger())
    assert [d.name for d in rt.drivers] == ["csvlog"]
