"""Cyclic tasks: a list of blocks scanned every ``interval`` with a priority and a phase offset.

Like S7 cyclic-interrupt OBs, a task's releases fall on the base-tick grid at
``phase + n * interval``. Within one tick the due tasks run in priority order (0 is the
highest priority, ties in the order the tasks were added), one after the other, in the
scan thread.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .context import CycleContext
from .fb import FunctionBlock
from .stats import ScanStats

OVERRUN_POLICIES = ("skip", "catch_up", "fault")


@dataclass(eq=False)
class Task:
    name: str
    blocks: list[FunctionBlock]
    interval_ticks: int
    phase_ticks: int
    priority: int
    overrun: str
    interval_ns: int
    budget_ns: int
    order: int
    stats: ScanStats = field(init=False)
    ctx: CycleContext | None = field(default=None, init=False)
    next_release: int = field(default=0, init=False)  # tick index of the next release

    def __post_init__(self) -> None:
        self.stats = ScanStats(self.name)

    @property
    def sort_key(self) -> tuple[int, int]:
        return (self.priority, self.order)

    def reset(self) -> None:
        self.stats.reset()
        self.next_release = self.phase_ticks
