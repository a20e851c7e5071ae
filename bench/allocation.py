"""The order-allocation experiments of seed 000 on the sample distribution centre.

Every run is the whole fleet program on the virtual clock (``examples/distribution-centre.toml``:
the plant, 17 pallet shuttles at 1.5 m/s, the seed's order mix): CAN link, traffic,
dispatcher, order runners, the simulated vehicles. Orders come from the seed's generator
(its relations and rates, 2 extra per 100 through the control station) with the run's seed;
a *pool* run takes the first N of them and makes them all known and startable at once
(start time 0, each keeping its latest delivery time), so every strategy chooses from the
same large pool, as in the seed's fixed-order experiments (``--no-deadlines``: without
their latest delivery times, so that no order is ever late). A run ends when every order is
FINISHED (or at ``--max-s``, then the unfinished are counted).

Measured per run: mean order execution time (from taking the order to the end of its Put,
the seed's measure), mean station wait per order (Get_Queue + Put_Queue), makespan (the
last order finished), orders finished; with batteries: charger visits, time on chargers and
the lowest charge seen. Each row is the mean over ``--seeds`` seeds with the spread (min-max).

Experiments (the seed's, ``docs/benchmarks.md`` "Order allocation"):

1. ``buffer``: B = 8, 18, 28, 38, 48, 58 s, two_stage, 17 vehicles, 150 orders (``--pool``);
2. ``fleet``: 11, 13, 15, 17 vehicles x {dhht, two_stage, nearest_idle}, 150 orders
   (this and the next at the configuration's B, the best of experiment 1);
3. ``fixed``: 100 orders, 17 vehicles, each strategy, and two_stage with 16 vehicles;
4. ``battery``: two_stage, 17 vehicles, the generator's arrival (each order known ``lead_s``
   before its start) for ``--battery-s`` seconds at ``--battery-load`` times the seed's
   rates (0.5 by default: our shuttles take about twice the seed's robots' time per order,
   so this leaves the fleet the slack the seed's had, some 70 % busy), with the vehicles
   starting part-charged (a seeded spread of 36-70 %) and the charging policy on, against
   the same run with batteries off (full, no policy): orders finished, throughput lost,
   charger use, the lowest charge. ``--top-up-below P``: idle vehicles charge by choice
   only below P % (the rule before was below ``sufficient``, 60), for a baseline of the
   policy over runs long enough for the batteries to run down (``--battery-s 14400``).

5. ``arrival``: 17 vehicles, each strategy, the generator's arrival for ``--arrival-s``
   seconds (each order known ``lead_s`` before its start, as the seed's warehouse system
   releases them) at each of ``--loads`` times the seed's rates, batteries off: orders
   finished by the end and their mean order time. The seed's fleet worked such a stream;
   the pool experiments above give every strategy the same orders to choose from.

Ratios against the seed's published figures are printed beside ours: two_stage against
dhht (the seed: -13.6 % mean order time at 17 vehicles, the largest gap of its fleet-size
experiment, -7.45 % with 100 orders, makespan -6.57 %), and the buffer with the least mean
order time (the seed: 38 s).

    .venv/bin/python bench/allocation.py [--experiments buffer fleet fixed battery arrival]
        [--seeds 3] [--jobs 2] [--fleets 11 13 15 17] [--buffers 8 18 28 38 48 58]
        [--pool 150] [--max-s 4000] [--battery-s 3600] [--battery-load 0.5] [--top-up-below P]
        [--arrival-s 3600] [--loads 0.5 0.75 1] [--strategies dhht two_stage nearest_idle]
        [--next-order on|off] [--bottleneck-s S] [--json FILE] [--report FILE ...] [--quick]

``--next-order`` and ``--bottleneck-s`` set two_stage's options of the same names
(docs/fleet-config.md) in its runs; the fleet table gives each setting found in the results
its own column, so runs under the seed's rules and under others can be reported together
(``--report a.json b.json``); the other tables refuse such a mix.

``--quick``: one seed, 20 orders, 17 vehicles only, B = 8 and 38, 300 s battery and arrival
runs at 0.5 x the rates:
a check that it all runs, not numbers to record.
"""

from __future__ import annotations

import argparse
import json
import random
import statistics
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, replace
from math import inf, isnan
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from blocks.dispatch.charging import ChargePolicy  # noqa: E402
from blocks.dispatch.generator import generate_orders  # noqa: E402
from blocks.dispatch.order_file import write_orders  # noqa: E402
from blocks.dispatch.orders import OrderState, TransportOrder  # noqa: E402
from fleet.config import first_vehicles, load_config  # noqa: E402
from fleet.order_report import execution_s, waiting_s  # noqa: E402
from fleet.program import FleetProgram  # noqa: E402

CONFIG = ROOT / "examples" / "distribution-centre.toml"
STRATEGIES = ("dhht", "two_stage", "nearest_idle")
BUFFERS = (8, 18, 28, 38, 48, 58)
FLEETS = (11, 13, 15, 17)
LOADS = (0.5, 0.75, 1.0)  # arrival: x the seed's rates (about 210, 315 and 420 orders per hour)
# the seed's published figures (reference/seed-000-order-allocation.md)
SEED_GAP_17 = -0.136  # two_stage vs dhht, mean order time, 17 robots (fleet-size runs)
SEED_GAP_100 = -0.0745  # the same with 100 orders (99.98 s -> 92.53 s)
SEED_MAKESPAN_100 = -0.0657  # makespan, 100 orders (714 s -> 667 s)
SEED_BEST_BUFFER = 38


@dataclass(frozen=True)
class Case:
    experiment: str
    strategy: str
    vehicles: int
    seed: int
    orders: int = 150  # pool size (pool runs)
    buffer_s: float | None = None  # None: the configuration's B
    battery: bool = False  # part-charged start, charging policy on
    arrival_s: float = 0.0  # > 0: the generator's arrival for that long instead of a pool
    load: float = 1.0  # arrival: a factor on the seed's rates
    max_s: float = 4000.0
    deadlines: bool = True  # pool runs: keep the generator's latest delivery times
    traffic: str = "reactive"  # the fleet's traffic mode
    top_up_below: float | None = None  # battery runs: idle vehicles charge below it (None: default)
    # two_stage's options (None: the configuration's, the seed's rules by default)
    next_order: bool | None = None
    bottleneck_s: float | None = None

    def variant(self) -> str:
        """The strategy with the options it ran under, as the tables name it."""
        parts = []
        if self.next_order is False:
            parts.append("no next order")
        if self.bottleneck_s:
            parts.append(f"bottleneck {self.bottleneck_s:g} s")
        return f"{self.strategy} ({', '.join(parts)})" if parts else self.strategy


@dataclass
class Result:
    case: Case
    finished: int
    total: int
    mean_order_s: float | None
    station_wait_s: float | None
    makespan_s: float | None
    sim_s: float
    wall_s: float
    charges: int
    charging_s: float
    min_battery: int
    conflicts: int
    top_ups: int | None = None  # (None in the JSON of runs made before they were counted)
    given_up: int | None = None
    chargers: int = 4  # the plant's (runs written before it had a fifth did not say)


def orders_for(case: Case, cfg) -> list[TransportOrder]:
    """The run's orders from the seed's generator, seeded by the case's seed."""
    g = cfg.orders.generator
    plant = cfg.plant
    units = {name: plant.stations_for(f) for name, f in g.units.items()}
    control = plant.stations_for(g.control)[0] if g.control is not None else None
    duration = case.arrival_s or 3600.0
    relations = [type(r)(r.source, r.target, r.rate_per_h * case.load) for r in g.relations]
    orders = generate_orders(relations, units, duration, case.seed, control, window_s=g.window_s)
    if case.arrival_s:
        if case.deadlines:
            return orders
        return [TransportOrder(o.id, o.get, o.put, o.start_s, inf) for o in orders]
    return [
        TransportOrder(o.id, o.get, o.put, start_s=0.0, end_s=o.end_s if case.deadlines else inf)
        for o in orders[: case.orders]
    ]


def run_case(case: Case) -> Result:
    cfg = load_config(CONFIG)
    first_vehicles(cfg, case.vehicles)
    cfg.dispatch.strategy = case.strategy
    cfg.traffic = case.traffic
    if case.buffer_s is not None:
        cfg.dispatch.buffer_s = case.buffer_s
    if case.next_order is not None:
        cfg.dispatch.next_order = case.next_order
    if case.bottleneck_s is not None:
        cfg.dispatch.bottleneck_s = case.bottleneck_s
    cfg.watchdog = 5.0  # a busy machine slows the wall clock, never the virtual one
    orders = orders_for(case, cfg)
    if case.battery:
        rng = random.Random(case.seed)
        cfg.battery.start = {v: rng.uniform(36.0, 70.0) for v in sorted(cfg.starts)}
        if case.top_up_below is not None:
            cfg.battery.top_up_below = case.top_up_below
    else:
        cfg.battery.enabled = False
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "orders.csv"
        write_orders(path, orders)
        cfg.orders.file, cfg.orders.generator = path, None
        if not case.arrival_s:
            cfg.orders.lead_s = 1e9  # a pool: every order known from the start
        program = FleetProgram(cfg)
        try:
            return _run(program, case, len(orders))
        finally:
            program.close()


def _run(program: FleetProgram, case: Case, total: int) -> Result:
    rt, book = program.rt, program.orders.book
    rt.start()
    per_s = round(1.0 / program.cfg.cycle_time)
    end_s = case.arrival_s or case.max_s
    begin = time.perf_counter()
    seconds = 0
    while seconds < end_s:
        rt.run(cycles=per_s)
        seconds += 1
        if rt.state != "RUN":
            raise RuntimeError(f"{case}: the runtime stopped: {rt.fault_reason}")
        if not case.arrival_s and book.counts()["FINISHED"] == total:
            break
    wall = time.perf_counter() - begin
    finished = [o for o in book if o.state is OrderState.FINISHED]
    times = [t for o in finished if (t := execution_s(o)) is not None]
    runners = program.orders.runners.values()
    return Result(
        case=case,
        finished=len(finished),
        total=total,
        mean_order_s=statistics.mean(times) if times else None,
        station_wait_s=statistics.mean(waiting_s(o) for o in finished) if finished else None,
        makespan_s=max(o.finished_s for o in finished) if finished else None,
        sim_s=float(seconds),
        wall_s=wall,
        charges=sum(r.charges for r in runners),
        charging_s=sum(r.charging_s for r in runners),
        min_battery=min(r.min_battery for r in runners),
        conflicts=program.monitor.head_on + program.monitor.node + program.monitor.area,
        top_ups=sum(r.top_ups for r in runners),
        given_up=sum(r.chargers_given_up for r in runners),
        chargers=len(program.cfg.plant.with_role("charger")),
    )


def cases(args: argparse.Namespace) -> list[Case]:
    seeds = range(1, args.seeds + 1)
    out: list[Case] = []
    m, d, tr = args.max_s, not args.no_deadlines, args.traffic
    if "buffer" in args.experiments:
        out += [
            Case("buffer", "two_stage", 17, s, args.pool, b, max_s=m, deadlines=d, traffic=tr)
            for b in args.buffers
            for s in seeds
        ]
    if "fleet" in args.experiments:
        out += [
            Case("fleet", st, n, s, args.pool, max_s=m, deadlines=d, traffic=tr)
            for n in args.fleets
            for st in STRATEGIES
            for s in seeds
        ]
    if "fixed" in args.experiments:
        out += [
            Case("fixed", st, 17, s, args.fixed, max_s=m, deadlines=d, traffic=tr)
            for st in STRATEGIES
            for s in seeds
        ]
        out += [
            Case("fixed", "two_stage", 16, s, args.fixed, max_s=m, deadlines=d, traffic=tr)
            for s in seeds
        ]
    if "battery" in args.experiments:
        out += [
            Case(
                "battery",
                "two_stage",
                17,
                s,
                battery=on,
                arrival_s=args.battery_s,
                load=args.battery_load,
                traffic=tr,
                top_up_below=args.top_up_below,
            )
            for on in (False, True)
            for s in seeds
        ]
    if "arrival" in args.experiments:
        out += [
            Case("arrival", st, 17, s, arrival_s=args.arrival_s, load=load, deadlines=d, traffic=tr)
            for load in args.loads
            for st in STRATEGIES
            for s in seeds
        ]
    options = {"next_order": args.next_order, "bottleneck_s": args.bottleneck_s}
    strategies = set(args.strategies)
    return [
        replace(c, **options) if c.strategy == "two_stage" else c
        for c in out
        if c.experiment in ("buffer", "battery") or c.strategy in strategies
    ]


def spread(values: list[float], fmt: str = "{:.1f}") -> str:
    if not values:
        return "-"
    mean = statistics.mean(values)
    if len(values) == 1:
        return fmt.format(mean)
    return f"{fmt.format(mean)} ({fmt.format(min(values))}-{fmt.format(max(values))})"


def counted(values: list[int | None]) -> str:
    """The spread of a count, blank for runs made before it was counted."""
    if any(v is None for v in values):
        return ""
    return spread([float(v) for v in values], "{:.0f}")  # type: ignore[arg-type]


def group(results: list[Result], **match) -> list[Result]:
    return [r for r in results if all(getattr(r.case, k) == v for k, v in match.items())]


def mean_of(results: list[Result], field: str) -> float:
    values = [getattr(r, field) for r in results if getattr(r, field) is not None]
    return statistics.mean(values) if values else float("nan")


class Table:
    """A markdown table, printed as docs/benchmarks.md records it."""

    def __init__(self, title: str) -> None:
        self.title, self.columns, self.rows = title, [], []

    def add_column(self, name: str, justify: str = "right") -> None:
        self.columns.append(name)

    def add_row(self, *cells: str) -> None:
        self.rows.append(cells)

    def __str__(self) -> str:
        lines = [f"### {self.title}", "", "| " + " | ".join(self.columns) + " |"]
        lines.append("|" + "|".join("---:" for _ in self.columns) + "|")
        lines += ["| " + " | ".join(row) + " |" for row in self.rows]
        return "\n".join(lines) + "\n"


class Console:
    def print(self, text: object) -> None:
        print(text, flush=True)


def report(results: list[Result], args: argparse.Namespace, console: Console) -> None:
    pool = "without deadlines" if args.no_deadlines else "with the generator's deadlines"
    modes = sorted({r.case.traffic for r in results})
    if modes != ["reactive"]:
        pool += f", {' / '.join(modes)} traffic"
    conflicts = sum(r.conflicts for r in results)
    for experiment in {r.case.experiment for r in results} - {"fleet"}:
        mixed = {
            r.case.variant() for r in group(results, experiment=experiment, strategy="two_stage")
        }
        if len(mixed) > 1:
            raise SystemExit(
                f"the {experiment} results mix two_stage run under other options "
                f"({'; '.join(sorted(mixed))}): report them apart"
            )
    if "buffer" in args.experiments:
        t = Table(title=f"1. Buffer sweep: two_stage, 17 vehicles, {args.pool} orders {pool}")
        for c in ("B (s)", "mean order time (s)", "station wait (s)", "makespan (s)", "finished"):
            t.add_column(c, justify="right")
        means = {}
        for b in args.buffers:
            rs = group(results, experiment="buffer", buffer_s=b)
            means[b] = mean_of(rs, "mean_order_s")
            t.add_row(
                f"{b:g}",
                spread([r.mean_order_s for r in rs if r.mean_order_s]),
                spread([r.station_wait_s for r in rs if r.station_wait_s is not None]),
                spread([r.makespan_s for r in rs if r.makespan_s]),
                f"{sum(r.finished for r in rs)}/{sum(r.total for r in rs)}",
            )
        console.print(t)
        best = min(means, key=means.get)
        console.print(
            f"least mean order time at B = {best} s; the seed's: B = {SEED_BEST_BUFFER} s"
        )
    if "fleet" in args.experiments:
        t = Table(
            title=f"2. Fleet size x strategy, {args.pool} orders in the pool {pool}: mean order time (s)"
        )
        fleet = group(results, experiment="fleet")
        ours = sorted({r.case.variant() for r in fleet if r.case.strategy == "two_stage"})
        columns = ["dhht", *(ours or ["two_stage"]), "nearest_idle"]
        for c in ("vehicles", *columns, *(f"{v} / dhht - 1" for v in ours), "seed at 17"):
            t.add_column(c, justify="right")
        for n in args.fleets:
            cells, means = [], {}
            for column in columns:
                rs = [r for r in fleet if r.case.vehicles == n and r.case.variant() == column]
                means[column] = mean_of(rs, "mean_order_s")
                cells.append(spread([r.mean_order_s for r in rs if r.mean_order_s]))
            gaps = [change(means[v], means["dhht"]) for v in ours]
            seed = f"{SEED_GAP_17:+.1%}" if n == 17 else ""
            t.add_row(str(n), *cells, *gaps, seed)
        console.print(t)
    if "fixed" in args.experiments:
        t = Table(title=f"3. Fixed {args.fixed} orders, {pool}")
        for c in (
            "strategy",
            "vehicles",
            "makespan (s)",
            "mean order time (s)",
            "station wait (s)",
            "finished",
        ):
            t.add_column(c, justify="right")
        rows = [(st, 17) for st in STRATEGIES] + [("two_stage", 16)]
        means = {}
        for st, n in rows:
            rs = group(results, experiment="fixed", strategy=st, vehicles=n)
            means[(st, n)] = (mean_of(rs, "makespan_s"), mean_of(rs, "mean_order_s"))
            t.add_row(
                st,
                str(n),
                spread([r.makespan_s for r in rs if r.makespan_s]),
                spread([r.mean_order_s for r in rs if r.mean_order_s]),
                spread([r.station_wait_s for r in rs if r.station_wait_s is not None]),
                f"{sum(r.finished for r in rs)}/{sum(r.total for r in rs)}",
            )
        console.print(t)
        (d_mk, d_mean), (n_mk, n_mean) = means[("dhht", 17)], means[("two_stage", 17)]
        s16 = means[("two_stage", 16)][0]
        console.print(
            f"two_stage / dhht - 1 at 17: makespan {change(n_mk, d_mk)} "
            f"(seed {SEED_MAKESPAN_100:+.2%}), mean order time {change(n_mean, d_mean)} "
            f"(seed {SEED_GAP_100:+.2%}); two_stage with 16 / dhht with 17 - 1: makespan "
            f"{change(s16, d_mk)} (seed {697 / 714 - 1:+.1%})"
        )
    if "battery" in args.experiments:
        t = Table(
            title=f"4. Batteries: two_stage, 17 vehicles, {args.battery_s:.0f} s of arrivals at "
            f"{args.battery_load:g} x the seed's rates, idle vehicles topping up below "
            + f"{ChargePolicy().top_up_below if args.top_up_below is None else args.top_up_below:g} %"
        )
        for c in (
            "batteries",
            "orders finished",
            "mean order time (s)",
            "charger visits",
            "of them topping up",
            "chargers given up",
            "charger use",
            "min battery %",
        ):
            t.add_column(c, justify="right")
        done = {}
        for on in (False, True):
            rs = group(results, experiment="battery", battery=on)
            done[on] = mean_of(rs, "finished")
            use = [r.charging_s / (r.chargers * r.sim_s) for r in rs]
            t.add_row(
                "on (36-70 % at start)" if on else "off",
                spread([float(r.finished) for r in rs], "{:.0f}"),
                spread([r.mean_order_s for r in rs if r.mean_order_s]),
                spread([float(r.charges) for r in rs], "{:.0f}"),
                counted([r.top_ups for r in rs]),
                counted([r.given_up for r in rs]),
                spread([100 * u for u in use], "{:.0f} %"),
                spread([float(r.min_battery) for r in rs], "{:.0f}"),
            )
        console.print(t)
        console.print(
            f"throughput lost to charging: {1 - done[True] / done[False]:.1%} (goal < 5 %)"
        )
    if "arrival" in args.experiments:
        arrival_table(results, args, console)
    console.print(f"conflicts seen by the independent monitor in all runs: {conflicts}")


def arrival_table(results: list[Result], args: argparse.Namespace, console: Console) -> None:
    """Experiment 5: per load, each strategy's orders finished and mean order time, and
    two_stage against dhht on both (finished: more is better). Loads and run length are
    the results' own, so a ``--report`` of earlier runs shows them as they were made."""
    runs = group(results, experiment="arrival")
    lengths = sorted({r.case.arrival_s for r in runs})
    lead = load_config(CONFIG).orders.lead_s
    t = Table(
        title=f"5. Steady arrival: 17 vehicles, {' / '.join(f'{x:.0f}' for x in lengths)} s of "
        f"the generator's orders (each known {lead:.0f} s before its start)"
    )
    columns = ["x seed's rates", "orders"]
    for st in STRATEGIES:
        columns += [f"{st} finished", f"{st} mean order time (s)"]
    for c in (*columns, "two_stage / dhht - 1: mean order time", "finished"):
        t.add_column(c)
    for load in sorted({r.case.load for r in runs}):
        cells, means, done = [], {}, {}
        rs = group(runs, load=load)
        for st in STRATEGIES:
            mine = group(rs, strategy=st)
            means[st], done[st] = mean_of(mine, "mean_order_s"), mean_of(mine, "finished")
            cells += [
                spread([float(r.finished) for r in mine], "{:.0f}"),
                spread([r.mean_order_s for r in mine if r.mean_order_s]),
            ]
        t.add_row(
            f"{load:g}",
            f"{mean_of(rs, 'total'):.0f}",
            *cells,
            change(means["two_stage"], means["dhht"]),
            change(done["two_stage"], done["dhht"]),
        )
    console.print(t)


def change(value: float, base: float) -> str:
    """``value / base - 1`` as a signed percentage; "-" where either is missing or base is 0."""
    if not base or isnan(base) or isnan(value):
        return "-"
    return f"{value / base - 1:+.1%}"


def loaded(item: dict) -> Result:
    """A Result from its --json form."""
    fields = dict(item)
    return Result(**{**fields, "case": Case(**fields["case"])})


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--experiments",
        nargs="+",
        choices=("buffer", "fleet", "fixed", "battery", "arrival"),
        default=["buffer", "fleet", "fixed", "battery", "arrival"],
    )
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--fleets", type=int, nargs="+", default=list(FLEETS))
    parser.add_argument("--buffers", type=float, nargs="+", default=list(BUFFERS))
    parser.add_argument("--jobs", type=int, default=2, help="runs in parallel (processes)")
    parser.add_argument("--max-s", type=float, default=4000.0, help="simulated time cap per run")
    parser.add_argument("--battery-s", type=float, default=3600.0)
    parser.add_argument("--battery-load", type=float, default=0.5, help="x the seed's rates")
    parser.add_argument(
        "--top-up-below",
        type=float,
        default=None,
        help="battery runs: idle vehicles charge by choice below this %% (default: 10 below full)",
    )
    parser.add_argument(
        "--arrival-s",
        type=float,
        default=3600.0,
        help="arrival runs' length in simulated s (--max-s is for pool runs)",
    )
    parser.add_argument(
        "--loads", type=float, nargs="+", default=list(LOADS), help="arrival: x the seed's rates"
    )
    parser.add_argument(
        "--no-deadlines",
        action="store_true",
        help="pool and arrival runs: orders without a latest delivery time (none is ever late)",
    )
    parser.add_argument(
        "--traffic",
        choices=("reactive", "time_windows"),
        default="reactive",
        help="the fleet's traffic mode in every run (default: reactive)",
    )
    parser.add_argument(
        "--pool", type=int, default=150, help="orders in the pool of the buffer and fleet runs"
    )
    parser.add_argument(
        "--strategies",
        nargs="+",
        choices=STRATEGIES,
        default=list(STRATEGIES),
        help="the strategies the fleet, fixed and arrival experiments run",
    )
    parser.add_argument(
        "--next-order",
        choices=("on", "off"),
        help="two_stage: give a busy vehicle its next order ahead (on, the seed's) or only "
        "once it is free (default: the configuration's)",
    )
    parser.add_argument(
        "--bottleneck-s",
        type=float,
        help="two_stage: the weight of the pool's busiest stations (default: the configuration's)",
    )
    parser.add_argument("--json", type=Path, help="also write every run's result here")
    parser.add_argument(
        "--report",
        type=Path,
        nargs="+",
        help="print the tables of results written earlier with --json instead of running",
    )
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    args.fixed = 100
    args.next_order = None if args.next_order is None else args.next_order == "on"
    if args.quick:
        args.seeds, args.pool, args.fixed = 1, 20, 20
        args.buffers, args.fleets, args.battery_s = (8, 38), (17,), 300.0
        args.arrival_s, args.loads = 300.0, (0.5,)
    console = Console()
    begin = time.perf_counter()
    if args.report:
        results = [loaded(item) for path in args.report for item in json.loads(path.read_text())]
        args.experiments = [e for e in args.experiments if group(results, experiment=e)]
    else:
        todo = cases(args)
        console.print(f"{len(todo)} runs on {args.jobs} processes ...")
        with ProcessPoolExecutor(args.jobs) as pool:
            results = []
            for k, r in enumerate(pool.map(run_case, todo), start=1):
                results.append(r)
                c = r.case
                console.print(
                    f"  run {k}/{len(todo)}: {c.experiment} {c.strategy} {c.vehicles} vehicles "
                    f"seed {c.seed}: {r.finished}/{r.total} finished in {r.sim_s:.0f} s "
                    f"simulated, {r.wall_s:.0f} s wall"
                )
    report(results, args, console)
    if args.json:
        args.json.write_text(
            json.dumps([asdict(r) for r in results], indent=1, default=str), encoding="utf-8"
        )
    console.print(f"wall time {time.perf_counter() - begin:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
