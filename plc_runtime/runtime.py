"""The scan-cycle runtime: operating states, the tick loop, cycle monitoring and retain.

One base tick = one scan: at its release time the runtime applies queued external writes
and forces (the single quiet point), copies the inputs in, runs every due task in priority
order, copies the outputs out, and checks the watchdog. Releases are on an absolute grid
``t0 + k * cycle_time``; how the clock reaches them is the clock's business.

Overruns: a task whose scan ends after its next release has overrun. Its policy decides:
``skip`` drops releases that are already stale when their turn comes (counted as omitted
cycles, the S7/CODESYS default); ``catch_up`` runs every release, late, back to back;
``fault`` stops the PLC. Independently, the watchdog faults the runtime when one tick's
execution exceeds the maximum cycle time, and (in the main thread) interrupts a block
that hangs, as a hardware watchdog would.
"""

from __future__ import annotations

import math
import signal
import threading
import traceback
import warnings
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from time import perf_counter_ns
from types import FrameType

from .clock import VirtualClock, WallClock
from .context import CycleContext
from .errors import ConfigError, RetainError, StartupError, StateError, WatchdogTimeout
from .fb import FunctionBlock
from .image import ProcessImage, ProgramImage
from .retain import RetainFile, layout_hash
from .stats import RuntimeStats, ScanStats
from .tags import TagTable
from .task import OVERRUN_POLICIES, Task

STOP, STARTUP, RUN, FAULT = "STOP", "STARTUP", "RUN", "FAULT"


def _ticks(value: float, tick: float, what: str) -> int:
    ratio = value / tick
    n = round(ratio)
    if abs(ratio - n) > 1e-6 * max(1.0, ratio):
        raise ConfigError(f"{what} {value} s is not a multiple of the base cycle time {tick} s")
    return n


class Runtime:
    """A soft PLC: tasks of function blocks scanned against a process image.

    ``cycle_time``: the base tick in seconds; task intervals are multiples of it.
    ``watchdog``: maximum cycle time in seconds (S7-1200 default 0.150).
    ``min_cycle_time``: optional; a tick never starts sooner than this after the previous one.
    ``safe_outputs``: output values published on FAULT and STOP (every other output is 0).
    ``retain_file``: path of the crash-safe retain file (None: retain only in memory).
    ``retain_interval``: also save the retain file every this many clock seconds while running.
    """

    def __init__(
        self,
        cycle_time: float = 0.010,
        clock: VirtualClock | WallClock | None = None,
        *,
        watchdog: float = 0.150,
        min_cycle_time: float | None = None,
        image_sizes: Mapping[str, int] | None = None,
        tags: TagTable | None = None,
        safe_outputs: Mapping[str, object] | None = None,
        retain_file: str | Path | None = None,
        retain_interval: float | None = None,
        watchdog_interrupt: bool = True,
    ) -> None:
        if not (
            isinstance(cycle_time, int | float) and math.isfinite(cycle_time) and cycle_time > 0
        ):
            raise ConfigError(
                f"cycle_time must be a positive number of seconds, got {cycle_time!r}"
            )
        if not (isinstance(watchdog, int | float) and 0 < watchdog <= 6000):
            raise ConfigError(f"watchdog must be between 0 and 6000 s, got {watchdog!r}")
        if min_cycle_time is not None and not 0 <= min_cycle_time <= watchdog:
            raise ConfigError(
                f"min_cycle_time must be between 0 and the watchdog time, got {min_cycle_time!r}"
            )
        if retain_interval is not None and retain_interval <= 0:
            raise ConfigError(f"retain_interval must be positive, got {retain_interval!r}")
        self.cycle_time = float(cycle_time)
        self.clock = clock if clock is not None else VirtualClock()
        self.watchdog = float(watchdog)
        self.min_cycle_time = min_cycle_time
        self.image = ProcessImage(image_sizes, tags)
        self.safe_outputs = dict(safe_outputs or {})
        for ref, value in self.safe_outputs.items():
            loc = self.image.resolve(ref)
            if loc.area != "Q":
                raise ConfigError(f"safe output {ref} is not an output (%Q) location")
            loc.type.check(value, f"safe output {ref}")
        self.retain_file = RetainFile(retain_file) if retain_file is not None else None
        self.retain_interval = retain_interval
        self.watchdog_interrupt = watchdog_interrupt
        self.tasks: list[Task] = []
        self.state = STOP
        self.fault_reason: str | None = None
        self.fault_traceback: str | None = None
        self.start_info: str | None = None
        self.retain_error: str | None = None  # last failure to write the retain file
        self.ticks = 0
        self.stats = RuntimeStats(self)
        self._tick_ns = round(self.cycle_time * 1e9)
        self._watchdog_ns = round(self.watchdog * 1e9)
        self._min_cycle_ns = round(min_cycle_time * 1e9) if min_cycle_time else 0
        self._scan_stats = ScanStats("scan")
        self._program_image = ProgramImage(self.image)
        self._t0 = 0
        self._last_tick_start: int | None = None
        self._retained: dict[str, object] | None = None
        self._retain_layout: list[tuple[str, str]] = []
        self._next_retain_save = 0
        self._stop_requested = threading.Event()
        self._in_scan = False
        self._scan_start_ns = 0
        self._alarm_pending = False
        self._ticks_at_alarm = 0
        self._alarm_thread: int | None = None
        self._previous_alarm_handler: object = signal.SIG_DFL

    # ----- configuration ------------------------------------------------------------------
    def add_task(
        self,
        name: str,
        blocks: Iterable[FunctionBlock],
        interval: float | None = None,
        priority: int = 0,
        phase: float = 0.0,
        overrun: str = "skip",
        budget: float | None = None,
    ) -> Task:
        """Add a cyclic task. ``interval`` defaults to the base cycle time; ``budget`` (the
        real-time deadline blocks see in ``ctx``) defaults to the interval."""
        self._require(STOP, "add a task")
        if not isinstance(name, str) or not name:
            raise ConfigError(f"task name must be a non-empty string, got {name!r}")
        if any(t.name == name for t in self.tasks):
            raise ConfigError(f"task {name!r} already exists")
        blocks = list(blocks)
        known = {id(b) for t in self.tasks for b in t.blocks}
        for i, block in enumerate(blocks):
            if not isinstance(block, FunctionBlock):
                raise ConfigError(
                    f"task {name!r}: block #{i} is {type(block).__name__}, not a FunctionBlock"
                )
            if id(block) in known or blocks.index(block) != i:
                raise ConfigError(
                    f"task {name!r}: block #{i} ({type(block).__name__}) is already scheduled"
                )
        interval = self.cycle_time if interval is None else interval
        if not (isinstance(interval, int | float) and interval > 0):
            raise ConfigError(f"task {name!r}: interval must be positive, got {interval!r}")
        interval_ticks = _ticks(interval, self.cycle_time, f"task {name!r}: interval")
        if interval_ticks < 1:
            raise ConfigError(
                f"task {name!r}: interval {interval} s is shorter than the base cycle"
            )
        if not (isinstance(phase, int | float) and phase >= 0):
            raise ConfigError(f"task {name!r}: phase must be >= 0, got {phase!r}")
        phase_ticks = _ticks(phase, self.cycle_time, f"task {name!r}: phase")
        if phase_ticks >= interval_ticks:
            raise ConfigError(
                f"task {name!r}: phase {phase} s must be smaller than the interval {interval} s"
            )
        if not isinstance(priority, int):
            raise ConfigError(f"task {name!r}: priority must be an integer, got {priority!r}")
        if overrun not in OVERRUN_POLICIES:
            raise ConfigError(
                f"task {name!r}: overrun policy {overrun!r} is not one of {', '.join(OVERRUN_POLICIES)}"
            )
        if budget is not None and not budget > 0:
            raise ConfigError(f"task {name!r}: budget must be positive, got {budget!r}")
        interval_ns = interval_ticks * self._tick_ns
        task = Task(
            name=name,
            blocks=blocks,
            interval_ticks=interval_ticks,
            phase_ticks=phase_ticks,
            priority=priority,
            overrun=overrun,
            interval_ns=interval_ns,
            budget_ns=round(budget * 1e9) if budget else interval_ns,
            order=len(self.tasks),
        )
        self.tasks.append(task)
        self.tasks.sort(key=lambda t: t.sort_key)
        self._retained = None  # a new program layout: in-memory retain data no longer fits
        return task

    # ----- operating state ----------------------------------------------------------------
    def start(self, mode: str = "warm") -> None:
        """STOP -> STARTUP -> RUN. ``warm`` keeps retentive data, ``cold`` clears it."""
        self._require(STOP, "start")
        if mode not in ("warm", "cold"):
            raise ConfigError(f"start mode must be 'warm' or 'cold', got {mode!r}")
        if not self.tasks:
            raise ConfigError("no tasks: add at least one task before start()")
        self.state = STARTUP
        self.fault_reason = self.fault_traceback = None
        self._stop_requested.clear()
        self.image.reset()
        retained = self._load_retain(mode)
        self._init_block_data(retained)
        for task in self.tasks:
            task.reset()
            task.ctx = CycleContext(self._program_image, task.name, task.interval_ns)
        self._scan_stats.reset()
        self.ticks = 0
        startup_ctx = CycleContext(self._program_image, "startup", self._tick_ns)
        startup_ctx.deadline_ns = 2**63 - 1  # no cycle monitoring in startup
        for task in self.tasks:
            for i, block in enumerate(task.blocks):
                try:
                    block.startup(startup_ctx)
                except Exception as exc:
                    self._fault(
                        f"startup of {task.name}/{i}:{type(block).__name__} raised {type(exc).__name__}: {exc}"
                    )
                    raise StartupError(self.fault_reason) from exc
        self._t0 = self.clock.now_ns()
        self._last_tick_start = None
        self._next_retain_save = self._t0 + round((self.retain_interval or 0) * 1e9)
        self.clock.enter_run()
        self._install_alarm()
        self.state = RUN

    def stop(self) -> None:
        """RUN/FAULT -> STOP: keep retentive data (and save the retain file), outputs to safe state."""
        if self.state == STOP:
            return
        was_running = self.state in (RUN, FAULT)
        self.clock.exit_run()
        self._uninstall_alarm()
        if was_running:
            self._retained = self._collect_retain()
            try:
                self._save_retain_file()
            except RetainError as exc:  # STOP must be reached even when the disk is not there
                self.retain_error = str(exc)
                warnings.warn(f"retain file not saved: {exc}", RuntimeWarning, stacklevel=2)
        self.image.publish_safe_state(self.safe_outputs)
        self.state = STOP

    def request_stop(self) -> None:
        """Ask a running ``run()`` loop to return after the current tick (thread/signal safe)."""
        self._stop_requested.set()

    # ----- stepping -----------------------------------------------------------------------
    def step(self, n: int = 1) -> int:
        """Run ``n`` base ticks; return how many ran (fewer if the runtime faulted)."""
        self._require(RUN, "step")
        if not isinstance(n, int) or n < 0:
            raise ConfigError(f"step count must be a non-negative integer, got {n!r}")
        for done in range(n):
            self._tick()
            if self.state != RUN:
                return done + 1
        return n

    def run(self, cycles: int | None = None, duration: float | None = None) -> int:
        """Run ``cycles`` ticks, or ``duration`` seconds of clock time, or until ``request_stop()``."""
        self._require(RUN, "run")
        if cycles is not None and duration is not None:
            raise ConfigError("give either cycles or duration, not both")
        if duration is not None:
            if not duration >= 0:
                raise ConfigError(f"duration must be >= 0, got {duration!r}")
            cycles = round(duration / self.cycle_time)
        if cycles is not None and (not isinstance(cycles, int) or cycles < 0):
            raise ConfigError(f"cycles must be a non-negative integer, got {cycles!r}")
        done = 0
        while (
            (cycles is None or done < cycles)
            and self.state == RUN
            and not self._stop_requested.is_set()
        ):
            self._tick()
            done += 1
        self._stop_requested.clear()
        return done

    def run_until(self, predicate: Callable[[], object], max_cycles: int) -> bool:
        """Step until ``predicate()`` is true (checked after every tick); False if it never was."""
        self._require(RUN, "run")
        if predicate():
            return True
        for _ in range(max_cycles):
            self._tick()
            if predicate():
                return True
            if self.state != RUN:
                return False
        return False

    @property
    def clock_time(self) -> float:
        """Seconds of clock time since the current run started (release time of the next tick)."""
        return self.ticks * self.cycle_time

    # ----- the scan -----------------------------------------------------------------------
    def _tick(self) -> None:
        k = self.ticks
        clock = self.clock
        release = self._t0 + k * self._tick_ns
        if self._min_cycle_ns and self._last_tick_start is not None:
            clock.wait_until(max(release, self._last_tick_start + self._min_cycle_ns))
        else:
            clock.wait_until(release)
        tick_real_start = perf_counter_ns()
        self._last_tick_start = clock.now_ns()
        if self.retain_interval and self._last_tick_start >= self._next_retain_save:
            self._save_retain_periodically()
        self.ticks = k + 1
        self._scan_start_ns = tick_real_start
        self._in_scan = True
        try:
            if not self._alarm_pending and self._alarm_thread is not None:
                self._arm_alarm(self._watchdog_ns)
            completed = self._scan(k, release)
        except WatchdogTimeout:
            self._in_scan = False
            self._fault(
                f"watchdog: scan {k} exceeded the maximum cycle time of {self.watchdog * 1e3:g} ms and was aborted"
            )
            return
        finally:
            self._in_scan = False
        if not completed:
            return
        tick_exec = perf_counter_ns() - tick_real_start
        self._scan_stats.record(tick_exec, self._last_tick_start - release)
        if tick_exec > self._watchdog_ns:
            self._fault(
                f"watchdog: scan {k} took {tick_exec / 1e6:.1f} ms, maximum cycle time is {self.watchdog * 1e3:g} ms"
            )

    def _scan(self, k: int, release: int) -> bool:
        """Quiet point, copy-in, due tasks, copy-out (under the watchdog); False on FAULT."""
        image = self.image
        image.apply_quiet_point()
        copied_in = False
        for task in self.tasks:
            if task.next_release != k:
                continue
            task.next_release += task.interval_ticks
            now = self.clock.now_ns()
            if task.overrun == "skip" and now >= release + task.interval_ns:
                task.stats.omitted += 1  # a later release has already passed: this one is stale
                continue
            if not copied_in:
                image.copy_in()
                copied_in = True
            if not self._scan_task(task, release, now):
                return False
        if copied_in:
            image.copy_out()
        return True

    def _scan_task(self, task: Task, release: int, now: int) -> bool:
        """Run one scan of a task; False if the runtime faulted."""
        ctx = task.ctx
        ctx.time_ns = release - self._t0
        ctx.cycle = task.stats.cycles
        ctx.first_scan = ctx.cycle == 0
        start = perf_counter_ns()
        ctx.deadline_ns = start + task.budget_ns
        block = None
        try:
            for block in task.blocks:
                block.cycle(ctx)
        except Exception as exc:
            self.fault_traceback = traceback.format_exc()
            index = task.blocks.index(block)
            self._fault(
                f"task {task.name}: block {index}:{type(block).__name__} raised {type(exc).__name__}: {exc}"
            )
            return False
        elapsed = perf_counter_ns() - start
        self.clock.charge(elapsed)
        task.stats.record(elapsed, now - release)
        if self.clock.now_ns() > release + task.interval_ns:
            task.stats.overruns += 1
            if task.overrun == "fault":
                self._fault(
                    f"task {task.name}: overrun, scan finished {(self.clock.now_ns() - release) / 1e6:.2f} ms "
                    f"after its release, interval is {task.interval_ns / 1e6:g} ms"
                )
                return False
        return True

    def _fault(self, reason: str) -> None:
        self.state = FAULT
        self.fault_reason = reason
        self.image.publish_safe_state(self.safe_outputs)

    # ----- watchdog interrupt -------------------------------------------------------------
    # A one-shot SIGALRM timer that re-arms itself from its handler: no system call per
    # tick, detection exactly at the watchdog time (a too-early alarm re-arms for the rest
    # of the current scan), and the chain ends by itself once no tick ran since the last
    # alarm, so an idle or abandoned runtime leaves no timer behind. SIGALRM can only be
    # handled in the main thread: a runtime started from another thread keeps the
    # after-the-fact watchdog check but cannot interrupt a hung block.
    def _install_alarm(self) -> None:
        self._alarm_thread = None
        self._alarm_pending = False
        if self.watchdog_interrupt and threading.current_thread() is threading.main_thread():
            self._previous_alarm_handler = signal.signal(signal.SIGALRM, self._on_alarm)
            self._alarm_thread = threading.get_ident()

    def _uninstall_alarm(self) -> None:
        self._in_scan = False
        if self._alarm_thread is not None and threading.get_ident() == self._alarm_thread:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, self._previous_alarm_handler)
        self._alarm_thread = None
        self._alarm_pending = False

    def _arm_alarm(self, delay_ns: int) -> None:
        self._alarm_pending = True
        self._ticks_at_alarm = self.ticks
        signal.setitimer(signal.ITIMER_REAL, max(delay_ns, 1000) / 1e9)

    def _on_alarm(self, signum: int, frame: FrameType | None) -> None:
        self._alarm_pending = False
        if self._in_scan:
            overdue = perf_counter_ns() - self._scan_start_ns - self._watchdog_ns
            if frame is not None and frame.f_code is _TICK_CODE:
                # Interrupted the tick's own bookkeeping, outside the guarded scan: an
                # exception here would escape, so look again in a millisecond.
                self._arm_alarm(1_000_000)
            elif overdue >= 0:
                self._in_scan = False
                raise WatchdogTimeout()
            self._arm_alarm(-overdue)
        elif self.state == RUN and self.ticks != self._ticks_at_alarm:
            self._arm_alarm(self._watchdog_ns)

    # ----- instance data and retain -------------------------------------------------------
    def _block_paths(self) -> Iterable[tuple[str, FunctionBlock]]:
        for task in self.tasks:
            for i, block in enumerate(task.blocks):
                yield from block.walk(f"{task.name}/{i}:{type(block).__name__}")

    def _layout(self) -> list[tuple[str, str]]:
        entries = [
            (f"tag:{t.name}", f"{t.address.text}:{t.type.name}")
            for t in self.image.tags
            if t.retain
        ]
        for path, block in self._block_paths():
            entries += [
                (f"fb:{path}.{name}", type(block).__name__) for name in block.retain_names()
            ]
        return entries

    def _init_block_data(self, retained: dict[str, object]) -> None:
        """Reset every block's declared variables, then restore the retained ones."""
        for path, block in self._block_paths():
            keep = set()
            for name in block.retain_names():
                key = f"fb:{path}.{name}"
                if key in retained:
                    setattr(block, name, retained[key])
                    keep.add(name)
            block.reset_vars(keep)
        for tag in self.image.tags:
            key = f"tag:{tag.name}"
            if tag.retain and key in retained:
                tag_loc = self.image.resolve(tag.name)
                tag_loc.writer(self.image.markers)(retained[key])

    def _collect_retain(self) -> dict[str, object]:
        values: dict[str, object] = {}
        for tag in self.image.tags:
            if tag.retain:
                values[f"tag:{tag.name}"] = self.image.read(tag.name)
        for path, block in self._block_paths():
            for name in block.retain_names():
                values[f"fb:{path}.{name}"] = getattr(block, name)
        return values

    def _load_retain(self, mode: str) -> dict[str, object]:
        self._retain_layout = self._layout()
        if mode == "cold":
            self._retained = None
            self.start_info = "cold"
            return {}
        if self._retained is not None:
            self.start_info = "warm (retain data from memory)"
            return self._retained
        if self.retain_file is None:
            self.start_info = "warm (no retain data yet)"
            return {}
        try:
            loaded = self.retain_file.load(layout_hash(self._retain_layout))
        except RetainError as exc:
            self.start_info = f"cold: {exc}"
            warnings.warn(f"retain data not used, cold start: {exc}", RuntimeWarning, stacklevel=3)
            return {}
        if loaded is None:
            self.start_info = f"warm ({self.retain_file.path} does not exist yet)"
            return {}
        self.start_info = f"warm (retain data from {self.retain_file.path})"
        return loaded

    def save_retain(self) -> None:
        """Write the retain file now (also done on stop() and every ``retain_interval``)."""
        if self.state not in (RUN, FAULT):
            raise StateError(f"cannot save retain data in state {self.state}")
        self._retained = self._collect_retain()
        self._save_retain_file()

    def _save_retain_file(self) -> None:
        if self.retain_file is not None and self._retained is not None:
            self.retain_file.save(layout_hash(self._retain_layout), self._retained)

    def _save_retain_periodically(self) -> None:
        self._next_retain_save += round(self.retain_interval * 1e9)
        self._retained = self._collect_retain()
        try:
            self._save_retain_file()
        except RetainError as exc:  # keep scanning; report it once per distinct problem
            if self.retain_error != str(exc):
                warnings.warn(f"retain file not saved: {exc}", RuntimeWarning, stacklevel=2)
            self.retain_error = str(exc)
        else:
            self.retain_error = None

    def _require(self, state: str, action: str) -> None:
        if self.state != state:
            detail = f" ({self.fault_reason})" if self.state == FAULT else ""
            raise StateError(
                f"cannot {action} in state {self.state}{detail}; required state is {state}"
            )


_TICK_CODE = Runtime._tick.__code__
