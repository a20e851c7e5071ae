"""The fleet program's tags: the words mirror the program's state, the blockade command and
the vehicles' holds act through the program's own paths (never past the reservations),
lifetime totals are retained across runs, and a Modbus client reads and commands the fleet
but cannot write anything else. Virtual clock, stepped; loopback only."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from fleet_scenarios import run
from pymodbus.client import ModbusTcpClient
from pymodbus.pdu import ExceptionResponse

from blocks.traffic.records import NO_NODE, STATES
from fleet.cli import main
from fleet.config import FleetConfig, load_config
from fleet.program import AREA_BYTES, FleetProgram
from fleet.tags import (
    CLOSE,
    DONE,
    HOLDING_BASE,
    NO_SEGMENT,
    PHASE_CODES,
    REOPEN,
    STATE_CODES,
    STRIDE,
    UNKNOWN_COMMAND,
    UNKNOWN_NODE,
    VEHICLE_BASE,
    fleet_tags,
    marker_bytes,
    vehicle_word,
)
from io_drivers.modbus_server import ModbusServer, map_entry

SEGMENT = (6, 7)  # a lane of the model plant the default job drives through every ~30 s


def config() -> FleetConfig:
    """The default job; a wide watchdog: a busy test machine must not fault a scan."""
    cfg = load_config()
    cfg.watchdog = 10.0
    return cfg


def default_job() -> FleetProgram:
    cfg = config()
    cfg.blockades = []  # no scheduled blockade: only the operator closes segments here
    return FleetProgram(cfg)


def read_all(program: FleetProgram, vehicle: int) -> dict[str, object]:
    image = program.rt.image
    return {
        t.name.split(".", 1)[1]: image.read(t.name)
        for t in image.tags
        if t.name.startswith(f"agv{vehicle}.")
    }


def expected(program: FleetProgram, vehicle: int) -> dict[str, object]:
    """A vehicle's words as the program's blocks and records say, read independently."""
    c, s = program.controls[vehicle], program.sequencers[vehicle]
    rec = program.records.inputs(vehicle)
    flags = int(rec["flags"])
    known = bool(flags & 0x03)
    area, local = program.records.vehicles[vehicle]
    output_base = program.records.areas[area].output_base
    command = program.rt.image.read(f"%QB{output_base + 8 * local + 6}")
    return {
        "node": c.current if c.current is not None else NO_NODE,
        "state": STATE_CODES[c.state],
        "battery": int(rec["battery"]),
        "speed": int(rec["speed"]),
        "next": int(rec["next"]) if known else NO_NODE,
        "target": NO_NODE if s.target is None else s.target,
        "recipe": list(program.cfg.recipes).index(s.recipe_name) + 1,
        "step": s.step + 1,
        "phase": PHASE_CODES[s.phase],
        "waits": c.waits,
        "replans": c.replans,
        "rounds": s.rounds_done,
        "waiting_for": c.waiting_for or 0,
        "reported": STATES.index(
            next(r for r in program.vehicle_rows() if r["vehicle"] == vehicle)["reported"]
        ),
        "online": bool(flags & 0x01),
        "stale": bool(flags & 0x02),
        "fault": bool(flags & 0x04),
        "go": bool(command & 0x80),
        "released": command & 0x03,
        "held": vehicle in program.commands.held,
        "suspect": c.suspect,
        "hold": 0,
        "ack": 0,
        "ack_result": 0,
    }


def command(program: FleetProgram, seq: int, code: int, a: int, b: int) -> tuple[int, int]:
    """Write a blockade command as one request (as the Modbus server would), run one scan,
    return (ack, result)."""
    image = program.rt.image
    image.write_many(
        {"fleet.cmd.a": a, "fleet.cmd.b": b, "fleet.cmd.code": code, "fleet.cmd.seq": seq}
    )
    program.rt.step()
    return image.read("fleet.cmd.ack"), image.read("fleet.cmd.result")


def closed(program: FleetProgram, a: int, b: int) -> bool:
    plant = program.cfg.plant
    return bool(program.blockades.blocked[plant.arcs_between(a, b)].all())


# ----- the table -----------------------------------------------------------------------------
def test_layout_fixed_stride_and_access():
    table = fleet_tags([1, 2, 40, 41, 300])
    names = {t.name: t for t in table}
    for v in (1, 2, 40, 41, 300):
        assert names[f"agv{v}.node"].address.text == f"%MW{VEHICLE_BASE + STRIDE * (v - 1)}"
        assert names[f"agv{v}.hold"].address.text == f"%MW{VEHICLE_BASE + STRIDE * (v - 1) + 21}"
        assert (
            names[f"agv{v}.online"].address.text
            == f"%MX{2 * (VEHICLE_BASE + STRIDE * (v - 1) + 14)}.0"
        )
    assert map_entry(names["agv1.node"].address).first == HOLDING_BASE + VEHICLE_BASE
    assert map_entry(names["agv300.hold"].address).first == HOLDING_BASE + 64 + 24 * 299 + 21
    writable = sorted(t.name for t in table.writable())
    assert writable == sorted(
        ["fleet.cmd.seq", "fleet.cmd.code", "fleet.cmd.a", "fleet.cmd.b"]
        + [f"agv{v}.{f}" for v in (1, 2, 40, 41, 300) for f in ("hold", "ack")]
    )
    assert sorted(t.name for t in table if t.retain) == [
        "fleet.total.busy_s",
        "fleet.total.recipes",
        "fleet.total.run_s",
        "fleet.total.starts",
        "fleet.total.station_visits",
    ]
    # one word per field: no two tags share a byte
    spans = sorted(
        (t.address.byte_offset, t.address.byte_offset + t.address.nbytes, t.name) for t in table
    )
    for (_a, end, first), (start, _b, second) in zip(spans, spans[1:], strict=False):
        assert end <= start, (first, second)
    assert marker_bytes([300]) >= 2 * (VEHICLE_BASE + STRIDE * 300)
    assert marker_bytes([4]) == 8192


# ----- status ----------------------------------------------------------------------------------
def test_words_mirror_the_program_state():
    program = default_job()
    try:
        program.rt.start()
        assert read_all(program, 1)["node"] == NO_NODE  # nothing reported before the first scan
        seen_states = set()
        for _ in range(12):
            program.rt.run(duration=10)
            assert program.rt.state == "RUN", program.rt.fault_reason
            for v in program.vehicles:
                assert read_all(program, v) == expected(program, v), v
                seen_states.add(program.controls[v].state)
            image = program.rt.image
            controls = program.controls.values()
            assert image.read("fleet.recipes_completed") == len(program.completed)
            assert image.read("fleet.stations_visited") == sum(
                s.stations_visited for s in program.sequencers.values()
            )
            assert image.read("fleet.waits") == sum(c.waits for c in controls)
            assert image.read("fleet.replans") == sum(c.replans for c in controls)
            assert image.read("fleet.pushes") == program.resolver.pushes
            assert image.read("fleet.deadlocks_detected") == program.resolver.detected
            assert image.read("fleet.vehicles") == 4 and image.read("fleet.online") == 4
            assert image.read("fleet.heartbeat") == program.rt.stats["fleet"].cycles % 65536
            assert image.read("fleet.orders.finished") == 0  # recipe vehicles only
        assert len(program.completed) > 0 and {"driving", "waiting"} <= seen_states
    finally:
        program.close()


def test_vehicles_on_a_second_bus_and_beyond_the_modbus_map_are_mirrored():
    cfg = config()
    cfg.starts = {1: 0, 130: 10}  # 130: the second bus (126 a bus), beyond vehicle 40
    cfg.vehicle_recipes = {1: cfg.vehicle_recipes[1], 130: cfg.vehicle_recipes[2]}
    program = FleetProgram(cfg)
    try:
        program.rt.start()
        program.rt.run(duration=60)
        assert program.rt.state == "RUN", program.rt.fault_reason
        assert program.records.vehicles[130][0] == 1  # its records are in the second area
        for v in (1, 130):
            assert read_all(program, v) == expected(program, v), v
        assert (
            read_all(program, 130)["node"] != NO_NODE and program.sequencers[130].stations_visited
        )
        assert program.rt.image.read("fleet.vehicles") == 2
        assert program.rt.image.read("fleet.online") == 2
    finally:
        program.close()


# ----- the blockade command --------------------------------------------------------------------
def test_blockade_command_closes_and_reopens_a_segment():
    program = default_job()
    try:
        run(program, 20)
        a, b = SEGMENT
        assert command(program, 1, CLOSE, a, b) == (1, DONE)
        assert closed(program, a, b) and program.rt.image.read("fleet.blocked_segments") == 1
        # a vehicle already released into the segment drives on: nodes are never taken back
        committed = set()
        for v, c in program.controls.items():
            path = [c.current, *c.released]
            if any({x, y} == {a, b} for x, y in zip(path, path[1:], strict=False)):
                committed.add(v)
        trace = run(program, 150)  # asserts zero conflicts after every scan
        entered = [(v, x, y) for _t, v, x, y in trace.entered if {x, y} == {a, b}]
        assert all(v in committed for v, _x, _y in entered), entered
        assert len(entered) <= len(committed)
        assert len(program.completed) > 0  # the fleet works around it
        assert command(program, 2, REOPEN, a, b) == (2, DONE)
        assert not closed(program, a, b) and program.rt.image.read("fleet.blocked_segments") == 0
        trace = run(program, 200)
        assert any({x, y} == {a, b} for _t, _v, x, y in trace.entered)  # in use again
    finally:
        program.close()


@pytest.mark.parametrize(
    ("code", "a", "b", "result"),
    [
        (9, 6, 7, UNKNOWN_COMMAND),
        (0, 6, 7, UNKNOWN_COMMAND),
        (CLOSE, 6, 999, UNKNOWN_NODE),
        (REOPEN, 4242, 7, UNKNOWN_NODE),
        (CLOSE, 0, 24, NO_SEGMENT),  # both nodes exist, no segment joins them
        (CLOSE, 0, 1, NO_SEGMENT),  # a return lane: not a routable segment
    ],
)
def test_a_bad_command_is_refused_with_a_result_and_changes_nothing(code, a, b, result):
    program = default_job()
    try:
        program.rt.start()
        program.rt.run(duration=1)
        epoch = program.blockades.epoch
        assert command(program, 7, code, a, b) == (7, result)
        assert program.blockades.epoch == epoch and not program.blockades.blocked.any()
    finally:
        program.close()


def test_a_command_runs_once_per_seq():
    program = default_job()
    try:
        program.rt.start()
        assert program.rt.image.read("fleet.cmd.ack") == 0
        assert command(program, 5, CLOSE, *SEGMENT) == (5, DONE)
        program.blockades.unblock(*SEGMENT)  # reopened by someone else meanwhile
        epoch = program.blockades.epoch
        assert command(program, 5, CLOSE, *SEGMENT) == (5, DONE)  # a retried request
        program.rt.step(10)
        assert program.blockades.epoch == epoch and not closed(program, *SEGMENT)
        assert command(program, 0, CLOSE, *SEGMENT) == (5, DONE)  # seq 0 never runs
        assert not closed(program, *SEGMENT)
    finally:
        program.close()


# ----- hold ------------------------------------------------------------------------------------
def test_hold_keeps_a_vehicle_from_a_new_route_and_release_lets_it_go_on():
    program = default_job()
    try:
        run(program, 20)
        control = program.controls[1]
        program.rt.image.write("agv1.hold", 1)
        program.rt.step()
        assert control.hold and program.rt.image.read("agv1.held") is True
        assert program.rt.image.read("fleet.held") == 1
        granted = {control.current, *control.released}  # what it was released: it drives that
        visits = program.sequencers[1].stations_visited
        trace = run(program, 60)  # zero conflicts, every scan
        assert {y for _t, v, _x, y in trace.entered if v == 1} <= granted
        assert control.current in granted and not control.released
        assert (
            program.sequencers[1].stations_visited <= visits + 1
        )  # at most the node it was sent to
        others = sum(program.sequencers[v].stations_visited for v in (2, 3, 4))
        program.rt.image.write("agv1.hold", 0)
        program.rt.step()
        assert not control.hold and program.rt.image.read("agv1.held") is False
        trace = run(program, 60)
        assert {y for _t, v, _x, y in trace.entered if v == 1} - granted  # it goes on
        assert program.sequencers[1].stations_visited > visits
        assert sum(program.sequencers[v].stations_visited for v in (2, 3, 4)) > others
    finally:
        program.close()


# ----- retain -----------------------------------------------------------------------------------
def test_lifetime_totals_carry_across_runs(tmp_path):
    retain = tmp_path / "fleet.retain"
    first = FleetProgram(config(), retain_file=str(retain))
    first.rt.start()
    first.rt.run(duration=120)
    assert first.rt.state == "RUN", first.rt.fault_reason
    image = first.rt.image
    totals = {t.name: image.read(t.name) for t in image.tags if t.retain}
    first.close()  # stop: the retain file is written
    assert totals["fleet.total.recipes"] == len(first.completed) > 0
    assert totals["fleet.total.station_visits"] == sum(
        s.stations_visited for s in first.sequencers.values()
    )
    assert totals["fleet.total.run_s"] == 120 and totals["fleet.total.starts"] == 1
    assert totals["fleet.total.busy_s"] == pytest.approx(sum(first.chooser.busy_s.values()), abs=1)

    cfg = config()
    del cfg.starts[4]  # another fleet on the same PLC: the totals are the PLC's, they stay
    cfg.vehicle_recipes.pop(4)
    second = FleetProgram(cfg, retain_file=str(retain))
    second.rt.start()
    assert second.rt.start_info.startswith("warm (retain data from")
    image = second.rt.image
    assert image.read("fleet.total.recipes") == totals["fleet.total.recipes"]
    assert image.read("fleet.total.starts") == 2
    second.rt.run(duration=60)
    assert second.rt.state == "RUN", second.rt.fault_reason
    assert image.read("fleet.recipes_completed") == len(second.completed)
    assert image.read("fleet.total.recipes") == totals["fleet.total.recipes"] + len(
        second.completed
    )
    assert image.read("fleet.total.run_s") == 180
    second.close()

    third = FleetProgram(config(), retain_file=str(retain))
    third.rt.start(mode="cold")  # a cold start clears them
    assert third.rt.image.read("fleet.total.recipes") == 0
    assert third.rt.image.read("fleet.total.starts") == 1
    third.close()


# ----- over Modbus -----------------------------------------------------------------------------
def exception_code(response) -> int:
    assert response.isError() and isinstance(response, ExceptionResponse), response
    return response.exception_code


def test_modbus_client_reads_the_fleet_and_writes_only_commands():
    program = default_job()
    server = ModbusServer(port=0)  # the default allow-list: the program's writable tags
    program.rt.add_driver(server)
    program.rt.start()
    client = ModbusTcpClient("127.0.0.1", port=server.port, timeout=2.0, retries=0)
    try:
        assert client.connect()
        program.rt.run(duration=15)
        node, state, battery = client.read_holding_registers(1088, count=3).registers  # agv1
        control = program.controls[1]
        assert (node, state) == (control.current, STATE_CODES[control.state])
        assert battery == int(program.records.inputs(1)["battery"])
        # the blockade command as one FC16 request: seq, code, a, b
        assert not client.write_registers(HOLDING_BASE + 48, [1, CLOSE, *SEGMENT]).isError()
        program.rt.step()
        assert client.read_holding_registers(HOLDING_BASE + 52, count=2).registers == [1, DONE]
        assert closed(program, *SEGMENT)
        assert not client.write_register(1088 + 21, 1).isError()  # agv1.hold
        program.rt.step()
        assert control.hold and program.rt.image.read("agv1.held") is True
        # refused, and nothing of it applied: a status word, the ack, a route command record
        assert exception_code(client.write_register(1088, 3)) == 2  # agv1.node
        assert exception_code(client.write_registers(HOLDING_BASE + 48, [2, REOPEN, 6, 7, 2])) == 2
        qw = (AREA_BYTES + 8 * 2) // 2  # vehicle 2's route command: %QW520..%QW523
        assert exception_code(client.write_registers(qw, [0, 1, 2, 0x0183])) == 2
        assert program.rt.image.pending_writes == 0
        program.rt.step()
        assert closed(program, *SEGMENT) and program.rt.image.read("fleet.cmd.ack") == 1
        assert server.stats()["refused"] == 3
    finally:
        client.close()
        program.close()


# ----- the tags command ------------------------------------------------------------------------
def test_tags_command_prints_the_table_and_json(capsys, tmp_path):
    assert main(["tags", "--json"]) == 0
    rows = {row["name"]: row for row in json.loads(capsys.readouterr().out)}
    assert len(rows) == len(fleet_tags(load_config().starts))
    assert rows["agv1.node"] == {
        "name": "agv1.node",
        "address": "%MW64",
        "type": "UINT",
        "writable": False,
        "retain": False,
        "modbus": {"table": "holding register", "first": 1088, "count": 1, "bits": None},
        "comment": "node last reported (65535: none yet, or one not in the plant: see suspect)",
    }
    assert rows["agv4.hold"]["writable"] and rows["fleet.total.recipes"]["retain"]
    assert rows["fleet.recipes_completed"]["modbus"]["count"] == 2
    assert main(["tags"]) == 0
    out = capsys.readouterr().out
    assert "agv1.node" in out and "HR 1088" in out and "[[recipes]]" in out
    assert main(["tags", str(tmp_path / "missing.toml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "missing.toml" in err


def _doc_rows(heading: str) -> list[list[str]]:
    """The rows of the table under ``heading`` in docs/hmi-map.md, cells stripped of `."""
    text = (Path(__file__).resolve().parent.parent / "docs" / "hmi-map.md").read_text()
    section = text.split(f"## {heading}\n", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in section.splitlines() if line.startswith("| ")]
    return [[c.strip().strip("`") for c in row.strip("|").split(" | ")] for row in rows[1:]]


def test_the_hmi_map_document_lists_every_tag_as_the_program_has_it():
    """docs/hmi-map.md is what an HMI builder wires registers from: every tag of the code is
    in its tables with the same address, register, type and access, and nothing else."""
    tags = {t.name: t for t in fleet_tags([1])}

    def expected(name: str) -> tuple[str, str, str, str]:
        tag = tags[name]
        entry = map_entry(tag.address)
        span = f"{entry.first}..{entry.first + 1}" if entry.count == 2 else f"{entry.first}"
        access = "write" if tag.writable else "read"
        return span, tag.address.text, tag.type.name, access + (", retained" if tag.retain else "")

    documented = {}
    for register, name, address, type_, access, _meaning in _doc_rows("The fleet's words"):
        documented[name] = (register, address, type_, access)
    for offset, register, field, type_, access, _meaning in _doc_rows("A vehicle's words"):
        name = f"agv1.{field}"
        address = tags[name].address.text if name in tags else "?"
        documented[name] = (register, address, type_, access)
        assert offset == f"+{vehicle_word(1, field) - VEHICLE_BASE}", name
    assert documented == {name: expected(name) for name in tags}
