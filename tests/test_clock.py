"""Clocks: virtual time is exact; the wall clock never wakes early; rt mode degrades cleanly."""

import gc
import os

import pytest
from conftest import Probe

from plc_runtime import Runtime, VirtualClock, WallClock


def test_virtual_clock_only_moves_forward():
    clock = VirtualClock(start=1.5)
    assert clock.now_ns() == 1_500_000_000
    clock.wait_until(2_000_000_000)
    clock.wait_until(1_000_000_000)
    assert clock.now() == 2.0
    clock.charge(5)  # deterministic by default: execution time is not simulated time
    assert clock.now_ns() == 2_000_000_000
    busy = VirtualClock(charge_execution=True)
    busy.charge(5)
    assert busy.now_ns() == 5


@pytest.mark.parametrize("spin", [0.0, 0.0005])
def test_wall_clock_never_returns_before_the_deadline(spin):
    clock = WallClock(spin=spin)
    for _ in range(5):
        deadline = clock.now_ns() + 2_000_000
        clock.wait_until(deadline)
        assert clock.now_ns() >= deadline


def test_runtime_on_wall_clock_keeps_absolute_deadlines():
    releases = []
    # about deadlines, not scan time: a busy machine must not fault a scan
    rt = Runtime(cycle_time=0.002, clock=WallClock(spin=0.0002), watchdog=5.0)
    rt.add_task("main", [Probe(lambda ctx: releases.append(rt.clock.now_ns()))])
    rt.start()
    t0 = rt._t0
    assert rt.run(cycles=20) == 20
    rt.stop()
    for k, started in enumerate(releases):
        assert started >= t0 + k * 2_000_000  # no scan starts before its release


def test_rt_mode_degrades_with_a_warning(monkeypatch):
    def refuse(*args):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    clock = WallClock(rt=True)
    with pytest.warns(RuntimeWarning, match="SCHED_FIFO not permitted"):
        clock.enter_run()
    status = clock.status()
    assert status["sched_fifo"].startswith("unavailable")
    assert not gc.isenabled()  # the GC part still applies
    clock.exit_run()
    assert gc.isenabled()


def test_rt_mode_sets_and_restores_the_scheduler(monkeypatch):
    calls = []
    monkeypatch.setattr(
        os,
        "sched_setscheduler",
        lambda pid, policy, param: calls.append((policy, param.sched_priority)),
    )
    clock = WallClock(rt=True, rt_priority=42)
    clock.enter_run()
    assert calls[-1] == (os.SCHED_FIFO, 42)
    assert clock.status()["sched_fifo"] == "priority 42"
    clock.exit_run()
    assert calls[-1][0] == os.sched_getscheduler(0)  # back to what it was
    assert gc.isenabled()


def test_rt_mode_collects_garbage_only_in_slack(monkeypatch):
    monkeypatch.setattr(os, "sched_setscheduler", lambda *args: None)
    clock = WallClock(rt=True, gc_slack=0.001)
    clock.enter_run()
    try:
        threshold = gc.get_threshold()[0]
        junk = [[i] for i in range(threshold * 2)]  # tracked allocations: generation 0 is due
        assert gc.get_count()[0] >= threshold
        clock.wait_until(clock.now_ns())  # no slack left: not collected
        assert gc.get_count()[0] >= threshold
        clock.wait_until(clock.now_ns() + 3_000_000)  # 3 ms of slack: collected there
        assert gc.get_count()[0] < threshold
        junk += [[i] for i in range(threshold * 21)]  # far past due and never any slack
        clock.wait_until(clock.now_ns())
        assert gc.get_count()[0] < threshold  # forced, so garbage cannot pile up
    finally:
        clock.exit_run()
    assert gc.isenabled()
