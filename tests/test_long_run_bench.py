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
        self.orders = SimpleNamespace(book=Book())
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
    samples, [(before, after)] = long_run["run"](hours, 120.0, every_s, 0.5, sites=3)
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
