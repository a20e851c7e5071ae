"""bench/long_run.py's own arithmetic: where the second half starts, which frames name an
allocation site, and its arguments. The fleet run itself is replaced by a stand-in that only
advances a clock, so these tests cost nothing; the bench's table is checked by its quick run
(make bench-quick)."""

from __future__ import annotations

import argparse
import math
import runpy
import tracemalloc
from pathlib import Path
from types import SimpleNamespace

import can
import pytest

ROOT = Path(__file__).resolve().parent.parent
long_run = runpy.run_path(str(ROOT / "bench" / "long_run.py"), run_name="long_run")


class Book(list):
    def counts(self) -> dict[str, int]:
        return {"FINISHED": 0}


class StandIn:
    """The fleet program as the bench drives it: start, run for a duration, close."""

    now_s = 0.0

    def __init__(self, cfg) -> None:
        StandIn.now_s = 0.0
        self.orders = SimpleNamespace(book=Book(), runners={}, cfg=cfg)
        self.rt = SimpleNamespace(start=lambda: None, state="RUN", fault_reason=None, run=self.run)

    def run(self, duration: float) -> None:
        assert duration >= 0
        StandIn.now_s += duration

    def close(self) -> None:
        pass


@pytest.mark.parametrize("n", range(1, 9))
def test_the_second_half_starts_at_the_middle_sample_and_spans_two(n):
    first = long_run["half_start"](n)
    assert first == (max(n - 2, 0) if n < 4 else n // 2)


@pytest.mark.parametrize(
    ("hours", "every_s"), [(0.1, 120.0), (1.0, 1400.0), (4.0, 1800.0), (3.33, 2.4), (4.7, 4.8)]
)
def test_the_sites_grew_over_the_span_the_growth_is_measured_over(monkeypatch, hours, every_s):
    """A fractional --every-s summed up in floating point once added a sample of 1e-9 s at
    the end, and the snapshot was then taken one sample before the growth's start."""
    names = long_run["run"].__globals__
    snapshots = []
    tracer = SimpleNamespace(
        start=lambda *frames: None,
        stop=lambda: None,
        get_traced_memory=lambda: (0, 0),
        take_snapshot=lambda: snapshots.append(StandIn.now_s) or StandIn.now_s,
    )
    monkeypatch.setitem(names, "FleetProgram", StandIn)
    monkeypatch.setitem(names, "tracemalloc", tracer)
    monkeypatch.setitem(names, "gc", SimpleNamespace(collect=lambda: None))
    monkeypatch.setitem(names, "grown_sites", lambda before, after, n: [(before, after)])
    samples, [(before, after)], _ = long_run["run"]("kept", hours, 120.0, every_s, 0.5, sites=3)
    assert len(samples) == math.ceil(hours * 3600 / every_s - 1e-9)
    assert samples[-1].hours * 3600 == pytest.approx(hours * 3600) == after
    start = samples[long_run["half_start"](len(samples))]
    assert before == pytest.approx(start.hours * 3600)


def allocate_library_objects(kept: list) -> None:
    for k in range(2000):
        kept.append(can.Message(arbitration_id=k, data=bytes(8)))


def test_a_site_is_named_by_the_projects_frames_not_its_libraries():
    """The virtual environment lies inside the project's folder; its libraries are not the
    project's code."""
    kept: list = []
    tracemalloc.start(long_run["FRAMES"])
    try:
        before = tracemalloc.take_snapshot()
        allocate_library_objects(kept)
        after = tracemalloc.take_snapshot()
    finally:
        tracemalloc.stop()
    sites = long_run["grown_sites"](before, after, 3)
    assert sites and all(s.grown_kib > 0 for s in sites)
    assert "tests/test_long_run_bench.py" in sites[0].frames
    assert not any("site-packages" in s.frames or ".venv" in s.frames for s in sites)


def test_a_negative_number_of_sites_is_refused():
    with pytest.raises(argparse.ArgumentTypeError, match="a number of sites >= 0, got -1"):
        long_run["count_of_sites"]("-1")
    assert long_run["count_of_sites"]("0") == 0


class Filling(StandIn):
    """A stand-in whose book fills with the simulated time, so that runs differ."""

    def run(self, duration: float) -> None:
        super().run(duration)
        self.orders.book.extend([None] * int(duration // 60))


def patch_program(monkeypatch, program) -> None:
    names = long_run["run"].__globals__
    monkeypatch.setitem(names, "FleetProgram", program)


def test_two_processes_give_the_results_of_one_in_the_order_given(monkeypatch):
    patch_program(monkeypatch, Filling)
    runs = [("a", 0.2, math.inf, 240.0, 0.5), ("b", 0.1, 120.0, 120.0, 0.5)]
    one = long_run["run_all"](runs, 1)
    two = long_run["run_all"](runs, 2)
    assert two == one
    assert [len(samples) for samples, _, _ in two] == [3, 3]
    # no vehicle took orders: nothing measured of the batteries, and the plant's chargers
    assert two[0][2]["chargers_needed"] is None and two[0][2]["chargers"] == 5
    assert [s.in_book for s in two[0][0]] == [4, 8, 12]


class Stopping(StandIn):
    def run(self, duration: float) -> None:
        self.rt.state = "STOP"
        self.rt.fault_reason = "watchdog"


def test_a_run_that_stops_in_its_process_stops_the_bench_with_its_reason(monkeypatch):
    patch_program(monkeypatch, Stopping)
    runs = [("a", 0.1, math.inf, 120.0, 0.5), ("b", 0.1, 120.0, 120.0, 0.5)]
    with pytest.raises(SystemExit, match="the run stopped at 120 s: watchdog"):
        long_run["run_all"](runs, 2)


def test_the_growth_between_samples_and_over_the_second_half():
    Sample = long_run["Sample"]
    mib = [1.0, 1.5, 1.5, 2.5]
    samples = [Sample(h + 1.0, 0, 0, m) for h, m in enumerate(mib)]
    assert long_run["interval_growth"](samples[0], samples[1]) == pytest.approx(0.5)
    assert long_run["interval_growth"](samples[1], samples[2]) == 0.0
    # the second half of four samples is from the third to the last
    assert long_run["growth_per_hour"](samples) == pytest.approx(1.0)


def test_only_one_or_two_processes():
    with pytest.raises(argparse.ArgumentTypeError, match="1 or 2 processes"):
        long_run["count_of_jobs"]("3")
    assert long_run["count_of_jobs"]("2") == 2
