"""Shared test helpers: small blocks whose behaviour the tests can observe."""

from __future__ import annotations

import signal
import time
from collections.abc import Callable

import pytest

from plc_runtime import FunctionBlock, Runtime

# The least maximum cycle time a test's runtime enforces: tests measure behaviour, and a busy
# machine can stall one scan of a virtual-clock run for longer than the 150 ms default.
WIDE_WATCHDOG_NS = 10_000_000_000


class Probe(FunctionBlock):
    """Runs a callback every cycle; used to look at the image from inside a scan."""

    def __init__(self, on_cycle: Callable, on_startup: Callable | None = None) -> None:
        super().__init__()
        self.on_cycle = on_cycle
        self.on_startup = on_startup

    def startup(self, ctx) -> None:
        if self.on_startup:
            self.on_startup(ctx)

    def cycle(self, ctx) -> None:
        self.on_cycle(ctx)


class Busy(FunctionBlock):
    """Burns real CPU time in chosen scans: the way to blow a budget on the virtual clock."""

    def __init__(self, seconds: float, scans: set[int] | None = None) -> None:
        super().__init__()
        self.seconds = seconds
        self.scans = scans  # None = every scan

    def cycle(self, ctx) -> None:
        if self.scans is None or ctx.cycle in self.scans:
            end = time.perf_counter() + self.seconds
            while time.perf_counter() < end:
                pass


@pytest.fixture(autouse=True)
def no_alarm_left_behind():
    """A test that forgets rt.stop() must not leave a watchdog timer for the next one."""
    handler = signal.getsignal(signal.SIGALRM)
    yield
    signal.setitimer(signal.ITIMER_REAL, 0)
    signal.signal(signal.SIGALRM, handler)


@pytest.fixture(autouse=True)
def watchdog_widened(request, monkeypatch):
    """Every runtime a test builds enforces a watchdog of at least ``WIDE_WATCHDOG_NS``.

    The runtime still reports the limit it was given (summaries, tags, the web view), so
    tests of those values see them unchanged. A test of the watchdog itself is marked
    ``@pytest.mark.watchdog`` and keeps the limit it sets. Runtimes started in a child
    process are not reached: those tests pass ``--watchdog`` themselves.
    """
    if request.node.get_closest_marker("watchdog"):
        return
    build = Runtime.__init__

    def widened(self, *args, **kwargs) -> None:
        build(self, *args, **kwargs)
        if self._watchdog_ns < WIDE_WATCHDOG_NS:
            self._watchdog_ns = self._alarm.limit_ns = WIDE_WATCHDOG_NS

    monkeypatch.setattr(Runtime, "__init__", widened)


@pytest.fixture
def made():
    """Programs a test makes (it appends each), closed after it whatever the outcome."""
    programs = []
    yield programs
    for p in programs:
        p.close()
