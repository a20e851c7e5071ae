"""The per-scan context handed to ``startup(ctx)`` and ``cycle(ctx)``.

It is the only place a block gets time from: the IEC time of the scan (its release time on
the runtime clock, advancing by exactly the task interval) and a deadline helper for
computations that must stop in time (A* expanding nodes until the budget is used up).

The deadline is kept on the runtime's clock. On a clock where time passes while a scan runs
(the wall clock, or a virtual clock that charges execution time) it is real time. On a plain
virtual clock time stands still during a scan, so the deadline is never reached: a block that
stops at its deadline then does the same work whatever the host is doing, and a run stays
reproducible bit for bit. Real execution time stays available as :meth:`elapsed_ns`, for a
block that is asked to bound it explicitly.
"""

from __future__ import annotations

from time import perf_counter_ns

from .image import ProgramImage


class CycleContext:
    __slots__ = (
        "image",
        "task",
        "cycle",
        "time_ns",
        "interval_ns",
        "budget_ns",
        "started_ns",
        "timed",
        "first_scan",
    )

    def __init__(
        self, image: ProgramImage, task: str, interval_ns: int, timed: bool = False
    ) -> None:
        self.image = image
        self.task = task  # name of the task this scan belongs to
        self.cycle = 0  # 0-based index of this scan within its task
        self.time_ns = 0  # IEC time of this scan: its release time since start(), in ns
        self.interval_ns = interval_ns  # task interval, in ns
        self.budget_ns = interval_ns  # how long this scan may take, in ns
        self.started_ns = 0  # perf_counter_ns() when this scan started
        self.timed = timed  # does the runtime's clock advance while a scan runs?
        self.first_scan = True  # True in the first scan after a start (like S7 FirstScan)

    @property
    def time(self) -> float:
        """IEC time of this scan in seconds."""
        return self.time_ns / 1e9

    @property
    def dt(self) -> float:
        """The task interval in seconds (the time between two scans of this task)."""
        return self.interval_ns / 1e9

    def elapsed_ns(self) -> int:
        """Real execution time of this scan so far, whatever the clock."""
        return perf_counter_ns() - self.started_ns

    def remaining_ns(self) -> int:
        """Time left of this scan's budget on the runtime's clock (negative when it is
        already past; the whole budget on a clock that stands still during a scan)."""
        if not self.timed:
            return self.budget_ns
        return self.budget_ns - (perf_counter_ns() - self.started_ns)

    def remaining(self) -> float:
        return self.remaining_ns() / 1e9

    def expired(self) -> bool:
        """True once the scan's budget is used up: stop and continue next cycle."""
        return self.remaining_ns() <= 0
