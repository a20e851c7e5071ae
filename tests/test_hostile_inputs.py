"""Hostile inputs an independent tester found: a block that tries to end the process, plant
and scenario files with values that read as something else, files too large to hold, and a
retain file one byte too long."""

from __future__ import annotations

import gc
import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plc_runtime import FunctionBlock, Runtime, StartupError, StateError, Static, VirtualClock
from topology import Edge, Node, Plant, TopologyError, load, load_scenarios
from topology.formats.movingai import load_map
from topology.grid import grid_plant
from topology.limits import MAX_EDGES, MAX_FILE_BYTES, MAX_NODES

EXAMPLE_JOB = str(Path(__file__).resolve().parent.parent / "examples" / "default.toml")

ROOT = Path(__file__).resolve().parent.parent


# ----- a block that raises SystemExit or KeyboardInterrupt ---------------------------------


class Lamp(FunctionBlock):
    """Switches the outputs on every scan; raises ``exc`` in scan ``at`` (or in startup)."""

    def __init__(self, exc: BaseException, at: int | None) -> None:
        super().__init__()
        self.exc, self.at = exc, at

    def startup(self, ctx) -> None:
        if self.at is None:
            raise self.exc

    def cycle(self, ctx) -> None:
        ctx.image.write("%QX0.0", True)
        ctx.image.write("%QW2", 7)
        if ctx.cycle == self.at:
            raise self.exc


def lamp_runtime(exc: BaseException, at: int | None) -> Runtime:
    rt = Runtime(cycle_time=0.01, clock=VirtualClock(), safe_outputs={"%QX0.1": True})
    rt.add_task("main", [FunctionBlock(), Lamp(exc, at)])
    return rt


def assert_faulted_safely(rt: Runtime, reason: str) -> None:
    assert rt.state == "FAULT" and rt.fault_reason == reason
    assert rt.fault_traceback.startswith("Traceback")
    assert rt.image.read("%QX0.0") is False and rt.image.read("%QW2") == 0  # outputs off...
    assert rt.image.read("%QX0.1") is True  # ...except the declared safe value
    with pytest.raises(StateError, match="in state FAULT"):
        rt.step()
    rt.stop()
    assert rt.state == "STOP"


def test_a_block_calling_sys_exit_faults_the_runtime_instead_of_ending_it():
    rt = lamp_runtime(SystemExit(3), at=2)
    rt.start()
    assert rt.step(5) == 3  # the third scan raised: no further scans
    assert_faulted_safely(rt, "task main: block 1:Lamp raised SystemExit: 3")


def test_a_block_raising_keyboard_interrupt_faults_then_passes_it_on():
    rt = lamp_runtime(KeyboardInterrupt(), at=2)
    rt.start()
    rt.step(2)
    assert rt.image.read("%QX0.0") is True and rt.image.read("%QW2") == 7
    with pytest.raises(KeyboardInterrupt):  # the caller's Ctrl-C handling still runs...
        rt.step(5)
    assert_faulted_safely(rt, "task main: block 1:Lamp raised KeyboardInterrupt")  # ...safely


def test_keyboard_interrupt_ends_run_in_fault():
    rt = lamp_runtime(KeyboardInterrupt(), at=4)
    rt.start()
    with pytest.raises(KeyboardInterrupt):
        rt.run(cycles=100)
    assert rt.ticks == 5
    assert_faulted_safely(rt, "task main: block 1:Lamp raised KeyboardInterrupt")


def test_ctrl_c_between_two_blocks_still_faults_the_cut_scan(monkeypatch):
    rt = lamp_runtime(SystemExit(0), at=99)
    rt.start()
    rt.step(2)

    def interrupted() -> None:  # the runtime's own copy-out, where a Ctrl-C may land too
        raise KeyboardInterrupt

    monkeypatch.setattr(rt.image, "copy_out", interrupted)
    with pytest.raises(KeyboardInterrupt):
        rt.step()
    monkeypatch.undo()
    assert rt.state == "FAULT" and rt.fault_reason == "scan 2 was interrupted (KeyboardInterrupt)"
    assert rt.image.read("%QX0.0") is False and rt.image.read("%QX0.1") is True
    rt.stop()


@pytest.mark.parametrize(
    "exc,reason",
    [
        (SystemExit("bye"), "startup of main/1:Lamp raised SystemExit: bye"),
        (GeneratorExit(), "startup of main/1:Lamp raised GeneratorExit"),
    ],
)
def test_startup_raising_a_base_exception_is_a_startup_error(exc, reason):
    rt = lamp_runtime(exc, at=None)
    with pytest.raises(StartupError, match=re.escape(reason)):
        rt.start()
    assert rt.state == "FAULT" and rt.fault_reason == reason
    assert rt.image.read("%QX0.1") is True
    rt.stop()


class ExitingDriver:
    """An I/O driver whose input read calls sys.exit() in the second tick."""

    name = "bus"

    def __init__(self) -> None:
        self.reads = 0

    def open(self, image) -> None: ...

    def read_inputs(self, image, now_ns: int) -> None:
        self.reads += 1
        if self.reads == 2:
            raise SystemExit(1)

    def write_outputs(self, image, now_ns: int) -> None: ...

    def close(self) -> None: ...

    def stats(self) -> dict[str, object]:
        return {}


def test_a_driver_calling_sys_exit_faults_the_runtime():
    rt = lamp_runtime(SystemExit(0), at=99)
    rt.add_driver(ExitingDriver())
    rt.start()
    assert rt.step(3) == 2
    assert_faulted_safely(rt, "driver bus: read_inputs raised SystemExit: 1")


# The operator's second Ctrl-C arrives as a KeyboardInterrupt in whatever block runs. A block
# that hangs in its first scan (until Ctrl-C) makes that deterministic: it says when the first
# Ctrl-C has been handled (the CLI then re-installs the default handler), and the test sends
# the second one only then.
HANGING_PROGRAM = """
import json, signal, sys, time
from plc_runtime import FunctionBlock, Runtime
from plc_runtime.cli import add_run_options, run_program
import argparse

class Hang(FunctionBlock):
    def cycle(self, ctx):
        ctx.image.write("%QX0.0", True)
        print("in scan", file=sys.stderr, flush=True)
        while signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
            time.sleep(0.005)  # the first Ctrl-C only asks for a stop after this scan
        print("stop requested", file=sys.stderr, flush=True)
        while True:
            time.sleep(0.005)

built = []

def build(clock, cycle_time, watchdog, retain_file):
    rt = Runtime(cycle_time, clock, watchdog=6000.0)  # the hang is on purpose
    rt.add_task("main", [Hang()])
    built.append(rt)
    return rt

parser = argparse.ArgumentParser()
add_run_options(parser)
code = run_program(parser.parse_args(["--json"]), "hang", build)
rt = built[0]
print(json.dumps({"state": rt.state, "fault_reason": rt.fault_reason,
                  "lamp": rt.image.read("%QX0.0")}))
sys.exit(code)
"""


def test_second_ctrl_c_in_a_block_faults_safely_and_the_cli_still_exits_130(tmp_path):
    script = tmp_path / "hang.py"
    script.write_text(textwrap.dedent(HANGING_PROGRAM))
    proc = subprocess.Popen(
        [sys.executable, str(script)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stderr.readline().strip() == "in scan"
        proc.send_signal(subprocess.signal.SIGINT)
        assert proc.stderr.readline().strip() == "stop requested"
        proc.send_signal(subprocess.signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == 130, err
    assert "interrupted in cycle 1; runtime stopped" in err and "Traceback" not in err
    assert json.loads(out) == {
        "state": "STOP",
        "fault_reason": "task main: block 0:Hang raised KeyboardInterrupt",
        "lamp": False,
    }


# ----- .scen files ------------------------------------------------------------------------


def scen(tmp_path: Path, *rows: str) -> Path:
    path = tmp_path / "bad.scen"
    path.write_text("version 1\n" + "".join(row + "\n" for row in rows))
    return path


GOOD = "0\tm.map\t32\t32\t1\t2\t3\t4\t5.5"


def test_scenarios_from_a_string_path(tmp_path):
    path = scen(tmp_path, GOOD, "", GOOD.replace("\t1\t2\t", "\t31\t31\t"))
    scenarios = load_scenarios(str(path))
    assert [(s.start, s.goal, s.optimal_octile) for s in scenarios] == [
        (2 * 32 + 1, 4 * 32 + 3, 5.5),
        (31 * 32 + 31, 4 * 32 + 3, 5.5),
    ]


@pytest.mark.parametrize(
    "row,message",
    [
        (
            "0\tm.map\t32\t32\t40\t2\t3\t4\t5",
            r"start x must be an integer 0\.\.31 \(the map width is 32\), got '40'",
        ),
        ("0\tm.map\t32\t32\t-1\t2\t3\t4\t5", "start x must be an integer 0..31.*got '-1'"),
        (
            "0\tm.map\t32\t16\t1\t2\t3\t16\t5",
            r"goal y must be an integer 0\.\.15 \(the map height is 16\), got '16'",
        ),
        ("0\tm.map\t32\t32\t1\t2\t٣\t4\t5", "goal x must be an integer 0..31.*got '٣'"),
        (
            "0\tm.map\t32\t32\t1\t2\t3\t4\tnan",
            "optimal length must be a finite number >= 0, got 'nan'",
        ),
        (
            "0\tm.map\t32\t32\t1\t2\t3\t4\tinf",
            "optimal length must be a finite number >= 0, got 'inf'",
        ),
        ("0\tm.map\t32\t32\t1\t2\t3\t4\t1e999", "optimal length must be a finite number >= 0"),
        (
            "0\tm.map\t32\t32\t1\t2\t3\t4\t-2.5",
            "optimal length must be a finite number >= 0, got '-2.5'",
        ),
        ("0\tm.map\t0\t32\t1\t2\t3\t4\t5", "width must be an integer >= 1, got '0'"),
        ("x\tm.map\t32\t32\t1\t2\t3\t4\t5", "bucket must be an integer >= 0, got 'x'"),
        ("0\t\t32\t32\t1\t2\t3\t4\t5", "map: the map file name is empty"),
        ("0\tm.map\t32\t32\t1\t2\t3\t4", "expected 9 tab-separated fields .* got 8"),
    ],
)
def test_scenario_values_outside_the_format_name_file_line_and_field(tmp_path, row, message):
    path = scen(tmp_path, GOOD, row)
    with pytest.raises(TopologyError, match=message) as err:
        load_scenarios(path)
    assert str(err.value).startswith(f"{path}: line 3: ")


# ----- size limits ------------------------------------------------------------------------


def movingai(width: int, height: int, row: str | None = None) -> str:
    return (
        f"type octile\nheight {height}\nwidth {width}\nmap\n"
        + ((row or "." * width) + "\n") * height
    )


def test_a_map_with_more_cells_than_a_plant_may_have_nodes_is_refused(tmp_path):
    path = tmp_path / "huge.map"
    path.write_text(movingai(1200, 1200))  # 1.4 MB: under the file limit, over the node limit
    assert path.stat().st_size < MAX_FILE_BYTES
    with pytest.raises(TopologyError) as err:
        load(path)
    assert str(err.value) == (
        f"{path}: 1,440,000 nodes: a plant may have at most {MAX_NODES:,} nodes "
        "(docs/plant-format.md, Size limits)"
    )


def test_the_same_map_size_with_enough_obstacles_loads(tmp_path):
    path = tmp_path / "sparse.map"
    path.write_text(movingai(1200, 100, "." * 600 + "@" * 600))
    plant = load(path)
    assert plant.n == 60_000 and plant.node(599).x == 599.0 and 600 not in plant.index


@pytest.mark.parametrize("suffix", [".toml", ".json", ".map", ".nodes", ".scen"])
def test_files_over_the_size_limit_are_refused_unread(tmp_path, suffix):
    path = tmp_path / f"big{suffix}"
    with open(path, "wb") as fh:
        fh.truncate(MAX_FILE_BYTES + 1)  # sparse: nothing to write, zeros to read
    reader = load_scenarios if suffix == ".scen" else load
    with pytest.raises(TopologyError) as err:
        reader(path)
    assert str(err.value) == (
        f"{path}: larger than {MAX_FILE_BYTES:,} bytes, the limit for plant files "
        "(docs/plant-format.md, Size limits)"
    )


def test_a_file_at_the_size_limit_is_read(tmp_path):
    path = tmp_path / "padded.nodes"
    record = "0 -1 0 -1 0 -1 0 -1 0 role=exit\n"
    path.write_text(record + "#" * (MAX_FILE_BYTES - len(record) - 1) + "\n")
    assert path.stat().st_size == MAX_FILE_BYTES
    assert load(path).n == 1


def test_plants_built_in_code_have_the_same_limits():
    with pytest.raises(
        TopologyError, match=f"1,049,600 nodes: a plant may have at most {MAX_NODES:,}"
    ):
        grid_plant(np.ones((1025, 1024), dtype=bool))
    too_many = [Edge(0, 1, 1.0)] * (MAX_EDGES + 1)  # one object, many times: cheap to hold
    with pytest.raises(TopologyError, match=f"{MAX_EDGES + 1:,} edges: a plant may have at most"):
        Plant.build([Node(0), Node(1)], too_many)
    with pytest.raises(TopologyError, match="a grid needs a 2-D boolean array, got 1-D bool"):
        grid_plant(np.ones(5, dtype=bool))
    with pytest.raises(TopologyError, match="a grid needs a 2-D boolean array, got 2-D int64"):
        grid_plant(np.ones((2, 2), dtype=np.int64))


def test_grid_order_positions_and_roles_are_those_of_the_cells():
    passable = np.array([[1, 1, 0], [1, 1, 1]], dtype=bool)
    plant = grid_plant(passable, 2.0, roles={4: ("station", (5,)), 5: ("charger", ())})
    for cell, says in (
        (2, "cell 2 (row 0, column 2) is blocked"),
        (6, "cell 6 is outside the 2 x 3 grid"),
    ):
        with pytest.raises(TopologyError, match=rf"roles: {re.escape(says)}.* a charger"):
            grid_plant(passable, 2.0, roles={cell: ("charger", ())})
    assert [n.id for n in plant.nodes] == [0, 1, 3, 4, 5]
    assert [(n.x, n.y) for n in plant.nodes] == [(0, 0), (2, 0), (0, 2), (2, 2), (4, 2)]
    assert plant.node(4).role == "station" and plant.node(4).functions == (5,)
    assert [(e.source, e.target, e.port_source, e.port_target) for e in plant.edges] == [
        (0, 1, "E", "W"),
        (3, 4, "E", "W"),
        (4, 5, "E", "W"),
        (0, 3, "S", "N"),
        (1, 4, "S", "N"),
    ]
    assert {e.length for e in plant.edges} == {2.0}


def test_building_a_grid_leaves_the_garbage_collector_as_it_was():
    assert gc.isenabled()
    grid_plant(np.ones((3, 3), dtype=bool))
    assert gc.isenabled()
    gc.disable()  # as the runtime's real-time mode has it while running
    try:
        grid_plant(np.ones((3, 3), dtype=bool))
        assert not gc.isenabled()
        with pytest.raises(TopologyError):
            grid_plant(np.zeros((3, 3), dtype=bool))  # no nodes: fails inside the pause
        assert not gc.isenabled()
    finally:
        gc.enable()
    with pytest.raises(TopologyError, match="the plant has no nodes"):
        grid_plant(np.zeros((3, 3), dtype=bool))
    assert gc.isenabled()


# Validation checks every node and edge at once (array masks); the error must still be the
# one a loop would raise: the first bad item, with the first rule it breaks.
NODE_DEFECTS = {
    "id": (lambda n: Node(-5, x=n.x), r"nodes\[{i}\]: node id must be an integer"),
    "duplicate": (lambda n: Node(0), r"nodes\[{i}\] \(id 0\): duplicate node id 0"),
    "role": (lambda n: Node(n.id, role="dock"), r"nodes\[{i}\] \(id \d+\): unknown role 'dock'"),
    "y": (lambda n: Node(n.id, y=float("nan")), r"nodes\[{i}\] \(id \d+\): y must be a finite"),
}


@settings(max_examples=80, deadline=None)
@given(
    st.integers(2, 40), st.dictionaries(st.integers(1, 39), st.sampled_from(sorted(NODE_DEFECTS)))
)
def test_the_first_bad_node_is_reported(n, defects):
    nodes = [Node(i, x=float(i)) for i in range(n)]
    defects = {at: kind for at, kind in defects.items() if at < n}
    for at, kind in defects.items():
        nodes[at] = NODE_DEFECTS[kind][0](nodes[at])
    if not defects:
        assert Plant.build(nodes, []).n == n
        return
    at = min(defects)
    with pytest.raises(TopologyError, match=NODE_DEFECTS[defects[at]][1].format(i=at)):
        Plant.build(nodes, [])


@settings(max_examples=80, deadline=None)
@given(
    st.lists(st.tuples(st.integers(0, 5), st.integers(0, 5), st.sampled_from("NESW")), max_size=12)
)
def test_a_port_used_twice_names_the_first_edge_that_used_it(segments):
    edges = [Edge(a, b, 1.0, port_source=p) for a, b, p in segments if a != b]
    owner: dict[tuple[int, str], int] = {}
    expected = None
    for i, e in enumerate(edges):
        if (e.source, e.port_source) in owner:
            expected = (i, owner[(e.source, e.port_source)], e)
            break
        owner[(e.source, e.port_source)] = i
    nodes = [Node(i) for i in range(6)]
    if expected is None:
        assert len(Plant.build(nodes, edges).edges) == len(edges)
        return
    i, j, e = expected
    message = (
        f"edges[{i}] ({e.source} -> {e.target}): port {e.port_source} of node {e.source} "
        f"is already used by edges[{j}]"
    )
    with pytest.raises(TopologyError, match=re.escape(message)):
        Plant.build(nodes, edges)


# ----- .nodes: digits of other scripts, options given twice ----------------------------------


@pytest.mark.parametrize(
    "record,message",
    [
        ("٣ -1 0 -1 0 -1 0 -1 0", "node id is '٣'"),
        ("0 -1 0 ３ 1.0 -1 0 -1 0", "E neighbour is '３'"),
        ("0 -1 0 -1 ١.٥ -1 0 -1 0", "E distance is '١.٥'"),
        ("0 -1 0 -1 0 -1 0 -1 0 x=٣", r"x must be a finite number \(ASCII digits\), got '٣'"),
        ("0 -1 0 -1 0 -1 0 -1 0 role=exit functions=1+٢", "functions must be integers >= 0"),
        (
            "0 -1 0 -1 0 -1 0 -1 0 role=exit role=station",
            r"option role given twice \(role='exit' and role='station'\)",
        ),
        ("0 -1 0 -1 0 -1 0 -1 0 x=1 x=2", r"option x given twice \(x='1' and x='2'\)"),
        ("0 -1 0 -1 0 -1 0 -1 0 1_0=2", "unknown option '1_0'"),
        ("1_0 -1 0 -1 0 -1 0 -1 0", "node id is '1_0'"),
        ("0 -1 0 1 nan -1 0 -1 0", "E distance is 'nan'"),
        ("0 -1 0 1 -2 -1 0 -1 0", "E distance must be >= 0, got -2"),
    ],
)
def test_node_list_refuses_foreign_digits_and_repeated_options(tmp_path, record, message):
    path = tmp_path / "bad.nodes"
    path.write_text("# id N d E d S d W d\n1 -1 0 -1 0 -1 0 -1 0 role=entry\n" + record + "\n")
    with pytest.raises(TopologyError, match=message) as err:
        load(path)
    assert str(err.value).startswith(f"{path}: line 3: ")


def test_map_header_refuses_foreign_digits_and_repeated_keys(tmp_path):
    path = tmp_path / "bad.map"
    path.write_text("type octile\nheight ٢\nwidth 2\nmap\n..\n..\n")
    with pytest.raises(TopologyError, match="line 2: header needs integer 'height' and 'width'"):
        load_map(str(path))
    path.write_text("type octile\nheight 2\nwidth 2\nheight 3\nmap\n..\n..\n")
    with pytest.raises(TopologyError, match=r"line 4: 'height' given twice \(first on line 2\)"):
        load(path)
    path.write_text("type octile\nheight 2\nmap\n..\n..\n")
    with pytest.raises(TopologyError, match="line 3: header needs .*: no width line before 'map'"):
        load(path)


@pytest.mark.parametrize("cell_size", [0, -1.0, float("nan"), float("inf"), True, "1", 1e308])
def test_map_cell_size_must_be_a_finite_positive_number(tmp_path, cell_size):
    path = tmp_path / "ok.map"
    path.write_text(movingai(2, 2))
    with pytest.raises(TopologyError, match="cell size must be a number > 0 and at most 1000 m"):
        load(path, cell_size=cell_size)


def test_the_cli_names_a_cell_size_too_large(tmp_path, capsys):
    from fleet.cli import main

    path = tmp_path / "ok.map"
    path.write_text(movingai(2, 2))
    with pytest.raises(SystemExit) as stop:
        main(["route", str(path), "--from", "0", "--to", "1", "--cell-size", "1e308"])
    assert stop.value.code == 2
    assert "--cell-size: must be at most 1000: '1e308'" in capsys.readouterr().err


# ----- a retain file of the wrong length, and what happens to a file that is not used ------


class Odometer(FunctionBlock):
    """Counts scans into a retentive variable."""

    scans = Static(0, retain=True)

    def cycle(self, ctx) -> None:
        self.scans += 1


def odometer(path: Path, name: str = "main") -> tuple[Runtime, Odometer]:
    rt = Runtime(cycle_time=0.01, clock=VirtualClock(), retain_file=path)
    block = Odometer()
    rt.add_task(name, [block])
    return rt, block


def run_and_stop(path: Path, steps: int, name: str = "main") -> Odometer:
    rt, block = odometer(path, name)
    rt.start()
    rt.step(steps)
    rt.stop()
    return block


def test_a_retain_file_one_byte_too_long_is_not_called_truncated_and_is_kept(tmp_path):
    path = tmp_path / "plc.retain"
    run_and_stop(path, 7)
    good = path.read_bytes()
    body = len(good.partition(b"\n")[2])
    path.write_bytes(good + b"x")
    rt, block = odometer(path)
    message = f"wrong length: 1 trailing byte(s) after the {body}-byte body the header declares"
    with pytest.warns(RuntimeWarning, match=re.escape(message)) as caught:
        rt.start()
    assert "truncated" not in str(caught[0].message)
    assert rt.start_info == f"cold: {path}: {message}; the file was kept as {path}.rejected"
    assert block.scans == 0
    rt.step(2)
    rt.stop()  # saves the new values: the old ones are beside them
    assert (tmp_path / "plc.retain.rejected").read_bytes() == good + b"x"
    assert run_and_stop(path, 0).scans == 2
    # what was stored comes back once the file is repaired
    os.replace(tmp_path / "plc.retain.rejected", path)
    path.write_bytes(path.read_bytes()[:-1])
    assert run_and_stop(path, 0).scans == 7


def test_every_rejected_file_is_kept(tmp_path):
    path = tmp_path / "plc.retain"
    run_and_stop(path, 3, name="old")
    first = path.read_bytes()
    with pytest.warns(RuntimeWarning, match="different program layout"):
        run_and_stop(path, 4, name="new")  # another program: cold start, old file set aside
    second = path.read_bytes()
    with pytest.warns(RuntimeWarning, match=f"kept as {re.escape(str(path))}.rejected.1"):
        assert run_and_stop(path, 0, name="old").scans == 0
    assert (tmp_path / "plc.retain.rejected").read_bytes() == first
    assert (tmp_path / "plc.retain.rejected.1").read_bytes() == second


def test_a_rejected_file_that_cannot_be_moved_is_not_overwritten(tmp_path, monkeypatch):
    path = tmp_path / "plc.retain"
    run_and_stop(path, 5, name="old")
    stored = path.read_bytes()

    def refuse(src, dst):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(os, "rename", refuse)
    rt, block = odometer(path, name="new")
    with pytest.warns(RuntimeWarning, match="cannot be moved aside \\(Permission denied\\)"):
        rt.start()
    rt.step(3)
    with pytest.warns(RuntimeWarning, match="retain file not saved: .* it is not overwritten"):
        rt.stop()
    assert path.read_bytes() == stored and rt.retain_error
    monkeypatch.undo()  # the rename works again: the next save sets the file aside first
    rt.start()  # warm, from memory
    assert block.scans == 3
    rt.stop()
    assert rt.retain_error is None
    assert (tmp_path / "plc.retain.rejected").read_bytes() == stored
    assert run_and_stop(path, 0, name="new").scans == 3


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (
            "[stations]",
            '[stations.clusters]\n"²" = [15]\n[stations]',
            r"stations\.clusters\.²: function ids",
        ),
        (
            "[stations]",
            "[stations.clusters]\n2 = [15, 22, 15]\n[stations]",
            r"stations\.clusters\.2: node 15 is listed twice",
        ),
        (
            "[stations]",
            '[stations.clusters]\n2 = [15]\n"02" = [22]\n[stations]',
            r"stations\.clusters\.02: function 2 again \(given as '2'\)",
        ),
        (
            "[bus]",
            '[web]\naddress = "[::1"\n[bus]',
            r"web\.address: expected HOST:PORT, e\.g\. 127\.0\.0\.1:8080, got '\[::1'",
        ),
        (
            "id = 1\n",
            "",
            r"vehicles\[0\]\.id: missing",
        ),
        (
            "start = 0",
            "start = 0\nrecipes = []",
            r"vehicles\[0\]\.recipes: must be a non-empty list",
        ),
        (
            "start = 0",
            'start = 0\nrecipes = [["a"]]',
            r"vehicles\[0\]\.recipes: must be a non-empty list",
        ),
        (
            "[bus]",
            "[[faults.vehicles]]\nid = 2\nspoof_rate = 0.1\n"
            "[[faults.vehicles]]\nid = 2\ndead_after_s = 5\n[bus]",
            r"faults\.vehicles\[1\]\.id: vehicle 2 is already given in faults\.vehicles\[0\]",
        ),
        (
            'channel = "agv"',
            'channel = "agv"\nstatus_period_s = 1.0\nstale_after_s = 0.5',
            r"bus\.status_period_s: status_period_s = 1 s must be less than stale_after_s = 0\.5 s",
        ),
        (
            'channel = "agv"',
            'channel = "agv"\nstale_after_s = 0.1',
            r"bus\.stale_after_s: status_period_s = 0\.1 s \(the default\) must be less than "
            r"stale_after_s = 0\.1 s: every vehicle would turn stale",
        ),
        (
            'name = "drill-mill-paint"',
            'name = "drill\\u001b[2J"',
            r"recipes\[0\]\.name: 'drill\\x1b\[2J': character 6 \(U\+001B\) is a control",
        ),
        (
            "[bus]",
            "[time_windows]\nwait_free_s = 40\n[bus]",
            r"time_windows\.wait_free_s: wait_free_s = 40 s must not exceed wait_occupied_s = 30 s "
            r"\(the default\)",
        ),
        (
            "[bus]",
            "[routing.extra]\nvalue = " + "9" * 5000 + "\n[bus]",
            r"^d\.toml: unreadable TOML: a number with too many digits$",
        ),
        (
            "[bus]",
            '[web]\naddress = "127.0.0.1:' + "8" * 5000 + '"\n[bus]',
            r"web\.address: expected HOST:PORT, e\.g\. 127\.0\.0\.1:8080, got '127\.0\.0\.1:888",
        ),
    ],
    ids=[
        "superscript-function-id",
        "cluster-station-twice",
        "cluster-function-spelt-twice",
        "web-address-unclosed-bracket",
        "vehicle-without-id",
        "no-recipes",
        "nested-recipes",
        "faults-vehicle-twice",
        "status-slower-than-stale",
        "stale-sooner-than-default-status",
        "escape-in-recipe-name",
        "wait-thresholds-backwards",
        "integer-of-5000-digits",
        "port-of-5000-digits",
    ],
)
def test_configuration_values_that_once_raised_tracebacks_are_located_errors(old, new, message):
    """Digits that str.isdigit() takes but int() does not, and recipe lists that are not
    lists of names: a ConfigError naming the key, not a ValueError or TypeError."""
    from fleet.config import DEFAULT_CONFIG, parse_config
    from plc_runtime.errors import ConfigError

    text = DEFAULT_CONFIG.read_text()
    assert old in text
    with pytest.raises(ConfigError, match=message):
        parse_config(text.replace(old, new, 1), "d.toml")


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["run", "--speed", "1e-300"], "--speed: must be a finite number >= 0.001"),
        (["run", "--duration", "1e300"], "--duration: must be at most 1e+07"),
        (["run", "--cycles", "100000000000"], "--cycles: must be at most 1e+10"),
        (["vehicles", "--plant", "model-plant", "--period", "5"], "--period: must be at most 1"),
        (["vehicles", "--plant", "model-plant", "--duration", "1e9"], "must be at most 1e+07"),
        (["vehicles", "--plant", "model-plant", "--seed", "-1"], "--seed: must be a whole number"),
        (["run", "--program", "demo", "--watchdog", "7e6"], "--watchdog: must be at most 6e+06"),
        (["route", "model-plant", "--from", "0", "--to", "5", "--budget", "1.5"], "whole number"),
        (
            ["route", "model-plant", "--from", "0", "--to", "5", "--budget", "1e9"],
            "--budget: not a whole number: '1e9' (write it as digits: 1000000000)",
        ),
        (
            ["vehicles", "--plant", "model-plant", "--seed", "1e3"],
            "--seed: must be a whole number >= 0: '1e3' (write it as digits: 1000)",
        ),
    ],
    ids=[
        "speed",
        "duration",
        "cycles",
        "vehicles-period",
        "vehicles-duration",
        "vehicles-seed",
        "watchdog-ms",
        "budget",
        "budget-as-float",
        "seed-as-float",
    ],
)
def test_command_line_numbers_beyond_sense_are_refused(args, message, capsys):
    """A pace at which no cycle ends (it overflowed the sleep), a run of centuries, a
    simulation step in which vehicles jump segments: refused before anything starts."""
    from fleet.cli import main

    with pytest.raises(SystemExit) as stop:
        main(args)
    err = capsys.readouterr().err
    assert stop.value.code == 2 and message in err and err.count("\n") == 1


def test_usage_errors_are_one_line_with_what_was_typed_escaped(capsys):
    """argparse prints the whole usage before its error; the command line's other errors are
    one line, and so are these, with an escape sequence typed (or pasted) shown, not run."""
    from fleet.cli import main

    with pytest.raises(SystemExit) as stop:
        main(["run", "fleet.toml", "\x1b[2J"])
    err = capsys.readouterr().err
    assert stop.value.code == 2
    assert err == (
        "plc-runtime: error: unrecognized arguments: \\x1b[2J (see plc-runtime --help)\n"
    )


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--plant", "model-plant"], "no link: give the bus the controller uses"),
        (["--plant", "model-plant", "--bus", "virtual:agv"], "--bus virtual:agv: the virtual bus"),
        (["--config", EXAMPLE_JOB], "default.toml: bus virtual:agv: the virtual bus"),
        (
            ["--config", EXAMPLE_JOB, "--count", "2", "--bus", "socketcan:vcan0"],
            "--count applies with --plant: a configuration names its vehicles",
        ),
        (
            ["--plant", "model-plant", "--bus", "modbus:10.0.0.1:5100"],
            "--bus modbus:10.0.0.1:5100: simulated vehicles serve Modbus on 127.0.0.1 only",
        ),
    ],
    ids=["no-link", "virtual", "config-virtual", "config-count", "modbus-elsewhere"],
)
def test_simulated_vehicles_no_controller_could_reach_are_refused(args, message, capsys):
    """The virtual bus lives inside one process: vehicles started on it alone would run,
    say they are ready and never hear from anyone. A --count the configuration would
    override is refused rather than ignored."""
    from fleet.cli import main

    assert main(["vehicles", *args, "--duration", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and "ready" not in err


@pytest.mark.parametrize(
    ("where", "plant", "message"),
    [
        ("missing/m.json", "model-plant", "no folder 'missing'"),
        (".", "model-plant", "a folder, not a file"),
        ("pipe", "model-plant", "a named pipe, not a file"),
        ("plant.toml", "plant.toml", "that is the plant file"),
        ("./sub/../c.toml", None, "that is the configuration file"),
    ],
)
def test_a_monitor_report_that_cannot_be_written_is_refused_before_the_run(
    where, plant, message, tmp_path, monkeypatch, capsys
):
    """The vehicles' monitor writes its report at exit: a run of hours must not learn only
    then that its folder is missing (or that the name is a folder), a named pipe would
    block the exit for ever, and the report must not replace the files the vehicles run
    on."""
    from fleet.cli import main
    from fleet.config import DEFAULT_CONFIG

    monkeypatch.chdir(tmp_path)
    os.mkfifo("pipe")
    (tmp_path / "sub").mkdir()
    (tmp_path / "plant.toml").write_bytes(
        (Path(__file__).parent.parent / "examples" / "plants" / "workshop.toml").read_bytes()
    )
    (tmp_path / "c.toml").write_text(DEFAULT_CONFIG.read_text())
    kept = {p.name: p.read_bytes() for p in tmp_path.glob("*.toml")}
    source = (
        ["--plant", plant]
        if plant
        else ["--config", "c.toml", "--bus", "udp_multicast:239.74.163.2"]
    )
    args = ["vehicles", *source, "--duration", "60", "--monitor-out", where]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"--monitor-out {where}: {message}" in err
    assert "vehicles ready" not in err  # refused before any vehicle started
    assert {p.name: p.read_bytes() for p in tmp_path.glob("*.toml")} == kept


def test_a_monitor_report_that_fails_to_be_written_names_the_option(tmp_path, monkeypatch, capsys):
    """A full disk at exit: one line naming the option and the file, no traceback."""
    from ports import free_base_port

    from fleet.cli import main
    from fleet.commands import vehicles

    def disk_full(*_args, **_kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(vehicles.json, "dump", disk_full)
    report = tmp_path / "m.json"
    args = ["vehicles", "--plant", "model-plant", "--modbus-base-port", str(free_base_port(4))]
    assert main([*args, "--duration", "0.2", "--monitor-out", str(report)]) == 2
    err = capsys.readouterr().err.splitlines()[-1]
    assert (
        err == f"plc-runtime: error: --monitor-out {report}: cannot write: No space left on device"
    )


_PLANT_WITH_ID = """name = "big ids"
[functions]
0 = "entry"
1 = "exit"
[[nodes]]
id = 7000
x = 0.0
y = 0.0
role = "entry"
functions = [0]
[[nodes]]
id = {node}
x = 1.0
y = 0.0
[[nodes]]
id = 3
x = 2.0
y = 0.0
role = "exit"
functions = [1]
[[edges]]
from = 7000
to = {node}
length = 1.0
[[edges]]
from = {node}
to = 3
length = 1.0
"""


@pytest.mark.parametrize("node", [65535, 70000])
def test_a_plant_whose_node_ids_the_vehicle_link_cannot_carry_is_refused(node, tmp_path, capsys):
    """Node ids on the link are 16 bits and 65535 means "no node": a vehicle on node 65535
    reported none (and was taken for lost), one on 70000 could not report at all. Refused
    when the plant is loaded, by the controller's configuration and the vehicles' process."""
    from fleet.cli import main
    from fleet.config import DEFAULT_CONFIG, parse_config
    from plc_runtime.errors import ConfigError

    plant = tmp_path / "big.toml"
    plant.write_text(_PLANT_WITH_ID.format(node=node))
    text = DEFAULT_CONFIG.read_text()
    start = text.index("[plant]")
    end = text.index("\n[", start + 1)
    config = text[:start] + '[plant]\nfile = "big.toml"\n' + text[end:]
    with pytest.raises(
        ConfigError,
        match=f"plant.file: .*big.toml: node {node}: the vehicle link names nodes 0..65534",
    ):
        parse_config(config, "c.toml", tmp_path)
    assert main(["vehicles", "--plant", str(plant), "--duration", "1"]) == 2
    err = capsys.readouterr().err
    assert (
        err
        == f"plc-runtime: error: {plant}: node {node}: the vehicle link names nodes 0..65534 (16 bits, 65535 means no node); number the plant's nodes within it\n"
    )


def test_the_retain_file_may_not_be_the_configuration(tmp_path, capsys):
    """It would be moved aside at start as retain data it cannot read."""
    from fleet.cli import main
    from fleet.config import DEFAULT_CONFIG

    config = tmp_path / "fleet.toml"
    config.write_text(DEFAULT_CONFIG.read_text())
    alias = tmp_path / "sub" / ".." / "fleet.toml"
    (tmp_path / "sub").mkdir()
    assert main(["run", str(config), "--retain", str(alias), "--cycles", "2"]) == 2
    assert "that is the configuration file" in capsys.readouterr().err
    assert config.read_text() == DEFAULT_CONFIG.read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fleet.toml", "sub"]


def _workshop_copy(folder: Path, orders: str = "orders.csv") -> Path:
    """examples/workshop-orders.toml with its plant beside it and its orders in ``orders``."""
    examples = Path(__file__).parent.parent / "examples"
    (folder / "plants").mkdir(parents=True)
    (folder / "plants" / "workshop.toml").write_bytes(
        (examples / "plants" / "workshop.toml").read_bytes()
    )
    (folder / orders).write_bytes((examples / "orders" / "workshop.csv").read_bytes())
    text = (examples / "workshop-orders.toml").read_text()
    assert 'file = "orders/workshop.csv"' in text
    config = folder / "w.toml"
    config.write_text(text.replace('file = "orders/workshop.csv"', f'file = "{orders}"'))
    return config


@pytest.mark.parametrize(
    ("retain", "message"),
    [
        ("plants/workshop.toml", "that is the plant file"),
        ("orders.csv", "that is the order file"),
        ("w.toml", "that is the configuration file"),
        ("out/summary.json", "that is the output out/summary.json"),
        ("out/orders.csv", "that is the output out/orders.csv"),
    ],
)
def test_the_retain_file_may_be_no_input_and_no_output(
    tmp_path, capsys, monkeypatch, retain, message
):
    """A file the run reads would be moved aside at start as retain data it cannot read,
    and an output would overwrite or remove the retain data at the end."""
    from fleet.cli import main

    _workshop_copy(tmp_path)
    monkeypatch.chdir(tmp_path)
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    assert main(["run", "w.toml", "--retain", retain, "--out", "out", "--cycles", "2"]) == 2
    assert message in capsys.readouterr().err
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before


def test_results_never_replace_or_remove_a_file_the_run_did_not_write(
    tmp_path, capsys, monkeypatch
):
    """``--out .`` beside the configuration: its order file named orders.csv is the run's
    input, and an orders.csv that no run wrote (a user's order file) is not removed by a
    run without orders either; an order history an earlier run wrote is replaced."""
    from fleet.cli import main

    config = _workshop_copy(tmp_path)
    monkeypatch.chdir(tmp_path)
    orders = (tmp_path / "orders.csv").read_bytes()
    assert main(["run", "w.toml", "--out", ".", "--cycles", "2"]) == 2
    assert "--out .: orders.csv there is the order file of this run" in capsys.readouterr().err
    assert main(["run", "--out", ".", "--cycles", "2"]) == 2  # the default job: no orders
    assert "orders.csv there is no order history a run wrote" in capsys.readouterr().err
    assert (tmp_path / "orders.csv").read_bytes() == orders and config.exists()
    assert (
        not (tmp_path / "summary.json").exists() and not (tmp_path / ".plc-runtime.lock").exists()
    )
    # a history a run wrote is the run's own to replace
    assert main(["run", "w.toml", "--out", "out", "--cycles", "2", "--json"]) == 0
    assert (tmp_path / "out" / "orders.csv").read_text().startswith("id,get,put,vehicle,state,")
    assert main(["run", "--out", "out", "--cycles", "2", "--json"]) == 0
    assert not (tmp_path / "out" / "orders.csv").exists()


def test_fleet_options_are_refused_for_another_program(capsys):
    from fleet.cli import main

    args = ["run", "--program", "demo", "--traffic", "time_windows", "--vehicles-count", "2"]
    assert main([*args, "--cycles", "3"]) == 2
    assert "--traffic, --vehicles-count: for the fleet program, not 'demo'" in (
        capsys.readouterr().err
    )


def test_time_window_settings_under_reactive_traffic_are_named(tmp_path, capsys):
    """One configuration serves both modes (--traffic), so the table is no error; but a run
    that does not use it says so, and one that does says nothing."""
    from fleet.cli import main
    from fleet.config import DEFAULT_CONFIG

    config = tmp_path / "fleet.toml"
    config.write_text(DEFAULT_CONFIG.read_text() + "\n[time_windows]\ngap_s = 0.4\n")
    out = str(tmp_path / "out")
    assert main(["run", str(config), "--cycles", "2", "--out", out]) == 0
    err = capsys.readouterr().err
    assert "[time_windows] is given but traffic is 'reactive'" in err
    assert (
        main(["run", str(config), "--cycles", "2", "--out", out, "--traffic", "time_windows"]) == 0
    )
    assert "[time_windows]" not in capsys.readouterr().err


def test_what_a_message_quotes_from_a_file_cannot_drive_the_terminal(tmp_path, capsys):
    """An unknown key with an escape sequence in it, quoted by the error: printed escaped,
    on one line."""
    from fleet.cli import main
    from fleet.config import DEFAULT_CONFIG

    config = tmp_path / "fleet.toml"
    config.write_text(DEFAULT_CONFIG.read_text() + '\n[web]\n"k\\u001b]0;owned\\u0007" = 1\n')
    assert main(["run", str(config), "--cycles", "2"]) == 2
    err = capsys.readouterr().err
    assert "\x1b" not in err and "\\x1b]0;owned\\x07" in err
    assert err.count("\n") == 1


def test_terminal_text_escapes_only_what_could_drive_a_terminal():
    from plc_runtime.cli import terminal_text

    kept = ["می\u200cخواهم", "Bohren\xa0Fräsen", "👨\u200d👩\u200d👧", "Lager\u00adhalle", "a\nb"]
    assert [terminal_text(t) for t in kept] == kept
    assert terminal_text("a\x1b[2Jb\tc") == "a\\x1b[2Jb\\tc"
    assert terminal_text("r\u202eev\u2028\udce4") == "r\\u202eev\\u2028\\udce4"
    assert terminal_text("agv\u200f12\u200e3\u061c") == "agv\\u200f12\\u200e3\\u061c"


def test_ctrl_c_while_the_command_is_still_being_imported_is_one_line(monkeypatch, capsys):
    """Importing the command line takes a second or more: a Ctrl-C then, before any
    command has set up its own handling, ends the command with exit code 130 and one line,
    not a traceback. (Made deterministic: the import of fleet.cli is what is interrupted.)"""
    import importlib.abc

    from fleet import console

    class Interrupted(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name == "fleet.cli":
                raise KeyboardInterrupt
            return None

    monkeypatch.delitem(sys.modules, "fleet.cli", raising=False)
    monkeypatch.setattr(sys, "meta_path", [Interrupted(), *sys.meta_path])
    assert console.main() == 130
    assert capsys.readouterr().err == "plc-runtime: interrupted\n"


def test_sigterm_while_the_program_is_built_unwinds_like_ctrl_c(monkeypatch, tmp_path, capsys):
    """SIGTERM before the run's own handling is in place (here: while the fleet program is
    built) ends the command with exit code 143 and one line, and the run's ``finally``
    clauses run: no output lock is left in the results folder, nothing is written."""
    import os
    import signal

    from fleet import console
    from fleet.commands import run as fleet_run

    def terminated_while_building(*_args, **_kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        raise AssertionError("SIGTERM did not end the build")

    monkeypatch.setattr(fleet_run, "FleetProgram", terminated_while_building)
    out = tmp_path / "out"
    before = signal.getsignal(signal.SIGTERM)
    assert console.main(["run", "--cycles", "5", "--out", str(out)]) == 143
    assert capsys.readouterr().err.splitlines()[-1] == "plc-runtime: stopped by SIGTERM"
    assert not out.exists()  # the lock went, no result was written, nor is the folder left
    assert signal.getsignal(signal.SIGTERM) is before  # the caller's handling is back


@pytest.mark.parametrize(
    ("functions", "message"),
    [
        ('"1" = "a"\n"01" = "b"', "function id '01' is function 1 again (given as '1')"),
        ('"1" = "a"\n"+1" = "b"', "function id '+1' is function 1 again (given as '1')"),
        ('"\u0661" = "a"', "function id '\u0661' is not an integer >= 0 in ASCII digits"),
        ('"1_0" = "a"', "function id '1_0' is not an integer >= 0 in ASCII digits"),
        ('"-1" = "a"', "function id '-1' is not an integer >= 0 in ASCII digits"),
        ('"' + "9" * 5000 + '" = "a"', "is not an integer >= 0 in ASCII digits"),
    ],
)
def test_a_plant_function_id_is_one_spelling_of_ascii_digits(tmp_path, functions, message):
    """int() takes "01", "+1", " 1", "1_0" and Arabic-Indic digits: two spellings of one id
    overwrote each other silently, and a 5000-digit one raised Python's conversion error."""
    plant = tmp_path / "p.toml"
    plant.write_text(
        f"[functions]\n{functions}\n"
        "[[nodes]]\nid = 0\n[[nodes]]\nid = 1\nx = 1.0\n[[edges]]\nfrom = 0\nto = 1\n"
    )
    with pytest.raises(TopologyError, match=re.escape(message)):
        load(plant)


@pytest.mark.parametrize(
    ("name", "text", "where"),
    [
        (
            "p.toml",
            '[[nodes]]\nid = 0\nrole = "station"\nfunctions = [2, 2]\n[[nodes]]\nid = 1\n'
            "x = 1.0\n[[edges]]\nfrom = 0\nto = 1\nlength = 1.0\n",
            r"nodes\[0\] \(id 0\)",
        ),
        (
            "p.nodes",
            "0 1 0 -1 0 -1 0 -1 0 role=station functions=2+2\n1 -1 0 -1 0 -1 0 0 1.0\n",
            r"line 1 \(id 0\)",  # a file of lines names the line
        ),
    ],
)
def test_a_node_listing_a_function_twice_is_refused(tmp_path, name, text, where):
    """A function given twice on one node is a slip (a copy-paste), taken silently before."""
    plant = tmp_path / name
    plant.write_text(text)
    with pytest.raises(TopologyError, match=rf"{where}: function 2 is listed twice"):
        load(plant)


@pytest.mark.parametrize(
    ("text", "line"),
    [
        ("0 -1 0 1 1.0 -1 0 -1 0 x=0 y=0\n1 -1 0 -1 0 -1 0 0 1.0\n", 2),
        ("0 -1 0 1 1.0 -1 0 -1 0 x=0\n1 -1 0 -1 0 -1 0 0 1.0 x=1 y=0\n", 1),
    ],
)
def test_a_node_list_gives_positions_on_every_node_or_on_none(tmp_path, text, line):
    """Positions on some nodes only put the others at (0, 0) silently: a drawing that lies."""
    plant = tmp_path / "p.nodes"
    plant.write_text(text)
    with pytest.raises(TopologyError, match=rf"p\.nodes: line {line}: x and y are given on some"):
        load(plant)


def test_a_byte_that_is_not_utf8_is_named_by_its_line(tmp_path):
    """Plant files and configurations name the line of a byte that is no UTF-8, as order
    files do, not only its offset in the file."""
    from fleet.config import load_config
    from plc_runtime.errors import ConfigError
    from topology import TopologyError, load

    plant = tmp_path / "p.toml"
    plant.write_bytes(b'name = "p"\n\n# caf\xe9\n')
    with pytest.raises(TopologyError, match=r"line 3: not UTF-8 text \(byte 17\)"):
        load(plant)
    config = tmp_path / "c.toml"
    config.write_bytes(b"[plant]\n# \xff\n")
    with pytest.raises(ConfigError, match=r"c.toml: line 2: not UTF-8 text \(byte 10\)"):
        load_config(config)
