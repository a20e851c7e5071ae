"""The runtime's garbage-collector settings: the young threshold raised for the cyclic
phase, and full collections made between scans; both restored at stop. And what they are
for: no young collection in the middle of a scan that allocates thousands of short-lived
objects, and no full collection in any scan of a program whose heap grows."""

from __future__ import annotations

import gc

import pytest

from fleet.config import DEFAULT_CONFIG, parse_config
from fleet.program import FleetProgram
from plc_runtime import Runtime
from plc_runtime.collector import DEFAULT_YOUNG_THRESHOLD, SUSPENDED, FullCollections
from plc_runtime.errors import ConfigError
from plc_runtime.fb import FunctionBlock


class Allocating(FunctionBlock):
    """Builds ``n`` small lists per scan, alive until the scan ends (a planner's
    temporaries), and counts the collections that ran while they were alive."""

    def __init__(self, n: int) -> None:
        super().__init__()
        self.n = n
        self.during = 0

    def cycle(self, ctx) -> None:
        before = sum(g["collections"] for g in gc.get_stats())
        temporaries = [[i] for i in range(self.n)]
        self.during += sum(g["collections"] for g in gc.get_stats()) - before
        assert len(temporaries) == self.n


def _runtime(threshold: int | None, block: FunctionBlock) -> Runtime:
    rt = Runtime(cycle_time=0.01, watchdog=60.0, gc_threshold=threshold)
    rt.add_task("main", [block])
    return rt


@pytest.fixture
def python_thresholds():
    saved = gc.get_threshold()
    gc.set_threshold(700, 10, 10)
    yield
    gc.set_threshold(*saved)


def test_raised_while_running_and_restored_at_stop(python_thresholds) -> None:
    rt = _runtime(DEFAULT_YOUNG_THRESHOLD, Allocating(1))
    rt.start()
    assert gc.get_threshold() == (DEFAULT_YOUNG_THRESHOLD, 10, SUSPENDED)
    assert rt.stats.to_dict()["gc"]["thresholds"] == [DEFAULT_YOUNG_THRESHOLD, 10, SUSPENDED]
    rt.run(cycles=3)
    rt.stop()
    assert gc.get_threshold() == (700, 10, 10)


def test_never_lowered_and_none_leaves_python_alone(python_thresholds) -> None:
    gc.set_threshold(50_000, 10, 10)
    rt = _runtime(2_000, Allocating(1))
    rt.start()
    assert gc.get_threshold()[:2] == (50_000, 10)
    rt.stop()
    gc.set_threshold(700, 10, 10)
    rt = _runtime(None, Allocating(1))
    rt.start()
    assert gc.get_threshold()[:2] == (700, 10)
    rt.stop()
    assert gc.get_threshold() == (700, 10, 10)


def test_a_threshold_changed_meanwhile_is_kept(python_thresholds) -> None:
    rt = _runtime(DEFAULT_YOUNG_THRESHOLD, Allocating(1))
    rt.start()
    gc.set_threshold(30_000, 5, 5)  # someone else's choice, while the runtime runs
    rt.stop()
    assert gc.get_threshold() == (30_000, 5, 5)


@pytest.mark.parametrize("bad", [0, -5, 1.5, "10000", True])
def test_bad_threshold_is_a_config_error(bad) -> None:
    with pytest.raises(ConfigError, match="gc_threshold"):
        Runtime(cycle_time=0.01, gc_threshold=bad)


def test_no_young_collection_inside_a_scan(python_thresholds) -> None:
    """5000 temporaries a scan: with Python's threshold (700) every scan collects while
    they are alive, with the runtime's none does (the count falls back when they are
    freed at the scan's end)."""
    quiet = Allocating(5_000)
    rt = _runtime(DEFAULT_YOUNG_THRESHOLD, quiet)
    rt.start()
    rt.run(cycles=50)
    rt.stop()
    busy = Allocating(5_000)
    rt = _runtime(None, busy)
    rt.start()
    rt.run(cycles=50)
    rt.stop()
    assert busy.during >= 50 * 5  # 5000 / 700: seven young collections a scan
    assert quiet.during <= 1  # at most one, if the count started near the threshold


def test_the_fleet_configuration_sets_the_threshold(python_thresholds) -> None:
    text = DEFAULT_CONFIG.read_text()
    assert parse_config(text, "d.toml").gc_threshold == DEFAULT_YOUNG_THRESHOLD
    cfg = parse_config(text.replace("watchdog_ms = 150", "watchdog_ms = 150\ngc_threshold = 0"))
    assert cfg.gc_threshold is None  # 0: Python's own
    cfg = parse_config(text.replace("watchdog_ms = 150", "watchdog_ms = 150\ngc_threshold = 3000"))
    program = FleetProgram(cfg)
    program.rt.start()
    try:
        assert gc.get_threshold()[0] == 3000
    finally:
        program.rt.stop()
    assert gc.get_threshold()[0] == 700
    with pytest.raises(ConfigError, match="gc_threshold"):
        parse_config(text.replace("watchdog_ms = 150", "watchdog_ms = 150\ngc_threshold = -1"))


# ----- full collections between scans -------------------------------------------------------
class Hoarding(FunctionBlock):
    """Keeps ``n`` new small lists a scan for good: a heap that grows, as an order book
    being released does, so that full collections become due."""

    def __init__(self, n: int) -> None:
        super().__init__()
        self.n = n
        self.kept: list[list[int]] = []

    def cycle(self, ctx) -> None:
        self.kept.extend([i] for i in range(self.n))


def full_collections(rt: Runtime, cycles: int) -> tuple[int, int]:
    """Run ``cycles`` and count the full collections made in a scan and between scans."""
    seen = {"in": 0, "between": 0}

    def callback(phase: str, info: dict) -> None:
        if phase == "start" and info["generation"] == 2:
            seen["between" if rt.between_scans.is_set() else "in"] += 1

    gc.callbacks.append(callback)
    try:
        rt.start()
        rt.run(cycles=cycles)
        rt.stop()
    finally:
        gc.callbacks.remove(callback)
    return seen["in"], seen["between"]


def test_full_collections_come_between_scans_never_in_one(python_thresholds) -> None:
    """With Python's own rule the full collections of a growing heap land in scans; with
    the runtime's they all come between two scans, and as the heap grows, not more often."""
    rt = Runtime(cycle_time=0.01, watchdog=60.0, gc_threshold=None, gc_full_between_scans=False)
    rt.add_task("main", [Hoarding(2_000)])
    inside, _ = full_collections(rt, 150)
    assert inside >= 1
    rt = Runtime(cycle_time=0.01, watchdog=60.0, gc_threshold=None)
    rt.add_task("main", [Hoarding(2_000)])
    inside, between = full_collections(rt, 150)
    assert inside == 0 and 1 <= between <= 30  # (the heap grows 300,000 lists: few quarters)
    assert rt.stats.to_dict()["gc"]["full_between_scans"] == between
    assert gc.get_threshold() == (700, 10, 10)  # put back at stop


def test_a_full_collection_once_the_heap_has_grown_by_a_quarter(python_thresholds) -> None:
    heap = [1000]
    full = FullCollections(True, blocks=lambda: heap[0])
    full.enter()
    assert gc.get_threshold() == (700, 10, SUSPENDED)
    heap[0] = 1249
    gc.collect(1)  # (a young collection that may have promoted objects: the heap is measured)
    assert not full.after_scan()
    heap[0] = 1250
    assert not full.after_scan()  # (no young collection since: not measured)
    gc.collect(1)
    assert full.after_scan() and full.collections == 1
    heap[0] = 1300  # the new baseline is 1250
    gc.collect(1)
    assert not full.after_scan()
    full.exit()
    assert gc.get_threshold() == (700, 10, 10)


def test_suspended_once_for_all_runtimes_and_left_to_a_disabled_collector(
    python_thresholds,
) -> None:
    first, second = FullCollections(True, lambda: 1), FullCollections(True, lambda: 2)
    first.enter()
    second.enter()  # (already suspended: the first puts it back)
    second.exit()
    assert gc.get_threshold()[2] == SUSPENDED
    first.exit()
    assert gc.get_threshold() == (700, 10, 10)
    off = FullCollections(False, lambda: 10**9)
    off.enter()
    assert gc.get_threshold() == (700, 10, 10) and not off.after_scan()
    gc.disable()  # (the wall clock's rt mode: it collects in idle time itself)
    try:
        manual = FullCollections(True, lambda: 10**9)
        manual.enter()
        assert gc.get_threshold() == (700, 10, 10) and not manual.after_scan()
    finally:
        gc.enable()


@pytest.mark.parametrize("bad", [1, "yes", None])
def test_bad_full_collection_setting_is_a_config_error(bad) -> None:
    with pytest.raises(ConfigError, match="gc_full_between_scans"):
        Runtime(cycle_time=0.01, gc_full_between_scans=bad)
