"""`make bench-quick` runs every benchmark, reduced, and `make bench` runs every one in full.

The static half checks that each bench/*.py script is listed in both make targets and has a
--quick option (its --help, in this process: the scripts' imports are shared, so this stays
cheap); the other half runs the two cheapest quick benchmarks in a subprocess and checks the
shape of what they print: the table recorded in docs/benchmarks.md (same header), a numeric
ratio against the baseline in every row, and the script's wall time. Wall-clock values
themselves are never asserted: the machine may be busy.
"""

from __future__ import annotations

import math
import runpy
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = sorted(p.name for p in (ROOT / "bench").glob("*.py"))
DOCS = (ROOT / "docs" / "benchmarks.md").read_text()
TRAFFIC = ("reactive", "time_windows")


def recipe(target: str) -> list[str]:
    """The command lines of a Makefile target's recipe."""
    lines = (ROOT / "Makefile").read_text().splitlines()
    start = lines.index(next(line for line in lines if line.startswith(f"{target}:")))
    commands = []
    for line in lines[start + 1 :]:
        if not line.startswith("\t"):
            break
        commands.append(line.strip())
    return commands


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, *args], cwd=ROOT, capture_output=True, text=True, timeout=120
    )


def table(stdout: str) -> tuple[list[str], list[list[str]], str]:
    """(columns, rows, header line) of the first markdown table in a script's output."""
    lines = stdout.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("| "))
    assert lines[start + 1].startswith("|---"), lines[start : start + 2]

    def cells(line: str) -> list[str]:
        return [c.strip() for c in line.strip().strip("|").split("|")]

    rows = []
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        rows.append(cells(line))
    return cells(lines[start]), rows, lines[start]


def test_bench_scripts_are_found():
    assert len(SCRIPTS) >= 7, SCRIPTS


def test_every_script_is_in_both_make_targets():
    full, quick = recipe("bench"), recipe("bench-quick")
    for name in SCRIPTS:
        run = f"$(BIN)/python bench/{name}"
        assert any(line == run or line.startswith(run + " ") for line in full), (
            f"make bench does not run {name}"
        )
        assert f"$(BIN)/python bench/{name} --quick" in quick, (
            f"make bench-quick does not run {name} --quick"
        )
    assert len(quick) == len(SCRIPTS), quick


def test_make_bench_states_its_duration_first():
    first = recipe("bench")[0]
    assert first.startswith("@echo") and "minutes" in first, first


@pytest.mark.parametrize("name", SCRIPTS)
def test_script_accepts_quick(name, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", [name, "--help"])
    monkeypatch.setattr(sys, "path", list(sys.path))  # the scripts put the repo on the path
    with pytest.raises(SystemExit) as exit_:
        runpy.run_path(str(ROOT / "bench" / name), run_name="__main__")
    assert exit_.value.code == 0
    assert "--quick" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("args", "ratio_column", "rows"),
    [
        (["step_rate.py", "--quick"], "runtime / bare", 4),  # 1, 10, 100, 1000 blocks
        # an explicit option still wins over --quick's defaults: only the 1e3-node grid
        (["heuristic_table.py", "--quick", "--max-nodes", "1024"], "networkx / ours", 3),
    ],
    ids=["step_rate", "heuristic_table"],
)
def test_quick_bench_prints_its_table_with_a_ratio(args, ratio_column, rows):
    name = args[0]
    result = run(f"bench/{name}", *args[1:])
    assert result.returncode == 0, result.stderr
    columns, body, header = table(result.stdout)
    assert header in DOCS, f"{name} --quick prints other columns than docs/benchmarks.md"
    assert len(body) == rows, body
    at = columns.index(ratio_column)
    for row in body:
        assert len(row) == len(columns), row
        ratio = float(row[at].replace(",", ""))
        assert math.isfinite(ratio) and ratio > 0, row
    last = result.stdout.strip().splitlines()[-1]
    assert last.startswith("wall time ") and last.endswith(" s"), last


def test_order_backlog_runs_its_rounds_without_a_fault():
    """The backlog bench times the dispatcher's pool against a plain sort in every round:
    a fault (a changed dispatcher it no longer fits) measures nothing and must fail it."""
    result = run(
        "bench/order_backlog.py", "--orders", "1000", "--strategies", "dhht", "--after-s", "10"
    )
    assert result.returncode == 0, result.stderr
    columns, body, header = table(result.stdout)
    assert header in DOCS, "order_backlog.py prints other columns than docs/benchmarks.md"
    (row,) = body
    assert row[columns.index("faults")] == "0" and int(row[columns.index("rounds")]) > 0, row
    # a wall-clock ratio: measured, printed, never asserted beyond being one
    ratio = float(row[columns.index("sort / ours")])
    assert math.isfinite(ratio) and ratio >= 0, row
    # then the sweep of the book's final orders, against a plain sorted list
    rest = result.stdout[result.stdout.index("Sweeping final orders") :]
    columns, body, header = table(rest)
    assert header in DOCS, "order_backlog.py's sweep table differs from docs/benchmarks.md"
    (row,) = body
    assert row[columns.index("orders in the book")] == "1,000", row
    assert row[columns.index("swept")] == "500", row
    ratio = float(row[columns.index("ours / plain")])
    assert math.isfinite(ratio) and ratio > 0, row


def test_warehouse_throughput_json_is_one_object_per_plant_and_fleet_size():
    """The contract for scripts: --json prints one JSON object per run (plant, traffic
    mode, fleet size, seed), one per line."""
    import json

    result = run(
        "bench/warehouse_throughput.py",
        "--json",
        "--plant",
        "kiva",
        "warehouse",
        "--sizes",
        "3",
        "5",
        "--timesteps",
        "15",
        "--bound-timesteps",
        "15",
        "--traffic",
        "reactive",
        "time_windows",
        "--seeds",
        "0",
        "1",
    )
    assert result.returncode == 0, result.stderr
    rows = [json.loads(line) for line in result.stdout.strip().splitlines()]
    assert [(r["plant"], r["traffic"], r["vehicles"], r["seed"]) for r in rows] == [
        (plant, traffic, n, seed)
        for plant in ("kiva", "warehouse")
        for traffic in ("reactive", "time_windows")
        for n in (3, 5)
        for seed in (0, 1)
    ]
    for r in rows:
        for key in (
            "traffic",
            "timesteps",
            "tasks_per_timestep",
            "bound_tasks_per_timestep",
            "head_on_conflicts",
            "node_conflicts",
            "stuck_vehicles",
        ):
            assert key in r, key
        assert r["timesteps"] == 15 and r["delay_rate"] == 0
        assert r["head_on_conflicts"] == 0 and r["node_conflicts"] == 0
        assert r["bound_tasks_per_timestep"] >= 0


def test_warehouse_throughput_summarises_several_seeds_per_configuration():
    """With --seeds the runs of each traffic mode and fleet size are summarised: the mean
    over the seeds with its min-max, and the time-window mean over the reactive mean."""
    options = "--plant kiva --sizes 4 --timesteps 15 --bound-timesteps 100 --seeds 0 1 2"
    result = run("bench/warehouse_throughput.py", *options.split(), "--traffic", *TRAFFIC)
    assert result.returncode == 0, result.stderr
    summary = result.stdout.split("Over the seeds, kiva")[1]
    rows = [line.split("│")[1:-1] for line in summary.splitlines() if line.startswith("│")]
    cells = {row[0].strip(): [c.strip() for c in row] for row in rows[:2]}
    assert set(cells) == {"reactive", "time_windows"}
    for row in cells.values():
        assert row[2] == "4" and row[3] == "3", row
        mean, spread = row[4].split(" ", 1)
        low, high = (float(x) for x in spread.strip("()").split("-"))
        assert low <= float(mean) <= high, row
    assert cells["reactive"][5] == "-" and float(cells["time_windows"][5]) > 0


def test_warehouse_throughput_without_a_bound_prints_no_ratio_to_it():
    """Runs too short for the lone vehicle (or any fleet) to finish a task give no bound
    and no rate to compare with: the ratios to them are '-', not a division by zero."""
    options = "--plant kiva --sizes 3 --timesteps 5 --bound-timesteps 5 --seeds 0 1"
    result = run("bench/warehouse_throughput.py", *options.split(), "--traffic", *TRAFFIC)
    assert result.returncode == 0, result.stderr
    assert "0.0000 tasks per timestep" in result.stdout
