"""The Modbus TCP server on the process image: map, quiet-point writes, exception codes,
an independent client (mbpoll), clean shutdown. Loopback only, ephemeral ports."""

import shutil
import subprocess
import threading

import pytest
from conftest import Probe
from pymodbus.client import ModbusTcpClient
from pymodbus.pdu import ExceptionResponse

from io_drivers.modbus_server import ModbusServer
from plc_runtime import Runtime, StartupError, VirtualClock


@pytest.fixture
def served():
    def cycle(ctx):
        ctx.image.write("%QW0", ctx.cycle % 65536)  # a value the program owns
        ctx.image.write("%QX4.0", True)  # coil 32 (not inside %QW0: sizes overlap in one memory)

    rt = Runtime(cycle_time=0.010, clock=VirtualClock())
    server = ModbusServer(port=0)
    rt.add_driver(server)
    rt.add_task("main", [Probe(cycle)])
    threads_before = threading.active_count()
    rt.start()
    client = ModbusTcpClient("127.0.0.1", port=server.port, timeout=2.0, retries=0)
    assert client.connect()
    yield rt, server, client
    client.close()
    rt.stop()
    assert threading.active_count() == threads_before  # the server thread is gone


def exception_code(response):
    assert response.isError() and isinstance(response, ExceptionResponse), response
    return response.exception_code


def test_reads_follow_the_openplc_map(served):
    rt, _server, client = served
    rt.image.write_many({"%IX0.1": True, "%IW3": 777, "%MW2": 4242})
    rt.step(5)
    assert client.read_holding_registers(0, count=1).registers == [4]  # %QW0 after scan 4
    assert client.read_coils(32, count=2).bits[:2] == [True, False]  # %QX4.0, %QX4.1
    assert client.read_discrete_inputs(0, count=3).bits[:3] == [False, True, False]  # %IX0.1
    assert client.read_input_registers(3, count=1).registers == [777]  # %IW3
    assert client.read_holding_registers(1026, count=1).registers == [4242]  # %MW2


def test_writes_are_applied_at_the_quiet_point(served):
    rt, server, client = served
    rt.step()
    assert not client.write_register(5, 123).isError()  # %QW5
    assert not client.write_registers(1024, [7, 8]).isError()  # %MW0, %MW1 together
    assert not client.write_coil(41, True).isError()  # %QX5.1
    assert rt.image.read("%MW0") == 0 and rt.image.pending_writes == 3  # queued, not applied
    rt.step()
    assert rt.image.read("%QW5") == 123 and rt.image.read("%QX5.1") is True
    assert (rt.image.read("%MW0"), rt.image.read("%MW1")) == (7, 8)
    assert client.read_holding_registers(5, count=1).registers == [123]
    assert server.stats()["writes"] == 3


def test_exception_codes(served):
    _rt, _server, client = served
    assert exception_code(client.read_coils(8192, count=1)) == 2
    assert exception_code(client.read_input_registers(1024, count=1)) == 2
    assert exception_code(client.read_holding_registers(2047, count=2)) == 2
    assert exception_code(client.write_register(2048, 1)) == 2
    assert exception_code(client.read_exception_status()) == 1  # FC7: not served
    assert exception_code(client.mask_write_register(address=0)) == 1  # FC22: not served


def test_busy_port_is_a_clear_startup_error(served):
    _rt, server, _client = served
    other = Runtime(cycle_time=0.010, clock=VirtualClock())
    other.add_driver(ModbusServer(port=server.port))
    other.add_task("main", [Probe(lambda ctx: None)])
    with pytest.raises(StartupError, match=f"Modbus server on 127.0.0.1:{server.port}"):
        other.start()
    other.stop()


@pytest.mark.skipif(shutil.which("mbpoll") is None, reason="mbpoll (Debian package) not installed")
def test_interoperates_with_mbpoll(served):
    rt, server, _client = served
    rt.image.write("%MW3", 31337)
    rt.step()
    base = ["mbpoll", "-m", "tcp", "-p", str(server.port), "-a", "1", "-0", "-1", "-o", "2"]
    read = subprocess.run(
        [*base, "-t", "4", "-r", "1027", "-c", "1", "127.0.0.1"],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert (
        read.returncode == 0
        and "[1027]: \t31337" in read.stdout.replace(" ", "\t")
        or "31337" in read.stdout
    )
    write = subprocess.run(
        [*base, "-t", "4", "-r", "10", "127.0.0.1", "555"],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert write.returncode == 0, write.stdout + write.stderr
    rt.step()
    assert rt.image.read("%QW10") == 555
    illegal = subprocess.run(
        [*base, "-t", "3", "-r", "1024", "-c", "1", "127.0.0.1"],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert illegal.returncode != 0 and "Illegal data address" in illegal.stdout + illegal.stderr


def test_cli_serves_the_image_while_running(tmp_path):
    import json
    import socket
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
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert "until Ctrl-C" in proc.stderr.readline()  # running, server listening
        client = ModbusTcpClient("127.0.0.1", port=port, timeout=2.0, retries=0)
        assert client.connect()
        assert not client.write_register(1024 + 10, 0).isError()  # %MW10 = 0, an ordinary write
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
    import socket

    rt, server, _client = served
    request = bytes(
        [0, 1, 0, 0, 0, 6, 1, 5, 0, 32, 0x12, 0x34]
    )  # FC5 coil 32 := 0x1234 (only FF00/0000 allowed)
    with socket.create_connection(("127.0.0.1", server.port), timeout=5) as sock:
        sock.sendall(request)
        reply = sock.recv(64)
    assert reply[7:9] == bytes([0x85, 3])  # exception 3: illegal data value
    assert rt.image.pending_writes == 0
