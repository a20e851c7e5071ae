"""Virtual-time scan rate: scans per second with 1, 10, 100 and 1000 trivial blocks.

Baseline, in the same process: a bare Python loop calling the same blocks' ``cycle``
directly (no image copy, no scheduling, no statistics, no watchdog), i.e. the cost of the
blocks alone. The ratio shows what the runtime's scan machinery costs on top.

The full run takes about 30 s; ``--quick`` measures 0.1 s per run instead of 1 s (about
5 s in all), enough to see the same ratios, with more noise.

    .venv/bin/python bench/step_rate.py [--seconds 1.0] [--quick]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from plc_runtime import FunctionBlock, Runtime, Static, VirtualClock  # noqa: E402

# --quick lowers these defaults; options given on the command line still win.
QUICK = {"seconds": 0.1}


class Trivial(FunctionBlock):
    n = Static(0)

    def cycle(self, ctx) -> None:
        self.n += 1


def timed(fn, seconds: float) -> float:
    """Calls per second of ``fn(batch)``, best of three runs of about ``seconds`` each."""
    batch = 1
    while True:  # find a batch that takes ~seconds/10
        t = time.perf_counter()
        fn(batch)
        if time.perf_counter() - t > seconds / 10:
            break
        batch *= 2
    best = 0.0
    for _ in range(3):
        reps = 0
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            fn(batch)
            reps += batch
        best = max(best, reps / (time.perf_counter() - t0))
    return best


def runtime_rate(n_blocks: int, seconds: float) -> float:
    rt = Runtime(cycle_time=0.001, clock=VirtualClock(), watchdog_interrupt=True)
    rt.add_task("main", [Trivial() for _ in range(n_blocks)])
    rt.start()
    rate = timed(rt.step, seconds)
    assert rt.state == "RUN", rt.fault_reason
    rt.stop()
    return rate


def bare_rate(n_blocks: int, seconds: float) -> float:
    blocks = [Trivial() for _ in range(n_blocks)]

    def loop(count: int) -> None:
        for _ in range(count):
            for block in blocks:
                block.cycle(None)

    return timed(loop, seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=1.0, help="measuring time per run")
    parser.add_argument("--quick", action="store_true", help="reduced run: --seconds 0.1")
    args = parser.parse_args()
    if args.quick:
        parser.set_defaults(**QUICK)
        args = parser.parse_args()
    begin = time.perf_counter()
    print(
        f"Virtual-clock scans per second (best of 3 x {args.seconds:g} s), Python {sys.version.split()[0]}"
    )
    print()
    print(
        "| trivial FBs | runtime scans/s | bare loop scans/s | runtime / bare | runtime us/scan |"
    )
    print("|---:|---:|---:|---:|---:|")
    for n in (1, 10, 100, 1000):
        rt, bare = runtime_rate(n, args.seconds), bare_rate(n, args.seconds)
        print(f"| {n} | {rt:,.0f} | {bare:,.0f} | {rt / bare:.2f} | {1e6 / rt:.1f} |")
    print()
    print(f"wall time {time.perf_counter() - begin:.1f} s")


if __name__ == "__main__":
    main()
