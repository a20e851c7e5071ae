"""Shared test helpers: small blocks whose behaviour the tests can observe."""

from __future__ import annotations

import signal
import time
from collections.abc import Callable

import pytest

from plc_runtime import FunctionBlock


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


@pytest.fixture
def made():
    """Programs a test makes (it appends each), closed after it whatever the outcome."""
    programs = []
    yield programs
    for p in programs:
        p.close()
