"""Bad options and instance files of bench/lorr.py, warehouse_throughput.py and time_windows.py
stop at once with one line naming what is wrong: argparse's error (exit code 2) for an
option, ``lorr.py: FILE: ...`` for an instance. No real run starts: the scripts run in this
process with their runs replaced by one that fails the test, except the duplicate-start
instance, which hung for ever and so runs in a subprocess with a timeout."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
LORR_DATA = ROOT / "tests" / "data" / "lorr2023" / "random"
MAP = LORR_DATA / "maps" / "random-32-32-20.map"


def load(name: str):
    spec = importlib.util.spec_from_file_location(f"bench_options_{name}", ROOT / "bench" / name)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


lorr = load("lorr.py")
warehouse = load("warehouse_throughput.py")
time_windows = load("time_windows.py")


class Ran(Exception):
    """The options passed: the script went on to its run."""


def ran(*args, **kwargs):
    raise Ran


@pytest.fixture
def script(monkeypatch):
    """script(module, *argv): runs its main with these options, its runs replaced by
    :func:`ran`; the SystemExit it stops with, or Ran."""
    monkeypatch.setattr(lorr, "solve", ran)
    monkeypatch.setattr(lorr, "kiva_table", ran)
    monkeypatch.setattr(warehouse, "single_vehicle_rate", ran)
    monkeypatch.setattr(warehouse, "run_size", ran)
    monkeypatch.setattr(time_windows, "report", ran)

    def call(module, *argv: str) -> SystemExit | Ran:
        monkeypatch.setattr(sys, "argv", [Path(module.__file__).name, *argv])
        try:
            module.main()
        except (SystemExit, Ran) as stop:
            return stop
        raise AssertionError("neither an error nor a run")

    return call


def error_of(stop, capsys) -> str:
    """The last line on stderr of an argparse error (exit code 2)."""
    assert isinstance(stop, SystemExit) and stop.code == 2, stop
    return capsys.readouterr().err.strip().splitlines()[-1]


@pytest.mark.parametrize(
    "argv",
    [
        ["--plan-budget", "0"],
        ["--plan-budget", "-5"],
        ["--stay-s", "-1"],
        ["--stay-s", "nan"],
        ["--stay-s", "inf"],
        ["--steps", "0"],
        ["--kiva", "-2"],
        ["--kiva", "0"],
        ["--kiva", "100000"],
        ["--kiva", "5", "--seeds", "-1"],
        ["--kiva", "5", "--seeds", "x"],
    ],
)
def test_lorr_refuses_a_bad_option(script, capsys, argv):
    option = next(a for a in argv[::-1] if a.startswith("--"))
    assert f"argument {option}: " in error_of(script(lorr, *argv), capsys)


def test_lorr_names_the_kiva_maps_free_cells(script, capsys):
    assert "1278 free cells" in error_of(script(lorr, "--kiva", "60", "1279"), capsys)


def test_lorr_accepts_the_limits(script):
    argv = ["--kiva", "1", "1278", "--seeds", "0", "--stay-s", "0", "--plan-budget", "1"]
    assert isinstance(script(lorr, *argv), Ran)


@pytest.mark.parametrize(
    "argv",
    [
        ["--sizes", "0"],
        ["--sizes", "60", "-1"],
        ["--sizes", "100000"],
        ["--quick", "--sizes", "100000"],
        ["--timesteps", "0"],
        ["--bound-timesteps", "0"],
        ["--seeds", "-1"],
        ["--seeds", "1.5"],
        ["--plan-budget", "0"],
        ["--highway-factor", "0.5"],
        ["--highway-factor", "nan"],
        ["--highway-factor", "inf"],
        ["--delay-rate", "-0.1"],
        ["--delay-rate", "0", "1.5"],
        ["--delay-rate", "nan"],
        ["--cycle-ms", "0"],
        ["--cycle-ms", "nan"],
        ["--watchdog-ms", "-1"],
        ["--watchdog-ms", "inf"],
    ],
)
def test_warehouse_throughput_refuses_a_bad_option_before_any_run(script, capsys, argv):
    option = next(a for a in argv[::-1] if a.startswith("--"))
    assert f"argument {option}: " in error_of(script(warehouse, *argv), capsys)


def test_warehouse_throughput_sizes_fit_every_plant_given(script, capsys):
    """The warehouse has 1068 nodes, kiva 1278: each vehicle starts on a node of its own."""
    line = error_of(script(warehouse, "--sizes", "1069"), capsys)
    assert "1069 vehicles" in line and "warehouse has 1068 nodes" in line
    assert isinstance(script(warehouse, "--plant", "kiva", "--sizes", "1069"), Ran)


def test_warehouse_throughput_accepts_the_limits(script):
    argv = "--sizes 1 1068 --seeds 0 --highway-factor 1 --delay-rate 0 1 --plan-budget 1"
    assert isinstance(script(warehouse, *argv.split()), Ran)


@pytest.mark.parametrize(
    "argv",
    [
        ["--cell-m", "0"],
        ["--cell-m", "-6"],
        ["--cell-m", "nan"],
        ["--cell-m", "inf"],
        ["--dwell-s", "-1"],
        ["--dwell-s", "nan"],
    ],
)
def test_time_windows_refuses_a_bad_option(script, capsys, argv):
    assert f"argument {argv[0]}: " in error_of(script(time_windows, *argv), capsys)


def test_time_windows_accepts_no_dwell(script):
    assert isinstance(script(time_windows, "--cell-m", "1", "--dwell-s", "0"), Ran)


MISSING = "No such file or directory"


def instance(
    tmp_path: Path, starts=(390, 479), tasks=(435, 363), rows=None, cell=None, **spec
) -> Path:
    """An instance on the test data's 32 x 32 map (``rows``: its first rows only; ``cell``:
    its first cell), with these starts and tasks; ``spec`` changes its JSON (None: the key
    is left out)."""
    lines = MAP.read_text().splitlines()
    first = lines.index("map") + 1
    if rows is not None:
        lines = lines[: first + rows]
    if cell is not None:
        lines[first] = cell + lines[first][1:]
    (tmp_path / "m.map").write_text("\n".join(lines) + "\n")
    (tmp_path / "a.agents").write_text("\n".join(map(str, (len(starts), *starts))) + "\n")
    (tmp_path / "t.tasks").write_text("\n".join(map(str, (len(tasks), *tasks))) + "\n")
    fields = {"mapFile": "m.map", "agentFile": "a.agents", "taskFile": "t.tasks"}
    fields |= {"teamSize": len(starts), "taskAssignmentStrategy": "roundrobin"} | spec
    path = tmp_path / "i.json"
    path.write_text(json.dumps({k: v for k, v in fields.items() if v is not None}))
    return path


def test_the_instance_helper_makes_a_good_instance(tmp_path, script):
    assert lorr.read_instance(instance(tmp_path)).team == 2
    assert isinstance(script(lorr, str(instance(tmp_path)), "--steps", "3"), Ran)


def test_robots_sharing_a_start_stop_at_once(tmp_path):
    """It used to plan for ever: each robot's safe stay voided the other's."""
    path = instance(tmp_path, starts=(390, 390, 479))
    proc = subprocess.run(
        [sys.executable, str(ROOT / "bench" / "lorr.py"), path.name, "--steps", "3"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    assert proc.stderr.strip() == "lorr.py: i.json: start 1 at 390 is also robot 0's start"


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"teamSize": 2.7}, "teamSize must be a whole number >= 1, got 2.7"),
        ({"teamSize": True}, "teamSize must be a whole number >= 1, got true"),
        ({"teamSize": "2"}, 'teamSize must be a whole number >= 1, got "2"'),
        ({"teamSize": 0}, "teamSize must be a whole number >= 1, got 0"),
        ({"teamSize": -1}, "teamSize must be a whole number >= 1, got -1"),
        ({"teamSize": 3}, "teamSize 3, but a.agents gives 2 starts"),
        ({"tasks": ()}, "t.tasks lists no tasks"),
        ({"mapFile": None}, "missing key 'mapFile'"),
        ({"teamSize": None}, "missing key 'teamSize'"),
        ({"rows": 20}, "m.map: line 24: truncated: 20 of 32 rows"),
        ({"cell": "X"}, "m.map: line 5: unknown cell 'X' at column 1"),
        ({"starts": (390, 10)}, "start 1 at 10 is not a free cell of the map"),
        ({"mapFile": "\x1b[31mred.map"}, "/\\x1b[31mred.map: cannot read plant file: " + MISSING),
        (
            {"mapFile": "x\nlorr.py: f.map"},
            "/x\\nlorr.py: f.map: cannot read plant file: " + MISSING,
        ),
    ],
)
def test_a_bad_instance_is_one_line_naming_the_file(tmp_path, script, change, message):
    path = instance(tmp_path, **change)
    with pytest.raises(lorr.InstanceError, match="i.json"):
        lorr.read_instance(path)
    stop = script(lorr, str(path), "--steps", "3")
    assert isinstance(stop, SystemExit)
    assert stop.code.startswith(f"lorr.py: {path}: ") and stop.code.endswith(message)
