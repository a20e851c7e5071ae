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
import threading
import traceback
import warnings
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from time import perf_counter_ns

from .clock import VirtualClock, WallClock
from .collector import DEFAULT_YOUNG_THRESHOLD, FullCollections, YoungThreshold
from .context import CycleContext
from .errors import (
    ConfigError,
    PlcError,
    RetainError,
    StartupError,
    StateError,
    WatchdogTimeout,
)
from .fb import FunctionBlock
from .image import ProcessImage, ProgramImage
from .io import IoDriver
from .retain import RetainStore, check_retain_header, check_retain_path, layout_hash
from .stats import RuntimeStats, ScanStats
from .tags import TagTable
from .task import OVERRUN_POLICIES, Task
from .watchdog import WatchdogAlarm

STOP, STARTUP, RUN, FAULT = "STOP", "STARTUP", "RUN", "FAULT"
MIN_CYCLE_TIME = 1e-6  # below a microsecond the nanosecond tick grid loses its meaning
MAX_TIME = 6000.0  # the S7 upper limit for cycle and watchdog times, in seconds


def _seconds(
    value: object, what: str, low: float = 0.0, high: float = MAX_TIME, low_ok: bool = True
) -> float:
    """Check a time in seconds; ConfigError naming ``what`` when it is not a finite number in range."""
    ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    if ok and (value >= low if low_ok else value > low) and value <= high:
        return float(value)
    lower = f">= {low:g}" if low_ok else f"> {low:g}"
    upper = "" if high == math.inf else f" and <= {high:g}"
    raise ConfigError(f"{what} must be a finite number of seconds {lower}{upper}, got {value!r}")


def _ticks(value: float, tick: float, what: str) -> int:
    ratio = value / tick
    n = round(ratio)
    if abs(ratio - n) > 1e-6 * max(1.0, ratio):
        raise ConfigError(f"{what} {value} s is not a multiple of the base cycle time {tick} s")
    return n


def _described(exc: BaseException) -> str:
    """``ValueError: bad value``, or just ``KeyboardInterrupt`` when there is no message."""
    text = str(exc)
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


class Runtime:
    """A soft PLC: tasks of function blocks scanned against a process image.

    ``cycle_time``: the base tick in seconds; task intervals are multiples of it.
    ``watchdog``: maximum cycle time in seconds (S7-1200 default 0.150).
    ``min_cycle_time``: optional, at most ``cycle_time``; a tick never starts sooner than
    this after the previous one (spaces out catch-up ticks after an overrun).
    ``safe_outputs``: output values published on FAULT and STOP (every other output is 0).
    ``retain_file``: path of the crash-safe retain file (None: retain only in memory).
    ``retain_interval``: also save the retain file every this many clock seconds while running.
    ``watchdog_interrupt``: let the watchdog abort a hung block (main thread only).
    ``gc_threshold``: the garbage collector's generation-0 threshold while the cyclic phase
    runs (raised, never lowered; None: Python's own), so that young collections do not run
    in the middle of scans and full collections stay rare (:mod:`plc_runtime.collector`).
    ``gc_full_between_scans``: no automatic full collection while the cyclic phase runs; the
    runtime makes one after a scan, outside its time and watchdog, once the heap has grown
    by a quarter (False: Python's own, which lands in whichever scan allocates then).
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
        gc_threshold: int | None = DEFAULT_YOUNG_THRESHOLD,
        gc_full_between_scans: bool = True,
    ) -> None:
        self.cycle_time = _seconds(cycle_time, "cycle_time", low=MIN_CYCLE_TIME)
        self.watchdog = _seconds(watchdog, "watchdog", low=0.0, low_ok=False)
        if min_cycle_time is not None:
            _seconds(
                min_cycle_time, "min_cycle_time (at most the cycle time)", high=self.cycle_time
            )
        if retain_interval is not None:
            _seconds(retain_interval, "retain_interval", low=0.0, low_ok=False, high=math.inf)
        self.clock = clock if clock is not None else VirtualClock()
        self.min_cycle_time = min_cycle_time
        self.image = ProcessImage(image_sizes, tags)
        self.safe_outputs = dict(safe_outputs or {})
        for ref, value in self.safe_outputs.items():
            loc = self.image.resolve(ref)
            if loc.area != "Q":
                raise ConfigError(f"safe output {ref} is not an output (%Q) location")
            loc.type.check(value, f"safe output {ref}")
        self.retain_interval = retain_interval
        self.watchdog_interrupt = watchdog_interrupt
        self._young = YoungThreshold(gc_threshold)
        if not isinstance(gc_full_between_scans, bool):
            raise ConfigError(
                f"gc_full_between_scans must be True or False, got {gc_full_between_scans!r}"
            )
        self._full = FullCollections(gc_full_between_scans)
        self._drivers_open = False  # every driver opened (they get the safe state at stop)
        self.tasks: list[Task] = []
        self.drivers: list[IoDriver] = []
        self.state = STOP
        self.fault_reason: str | None = None
        self.fault_traceback: str | None = None
        self.ticks = 0
        self.stats = RuntimeStats(self)
        if retain_file is not None:
            check_retain_path(retain_file)
            check_retain_header(retain_file)
        self._retain = RetainStore(retain_file)
        if self._retain.file is not None:
            try:
                self._retain.file.check_writable()
            except RetainError as exc:
                raise ConfigError(str(exc)) from None
        self._tick_ns = round(self.cycle_time * 1e9)
        self._watchdog_ns = round(self.watchdog * 1e9)
        self._min_cycle_ns = round(min_cycle_time * 1e9) if min_cycle_time else 0
        self._scan_stats = ScanStats("scan")
        self._program_image = ProgramImage(self.image)
        self._alarm = WatchdogAlarm(self._watchdog_ns)
        self._t0 = 0
        self._last_tick_start: int | None = None
        self._next_retain_save = 0
        self._stop_requested = threading.Event()
        # Held while a tick runs and by start/stop/save_retain, so another thread (an HMI,
        # a supervisor) can stop the runtime or save retain data safely between two scans.
        self._lock = threading.RLock()
        self._stopping = threading.Event()  # set while stop() waits for the lock
        self._scan_thread: int | None = None  # thread id while a scan runs
        # Set whenever no scan runs or is about to (``quiet_lead``). A thread serving
        # clients (an HMI server) waits on it before it works, so it never competes with a
        # scan for the interpreter.
        self.between_scans = threading.Event()
        self.between_scans.set()
        self._quiet_lead_ns = 0
        self._scan_ran = False  # whether any task ran in the last tick
        self._retain_layout_before: list[tuple[str, str]] = []

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
        what = f"task {name!r}:"
        interval = _seconds(
            self.cycle_time if interval is None else interval, f"{what} interval", low_ok=False
        )
        interval_ticks = _ticks(interval, self.cycle_time, f"{what} interval")
        if interval_ticks < 1:
            raise ConfigError(f"{what} interval {interval} s is shorter than the base cycle")
        phase = _seconds(phase, f"{what} phase")
        phase_ticks = _ticks(phase, self.cycle_time, f"{what} phase")
        if phase_ticks >= interval_ticks:
            raise ConfigError(
                f"{what} phase {phase} s must be smaller than the interval {interval} s"
            )
        if not isinstance(priority, int) or isinstance(priority, bool):
            raise ConfigError(f"{what} priority must be an integer, got {priority!r}")
        if overrun not in OVERRUN_POLICIES:
            raise ConfigError(
                f"{what} overrun policy {overrun!r} is not one of {', '.join(OVERRUN_POLICIES)}"
            )
        if budget is not None:
            budget = _seconds(budget, f"{what} budget", low_ok=False)
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
        self._retain.forget()  # a new program layout: retain data kept in memory no longer fits
        return task

    def add_driver(self, driver: IoDriver) -> None:
        """Add a bus driver; it is opened in startup, called every tick, closed on stop."""
        self._require(STOP, "add a driver")
        if not isinstance(driver, IoDriver):
            raise ConfigError(
                f"{type(driver).__name__} is not an IoDriver (open/read_inputs/write_outputs/close/stats)"
            )
        if any(d.name == driver.name for d in self.drivers):
            raise ConfigError(f"driver {driver.name!r} already added")
        added_to = getattr(driver, "added_to", None)  # optional (io.py)
        if callable(added_to):
            added_to(self)  # before it counts as added: if this fails, it is not
        self.drivers.append(driver)

    @property
    def quiet_lead(self) -> float:
        """Seconds before each scan's release from which ``between_scans`` is already clear
        (0: from the release). A thread that waits on it before it works then does not
        start work that would run into the scan."""
        return self._quiet_lead_ns / 1e9

    def ask_quiet_lead(self, seconds: float) -> None:
        """Make ``quiet_lead`` at least ``seconds`` (at most half the cycle time): what a
        driver whose thread serves clients asks for when it opens."""
        lead = _seconds(seconds, "quiet lead", high=self.cycle_time / 2)
        self._quiet_lead_ns = max(self._quiet_lead_ns, round(lead * 1e9))

    # ----- operating state ----------------------------------------------------------------
    def start(self, mode: str = "warm") -> None:
        """STOP -> STARTUP -> RUN. ``warm`` keeps retentive data, ``cold`` clears it."""
        with self._lock:
            self._require(STOP, "start")
            if mode not in ("warm", "cold"):
                raise ConfigError(f"start mode must be 'warm' or 'cold', got {mode!r}")
            if not self.tasks:
                raise ConfigError("no tasks: add at least one task before start()")
            self.state = STARTUP
            self.fault_reason = self.fault_traceback = None
            self._stop_requested.clear()
            self.image.reset()
            self._retain_layout_before = self._retain_layout()
            self._init_block_data(
                self._retain.load(mode, self._retain_layout_before, self._retained_problem)
            )
            if mode == "cold" and self._retain.file is not None:
                self._retain.save_or_warn(
                    self._collect_retain(), "cleared"
                )  # no old values after a crash
            for task in self.tasks:
                task.reset()
                task.ctx = CycleContext(
                    self._program_image, task.name, task.interval_ns, self.clock.time_passes
                )
            self._scan_stats.reset()
            self.ticks = 0
            self._open_drivers()
            self._run_startup()
            self._check_layout_after_startup()
            self._young.enter()
            self.clock.enter_run()  # before t0: rt mode's initial full collection must not make tick 0 late
            self._full.enter()  # (after: rt mode's collector in idle time makes its own)
            self._t0 = self.clock.now_ns()
            self._last_tick_start = None
            self._next_retain_save = self._t0 + round((self.retain_interval or 0) * 1e9)
            if self.watchdog_interrupt:
                self._alarm.install(
                    frozenset({Runtime._run_tick.__code__, Runtime._fault.__code__})
                )
            self.state = RUN

    def _open_drivers(self) -> None:
        self._drivers_open = False
        opened = []
        for driver in self.drivers:
            try:
                driver.open(self.image)
            except Exception as exc:
                for other in opened:
                    other.close()
                self._fault(f"driver {driver.name}: cannot open: {exc}")
                raise StartupError(self.fault_reason) from exc
            opened.append(driver)
        self._drivers_open = True

    def _run_startup(self) -> None:
        """Every block's startup, in task priority order, without cycle monitoring."""
        ctx = CycleContext(self._program_image, "startup", self._tick_ns)
        ctx.budget_ns = 2**62  # the startup phase has no deadline
        for task in self.tasks:
            for i, block in enumerate(task.blocks):
                try:
                    block.startup(ctx)
                except BaseException as exc:  # see _fault_on
                    self._fault_on(f"startup of {task.name}/{i}:{type(block).__name__}", exc)
                    raise StartupError(self.fault_reason) from exc

    def stop(self) -> None:
        """RUN/FAULT -> STOP: keep retentive data (and save the retain file), outputs to safe state.

        Safe to call from another thread: it waits for the current scan to finish. From
        inside a block, use ``request_stop()``.
        """
        self._refuse_inside_scan("stop()")
        self._stopping.set()
        try:
            self._stop()
        finally:
            self._stopping.clear()

    def _stop(self) -> None:
        with self._lock:
            if self.state == STOP:
                return
            was_running = self.state in (RUN, FAULT)
            self.clock.exit_run()
            self._full.exit()  # (first: the young threshold restores only what it set)
            self._young.exit()
            self._alarm.uninstall()
            retained = self._collect_retain() if was_running else None
            self.image.publish_safe_state(self.safe_outputs)
            if was_running and self._drivers_open:
                # the safe state goes out through every driver before it closes: the devices
                # must see it, not only the image
                self._write_safe_state("at stop")
            for driver in self.drivers:
                driver.close()
            if retained is not None:
                self._retain.save_or_warn(retained)
            self.state = STOP

    def request_stop(self) -> None:
        """Ask a running ``run()`` loop to return after the current tick (thread/signal safe)."""
        self._stop_requested.set()

    @property
    def start_info(self) -> str | None:
        """How the last start went: warm or cold, and where retain data came from (or why not)."""
        return self._retain.start_info

    @property
    def retain_error(self) -> str | None:
        """The last failure to write the retain file, None after a successful write."""
        return self._retain.error

    @property
    def clock_time(self) -> float:
        """Seconds of clock time since the current run started (release time of the next tick)."""
        return self.ticks * self.cycle_time

    # ----- stepping -----------------------------------------------------------------------
    def step(self, n: int = 1) -> int:
        """Run ``n`` base ticks; return how many ran (fewer if the runtime faulted)."""
        self._require(RUN, "step")
        self._refuse_inside_scan("step()")
        if isinstance(n, bool) or not isinstance(n, int) or n < 0:
            raise ConfigError(f"step count must be a non-negative integer, got {n!r}")
        for done in range(n):
            self._tick()
            if self.state != RUN:
                return done + 1
        return n

    def run(self, cycles: int | None = None, duration: float | None = None) -> int:
        """Run ``cycles`` ticks, or ``duration`` seconds of clock time, or until ``request_stop()``."""
        self._require(RUN, "run")
        self._refuse_inside_scan("run()")
        if cycles is not None and duration is not None:
            raise ConfigError("give either cycles or duration, not both")
        if duration is not None:
            seconds = _seconds(duration, "duration", high=math.inf)
            cycles = round(seconds / self.cycle_time)
            if seconds > 0 and cycles == 0:  # asked for time, and no cycle would run
                raise ConfigError(
                    f"duration {seconds:g} s is less than half a cycle ({self.cycle_time:g} s): "
                    "no cycle would run"
                )
        if cycles is not None and (
            isinstance(cycles, bool) or not isinstance(cycles, int) or cycles < 0
        ):
            raise ConfigError(f"cycles must be a non-negative integer, got {cycles!r}")
        done = 0
        while (cycles is None or done < cycles) and self.state == RUN:
            if self._stop_requested.is_set():
                self._stop_requested.clear()  # consumed here; one arriving later waits for the next run()
                break
            self._tick()
            done += 1
        return done

    def run_until(self, predicate: Callable[[], object], max_cycles: int) -> bool:
        """Step until ``predicate()`` is true after a tick, at most ``max_cycles`` ticks;
        False if it never was.

        At least one tick runs before the predicate is asked: what the caller has just
        changed (a block's input, a forced tag) takes effect in the next scan, so the
        outputs read before it would still be the last scan's (a search's ``done`` of the
        request before)."""
        self._require(RUN, "run")
        self._refuse_inside_scan("run_until()")
        if isinstance(max_cycles, bool) or not isinstance(max_cycles, int) or max_cycles < 1:
            raise ConfigError(f"max_cycles must be a positive integer, got {max_cycles!r}")
        for _ in range(max_cycles):
            self._tick()
            if self.state != RUN:  # (the safe state may satisfy the predicate: not success)
                return False
            if predicate():
                return True
        return False

    # ----- the scan -----------------------------------------------------------------------
    def _tick(self) -> None:
        k = self.ticks
        release = self._t0 + k * self._tick_ns
        due = release
        if self._min_cycle_ns and self._last_tick_start is not None:
            due = max(release, self._last_tick_start + self._min_cycle_ns)
        if self._quiet_lead_ns:
            self.clock.wait_until(due - self._quiet_lead_ns)
            self.between_scans.clear()  # the scan is near: serving threads hold off now
        try:
            self.clock.wait_until(due)
            if self._stopping.is_set():
                return  # another thread is stopping the runtime: let it have the lock
            with self._lock:
                if self.state != RUN:  # stopped by another thread while this one waited
                    return
                if self.retain_interval and self.clock.now_ns() >= self._next_retain_save:
                    self._next_retain_save = self.clock.now_ns() + round(self.retain_interval * 1e9)
                    # (it costs lateness, not scan time)
                    self._retain.save_or_warn(self._collect_retain())
                self._scan_thread = threading.get_ident()
                self.between_scans.clear()
                try:
                    self._run_tick(k, release)
                finally:
                    self._scan_thread = None
                    self.between_scans.set()
                if self.state == RUN:
                    self._after_scan()
                    self._full.after_scan()  # (it costs lateness, not scan time)
        finally:
            # (an Event's set() takes its lock and wakes waiters even when it is set: a
            # tenth of a trivial scan's cost, so only where a path above left it clear)
            if not self.between_scans.is_set():
                self.between_scans.set()

    def _after_scan(self) -> None:
        """The drivers' ``after_scan`` (io.py): outside the scan's time and watchdog."""
        for driver in self.drivers:
            after = getattr(driver, "after_scan", None)
            if after is not None:
                try:
                    after()
                except BaseException as exc:  # see _fault_on
                    self._fault_on(f"driver {driver.name}: after_scan", exc)
                    return

    def _run_tick(self, k: int, release: int) -> None:
        """One scan under the watchdog, then its statistics."""
        tick_real_start = perf_counter_ns()
        tick_start = self.clock.now_ns()
        self.ticks = k + 1
        try:
            self._alarm.begin_scan(tick_real_start)
            completed = self._scan(k, release, tick_real_start)
        except WatchdogTimeout:
            self._fault(
                f"watchdog: scan {k} exceeded the maximum cycle time of {self.watchdog * 1e3:g} ms and was aborted"
            )
            return
        except KeyboardInterrupt:
            if self.state == RUN:  # Ctrl-C landed in the runtime's own code: still a cut scan
                self._fault(f"scan {k} was interrupted (KeyboardInterrupt)")
            raise
        finally:
            self._alarm.end_scan()
        if not completed:
            return
        if self._scan_ran:
            self._last_tick_start = tick_start  # min_cycle_time spaces scans, not skipped ticks
        tick_exec = perf_counter_ns() - tick_real_start
        self._scan_stats.record(tick_exec, tick_start - release)
        if tick_exec > self._watchdog_ns:
            self._fault(
                f"watchdog: scan {k} took {tick_exec / 1e6:.1f} ms, maximum cycle time is {self.watchdog * 1e3:g} ms"
            )

    def _scan(self, k: int, release: int, started_ns: int) -> bool:
        """Quiet point, copy-in, due tasks, copy-out; False if the runtime faulted.

        Drivers get the tick's IEC time (its release since the start) on both sides. A
        scan found over the watchdog's limit after its tasks (the interrupt cannot reach
        a runtime outside the main thread, and a block may swallow it) faults before its
        copy-out: late and perhaps half-computed outputs never reach the field."""
        image = self.image
        image.apply_quiet_point()
        iec_now = release - self._t0
        for driver in self.drivers:
            if not self._run_driver(driver.read_inputs, driver, iec_now):
                return False
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
            took = perf_counter_ns() - started_ns
            if took > self._watchdog_ns:
                self._fault(
                    f"watchdog: scan {k} took {took / 1e6:.1f} ms, maximum cycle time is "
                    f"{self.watchdog * 1e3:g} ms; its outputs were not copied out"
                )
                return False
            image.copy_out()
        for driver in self.drivers:
            if not self._run_driver(driver.write_outputs, driver, iec_now):
                return False
        self._scan_ran = copied_in
        return True

    def _run_driver(
        self, method: Callable[[ProcessImage, int], None], driver: IoDriver, now: int
    ) -> bool:
        try:
            method(self.image, now)
        except WatchdogTimeout:
            raise
        except BaseException as exc:  # see _fault_on
            self._fault_on(f"driver {driver.name}: {method.__name__}", exc)
            return False
        return True

    def _scan_task(self, task: Task, release: int, now: int) -> bool:
        """Run one scan of a task; False if the runtime faulted."""
        ctx = task.ctx
        ctx.time_ns = release - self._t0
        ctx.cycle = task.stats.cycles
        ctx.first_scan = ctx.cycle == 0
        start = perf_counter_ns()
        ctx.started_ns, ctx.budget_ns = start, task.budget_ns
        index = 0
        try:
            for index, block in enumerate(task.blocks):  # noqa: B007 - index names the failing block
                block.cycle(ctx)
        except WatchdogTimeout:
            raise
        except BaseException as exc:  # see _fault_on
            name = type(task.blocks[index]).__name__
            self._fault_on(f"task {task.name}: block {index}:{name}", exc)
            return False
        elapsed = perf_counter_ns() - start
        self.clock.charge(elapsed)
        late = now - release
        task.stats.record(elapsed, late)
        if late + elapsed > task.interval_ns:  # the scan ended after the task's next release
            task.stats.overruns += 1
            if task.overrun == "fault":
                self._fault(
                    f"task {task.name}: overrun, scan finished {(late + elapsed) / 1e6:.2f} ms "
                    f"after its release, interval is {task.interval_ns / 1e6:g} ms"
                )
                return False
        return True

    def _fault(self, reason: str) -> None:
        # the watchdog holds off while the safe state is published, so it is published
        # whole (an alarm landing before the first line finds this function unsafe and
        # waits); it is on again afterwards, for what the failed scan's cleanup runs
        self._alarm.held = True
        try:
            self.state = FAULT
            self.fault_reason = reason
            self.image.publish_safe_state(self.safe_outputs)
            if self._drivers_open:
                # at once, as a CPU going to STOP does: a driver that pushes outputs (a
                # bus, a coupler) would hold the last scan's until stop() otherwise
                self._write_safe_state("at the fault")
        finally:
            self._alarm.held = False

    def _write_safe_state(self, when: str) -> None:
        """The safe state out through every driver; one that cannot write is reported."""
        now = self.clock.now_ns() - self._t0
        for driver in self.drivers:
            try:
                driver.write_outputs(self.image, now)
            except Exception as exc:
                warnings.warn(
                    f"{type(driver).__name__}: safe state not written {when}: {exc}",
                    RuntimeWarning,
                    stacklevel=3,
                )

    def _fault_on(self, who: str, exc: BaseException) -> None:
        """FAULT because ``exc`` escaped a block or a driver, whatever its class.

        ``SystemExit`` and ``KeyboardInterrupt`` fault too: a program cannot end the PLC
        (``sys.exit()`` in a block stops the PLC like any other error, with the outputs in
        the safe state). A ``KeyboardInterrupt`` is passed on after the fault, because the
        operator's second Ctrl-C arrives as one, raised in whatever block was running, and
        cannot be told apart: the caller's abort still works (the CLI stops and exits 130).
        """
        self.fault_traceback = traceback.format_exc()
        self._fault(f"{who} raised {_described(exc)}")
        if isinstance(exc, KeyboardInterrupt):
            raise exc

    # ----- instance data and retain -------------------------------------------------------
    def _block_paths(self) -> Iterable[tuple[str, FunctionBlock]]:
        for task in self.tasks:
            for i, block in enumerate(task.blocks):
                yield from block.walk(f"{task.name}/{i}:{type(block).__name__}")

    def _retain_layout(self) -> list[tuple[str, str]]:
        """Which retentive variables exist, with their types: a changed program gets a cold start."""
        entries = [
            (f"tag:{t.name}", f"{t.address.text}:{t.type.name}")
            for t in self.image.tags
            if t.retain
        ]
        for path, block in self._block_paths():
            entries += [
                (f"fb:{path}.{name}", f"{type(block).__name__}:{block.declared_type(name)}")
                for name in block.retain_names()
            ]
        return entries

    def _retained_problem(self, retained: dict[str, object]) -> str | None:
        """What in a retain file's values its tags cannot take, or None.

        The layout hash matched, so the file was written for this program's retentive
        variables, but a file edited by hand may carry others, which would be kept and
        written back for ever unnoticed: they are refused. A tag's value is checked as a
        write from outside would be (its type and range). A block variable is a plain
        attribute whose type nothing fixes (a counter may hold a float), so its value is
        restored as it was saved."""
        known = {key for key, _ in self._retain_layout_before}
        unknown = [key for key in retained if key not in known]
        if unknown:
            return f"{unknown[0]!r} is no retentive variable of this program"
        for key, value in retained.items():
            kind, _, name = key.partition(":")
            if kind == "tag" and name in self.image.tags:
                try:
                    self.image.resolve(name).type.check(value, key)
                except PlcError as exc:
                    return str(exc)
        return None

    def _init_block_data(self, retained: dict[str, object]) -> None:
        """Reset every block's declared variables, then restore the retained ones."""
        for path, block in self._block_paths():
            keep = set()
            for name in block.retain_names():
                key = f"fb:{path}.{name}"
                if key in retained:
                    value = retained[key]
                    if isinstance(block._vars[name].default, tuple) and isinstance(value, list):
                        value = tuple(value)  # JSON has no tuples
                    setattr(block, name, value)
                    keep.add(name)
            block.reset_vars(keep)
        for tag in self.image.tags:
            key = f"tag:{tag.name}"
            if tag.retain and key in retained:
                self.image.resolve(tag.name).writer(self.image.markers)(retained[key])

    def _check_layout_after_startup(self) -> None:
        """Blocks created in startup() cannot be restored (restoring happens before it):
        say so instead of saving values that would be dropped at the next start."""
        after = self._retain_layout()
        added = sorted({key for key, _ in after} - {key for key, _ in self._retain_layout_before})
        if added:
            warnings.warn(
                f"retentive variables of blocks created in startup() are not kept: {', '.join(added[:5])}; "
                "create retentive blocks in __init__",
                RuntimeWarning,
                stacklevel=3,
            )
            self._retain.layout = layout_hash(after)

    def _collect_retain(self) -> dict[str, object]:
        values: dict[str, object] = {}
        for tag in self.image.tags:
            if tag.retain:
                values[f"tag:{tag.name}"] = self.image.read(tag.name)
        for path, block in self._block_paths():
            for name in block.retain_names():
                values[f"fb:{path}.{name}"] = getattr(block, name)
        return values

    def save_retain(self) -> None:
        """Write the retain file now (also done on stop() and every ``retain_interval``)."""
        with self._lock:
            if self.state not in (RUN, FAULT):
                raise StateError(f"cannot save retain data in state {self.state}")
            self._retain.save(self._collect_retain())

    # ----- guards -------------------------------------------------------------------------
    def _require(self, state: str, action: str) -> None:
        if self.state != state:
            detail = f" ({self.fault_reason})" if self.state == FAULT else ""
            raise StateError(
                f"cannot {action} in state {self.state}{detail}; required state is {state}"
            )

    def _refuse_inside_scan(self, action: str) -> None:
        if self._scan_thread == threading.get_ident():
            raise StateError(
                f"cannot call {action} from inside a scan; use request_stop() from a block"
            )
