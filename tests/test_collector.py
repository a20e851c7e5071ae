"""The runtime's garbage-collector threshold: raised for the cyclic phase, restored at stop,
and what it is for: no young collection in the middle of a scan that allocates thousands
of short-lived objects."""

from __future__ import annotations

import gc

import pytest

from fleet.config import DEFAULT_CONFIG, parse_config
from fleet.program import FleetProgram
from plc_runtime import Runtime
from plc_runtime.collector import DEFAULT_YOUNG_THRESHOLD
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
    assert gc.get_threshold() == (DEFAULT_YOUNG_THRESHOLD, 10, 10)
    assert rt.stats.to_dict()["gc"]["thresholds"] == [DEFAULT_YOUNG_THRESHOLD, 10, 10]
    rt.run(cycles=3)
    rt.stop()
    assert gc.get_threshold() == (700, 10, 10)


def test_never_lowered_and_none_leaves_python_alone(python_thresholds) -> None:
    gc.set_threshold(50_000, 10, 10)
    rt = _runtime(2_000, Allocating(1))
    rt.start()
    assert gc.get_threshold() == (50_000, 10, 10)
    rt.stop()
    gc.set_threshold(700, 10, 10)
    rt = _runtime(None, Allocating(1))
    rt.start()
    assert gc.get_threshold() == (700, 10, 10)
    rt.stop()


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
