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
        [--scale 0.5] [--sites N] [--jobs 2]

Each sample is also printed on stderr as it is measured, so a run of many hours shows its
course (and what it measured if it is stopped). ``--jobs 2`` runs the baseline and the kept
run in two processes at once, for half the wall time on two cores; the results are the same.

``--sites N``: also where the memory that grew over the second half of the kept run was
allocated, the N sites that grew most, each as its innermost frames in the project (what
allocated it, not what holds it: a record of node ids shows as the code that decoded the
ids). Tracing the frames makes the run about twice as slow.

``--quick``: 0.1 simulated hours, orders kept 120 s, a line every 120 s.
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import math
import multiprocessing
import sys
import time
import tracemalloc
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from fleet.config import load_config  # noqa: E402
from fleet.order_report import energy_summary  # noqa: E402
from fleet.program import FleetProgram  # noqa: E402

CONFIG = ROOT / "examples" / "distribution-centre.toml"
FRAMES = 10  # frames traced per allocation with --sites: enough to reach the project's code
SHOWN_FRAMES = 3  # of those, the innermost ones in the project, printed per site


@dataclasses.dataclass
class Sample:
    hours: float
    finished: int
    in_book: int
    mib: float


def show(name: str, s: Sample) -> None:
    """One sample on stderr, as it is measured."""
    print(
        f"[{name}] {s.hours:.2f} h: {s.finished} finished, {s.in_book} in the book, "
        f"{s.mib:.2f} MiB",
        file=sys.stderr,
        flush=True,
    )


@dataclasses.dataclass
class Site:
    frames: str  # "file:line <- file:line ...", innermost first
    grown_kib: float
    blocks: int


def run(
    name: str, hours: float, keep_s: float, every_s: float, scale: float, sites: int = 0
) -> tuple[list[Sample], list[Site], dict]:
    cfg = load_config(CONFIG)
    cfg.orders.generator = dataclasses.replace(
        cfg.orders.generator, duration_s=hours * 3600, scale=scale
    )
    cfg.orders.keep_final_s = keep_s
    cfg.watchdog = 10.0  # tracemalloc slows every scan: the watchdog is not what is measured
    program = FleetProgram(cfg)
    samples = []
    halfway = None
    grown: list[Site] = []
    total_s = hours * 3600
    count = max(math.ceil(total_s / every_s - 1e-9), 1)  # samples: one per --every-s
    # the sample growth_per_hour measures from, so that the sites grew over the same span
    half_index = half_start(count)
    try:
        program.rt.start()
        gc.collect()
        tracemalloc.start(FRAMES if sites else 1)
        base = tracemalloc.get_traced_memory()[0]
        for k in range(count):
            done = min((k + 1) * every_s, total_s)
            program.rt.run(duration=done - min(k * every_s, total_s))
            if program.rt.state != "RUN":
                raise SystemExit(f"the run stopped at {done:.0f} s: {program.rt.fault_reason}")
            gc.collect()
            book = program.orders.book
            held = (tracemalloc.get_traced_memory()[0] - base) / 2**20
            samples.append(Sample(done / 3600, book.counts()["FINISHED"], len(book), held))
            show(name, samples[-1])
            if sites and k == half_index:
                halfway = tracemalloc.take_snapshot()
        if sites and halfway is not None:
            grown = grown_sites(halfway, tracemalloc.take_snapshot(), sites)
        energy = energy_summary(program.orders)
    finally:
        tracemalloc.stop()
        program.close()
    return samples, grown, energy


def _child(conn, args: tuple) -> None:
    """One run in a forked process: its samples and sites back as plain tuples, with its
    batteries' energy balance, or the reason it stopped."""
    try:
        samples, sites, energy = run(*args)
        conn.send(
            (
                [dataclasses.astuple(s) for s in samples],
                [dataclasses.astuple(s) for s in sites],
                energy,
            )
        )
    except BaseException as exc:  # noqa: BLE001 - any failure goes back to the parent
        conn.send(str(exc) or type(exc).__name__)
    finally:
        conn.close()


def run_all(runs: list[tuple], jobs: int) -> list[tuple[list[Sample], list[Site], dict]]:
    """The runs (``run``'s arguments each), one after another or ``jobs`` at a time in
    forked processes; the results in the order given either way."""
    if jobs <= 1:
        return [run(*args) for args in runs]
    ctx = multiprocessing.get_context("fork")
    out: list = []
    for first in range(0, len(runs), jobs):
        started = []
        for args in runs[first : first + jobs]:
            parent, child = ctx.Pipe(duplex=False)
            proc = ctx.Process(target=_child, args=(child, args))
            proc.start()
            child.close()
            started.append((proc, parent))
        for proc, parent in started:
            try:
                got = parent.recv()
            except EOFError:
                got = "the run's process ended without a result"
            proc.join()
            if isinstance(got, str):
                for other, _ in started:
                    other.kill()
                    other.join()
                raise SystemExit(got)
            samples, sites, energy = got
            out.append(([Sample(*s) for s in samples], [Site(*s) for s in sites], energy))
    return out


def _ours(filename: str) -> bool:
    """A file of the project's own source (its virtual environment's libraries are not)."""
    path = Path(filename)
    return path.is_relative_to(ROOT) and not path.is_relative_to(ROOT / ".venv")


def grown_sites(before: tracemalloc.Snapshot, after: tracemalloc.Snapshot, n: int) -> list[Site]:
    """The ``n`` allocation sites whose held memory grew most between the snapshots, each
    named by its innermost frames in the project's source (outside it, a site is only a
    library's line)."""
    out = []
    # compare_to orders by the size of the change, shrinking sites too: only growth counts
    stats = sorted(after.compare_to(before, "traceback"), key=lambda st: -st.size_diff)
    for stat in [st for st in stats if st.size_diff > 0][:n]:
        ours = [f for f in stat.traceback if _ours(f.filename)]
        names = [f"{Path(f.filename).relative_to(ROOT)}:{f.lineno}" for f in ours]
        frames = " <- ".join(names[-SHOWN_FRAMES:][::-1]) or "(outside the project)"
        out.append(Site(frames, stat.size_diff / 1024, stat.count_diff))
    return out


def half_start(n: int) -> int:
    """Of ``n`` samples, the one the second half is measured from (the first half fills the
    book): the middle one, or the one before the last if that leaves a single sample."""
    return max(min(n // 2, n - 2), 0)


def interval_growth(before: Sample, after: Sample) -> float:
    """MiB per simulated hour between two samples: where the curve levels off, about 0."""
    return (after.mib - before.mib) / max(after.hours - before.hours, 1e-9)


def growth_per_hour(samples: list[Sample]) -> float:
    """MiB per simulated hour over the second half of the run."""
    return interval_growth(samples[half_start(len(samples))], samples[-1])


def count_of_jobs(text: str) -> int:
    n = int(text)
    if n not in (1, 2):
        raise argparse.ArgumentTypeError(f"1 or 2 processes (one per run), got {n}")
    return n


def count_of_sites(text: str) -> int:
    n = int(text)
    if n < 0:
        raise argparse.ArgumentTypeError(f"a number of sites >= 0, got {n}")
    return n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=4.0)
    ap.add_argument("--keep-s", type=float, default=1800.0)
    ap.add_argument("--every-s", type=float, default=1800.0)
    ap.add_argument("--scale", type=float, default=0.5, help="x the seed's order rates")
    ap.add_argument(
        "--sites",
        type=count_of_sites,
        default=0,
        help="print the N allocation sites that grew most",
    )
    ap.add_argument(
        "--jobs",
        type=count_of_jobs,
        default=1,
        help="2: the baseline and the kept run in two processes at once",
    )
    ap.add_argument("--quick", action="store_true", help="0.1 h, kept 120 s, a line each 120 s")
    args = ap.parse_args()
    if args.quick:
        args.hours, args.keep_s, args.every_s = 0.1, 120.0, 120.0
    begin = time.perf_counter()
    names = ["for ever (baseline)", f"{args.keep_s:g} s"]
    (baseline, _, energy), (kept, sites, _) = run_all(
        [
            (names[0], args.hours, math.inf, args.every_s, args.scale),
            (names[1], args.hours, args.keep_s, args.every_s, args.scale, args.sites),
        ],
        args.jobs,
    )
    runs = dict(zip(names, [baseline, kept], strict=True))
    print(
        f"distribution centre, 17 shuttles, {args.scale:g} x the seed's order rates, "
        f"{args.hours:g} simulated h; memory: Python "
        "objects allocated since the start and still held (tracemalloc)\n"
    )
    print(
        "| final orders kept | simulated h | orders finished | orders in the book | MiB held "
        "| MiB per h since the sample before |"
    )
    print("|---|---:|---:|---:|---:|---:|")
    for name, samples in runs.items():
        for before, s in zip([None, *samples[:-1]], samples, strict=True):
            rate = "" if before is None else f"{interval_growth(before, s):+.3f}"
            print(f"| {name} | {s.hours:.2f} | {s.finished} | {s.in_book} | {s.mib:.2f} | {rate} |")
    base_rate, rate = growth_per_hour(baseline), growth_per_hour(kept)
    print("\n| final orders kept | MiB per simulated h (second half) | / baseline |")
    print("|---|---:|---:|")
    print(f"| for ever (baseline) | {base_rate:.3f} | 1.00 |")
    ratio = rate / base_rate if base_rate > 0 else math.nan
    print(f"| {args.keep_s:g} s | {rate:.3f} | {ratio:.2f} |")
    print(
        "\nThe batteries (the baseline run): % of the capacity per hour lost off the chargers "
        f"(per vehicle) {energy['drain_pct_per_h']}, gained on a charger "
        f"{energy['charge_pct_per_h']}; chargers the fleet's work needs, sustained, "
        f"{energy['chargers_needed']} of the plant's {energy['chargers']}"
    )
    if sites:
        print(f"\nWhere the kept run's memory grew over its second half, the {len(sites)} sites")
        print("that grew most (innermost frames in the project first):\n")
        print("| allocated at | KiB grown | blocks grown |")
        print("|---|---:|---:|")
        for site in sites:
            print(f"| {site.frames} | {site.grown_kib:.1f} | {site.blocks} |")
    print(f"\nwall time {time.perf_counter() - begin:.0f} s")


if __name__ == "__main__":
    main()
