"""The per-scan context handed to ``startup(ctx)`` and ``cycle(ctx)``.

It is the only place a block gets time from: the IEC time of the scan (its release time on
the runtime clock, advancing by exactly the task interval) and a real-time deadline helper
for computations that must stop in time (A* expanding nodes until the budget is used up).
"""

from __future__ import annotations

from time import perf_counter_ns

from .image import ProgramImage


class CycleContext:
    __slots__ = ("image", "task", "cycle", "time_ns", "interval_ns", "deadline_ns", "first_scan")

    def __init__(self, image: ProgramImage, task: str, interval_ns: int) -> None:
        self.image = image
        self.task = task  # name of the task this scan belongs to
        self.cycle = 0  # 0-based index of this scan within its task
        self.time_ns = 0  # IEC time of this scan: its release time since start(), in ns
        self.interval_ns = interval_ns  # task interval, in ns
        self.deadline_ns = 0  # perf_counter_ns() value by which this scan should be done
        self.first_scan = True  # True in the first scan after a start (like S7 FirstScan)

    @property
    def time(self) -> float:
        """IEC time of this scan in seconds."""
        return self.time_ns / 1e9

    @property
    def dt(self) -> float:
        """The task interval in seconds (the time between two scans of this task)."""
        return self.interval_ns / 1e9

    def remaining_ns(self) -> int:
        """Real time left before this scan's deadline (negative when it is already past)."""
        return self.deadline_ns - perf_counter_ns()

    def remaining(self) -> float:
        return self.remaining_ns() / 1e9

    def expired(self) -> bool:
        """True once the scan's real-time budget is used up: stop and continue next cycle."""
        return perf_counter_ns() >= self.deadline_ns
