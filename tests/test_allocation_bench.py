"""bench/allocation.py's steady-arrival experiment: which runs it makes, what its table says,
and one short run of the whole fleet program with the generator's orders arriving."""

import importlib.util
import sys
from argparse import Namespace
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
spec = importlib.util.spec_from_file_location("bench_allocation", ROOT / "bench" / "allocation.py")
allocation = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = allocation
spec.loader.exec_module(allocation)


def arrival_args(**over) -> Namespace:
    args = dict(
        experiments=["arrival"],
        seeds=2,
        max_s=4000.0,
        no_deadlines=False,
        traffic="reactive",
        arrival_s=1800.0,
        loads=[0.5, 1.0],
        pool=150,
    )
    return Namespace(**{**args, **over})


def test_the_arrival_experiment_runs_every_strategy_at_every_load_and_seed():
    cases = allocation.cases(arrival_args())
    assert len(cases) == 2 * 3 * 2
    assert {(c.load, c.strategy, c.seed) for c in cases} == {
        (load, st, s) for load in (0.5, 1.0) for st in allocation.STRATEGIES for s in (1, 2)
    }
    assert all(c.experiment == "arrival" and c.vehicles == 17 for c in cases)
    assert all(c.arrival_s == 1800.0 and not c.battery for c in cases)


def result(strategy: str, load: float, seed: int, finished: int, mean_s: float):
    case = allocation.Case("arrival", strategy, 17, seed, arrival_s=1800.0, load=load)
    return allocation.Result(case, finished, 200, mean_s, 10.0, 1700.0, 1800.0, 1.0, 0, 0.0, 100, 0)


def test_the_arrival_table_compares_two_stage_with_dhht_per_load(capsys):
    results = [
        result("dhht", 0.5, 1, 100, 200.0),
        result("dhht", 0.5, 2, 110, 220.0),
        result("two_stage", 0.5, 1, 120, 180.0),
        result("two_stage", 0.5, 2, 111, 198.0),
        result("nearest_idle", 0.5, 1, 90, 300.0),
        result("nearest_idle", 0.5, 2, 92, 310.0),
    ]
    allocation.arrival_table(results, arrival_args(), allocation.Console())
    out = capsys.readouterr().out
    assert "1800 s of the generator's orders (each known 600 s before its start)" in out
    (row,) = [line for line in out.splitlines() if line.startswith("| 0.5 ")]
    cells = [c.strip() for c in row.split("|")[1:-1]]
    assert cells[:4] == ["0.5", "200", "105 (100-110)", "210.0 (200.0-220.0)"]
    assert cells[4:6] == ["116 (111-120)", "189.0 (180.0-198.0)"]
    assert cells[-2:] == ["-10.0%", "+10.0%"]  # 189 / 210 - 1, 115.5 / 105 - 1
    assert not [line for line in out.splitlines() if line.startswith("| 1 ")]  # no runs


def test_a_short_arrival_run_drives_the_generators_orders_without_conflict():
    case = allocation.Case("arrival", "two_stage", 17, 1, arrival_s=120.0, load=1.0)
    r = allocation.run_case(case)
    assert r.sim_s == 120.0 and r.total > 0 and 0 < r.finished < r.total
    assert r.conflicts == 0 and r.charges == 0
