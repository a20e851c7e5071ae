"""Wall-clock scan lateness (jitter) of the runtime at 10 ms and 1 ms cycles.

Lateness = actual start of a scan minus its release time on the absolute grid
``t0 + k * cycle``. Modes: the runtime on ``WallClock()`` (sleep to deadline),
``WallClock(spin=...)`` (sleep, then spin the tail), and rt mode (SCHED_FIFO, 1 ns timer
slack, GC in idle slack; reported as unavailable where the OS refuses it), with and
without spin. Baseline, in the same process: the naive loop many soft-PLCs started with,
``work(); time.sleep(cycle)``, whose lateness against the same grid grows with every
cycle (drift). Ratios are p99 lateness over the baseline's p99.

The run lasts what its cycles last: 5 rows of 2000 cycles at 10 ms and at 1 ms, about
2 minutes. ``--quick`` runs 200 cycles per row (about 12 s): p99 and max then rest on a
few samples, and the baseline has drifted a tenth as far.

    .venv/bin/python bench/scan_jitter.py [--cycles 2000] [--spin-ms 0.5] [--quick]
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from plc_runtime import FunctionBlock, Runtime, Static, WallClock  # noqa: E402

# --quick lowers these defaults; options given on the command line still win.
QUICK = {"cycles": 200}


class Trivial(FunctionBlock):
    n = Static(0)

    def cycle(self, ctx) -> None:
        self.n += 1


def naive_relative_sleep(cycle: float, cycles: int) -> np.ndarray:
    block = Trivial()
    starts = np.zeros(cycles, dtype=np.int64)
    t0 = time.monotonic_ns()
    for k in range(cycles):
        starts[k] = time.monotonic_ns()
        block.cycle(None)
        time.sleep(cycle)
    return starts - (t0 + np.arange(cycles, dtype=np.int64) * round(cycle * 1e9))


def runtime_lateness(
    cycle: float, cycles: int, clock: WallClock
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Lateness at task start and at tick start, and the clock's status, for one mode."""
    rt = Runtime(cycle_time=cycle, clock=clock, watchdog=1.0)
    rt.add_task("main", [Trivial() for _ in range(10)], overrun="catch_up")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rt.start()
        rt.run(cycles=cycles)
        status = rt.clock.status()
        task_late = rt.stats["main"].lateness_ns()
        tick_late = rt.stats.scan.lateness_ns()
        rt.stop()
    status["warnings"] = [str(w.message) for w in caught]
    return task_late, tick_late, status


def percentiles_us(late_ns: np.ndarray) -> tuple[float, float, float]:
    us = late_ns / 1e3
    return float(np.percentile(us, 50)), float(np.percentile(us, 99)), float(us.max())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=2000)
    parser.add_argument("--spin-ms", type=float, default=0.5, help="spin tail for the spin modes")
    parser.add_argument("--quick", action="store_true", help="reduced run: --cycles 200")
    args = parser.parse_args()
    if args.quick:
        parser.set_defaults(**QUICK)
        args = parser.parse_args()
    begin = time.perf_counter()
    spin = args.spin_ms / 1e3
    print(
        f"Lateness in us over {args.cycles} cycles each, 10 trivial FBs, Python {sys.version.split()[0]}"
    )
    print()
    print(
        "| cycle | mode | task start p50 | p99 | max | tick start p50 | p99 | p99 / baseline p99 | note |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|---|")
    for cycle in (0.010, 0.001):
        base = naive_relative_sleep(cycle, args.cycles)
        p50, p99, mx = percentiles_us(base)
        base_p99 = p99
        drift = f"drift after {args.cycles} cycles: {base[-1] / 1e6:.1f} ms"
        print(
            f"| {cycle * 1e3:g} ms | baseline: work(); sleep(cycle) | {p50:,.1f} | {p99:,.1f} | {mx:,.1f} | - | - | 1 | {drift} |"
        )
        modes = [
            ("sleep to deadline", WallClock()),
            (f"sleep + spin {args.spin_ms:g} ms", WallClock(spin=spin)),
            ("rt mode", WallClock(rt=True)),
            (f"rt mode + spin {args.spin_ms:g} ms", WallClock(spin=spin, rt=True)),
        ]
        for name, clock in modes:
            task_late, tick_late, status = runtime_lateness(cycle, args.cycles, clock)
            note = "; ".join(status["warnings"])
            if clock.rt and not note:
                note = f"SCHED_FIFO {status.get('sched_fifo')}, slack {status.get('timer_slack')}"
            p50, p99, mx = percentiles_us(task_late)
            t50, t99, _ = percentiles_us(tick_late)
            print(
                f"| {cycle * 1e3:g} ms | {name} | {p50:,.1f} | {p99:,.1f} | {mx:,.1f} | {t50:,.1f} | {t99:,.1f} "
                f"| {p99 / base_p99:.5f} | {note} |"
            )
    print()
    print(f"wall time {time.perf_counter() - begin:.1f} s")


if __name__ == "__main__":
    main()
