"""Clocks: the virtual clock for deterministic tests and simulation, the wall clock for plants.

The runtime schedules every base tick against an absolute deadline ``t0 + k * tick``, so
there is no drift however long it runs; the clock only has to *wait until* a deadline.

``VirtualClock`` jumps there: each step advances exactly one tick, as fast as the CPU
allows, deterministically. Execution time is still measured in real time, so overruns and
the watchdog are caught in tests; with ``charge_execution=True`` the measured time is also
added to simulated time, so an overrunning scan makes the following ticks late exactly as
it would on a plant.

``PacedClock`` is the virtual clock slowed down for people to watch: simulated time still
advances exactly one tick per step (the same run, bit for bit, as on the virtual clock), but
each step waits until the wall clock has caught up with ``speed`` simulated seconds per wall
second. A machine too slow for the speed just runs slower; it never drops ticks.

A scan's deadline (``ctx.remaining()``, ``ctx.expired()``) is kept on the same clock: it
passes in real time on the wall clock and on a virtual clock that charges execution, and
never on the plain virtual and paced clocks, where time stands still while a scan runs; so
a block that stops at its deadline cannot make their runs depend on the host's load.

``WallClock`` sleeps to the deadline (``time.sleep`` uses an absolute monotonic deadline
since Python 3.11), optionally spinning the last part, and optionally in "rt" mode:
SCHED_FIFO, 1 ns timer slack, ``gc.freeze()`` after startup and garbage collection only in
idle slack. Each rt measure that the OS refuses is reported with a warning and skipped.
"""

from __future__ import annotations

import ctypes
import gc
import math
import os
import threading
import time
import warnings

from .errors import ConfigError

PR_SET_TIMERSLACK = 29
PR_GET_TIMERSLACK = 30
FORCE_FACTOR = (
    20  # rt mode: collect even without slack once generation 0 is this many thresholds full
)


class VirtualClock:
    """Deterministic simulated time in integer nanoseconds.

    ``charge_execution=False`` (default): time advances by exactly one tick per step, so a
    run is reproducible bit for bit whatever the host does; overruns and the watchdog are
    still detected from the measured real execution time. ``charge_execution=True``:
    measured execution time is also added to simulated time, so an overrunning scan makes
    the following ticks late and the ``skip`` policy drops releases as it would on a plant
    (reproducible only as long as no scan overruns).
    """

    is_virtual = True

    def __init__(self, start: float = 0.0, charge_execution: bool = False) -> None:
        self._now_ns = round(start * 1e9)
        self.charge_execution = charge_execution

    @property
    def time_passes(self) -> bool:
        """Does this clock advance while a scan runs (so that a scan's deadline can pass)?"""
        return self.charge_execution

    def now_ns(self) -> int:
        return self._now_ns

    def now(self) -> float:
        return self._now_ns / 1e9

    def wait_until(self, deadline_ns: int) -> None:
        if deadline_ns > self._now_ns:
            self._now_ns = deadline_ns

    def charge(self, elapsed_ns: int) -> None:
        """Account real execution time to simulated time, if this clock emulates a busy CPU."""
        if self.charge_execution:
            self._now_ns += elapsed_ns

    def enter_run(self) -> None:
        pass

    def exit_run(self) -> None:
        pass

    def status(self) -> dict[str, object]:
        return {"clock": "virtual", "charge_execution": self.charge_execution}


class PacedClock(VirtualClock):
    """Simulated time, paced against the wall clock at ``speed`` simulated seconds per wall second.

    ``speed=1`` is real time. When a step takes longer than its share of wall time the clock
    falls behind; once it is more than ``max_lag`` wall seconds behind it takes the present
    as its new reference instead of racing to catch up, so a pause (a busy machine, a
    debugger) is not followed by a burst of fast-forward.
    """

    def __init__(self, speed: float = 1.0, start: float = 0.0, max_lag: float = 0.5) -> None:
        if not (isinstance(speed, int | float) and math.isfinite(speed) and speed > 0):
            raise ConfigError(f"PacedClock speed must be a finite number > 0, got {speed!r}")
        super().__init__(start)
        self.speed = float(speed)
        self.max_lag_ns = round(max_lag * 1e9)
        self.resyncs = 0
        self._anchor: tuple[int, int] | None = None  # (wall ns, simulated ns) pacing reference

    def wait_until(self, deadline_ns: int) -> None:
        super().wait_until(deadline_ns)
        now = time.monotonic_ns()
        if self._anchor is None:
            self._anchor = (now, self._now_ns)
            return
        wall0, sim0 = self._anchor
        due = wall0 + round((self._now_ns - sim0) / self.speed)
        if due > now:
            time.sleep((due - now) / 1e9)
        elif now - due > self.max_lag_ns:
            self._anchor = (now, self._now_ns)
            self.resyncs += 1

    def enter_run(self) -> None:
        self._anchor = None  # the startup phase is not paced: the cyclic phase starts now

    def status(self) -> dict[str, object]:
        return {"clock": "paced", "speed": self.speed, "resyncs": self.resyncs}


class WallClock:
    """Real time on the monotonic clock, with an optional spin tail and "rt" mode.

    ``spin``: seconds before each deadline spent busy-waiting instead of sleeping (0.0002 to
    0.001 cuts p99 lateness on an idle machine, but costs CPU and is worse under load).
    ``rt``: request SCHED_FIFO (priority ``rt_priority``), 1 ns timer slack and GC control.
    ``gc_slack``: in rt mode, collect garbage only when at least this much idle time
    remains before the next deadline.
    """

    is_virtual = False
    time_passes = True  # a scan's deadline passes in real time

    def __init__(
        self, spin: float = 0.0, rt: bool = False, rt_priority: int = 50, gc_slack: float = 0.0005
    ) -> None:
        for name, value in (("spin", spin), ("gc_slack", gc_slack)):
            if not (isinstance(value, int | float) and math.isfinite(value) and 0 <= value <= 1):
                raise ConfigError(f"WallClock {name} must be between 0 and 1 second, got {value!r}")
        self.spin_ns = round(spin * 1e9)
        self.rt = rt
        self.rt_priority = rt_priority
        self.gc_slack_ns = round(gc_slack * 1e9)
        self._rt_state: dict[str, object] = {}
        self._saved_sched: tuple[int, int] | None = None
        self._saved_slack: int | None = None
        self._gc_in_slack = False
        self._rt_thread = 0

    def now_ns(self) -> int:
        return time.monotonic_ns()

    def now(self) -> float:
        return time.monotonic_ns() / 1e9

    def charge(self, elapsed_ns: int) -> None:
        pass  # real time passes by itself

    def wait_until(self, deadline_ns: int) -> None:
        now = time.monotonic_ns()
        if self._gc_in_slack:
            self._collect_in_slack(forced_only=deadline_ns - now < self.gc_slack_ns)
            now = time.monotonic_ns()
        sleep_until = deadline_ns - self.spin_ns
        if sleep_until > now:
            time.sleep((sleep_until - now) / 1e9)
        while time.monotonic_ns() < deadline_ns:
            pass

    @staticmethod
    def _collect_in_slack(forced_only: bool = False) -> None:
        """Run the oldest generation that is due, as the automatic collector would have.

        With ``forced_only`` (not enough slack before the deadline) collect only once
        generation 0 has grown to ``FORCE_FACTOR`` times its threshold, so a cycle that never
        leaves enough slack still cannot accumulate garbage without bound.
        """
        counts, thresholds = gc.get_count(), gc.get_threshold()
        if forced_only and counts[0] < FORCE_FACTOR * thresholds[0]:
            return
        generation = -1
        for gen in range(3):
            if thresholds[gen] and counts[gen] >= thresholds[gen]:
                generation = gen
        if generation >= 0:
            gc.collect(generation)

    # ----- rt mode ------------------------------------------------------------------------
    def enter_run(self) -> None:
        """Called after the startup phase, right before the cyclic phase begins."""
        self._rt_state = {}
        if not self.rt:
            return
        self._set_fifo()
        self._set_timer_slack()
        gc.collect()
        gc.freeze()  # startup objects never need scanning again
        gc.disable()
        self._gc_in_slack = True
        self._rt_state["gc"] = "frozen after startup; collected only in idle slack"

    def exit_run(self) -> None:
        if self._gc_in_slack:
            gc.unfreeze()
            gc.enable()
            self._gc_in_slack = False
        self._rt_thread = 0
        if self._saved_sched is not None:
            policy, priority = self._saved_sched
            try:
                os.sched_setscheduler(self._rt_thread, policy, os.sched_param(priority))
            except OSError:
                pass
            self._saved_sched = None
        if self._saved_slack is not None:
            _prctl(PR_SET_TIMERSLACK, self._saved_slack)
            self._saved_slack = None

    def _set_fifo(self) -> None:
        if not hasattr(os, "sched_setscheduler"):
            self._degrade("sched_fifo", "SCHED_FIFO is not available on this platform")
            return
        # The scan thread's own id, so stop() from another thread restores the right thread.
        self._rt_thread = threading.get_native_id()
        try:
            saved = (
                os.sched_getscheduler(self._rt_thread),
                os.sched_getparam(self._rt_thread).sched_priority,
            )
            os.sched_setscheduler(self._rt_thread, os.SCHED_FIFO, os.sched_param(self.rt_priority))
        except (PermissionError, OSError) as exc:
            self._degrade(
                "sched_fifo",
                f"SCHED_FIFO not permitted ({exc.strerror or exc}); running with the normal scheduler",
            )
            return
        self._saved_sched = saved
        self._rt_state["sched_fifo"] = f"priority {self.rt_priority}"

    def _set_timer_slack(self) -> None:
        old = _prctl(PR_GET_TIMERSLACK, 0)
        if old < 0 or _prctl(PR_SET_TIMERSLACK, 1) != 0:
            self._degrade("timer_slack", "cannot set the timer slack to 1 ns (prctl unavailable)")
            return
        self._saved_slack = old
        self._rt_state["timer_slack"] = "1 ns"

    def _degrade(self, key: str, message: str) -> None:
        self._rt_state[key] = f"unavailable: {message}"
        warnings.warn(f"rt mode: {message}", RuntimeWarning, stacklevel=3)

    def status(self) -> dict[str, object]:
        status: dict[str, object] = {"clock": "wall", "spin_us": self.spin_ns / 1000, "rt": self.rt}
        status.update(self._rt_state)
        return status


def _prctl(option: int, value: int) -> int:
    """Call Linux prctl; -1 where there is no libc prctl."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        prctl = libc.prctl
    except (OSError, AttributeError):
        return -1
    prctl.argtypes = [ctypes.c_int, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong]
    prctl.restype = ctypes.c_int
    return prctl(option, value, 0, 0, 0)
