"""bench/allocation.py's steady-arrival experiment: which runs it makes, what its table says,
and one short run of the whole fleet program with the generator's orders arriving."""

import importlib.util
import sys
from argparse import Namespace
from pathlib import Path

import pytest

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
        strategies=list(allocation.STRATEGIES),
        next_order=None,
        bottleneck_s=None,
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
    assert all(c.traffic == "reactive" and c.deadlines for c in cases)
    other = allocation.cases(arrival_args(traffic="time_windows", no_deadlines=True))
    assert all(c.traffic == "time_windows" and not c.deadlines for c in other)


def test_two_stage_options_reach_only_its_runs_and_name_its_column(capsys):
    args = arrival_args(
        experiments=["fleet", "fixed"], fleets=[17], seeds=1, strategies=["dhht", "two_stage"]
    )
    args.fixed = 100
    plain = allocation.cases(args)
    assert {c.strategy for c in plain} == {"dhht", "two_stage"}
    tuned = allocation.cases(Namespace(**{**vars(args), "next_order": False, "bottleneck_s": 60}))
    for c in tuned:
        assert (c.next_order, c.bottleneck_s) == (
            (False, 60) if c.strategy == "two_stage" else (None, None)
        )
    assert tuned[1].variant() == "two_stage (no next order, bottleneck 60 s)"

    def run(case, mean_s):
        return allocation.Result(case, 150, 150, mean_s, 10.0, 1700.0, 1700.0, 1.0, 0, 0.0, 100, 0)

    fleet = [run(c, m) for c, m in zip(plain[:2] + tuned[1:2], (200.0, 190.0, 160.0), strict=True)]
    allocation.report(
        fleet, Namespace(**{**vars(args), "experiments": ["fleet"]}), allocation.Console()
    )
    (row,) = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| 17")]
    assert [c.strip() for c in row.split("|")[1:-1]] == [
        "17",
        "200.0",
        "190.0",
        "160.0",
        "-",
        "-5.0%",
        "-20.0%",
        "-13.6%",
    ]
    fixed = [run(c, 100.0) for c in plain + tuned if c.experiment == "fixed"]
    with pytest.raises(SystemExit, match="the fixed results mix two_stage run under other options"):
        allocation.report(
            fixed, Namespace(**{**vars(args), "experiments": ["fixed"]}), allocation.Console()
        )


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
    # the loads and the length are the results' own, whatever the command line says now
    allocation.arrival_table(
        results, arrival_args(loads=[2.0], arrival_s=60.0), allocation.Console()
    )
    out = capsys.readouterr().out
    assert "1800 s of the generator's orders (each known 600 s before its start)" in out
    (row,) = [line for line in out.splitlines() if line.startswith("| 0.5 ")]
    cells = [c.strip() for c in row.split("|")[1:-1]]
    assert cells[:4] == ["0.5", "200", "105 (100-110)", "210.0 (200.0-220.0)"]
    assert cells[4:6] == ["116 (111-120)", "189.0 (180.0-198.0)"]
    assert cells[6:8] == ["91 (90-92)", "305.0 (300.0-310.0)"]
    assert cells[-2:] == ["-10.0%", "+10.0%"]  # 189 / 210 - 1, 115.5 / 105 - 1
    assert len(cells) == 10
    assert [line[:6] for line in out.splitlines() if line[:2] == "| " and line[2].isdigit()] == [
        "| 0.5 "
    ]


def test_an_arrival_row_without_dhht_runs_has_no_ratio(capsys):
    results = [result("two_stage", 1.0, 1, 50, 180.0)]
    allocation.arrival_table(results, arrival_args(), allocation.Console())
    (row,) = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| 1 ")]
    cells = [c.strip() for c in row.split("|")[1:-1]]
    assert cells[2:6] == ["-", "-", "50", "180.0"] and cells[-2:] == ["-", "-"]


def test_arrival_orders_keep_or_drop_their_deadlines():
    cfg = allocation.load_config(allocation.CONFIG)
    case = allocation.Case("arrival", "dhht", 17, 1, arrival_s=600.0, load=1.0)
    kept = allocation.orders_for(case, cfg)
    dropped = allocation.orders_for(
        allocation.Case("arrival", "dhht", 17, 1, arrival_s=600.0, load=1.0, deadlines=False), cfg
    )
    assert kept and all(o.end_s < float("inf") for o in kept)
    assert [(o.id, o.get, o.put, o.start_s) for o in dropped] == [
        (o.id, o.get, o.put, o.start_s) for o in kept
    ]
    assert all(o.end_s == float("inf") for o in dropped)


def test_a_short_arrival_run_drives_the_generators_orders_without_conflict():
    case = allocation.Case("arrival", "two_stage", 17, 1, arrival_s=120.0, load=1.0)
    r = allocation.run_case(case)
    assert r.sim_s == 120.0 and r.total > 0 and 0 < r.finished < r.total
    assert r.conflicts == 0 and r.charges == 0


def test_charger_use_is_time_on_chargers_over_the_plants_chargers(capsys):
    """Each run's charger use divides by its own plant's chargers: 5 in a run of now, 4 in
    the JSON of a run made before the distribution centre had its fifth (no such key)."""

    def battery(on: bool, charging_s: float, **more) -> allocation.Result:
        case = allocation.Case("battery", "two_stage", 17, 1, battery=on, arrival_s=3600.0)
        return allocation.Result(
            case, 100, 110, 200.0, 10.0, 3600.0, 3600.0, 1.0, 3, charging_s, 40, 0, **more
        )

    now = battery(True, 10800.0, top_ups=1, given_up=0, chargers=5)
    assert now.chargers == len(allocation.load_config(allocation.CONFIG).plant.with_role("charger"))
    old = {**vars(battery(True, 10800.0)), "case": vars(battery(True, 0.0).case)}
    del old["chargers"]
    args = Namespace(
        experiments=["battery"],
        no_deadlines=False,
        battery_s=3600.0,
        battery_load=0.5,
        top_up_below=None,
    )
    for runs, use in (([now], "60 %"), ([allocation.loaded(old)], "75 %")):
        allocation.report([battery(False, 0.0), *runs], args, allocation.Console())
        (row,) = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| on")]
        assert [c.strip() for c in row.split("|")[1:-1]][6] == use, row
