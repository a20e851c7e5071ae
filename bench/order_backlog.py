"""A backlog of orders: what a large order file costs the scan.

A warehouse system may hand the fleet tens of thousands of orders at once. The fleet
program then releases them into the order book a bounded number per scan
(``fleet.order_system.RELEASE_BUDGET``), and each allocation round takes its pool, the
``pool_limit`` most urgent waiting orders, from an urgency index
(``blocks/dispatch/urgent_orders.py``) instead of sorting every waiting order.

Each run is the whole fleet program on the virtual clock on the sample distribution
centre (``examples/distribution-centre.toml``, 17 shuttles), its generator replaced by an
order file of ``N`` orders all due at the first scan (seeded stations, latest delivery
times spread over the hour), for ``--after-s`` simulated seconds after the last order is
released. Measured, in wall time:

* every scan while the orders are released, and every scan afterwards (p50 / p99 / max,
  the time the watchdog measures), beside the cycle time;
* the interpreter's full garbage collections during the run: their number and the
  longest. They take as long as the objects alive are many (a backlog of 100,000 orders
  is about 700,000), whatever the scan does; the runtime makes them between scans
  (``Runtime(gc_full_between_scans=True)``, the default; ``--python-gc``: Python's own,
  which lands in a scan). The watchdog is 5 s here, as in the other fleet benches, so
  that a run with Python's collections goes on to be measured;
* every pool a round takes, from the index (ours) and, at the same moment on the same
  book, as the plain definition gives it: sort the waiting orders (the startable ones for
  dhht) by urgency and take the first ``pool_limit`` (the baseline). The two must be the
  same orders in the same order; the bench stops if they differ;
* the sweep of final orders out of a book of N (every other order final, the oldest
  first, ``SWEEP_BUDGET`` a call, as a scan sweeps): microseconds per order taken out of
  the book, against the same book keeping its positions in a plain sorted list (the
  baseline: each order taken out moves every later position). Both must sweep the same
  orders and leave the same pages; the bench stops if they do not.

    .venv/bin/python bench/order_backlog.py [--orders 1000 10000 100000]
        [--strategies two_stage dhht] [--after-s 300] [--python-gc] [--quick]

``--quick``: 1,000 and 10,000 orders, 10 s after the release: a check that it runs.
"""

from __future__ import annotations

import argparse
import bisect
import gc
import heapq
import random
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from blocks.dispatch.dispatcher import Dispatcher  # noqa: E402
from blocks.dispatch.order_file import write_orders  # noqa: E402
from blocks.dispatch.orders import OrderBook, TransportOrder  # noqa: E402
from blocks.dispatch.urgent_orders import urgency  # noqa: E402
from fleet.config import load_config  # noqa: E402
from fleet.order_system import RELEASE_BUDGET, SWEEP_BUDGET, order_stations  # noqa: E402
from fleet.program import FleetProgram  # noqa: E402
from plc_runtime.cli import positive  # noqa: E402

CONFIG = ROOT / "examples" / "distribution-centre.toml"
SEED = 1


@dataclass
class Result:
    orders: int
    strategy: str
    release_scans: int
    release_ms: list[float]
    after_ms: list[float]
    pool_ms: list[float]  # ours, per round
    sort_ms: list[float]  # the baseline, per round
    cycle_ms: float
    full_gc_ms: list[float]
    faults: int
    fault_reason: str | None = None


def backlog(cfg, n: int) -> list[TransportOrder]:
    """``n`` orders due at once between the plant's Get/Put stations, seeded."""
    rng = random.Random(SEED)
    stations = sorted(order_stations(cfg.plant))
    out = []
    for k in range(n):
        get, put = rng.sample(stations, 2)
        out.append(TransportOrder(f"b{k}", get, put, 0.0, rng.uniform(900.0, 3600.0)))
    return out


def timed_pools(
    dispatcher: Dispatcher, ours: list[float], sort: list[float], in_scan: list[float]
) -> None:
    """Time every pool the dispatcher takes, and the plain sort at the same moment (added
    to ``in_scan[0]``, which the scan's time leaves out)."""
    take = dispatcher._pool

    def pool(ctx, vehicles):
        begin = time.perf_counter()
        waiting = dispatcher.book.dispatchable()
        if dispatcher.strategy != "two_stage":
            waiting = [o for o in waiting if o.start_s <= ctx.time]
        servable = [o for o in waiting if dispatcher._servable(o, vehicles)] if vehicles else []
        plain = heapq.nsmallest(dispatcher.pool_limit, servable, key=urgency)
        middle = time.perf_counter()
        got = take(ctx, vehicles)
        end = time.perf_counter()
        if [o.id for o in got] != [o.id for o in plain]:
            raise SystemExit(
                f"order_backlog.py: the index's pool differs from the sort at {ctx.time} s"
            )
        sort.append((middle - begin) * 1e3)
        in_scan[0] += sort[-1]
        ours.append((end - middle) * 1e3)
        return got

    dispatcher._pool = pool


def run(n: int, strategy: str, after_s: float, python_gc: bool = False) -> Result:
    cfg = load_config(CONFIG)
    cfg.gc_full_between_scans = not python_gc
    cfg.dispatch.strategy = strategy
    cfg.battery.enabled = False
    cfg.watchdog = 5.0  # a busy machine, or the collector, slows the wall clock only
    orders = backlog(cfg, n)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "orders.csv"
        write_orders(path, orders)
        cfg.orders.file, cfg.orders.generator = path, None
        program = FleetProgram(cfg)
        try:
            return _run(program, n, strategy, after_s)
        finally:
            program.close()


def _run(program: FleetProgram, n: int, strategy: str, after_s: float) -> Result:
    rt = program.rt
    ours: list[float] = []
    sort: list[float] = []
    baseline_in_scan = [0.0]
    timed_pools(program.orders.dispatcher, ours, sort, baseline_in_scan)
    full_gc: list[float] = []
    started: list[float] = []

    def collector(phase: str, info: dict) -> None:
        if info["generation"] != 2:
            return
        if phase == "start":
            started.append(time.perf_counter())
        elif started:
            full_gc.append((time.perf_counter() - started.pop()) * 1e3)

    gc.callbacks.append(collector)
    try:
        rt.start()
        release, after, faults = _scans(program, n, after_s, baseline_in_scan)
    finally:
        gc.callbacks.remove(collector)
    return Result(
        n,
        strategy,
        len(release),
        release,
        after,
        ours,
        sort,
        program.cfg.cycle_time * 1e3,
        full_gc,
        faults,
        rt.fault_reason,
    )


def _scans(program: FleetProgram, n: int, after_s: float, baseline: list[float]):
    """Step the scans; the wall ms of each while releasing and after (the baseline's sort
    left out), and faults."""
    rt, book = program.rt, program.orders.book
    release: list[float] = []
    after: list[float] = []
    faults = 0
    after_scans = round(after_s / program.cfg.cycle_time)
    while len(after) < after_scans:
        releasing = len(book) < n
        baseline[0] = 0.0
        rt.step()
        # the scan under the watchdog (a collection after it is not in it)
        took = rt.stats.scan.exec_last_ns / 1e6 - baseline[0]
        (release if releasing else after).append(took)
        if rt.state != "RUN":
            faults += 1
            break
    return release, after, faults


class ListPositions(list):
    """The baseline's positions: a plain ascending list, as the book kept them before, with
    the calls the book makes of its sorted list."""

    def add(self, position: int) -> None:
        self.insert(bisect.bisect_right(self, position), position)

    def remove(self, position: int) -> None:
        del self[bisect.bisect_left(self, position)]

    def bisect_left(self, position: int) -> int:
        return bisect.bisect_left(self, position)

    def islice(self, start: int, stop: int) -> list[int]:
        return self[start:stop]


@dataclass
class SweepResult:
    orders: int
    swept: int
    ours_us: float  # per order taken out
    list_us: float


def swept_book(n: int, positions: type | None) -> tuple[OrderBook, float]:
    """A book of ``n`` orders, every other one withdrawn (final) at 0 s, swept at
    ``keep_final_s``, ``SWEEP_BUDGET`` a call; the wall seconds the sweeps took."""
    book = OrderBook({1: "a", 2: "b"}, keep_final_s=60.0)
    if positions is not None:
        book._positions = positions()
    for k in range(n):
        book.add(TransportOrder(f"o{k}", 1, 2, 0.0, 3600.0), 0.0)
        if k % 2 == 0:
            book.withdraw(f"o{k}", 0.0)
    took = 0.0
    while True:
        begin = time.perf_counter()
        out = book.sweep(60.0, SWEEP_BUDGET)
        took += time.perf_counter() - begin
        if not out:
            return book, took


def sweep_costs(n: int) -> SweepResult:
    ours, ours_s = swept_book(n, None)
    plain, list_s = swept_book(n, ListPositions)
    if ours.swept != plain.swept or any(
        [o.id for o in ours.page(k, 100)] != [o.id for o in plain.page(k, 100)]
        for k in range(0, n, max(n // 50, 1))
    ):
        raise SystemExit(f"order_backlog.py: the sweeps of {n:,} orders differ")
    return SweepResult(n, ours.swept, ours_s / ours.swept * 1e6, list_s / plain.swept * 1e6)


def quantiles(values: list[float]) -> str:
    if not values:
        return "-"
    ordered = sorted(values)
    p99 = ordered[min(len(ordered) - 1, round(0.99 * (len(ordered) - 1)))]
    return f"{statistics.median(ordered):.2f} / {p99:.2f} / {ordered[-1]:.2f}"


COLUMNS = (
    "orders",
    "strategy",
    "release scans",
    "scan while releasing p50 / p99 / max",
    "scan after p50 / p99 / max",
    "rounds",
    "pool: ours mean / max",
    "pool: plain sort mean / max",
    "sort / ours",
    "cycle",
    "full collections: n / longest",
    "faults",
)


def report(results: list[Result]) -> None:
    print("A backlog of orders on the distribution centre, 17 shuttles (wall ms)")
    print()
    print("| " + " | ".join(COLUMNS) + " |")
    print("|" + "|".join("---:" for _ in COLUMNS) + "|")
    for r in results:
        ratio = statistics.mean(r.sort_ms) / statistics.mean(r.pool_ms) if r.pool_ms else None
        cells = (
            f"{r.orders:,}",
            r.strategy,
            f"{r.release_scans}",
            quantiles(r.release_ms),
            quantiles(r.after_ms),
            f"{len(r.pool_ms)}",
            f"{statistics.mean(r.pool_ms):.3f} / {max(r.pool_ms):.3f}" if r.pool_ms else "-",
            f"{statistics.mean(r.sort_ms):.3f} / {max(r.sort_ms):.3f}" if r.sort_ms else "-",
            "-" if ratio is None else f"{ratio:.0f}" if ratio >= 10 else f"{ratio:.2f}",
            f"{r.cycle_ms:.0f}",
            f"{len(r.full_gc_ms)} / {max(r.full_gc_ms, default=0.0):.1f}",
            f"{r.faults}",
        )
        print("| " + " | ".join(cells) + " |")
    print()
    print(f"release budget: {RELEASE_BUDGET} orders a scan; every pool matched the sort's")


SWEEP_COLUMNS = (
    "orders in the book",
    "swept",
    "us per order swept: ours",
    "plain sorted list",
    "ours / plain",
)


def report_sweeps(results: list[SweepResult]) -> None:
    print()
    print(f"Sweeping final orders out of the book, {SWEEP_BUDGET} a call (wall us per order)")
    print()
    print("| " + " | ".join(SWEEP_COLUMNS) + " |")
    print("|" + "|".join("---:" for _ in SWEEP_COLUMNS) + "|")
    for r in results:
        cells = (
            f"{r.orders:,}",
            f"{r.swept:,}",
            f"{r.ours_us:.2f}",
            f"{r.list_us:.2f}",
            f"{r.ours_us / r.list_us:.2f}",
        )
        print("| " + " | ".join(cells) + " |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--orders", type=positive(int), nargs="+", default=[1_000, 10_000, 100_000])
    parser.add_argument(
        "--strategies",
        nargs="+",
        choices=("two_stage", "dhht", "nearest_idle"),
        default=["two_stage", "dhht"],
    )
    parser.add_argument(
        "--after-s", type=positive(float), default=300.0, help="simulated s after the release"
    )
    parser.add_argument(
        "--python-gc",
        action="store_true",
        help="Python's own full collections, in whichever scan (not between scans)",
    )
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    if args.quick:
        args.orders, args.after_s = [1_000, 10_000], 10.0
    begin = time.perf_counter()
    results = []
    for n in args.orders:
        for strategy in args.strategies:
            results.append(run(n, strategy, args.after_s, args.python_gc))
            print(f"  {n:,} orders, {strategy}: done", flush=True)
    report(results)
    report_sweeps([sweep_costs(n) for n in args.orders])
    print(f"wall time {time.perf_counter() - begin:.0f} s")
    faulted = [f"{r.orders:,} orders, {r.strategy}: {r.fault_reason}" for r in results if r.faults]
    if faulted:  # a faulted run measured nothing: not a result to record
        print("order_backlog.py: the runtime faulted: " + "; ".join(faulted), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
