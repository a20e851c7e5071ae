"""A long run: does the controller's memory grow with the time it runs?

A controller on a plant runs for months. Whatever it keeps per order, per task or per
node driven must leave again, or its memory grows until the machine runs out. This bench
runs the sample distribution centre (``examples/distribution-centre.toml``, 17 shuttles,
its generator stretched over the whole run at ``--scale`` times the seed's 420 orders an
hour: 0.5 by default, a load the fleet keeps up with, so that open orders do not pile up)
on the virtual clock for ``--hours`` simulated hours, twice: final orders kept for ever (the baseline:
every order of the run stays in the book) and kept ``--keep-s`` seconds after they end
(``[orders] keep_final_s``; the default keeps them a day, too long to show in a short run).

Per ``--every-s`` of simulated time it prints the orders finished, the orders in the book
and the memory the Python objects allocated since the start hold (``tracemalloc``: what
the program keeps, not what the allocator has not given back yet); at the end, the growth
per simulated hour over the second half of the run, each run's and the baseline's, and
their ratio.

    .venv/bin/python bench/long_run.py [--hours 4] [--keep-s 1800] [--every-s 1800]
        [--scale 0.5]

``--quick``: 0.1 simulated hours, orders kept 120 s, a line every 120 s.
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import math
import sys
import time
import tracemalloc
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from fleet.config import load_config  # noqa: E402
from fleet.program import FleetProgram  # noqa: E402

CONFIG = ROOT / "examples" / "distribution-centre.toml"


@dataclasses.dataclass
class Sample:
    hours: float
    finished: int
    in_book: int
    mib: float


def run(hours: float, keep_s: float, every_s: float, scale: float) -> list[Sample]:
    cfg = load_config(CONFIG)
    cfg.orders.generator = dataclasses.replace(
        cfg.orders.generator, duration_s=hours * 3600, scale=scale
    )
    cfg.orders.keep_final_s = keep_s
    cfg.watchdog = 10.0  # tracemalloc slows every scan: the watchdog is not what is measured
    program = FleetProgram(cfg)
    samples = []
    try:
        program.rt.start()
        gc.collect()
        tracemalloc.start()
        base = tracemalloc.get_traced_memory()[0]
        done = 0.0
        while done < hours * 3600 - 1e-9:
            step = min(every_s, hours * 3600 - done)
            program.rt.run(duration=step)
            done += step
            if program.rt.state != "RUN":
                raise SystemExit(f"the run stopped at {done:.0f} s: {program.rt.fault_reason}")
            gc.collect()
            book = program.orders.book
            held = (tracemalloc.get_traced_memory()[0] - base) / 2**20
            samples.append(Sample(done / 3600, book.counts()["FINISHED"], len(book), held))
    finally:
        tracemalloc.stop()
        program.close()
    return samples


def growth_per_hour(samples: list[Sample]) -> float:
    """MiB per simulated hour over the second half of the run (the first fills the book)."""
    half = samples[len(samples) // 2 :]
    if len(half) < 2:
        half = samples[-2:]
    first, last = half[0], half[-1]
    return (last.mib - first.mib) / max(last.hours - first.hours, 1e-9)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=4.0)
    ap.add_argument("--keep-s", type=float, default=1800.0)
    ap.add_argument("--every-s", type=float, default=1800.0)
    ap.add_argument("--scale", type=float, default=0.5, help="x the seed's order rates")
    ap.add_argument("--quick", action="store_true", help="0.1 h, kept 120 s, a line each 120 s")
    args = ap.parse_args()
    if args.quick:
        args.hours, args.keep_s, args.every_s = 0.1, 120.0, 120.0
    begin = time.perf_counter()
    runs = {
        "for ever (baseline)": run(args.hours, math.inf, args.every_s, args.scale),
        f"{args.keep_s:g} s": run(args.hours, args.keep_s, args.every_s, args.scale),
    }
    print(
        f"distribution centre, 17 shuttles, {args.scale:g} x the seed's order rates, "
        f"{args.hours:g} simulated h; memory: Python "
        "objects allocated since the start and still held (tracemalloc)\n"
    )
    print("| final orders kept | simulated h | orders finished | orders in the book | MiB held |")
    print("|---|---:|---:|---:|---:|")
    for name, samples in runs.items():
        for s in samples:
            print(f"| {name} | {s.hours:.2f} | {s.finished} | {s.in_book} | {s.mib:.2f} |")
    (base_name, base), (name, kept) = runs.items()
    base_rate, rate = growth_per_hour(base), growth_per_hour(kept)
    print("\n| final orders kept | MiB per simulated h (second half) | / baseline |")
    print("|---|---:|---:|")
    print(f"| {base_name} | {base_rate:.3f} | 1.00 |")
    ratio = rate / base_rate if base_rate > 0 else math.nan
    print(f"| {name} | {rate:.3f} | {ratio:.2f} |")
    print(f"\nwall time {time.perf_counter() - begin:.0f} s")


if __name__ == "__main__":
    main()
