"""Shared test helpers: small blocks whose behaviour the tests can observe."""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest

from plc_runtime import FunctionBlock, Runtime, VirtualClock


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


@pytest.fixture
def make_runtime() -> Callable[..., Runtime]:
    """A Runtime on a fresh virtual clock; stopped again after the test."""
    created: list[Runtime] = []

    def make(cycle_time: float = 0.010, **kwargs) -> Runtime:
        kwargs.setdefault("clock", VirtualClock())
        rt = Runtime(cycle_time=cycle_time, **kwargs)
        created.append(rt)
        return rt

    yield make
    for rt in created:
        rt.stop()
