"""Where the vehicles are and which clock runs the fleet: paced simulation (``--speed``),
the wall clock with in-process vehicles, controller-only mode against vehicles started
elsewhere (Modbus TCP on loopback), the Modbus vehicle link from the configuration, and
the combinations that are refused before anything runs."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from ports import free_base_port

from fleet.cli import main
from fleet.commands.vehicles import READY_LINE
from fleet.config import DEFAULT_CONFIG
from fleet.report import MONITORED_IN_VEHICLES, NOT_MONITORED
from plc_runtime import PacedClock

PLC = [sys.executable, "-m", "fleet"]
WIDE_WATCHDOG = ["--watchdog", "5000"]  # real-time runs: a busy machine must not fault them


def with_bus(interface: str, channel: str) -> str:
    """The default job's configuration text with another vehicle link."""
    text = DEFAULT_CONFIG.read_text()
    old = '[bus]\ninterface = "virtual"\nchannel = "agv"\n'
    assert old in text
    return text.replace(old, f'[bus]\ninterface = "{interface}"\nchannel = "{channel}"\n')


class FakeTime:
    """Stands in for the ``time`` module inside plc_runtime.clock: sleeping advances it."""

    def __init__(self) -> None:
        self.ns = 1_000_000_000
        self.slept: list[float] = []

    def monotonic_ns(self) -> int:
        return self.ns

    def sleep(self, seconds: float) -> None:
        self.slept.append(seconds)
        self.ns += round(seconds * 1e9)


def test_paced_clock_keeps_pace_and_never_drops_a_tick(monkeypatch):
    fake = FakeTime()
    monkeypatch.setattr("plc_runtime.clock.time", fake)
    clock = PacedClock(speed=4.0)
    clock.enter_run()
    tick = 10_000_000  # 10 ms of simulated time
    for k in range(1, 101):
        clock.wait_until(k * tick)
        assert clock.now_ns() == k * tick  # simulated time: exactly the deadline
    # 1 s simulated at 4x: 0.25 s of (fake) wall time after the first step anchored
    assert fake.ns - 1_000_000_000 == pytest.approx(0.99e9 / 4, abs=1e3)
    assert clock.resyncs == 0


def test_paced_clock_falls_behind_without_racing_afterwards(monkeypatch):
    fake = FakeTime()
    monkeypatch.setattr("plc_runtime.clock.time", fake)
    clock = PacedClock(speed=1.0, max_lag=0.5)
    clock.enter_run()
    clock.wait_until(10_000_000)
    fake.ns += 2_000_000_000  # the machine stalled for 2 s
    clock.wait_until(20_000_000)
    assert clock.resyncs == 1
    slept_before = len(fake.slept)
    clock.wait_until(30_000_000)  # paced again from the new reference: one tick, 10 ms
    assert fake.slept[slept_before:] == [pytest.approx(0.01)]


def test_speed_runs_the_same_fleet_as_the_virtual_clock(tmp_path, capsys):
    """Pacing changes when a step happens, never what it does."""
    runs = []
    for extra in ([], ["--speed", "500"]):
        out = tmp_path / ("paced" if extra else "virtual")
        args = ["run", "--duration", "30", "--json", "--out", str(out), *extra]
        assert main(args) == 0
        runs.append(json.loads(capsys.readouterr().out))
    virtual, paced = runs
    assert virtual["clock"] == "virtual" and paced["clock"] == "paced" and paced["speed"] == 500
    for key in ("cycles", "sim_time_s", "vehicles", "waits", "replans", "stations_visited"):
        assert paced[key] == virtual[key], key


def test_realtime_without_a_bus_runs_the_vehicles_in_this_process(tmp_path, capsys):
    args = ["run", "--realtime", "--duration", "1", "--json", "--out", str(tmp_path)]
    assert main([*args, *WIDE_WATCHDOG]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["clock"] == "wall" and summary["vehicles_mode"] == "in this process"
    assert summary["drivers"]["can"]["online"] == 4
    assert summary["head_on_conflicts"] == 0 and summary["node_conflicts"] == 0


@pytest.mark.parametrize(
    "args, says",
    [
        (["--bus", "socketcan:vcan0"], "could never answer on the virtual clock: add --realtime"),
        (["--bus", "modbus:127.0.0.1:5100", "--speed", "2"], "could never answer on --speed 2"),
        (["--vehicles", "external"], "cannot reach the in-process virtual bus"),
        (
            ["--vehicles", "external", "--bus", "socketcan:vcan0", "--speed", "3"],
            "--speed cannot apply",
        ),
        (["--realtime", "--bus", "modbus:10.1.2.3:5100"], "serve Modbus on 127.0.0.1 only"),
        (["--bus", "modbus:127.0.0.1:notaport"], "expected HOST:BASE_PORT"),
        (["--bus", "modbus:::1:5100"], "an IPv6 host goes in brackets, e.g. [::1]:5100"),
        (["--bus", "vcan0"], "expected INTERFACE:CHANNEL"),
        (["--rt"], "--rt and --spin only apply with --realtime"),
    ],
)
def test_combinations_where_vehicles_could_never_answer_are_refused(tmp_path, capsys, args, says):
    out = tmp_path / "out"
    assert main(["run", "--duration", "1", "--out", str(out), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("plc-runtime: error: ") and says in err[-1]
    assert "Traceback" not in "\n".join(err)
    assert not out.exists()  # refused before anything ran


def test_a_bus_in_the_configuration_is_checked_the_same_way(tmp_path, capsys):
    cfg = tmp_path / "fleet.toml"
    cfg.write_text(with_bus("socketcan", "vcan0"))
    assert main(["run", str(cfg), "--duration", "1", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "bus.interface socketcan:vcan0 reaches vehicles outside this process" in err


def test_a_failing_vehicle_process_shows_its_own_error(tmp_path, capsys):
    # no interface of this name exists on any machine: the child process fails to open it
    args = ["run", "--realtime", "--bus", "socketcan:nosuchcan7", "--duration", "1"]
    assert main([*args, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "the vehicle process did not start (exit code 2): vehicle link:" in err
    assert "no output" not in err


def test_a_vehicle_port_in_use_stops_the_run_with_the_vehicle_process_error(tmp_path, capsys):
    """The vehicle process's error "address already in use" contains "ready": it must not be
    taken for the ready line, or the run goes on with every vehicle offline and exits 0."""
    base = free_base_port(4)
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", base + 2))
        taken.listen()
        args = ["run", "--realtime", "--bus", f"modbus:127.0.0.1:{base}", "--duration", "2"]
        assert main([*args, "--out", str(tmp_path / "o"), *WIDE_WATCHDOG]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "the vehicle process did not start (exit code 2): vehicle link:" in err
    assert "address already in use" in err.lower(), err


def start_modbus_vehicles() -> tuple[int, subprocess.Popen]:
    """The default job's vehicles in their own process, each a Modbus server on loopback;
    started again on other ports if another process took one of them meanwhile."""
    for _ in range(3):
        base = free_base_port(4)
        cmd = [*PLC, "vehicles", "--config", str(DEFAULT_CONFIG), "--modbus-base-port", str(base)]
        proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
        line = proc.stderr.readline()
        if READY_LINE.match(line):
            return base, proc
        stop(proc)
        assert "address already in use" in line, line + proc.stderr.read()
    raise AssertionError("no free ports for the vehicles")


def stop(proc: subprocess.Popen) -> None:
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def test_controller_only_mode_attaches_to_vehicles_started_elsewhere(tmp_path, capsys):
    base, vehicles = start_modbus_vehicles()
    try:
        args = ["run", "--vehicles", "external", "--bus", f"modbus:127.0.0.1:{base}"]
        args += ["--duration", "4", "--json", "--out", str(tmp_path), *WIDE_WATCHDOG]
        assert main(args) == 0
        summary = json.loads(capsys.readouterr().out)
    finally:
        stop(vehicles)
    assert summary["vehicles_mode"] == "external" and summary["clock"] == "wall"
    link = summary["drivers"]["modbus-vehicles"]
    assert link["online"] == 4 and link["polls"] > 0 and link["writes"] > 0
    assert summary["plans"] >= 4  # every vehicle was given a route
    assert summary["conflict_monitor"] == NOT_MONITORED  # nothing of ours simulated


def test_vehicles_that_never_answer_are_not_online_and_each_is_an_alarm(tmp_path, capsys):
    """Controller only, and nobody serves the vehicles' ports: the link's count of vehicles
    online is 0 (it was counted as every vehicle not stale, and read 4 once the link had
    closed), and each vehicle gets an event once it has been silent for the stale time."""
    base = free_base_port(4)
    args = ["run", "--vehicles", "external", "--bus", f"modbus:127.0.0.1:{base}"]
    args += ["--duration", "2", "--json", "--out", str(tmp_path), *WIDE_WATCHDOG]
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    link = summary["drivers"]["modbus-vehicles"]
    assert link["online"] == 0 and link["reads"] == 0 and link["stale"] == [1, 2, 3, 4]
    silent = [e for e in summary["events"] if e["text"].endswith("since the start")]
    assert [(e["kind"], e["vehicle"]) for e in silent] == [("vehicle", v) for v in (1, 2, 3, 4)]
    assert all(e["time_s"] > 0.5 for e in silent)  # [bus] stale_after_s = 0.5


def test_the_modbus_vehicle_link_from_the_configuration(tmp_path):
    """``[bus] interface = "modbus"``: with --realtime the simulated vehicles are started in
    their own process, each serving Modbus TCP on loopback; their monitor reports back."""
    base = free_base_port(4)
    cfg = tmp_path / "modbus.toml"
    cfg.write_text(with_bus("modbus", f"127.0.0.1:{base}"))
    cmd = [*PLC, "run", str(cfg), "--realtime", "--duration", "4", "--json"]
    result = subprocess.run(
        [*cmd, "--out", str(tmp_path / "o"), *WIDE_WATCHDOG],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    assert summary["vehicles_mode"] == "child process"
    assert summary["drivers"]["modbus-vehicles"]["online"] == 4
    assert summary["head_on_conflicts"] == 0 and summary["node_conflicts"] == 0
    assert summary["conflict_monitor"] == MONITORED_IN_VEHICLES


def signalled(
    cmd: list[str], ready: Callable[[], bool], settle_s: float, sig: int
) -> tuple[int, str, str]:
    """Run ``cmd``; once ``ready()`` (or after 60 s) and ``settle_s`` more, send ``sig``;
    its exit code and output. The process never outlives the call."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not ready():
            time.sleep(0.1)
        time.sleep(settle_s)
        proc.send_signal(sig)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, stdout, stderr


def test_ctrl_c_ends_the_run_cleanly_and_says_so(tmp_path):
    out = tmp_path / "out"
    cmd = [*PLC, "run", "--speed", "1", "--duration", "600", "--json", "--out", str(out)]
    cmd += WIDE_WATCHDOG
    # the output folder is made (checked) right before the run starts
    code, stdout, stderr = signalled(cmd, out.exists, 1.5, signal.SIGINT)
    assert code == 130, stderr[-2000:]
    summary = json.loads(stdout.strip().splitlines()[-1])
    assert summary["interrupted"] is True and 0 <= summary["sim_time_s"] < 600
    assert json.loads((out / "summary.json").read_text())["interrupted"] is True
    assert "interrupted at" in stderr


def accepts(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(1)
        return s.connect_ex(("127.0.0.1", port)) == 0


def vehicle_processes(base: int) -> list[int]:
    """The pids of vehicle processes serving above ``base`` (from /proc: any Linux)."""
    found = []
    for entry in Path("/proc").iterdir():
        try:
            cmd = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:  # not a process, or gone meanwhile
            continue
        if b"vehicles" in cmd and str(base).encode() in cmd and b"--modbus-base-port" in cmd:
            found.append(int(entry.name))
    return found


def test_sigterm_ends_a_realtime_run_like_ctrl_c_and_stops_its_vehicle_process(tmp_path):
    """A service manager (systemd, ``docker stop``) ends the controller with SIGTERM: the
    results are written, the vehicle process is stopped with it (not left serving its ports
    to the next run), and the exit code says which signal it was (128 + 15)."""
    base = free_base_port(4)
    out = tmp_path / "out"
    cmd = [*PLC, "run", "--realtime", "--bus", f"modbus:127.0.0.1:{base}", "--duration", "600"]
    cmd += ["--json", "--out", str(out), *WIDE_WATCHDOG]
    try:  # the vehicle process serves once it is ready
        code, stdout, stderr = signalled(cmd, lambda: accepts(base + 1), 1.0, signal.SIGTERM)
    finally:
        left = vehicle_processes(base)
        for pid in left:  # (never, if the run stops its child: asserted below)
            os.kill(pid, signal.SIGKILL)
    assert not left, f"vehicle process left running: {left}"
    assert code == 128 + signal.SIGTERM, stderr[-2000:]
    assert "stopped by SIGTERM at" in stderr and "results written" in stderr
    summary = json.loads(stdout.strip().splitlines()[-1])
    assert summary["interrupted"] is True and 0 <= summary["sim_time_s"] < 600
    assert json.loads((out / "summary.json").read_text())["interrupted"] is True
    assert not any(accepts(base + v) for v in range(1, 5))  # the vehicles went with it


def test_an_unwritable_output_folder_is_refused_before_the_run(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    started = time.monotonic()
    assert main(["run", "--duration", "600", "--out", str(blocker / "out")]) == 2
    assert time.monotonic() - started < 30  # 600 simulated seconds were never run
    err = capsys.readouterr().err
    assert f"--out {blocker / 'out'}: cannot write results there" in err
    taken = tmp_path / "taken"
    (taken / "summary.json").mkdir(parents=True)
    assert main(["run", "--duration", "600", "--out", str(taken)]) == 2
    assert "summary.json exists and cannot be overwritten" in capsys.readouterr().err
    assert [p.name for p in taken.iterdir()] == ["summary.json"]  # no lock file left


def test_no_output_folder_no_files_left_from_the_check(tmp_path, capsys):
    out = tmp_path / "new" / "deeper"
    assert main(["run", "--duration", "5", "--json", "--out", str(out)]) == 0
    capsys.readouterr()
    assert sorted(p.name for p in out.iterdir()) == ["recipes.csv", "routes.png", "summary.json"]


def test_demo_program_refuses_fleet_options(capsys):
    assert main(["run", "--program", "demo", "--bus", "socketcan:vcan0", "--cycles", "1"]) == 2
    assert "are for the fleet program" in capsys.readouterr().err


def test_demo_program_can_be_paced(capsys):
    assert main(["run", "--program", "demo", "--speed", "100", "--duration", "1", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["clock"] == "paced" and summary["cycles"] == 100


@pytest.fixture(autouse=True)
def _no_stray_children():
    yield
    # every process a test started (directly or through main()) was stopped by it
    children = subprocess.run(
        ["pgrep", "-P", str(os.getpid())], capture_output=True, text=True
    ).stdout.split()
    alive = [pid for pid in children if Path(f"/proc/{pid}/cmdline").exists()]
    cmdlines = [Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ") for pid in alive]
    assert not [c for c in cmdlines if b"fleet" in c], cmdlines
