"""Cycle statistics, readable while running (like CODESYS Task_Info2 or the S7 cycle-time page).

Execution time is measured in real time for every scan. Counters, min, max and mean cover
every scan since start; percentiles cover the most recent ``window`` scans, kept in a
preallocated ring buffer so recording a scan costs two array stores and no allocation.
"""

from __future__ import annotations

import gc
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .runtime import Runtime

DEFAULT_WINDOW = 8192


class ScanStats:
    """Execution time and lateness of one task (or of whole base ticks)."""

    def __init__(self, name: str, window: int = DEFAULT_WINDOW) -> None:
        self.name = name
        self.window = window
        self._exec = np.zeros(window, dtype=np.int64)
        self._late = np.zeros(window, dtype=np.int64)
        self.reset()

    def reset(self) -> None:
        self.cycles = 0
        self.overruns = 0
        self.omitted = 0
        self.exec_last_ns = 0
        self.exec_min_ns = 0
        self.exec_max_ns = 0
        self._exec_sum_ns = 0
        self.late_max_ns = 0

    def record(self, exec_ns: int, late_ns: int) -> None:
        i = self.cycles % self.window
        self._exec[i] = exec_ns
        self._late[i] = late_ns
        if self.cycles == 0 or exec_ns < self.exec_min_ns:
            self.exec_min_ns = exec_ns
        if exec_ns > self.exec_max_ns:
            self.exec_max_ns = exec_ns
        if late_ns > self.late_max_ns:
            self.late_max_ns = late_ns
        self.exec_last_ns = exec_ns
        self._exec_sum_ns += exec_ns
        self.cycles += 1

    def copy(self, share_window: bool = False) -> ScanStats:
        """A frozen copy: a monitor in another thread computes the percentiles of
        ``to_dict`` on it, outside the scan.

        ``share_window``: the counters are copied, the ring buffers are not (two copies of
        ``window`` values each, which in a scan's cache-cold end cost several times their
        microseconds). Recording overwrites one slot per scan in place and never moves the
        buffers, so percentiles read later cover the window as it is then: the same
        number of real scans, moved on by those recorded since, beside counters, min, max
        and mean as they were at the copy."""
        clone = object.__new__(ScanStats)
        clone.__dict__.update(self.__dict__)
        if not share_window:
            clone._exec, clone._late = self._exec.copy(), self._late.copy()
        return clone

    def _recent(self, data: np.ndarray) -> np.ndarray:
        return data[: min(self.cycles, self.window)]

    def exec_percentile_ns(self, q: float) -> float:
        recent = self._recent(self._exec)
        return float(np.percentile(recent, q)) if len(recent) else 0.0

    def late_percentile_ns(self, q: float) -> float:
        recent = self._recent(self._late)
        return float(np.percentile(recent, q)) if len(recent) else 0.0

    @property
    def exec_mean_ns(self) -> float:
        return self._exec_sum_ns / self.cycles if self.cycles else 0.0

    def lateness_ns(self) -> np.ndarray:
        """Lateness of the recent scans, oldest first (for benchmarks and plots)."""
        recent = self._recent(self._late)
        if self.cycles <= self.window:
            return recent.copy()
        i = self.cycles % self.window
        return np.concatenate([recent[i:], recent[:i]])

    def to_dict(self) -> dict[str, object]:
        us = 1e-3
        return {
            "cycles": self.cycles,
            "overruns": self.overruns,
            "omitted": self.omitted,
            "exec_us": {
                "last": round(self.exec_last_ns * us, 3),
                "min": round(self.exec_min_ns * us, 3),
                "max": round(self.exec_max_ns * us, 3),
                "mean": round(self.exec_mean_ns * us, 3),
                "p50": round(self.exec_percentile_ns(50) * us, 3),
                "p99": round(self.exec_percentile_ns(99) * us, 3),
            },
            "lateness_us": {
                "p50": round(self.late_percentile_ns(50) * us, 3),
                "p99": round(self.late_percentile_ns(99) * us, 3),
                "max": round(self.late_max_ns * us, 3),
            },
        }


class RuntimeStats:
    """Everything a monitor shows: state, tick count, per-task and whole-scan statistics, forces."""

    def __init__(self, runtime: Runtime) -> None:
        self._rt = runtime

    @property
    def tasks(self) -> dict[str, ScanStats]:
        return {t.name: t.stats for t in self._rt.tasks}

    @property
    def scan(self) -> ScanStats:
        """Whole base ticks: the sum of all tasks that ran in a tick (the PLC's cycle time)."""
        return self._rt._scan_stats

    def __getitem__(self, task: str) -> ScanStats:
        return self.tasks[task]

    @property
    def cycles(self) -> int:
        return self._rt.ticks

    @property
    def overruns(self) -> int:
        return sum(s.overruns for s in self.tasks.values())

    @property
    def omitted(self) -> int:
        return sum(s.omitted for s in self.tasks.values())

    def to_dict(self) -> dict[str, object]:
        rt = self._rt
        return {
            "state": rt.state,
            "cycles": self.cycles,
            "cycle_time_s": rt.cycle_time,
            "clock_time_s": round(rt.clock_time, 9),
            "overruns": self.overruns,
            "omitted": self.omitted,
            "fault_reason": rt.fault_reason,
            "start_mode": rt.start_info,
            "retain_error": rt.retain_error,
            "watchdog_ms": rt.watchdog * 1e3,
            "forces": rt.image.forces,
            "clock": rt.clock.status(),
            # how often the collector ran, per generation: a full collection (the last) is
            # what shows as a scan-time spike on a large program
            "gc": {
                "thresholds": list(gc.get_threshold()),
                "collections": [g["collections"] for g in gc.get_stats()],
                "full_between_scans": rt._full.collections,
            },
            "scan": self.scan.to_dict(),
            "tasks": {name: s.to_dict() for name, s in self.tasks.items()},
            "drivers": {d.name: d.stats() for d in rt.drivers},
        }
