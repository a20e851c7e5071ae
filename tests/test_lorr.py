"""bench/lorr.py writes the competition's output; this replays it by the competition's rules.

The replay is written here from the rules in the data's README alone: every robot starts at
its start cell facing east; F moves one cell forward (never into an obstacle or off the
map), R and C turn 90 degrees clockwise and counter-clockwise, W waits; no two robots in one
cell after a timestep, no two swapping cells; tasks round-robin, one revealed at a time, a
task finished when its robot stands on its cell. It recounts the finished tasks and
requires zero conflicts.
"""

import argparse
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
INSTANCE = ROOT / "tests" / "data" / "lorr2023" / "random" / "EI23-random_100.json"

spec = importlib.util.spec_from_file_location("bench_lorr", ROOT / "bench" / "lorr.py")
lorr = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = lorr
spec.loader.exec_module(lorr)

MOVES = {"E": (0, 1), "S": (1, 0), "W": (0, -1), "N": (-1, 0)}  # (row, column)
CLOCKWISE = "ESWN"


def bench(*args: str, timeout: float = 900) -> subprocess.CompletedProcess:
    """bench/lorr.py run as a user runs it, with these arguments."""
    return subprocess.run(
        [sys.executable, str(ROOT / "bench" / "lorr.py"), *args],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def replay(instance_path: Path, out: dict, follow: bool = True) -> tuple[int, list[str]]:
    """(tasks finished, conflicts and invalid moves) by the competition's rules; without
    ``follow``, also every move into a cell that was not empty as the step began."""
    spec = json.loads(instance_path.read_text())
    base = instance_path.parent
    rows = base.joinpath(spec["mapFile"]).read_text().splitlines()
    start_row = rows.index("map") + 1
    height = int(next(r for r in rows if r.startswith("height")).split()[1])
    grid = rows[start_row : start_row + height]
    width = len(grid[0])
    team = spec["teamSize"]
    starts = [int(v) for v in base.joinpath(spec["agentFile"]).read_text().split()][1 : 1 + team]
    tasks = [int(v) for v in base.joinpath(spec["taskFile"]).read_text().split()]
    tasks = tasks[1 : 1 + tasks[0]]
    paths = [p.split(",") if p else [] for p in out["actualPaths"]]
    assert len(paths) == team
    steps = max(len(p) for p in paths)
    pos = [(s // width, s % width) for s in starts]
    face = ["E"] * team
    task_of = list(range(team))  # index into the task list of each robot's current task
    problems, finished = [], 0

    def check_tasks(t):
        nonlocal finished
        for i in range(team):
            r, c = pos[i]
            if r * width + c == tasks[task_of[i] % len(tasks)]:
                finished += 1
                task_of[i] += team

    check_tasks(0)
    for t in range(steps):
        before = list(pos)
        for i in range(team):
            a = paths[i][t]
            if a == "F":
                dr, dc = MOVES[face[i]]
                r, c = pos[i][0] + dr, pos[i][1] + dc
                if not (0 <= r < height and 0 <= c < width) or grid[r][c] in "@T":
                    problems.append(f"t {t}: robot {i} drives into an obstacle or off the map")
                    continue
                if not follow and (r, c) in before:
                    problems.append(f"t {t}: robot {i} follows into ({r}, {c}) in one step")
                pos[i] = (r, c)
            elif a == "R":
                face[i] = CLOCKWISE[(CLOCKWISE.index(face[i]) + 1) % 4]
            elif a == "C":
                face[i] = CLOCKWISE[(CLOCKWISE.index(face[i]) - 1) % 4]
            elif a != "W":
                problems.append(f"t {t}: robot {i}: unknown action {a!r}")
        cells = {}
        for i, p in enumerate(pos):
            if p in cells:
                problems.append(f"t {t + 1}: robots {cells[p]} and {i} in cell {p}")
            cells[p] = i
        moved = {i for i in range(team) if pos[i] != before[i]}
        where_before = {before[i]: i for i in range(team)}
        for i in moved:
            j = where_before.get(pos[i])
            if j is not None and j != i and pos[j] == before[i]:
                if i < j:
                    problems.append(f"t {t}: robots {i} and {j} swap cells")
        check_tasks(t + 1)
    return finished, problems


@pytest.fixture(scope="module", params=["time_windows", "one_step"])
def result(request, tmp_path_factory):
    out = tmp_path_factory.mktemp("lorr") / "result.json"
    proc = bench(
        str(INSTANCE), "--steps", "120", "--out", str(out), "--traffic", request.param, timeout=900
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(out.read_text()), json.loads(proc.stdout)


def test_the_output_has_the_competitions_fields(result):
    out, _ = result
    for key in (
        "actionModel",
        "AllValid",
        "teamSize",
        "start",
        "numTaskFinished",
        "actualPaths",
        "plannerTimes",
        "errors",
        "events",
        "tasks",
        "sumOfCost",
        "makespan",
    ):
        assert key in out, key
    assert out["actionModel"] == "MAPF_T" and out["teamSize"] == 100
    assert len(out["plannerTimes"]) == 120
    assert all(len(p.split(",")) == 120 for p in out["actualPaths"])


def test_a_replay_by_the_rules_finds_no_conflict_and_the_same_tasks_finished(result):
    out, printed = result
    finished, problems = replay(INSTANCE, out)
    assert problems == []
    assert finished == out["numTaskFinished"] == printed["tasks_finished"]
    assert out["AllValid"] == "Yes" and out["errors"] == [] and printed["conflicts"] == 0
    assert finished > 100  # it does work: about two tasks per timestep on this instance


def tiny_instance(tmp_path, rows, starts, tasks):
    (tmp_path / "m.map").write_text(
        f"type octile\nheight {len(rows)}\nwidth {len(rows[0])}\nmap\n" + "\n".join(rows) + "\n"
    )
    (tmp_path / "a.agents").write_text(f"{len(starts)}\n" + "\n".join(map(str, starts)) + "\n")
    (tmp_path / "t.tasks").write_text(f"{len(tasks)}\n" + "\n".join(map(str, tasks)) + "\n")
    path = tmp_path / "i.json"
    path.write_text(
        json.dumps(
            {
                "mapFile": "m.map",
                "agentFile": "a.agents",
                "taskFile": "t.tasks",
                "teamSize": len(starts),
                "numTasksReveal": 1,
                "taskAssignmentStrategy": "roundrobin",
            }
        )
    )
    return path


def test_the_replay_catches_swaps_shared_cells_and_obstacles_and_counts_tasks(tmp_path):
    """Hand-made: the replay is not just agreeing with the bench."""
    path = tiny_instance(tmp_path, ["....", "..@."], [0, 1], [1, 3, 0, 0])
    # robot 0 faces east and drives to 1 while robot 1 turns round and drives to 0: a swap
    swap = {"actualPaths": ["W,W,F", "R,R,F"]}
    _, problems = replay(path, swap)
    assert any("swap" in p for p in problems)
    # robot 1 drives on to 2 and 3 while robot 0 follows into the cells it leaves: valid;
    # robot 0 finishes task 0 (cell 1) passing through, robot 1 task 1 (cell 3)
    follow = {"actualPaths": ["F,F", "F,F"]}
    finished, problems = replay(path, follow)
    assert problems == [] and finished == 2
    # into the obstacle at row 1, column 2, and both into one cell
    crash = {"actualPaths": ["R,F,C,F", "W,W,W,W"]}  # 0 -> (1,0) -> (1,1)
    path2 = tiny_instance(tmp_path, ["....", "..@."], [0, 5], [3, 3])
    _, problems = replay(path2, crash)
    assert any("in cell" in p for p in problems)
    into_wall = {"actualPaths": ["W", "F"]}
    _, problems = replay(path2, into_wall)
    assert any("obstacle" in p for p in problems)


def test_a_bad_instance_gets_a_clear_error(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text(
        json.dumps({"mapFile": "nope.map", "agentFile": "a", "taskFile": "t", "teamSize": 3})
    )
    with pytest.raises(lorr.InstanceError, match="bad.json"):
        lorr.read_instance(bad)
    proc = bench(str(bad), timeout=60)
    assert proc.returncode != 0 and "bad.json" in proc.stderr and "Traceback" not in proc.stderr


def test_the_bench_reports_a_conflict_it_would_make():
    """Its own check (AllValid, errors) is not a constant: a swap and a shared cell show."""
    a, b, c = (lorr.Robot(i, node, 0, 0, i) for i, node in enumerate((5, 6, 9)))
    before = {0: 6, 1: 5, 2: 8}  # 0 and 1 swapped; 2 moved from 8 to 9
    assert [e[3] for e in lorr.conflicts([a, b, c], before, 0)] == ["edge conflict"]
    c.node = 6
    assert "vertex conflict" in [e[3] for e in lorr.conflicts([a, b, c], before, 0)]


@pytest.mark.parametrize("traffic", ["time_windows", "one_step"])
def test_following_a_step_later_is_kept_and_replayed(traffic, tmp_path):
    """``--follow next_step``: nobody drives into a cell its robot leaves in the same step;
    the replay checks that too, and still finds the same tasks and no conflict."""
    out = tmp_path / "next.json"
    proc = bench(
        str(INSTANCE),
        "--steps",
        "60",
        "--traffic",
        traffic,
        "--follow",
        "next_step",
        "--out",
        str(out),
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    result = json.loads(out.read_text())
    finished, problems = replay(INSTANCE, result, follow=False)
    assert problems == [] and finished == result["numTaskFinished"] > 0
    # the check itself is not empty: the competition's own rule does follow in one step
    same = lorr.run_one_step(lorr.read_instance(INSTANCE), 60, follow=True)
    _, problems = replay(INSTANCE, same, follow=False)
    assert any("follows into" in p for p in problems)


def test_the_kiva_instance_is_rhcrs_map_with_seeded_starts_and_tasks():
    from topology.samples import kiva

    plant = kiva()
    endpoints = set(plant.with_role("station"))
    a, b, c = lorr.kiva_instance(140, 0), lorr.kiva_instance(140, 0), lorr.kiva_instance(140, 1)
    assert a.starts == b.starts and a.tasks == b.tasks  # the seed decides
    assert a.starts != c.starts and a.tasks != c.tasks
    assert len(set(a.starts)) == 140 and all(a.passable.flat[s] for s in a.starts)
    assert set(a.tasks) <= endpoints and len(set(a.tasks)) > 400  # uniform over the 480
    assert int(a.passable.sum()) == plant.n == 1278


def test_the_kiva_table_runs_both_planners_without_conflict():
    proc = bench(
        "--kiva",
        "20",
        "--steps",
        "30",
        "--seeds",
        "0",
        "--traffic",
        "time_windows",
        "one_step",
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    rows = [line.split("|")[1:-1] for line in proc.stdout.splitlines() if line.startswith("| 20 ")]
    assert [r[2].strip() for r in rows] == ["time_windows", "one_step"]
    assert all(r[1].strip() == "same_step" for r in rows)
    assert all(r[-1].strip() == "0" for r in rows)  # conflicts
    assert all(float(r[3].split()[0]) > 0 for r in rows)  # tasks per step
    for r in rows:  # a task's robot-steps: 20 robots x 30 steps over the tasks finished
        moves, turns, waits = (float(x) for x in r[6].split(" / "))
        tasks = float(r[3].split()[0]) * 30
        assert moves > 0 and turns >= 0 and waits >= 0
        # (the rate is printed to two decimals)
        assert moves + turns + waits == pytest.approx(20 * 30 / tasks, rel=0.03)


def test_the_kiva_table_averages_each_column_over_the_seeds(monkeypatch, capsys):
    runs = {  # seed -> (tasks, paths of two robots over 4 steps)
        0: (2, ["F,F,F,R", "W,W,F,F"]),  # 2.5 / 0.5 / 1.0 per task
        1: (4, ["F,F,F,F", "F,F,C,C"]),  # 1.5 / 0.5 / 0.0 per task
    }

    def solved(traffic, seed, steps, args):
        tasks, paths = runs[seed]
        times = [0.01 * (seed + 1)] * steps
        return {
            "numTaskFinished": tasks,
            "actualPaths": paths,
            "plannerTimes": times,
            "_stats": {"conflicts": seed},
        }

    monkeypatch.setattr(lorr, "kiva_instance", lambda robots, seed: seed)
    monkeypatch.setattr(lorr, "solve", solved)
    args = argparse.Namespace(
        steps=4, kiva=[2], traffic=["time_windows"], seeds=[0, 1], follow="same_step"
    )
    lorr.kiva_table(args)
    (row,) = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| 2 ")]
    cells = [c.strip() for c in row.split("|")[1:-1]]
    assert cells[3] == "0.75 (0.50-1.00)"  # 2 and 4 tasks in 4 steps
    assert cells[6] == "2.0 / 0.5 / 0.5"
    assert cells[7:] == ["0.015", "0.020", "1"]  # mean and max planning time, conflicts


def test_a_tasks_steps_are_counted_by_action():
    result = {"numTaskFinished": 2, "actualPaths": ["F,F,R,W", "C,F,W,W", ""]}
    assert lorr.actions_per_task(result) == (1.5, 1.0, 1.5)
    assert (
        lorr.actions_per_task({"numTaskFinished": 0, "actualPaths": ["W"]}) == (float("inf"),) * 3
    )


def test_several_planners_with_one_instance_is_a_clear_error():
    proc = bench(str(INSTANCE), "--traffic", "time_windows", "one_step", timeout=60)
    assert proc.returncode == 2 and "one --traffic" in proc.stderr  # a usage error
    assert "Traceback" not in proc.stderr
