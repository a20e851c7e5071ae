"""Cycle monitoring: watchdog, overrun policies, faults and minimum cycle time.

Budgets are blown with real busy-waiting (``Busy``) on the virtual clock: execution time is
always measured in real time. Tests of what an overrun does to the schedule use
``VirtualClock(charge_execution=True)``, which adds that time to simulated time as a plant
CPU would experience it.
"""

import time

import pytest
from conftest import Busy, Probe

from plc_runtime import Runtime, StartupError, StateError, VirtualClock

pytestmark = pytest.mark.watchdog  # the watchdog is what these tests check

MS = 1_000_000


def test_skip_policy_omits_the_releases_that_passed():
    rt = Runtime(cycle_time=0.010, clock=VirtualClock(charge_execution=True))
    rt.add_task("main", [Busy(0.035, scans={0})], overrun="skip")
    rt.start()
    rt.step(10)
    stats = rt.stats["main"]
    assert stats.overruns == 1
    # releases at 10, 20, 30 ms passed during the 35 ms scan: the latest runs (late), the rest are omitted
    assert stats.omitted == stats.exec_max_ns // (10 * MS) - 1 >= 2
    assert stats.cycles == 10 - stats.omitted
    assert rt.state == "RUN"
    rt.stop()


def test_skip_policy_with_slower_task():
    rt = Runtime(cycle_time=0.010, clock=VirtualClock(charge_execution=True))
    rt.add_task("fast", [Probe(lambda ctx: None)], priority=0, overrun="catch_up")
    rt.add_task("slow", [Busy(0.045, scans={0})], interval=0.020, priority=1, overrun="skip")
    rt.start()
    rt.step(20)
    slow = rt.stats["slow"]
    assert slow.omitted == slow.exec_max_ns // (20 * MS) - 1 >= 1
    assert slow.cycles + slow.omitted == 10
    assert rt.stats["fast"].cycles == 20  # a catch-up task loses no release, it only runs late
    assert rt.stats["fast"].late_max_ns >= 25 * MS
    rt.stop()


def test_catch_up_policy_runs_every_release():
    rt = Runtime(cycle_time=0.010, clock=VirtualClock(charge_execution=True))
    rt.add_task("main", [Busy(0.035, scans={0})], overrun="catch_up")
    rt.start()
    rt.step(10)
    stats = rt.stats["main"]
    assert stats.cycles == 10 and stats.omitted == 0
    assert stats.overruns >= 3  # scan 0 and the late scans 1, 2 end after their next release
    assert stats.late_max_ns >= 15 * MS
    rt.stop()


def test_fault_policy_goes_to_fault_with_safe_outputs():
    def cycle(ctx):
        ctx.image.write("%QW1", 5)
        ctx.image.write("%QX0.0", False)

    rt = Runtime(
        cycle_time=0.100, clock=VirtualClock(), safe_outputs={"%QX0.0": True}, watchdog=1.0
    )
    rt.add_task("main", [Probe(cycle), Busy(0.110, scans={2})], overrun="fault")
    rt.start()
    assert rt.step(10) == 3
    assert rt.image.read("%QW1") == 0 and rt.image.read("%QX0.0") is True
    assert rt.state == "FAULT"
    assert "task main: overrun" in rt.fault_reason and "interval is 100 ms" in rt.fault_reason
    with pytest.raises(StateError, match="FAULT"):
        rt.step()
    rt.stop()
    rt.start()  # recovers after STOP
    assert rt.state == "RUN"
    rt.stop()


def test_watchdog_measured_in_real_time_on_the_virtual_clock():
    rt = Runtime(cycle_time=1.0, clock=VirtualClock(), watchdog=0.020, watchdog_interrupt=False)
    rt.add_task("main", [Busy(0.030, scans={1})], overrun="catch_up")
    rt.start()
    assert rt.step(5) == 2
    assert rt.state == "FAULT"
    assert (
        "watchdog: scan 1 took" in rt.fault_reason
        and "maximum cycle time is 20 ms" in rt.fault_reason
    )


def test_watchdog_interrupts_a_hung_block():
    def hang(ctx):
        try:
            while True:
                pass
        except Exception:  # a block cannot swallow the watchdog
            pass

    rt = Runtime(cycle_time=1.0, clock=VirtualClock(), watchdog=0.050)
    rt.add_task("main", [Probe(hang)])
    rt.start()
    rt.step()
    assert rt.state == "FAULT"
    assert "exceeded the maximum cycle time of 50 ms and was aborted" in rt.fault_reason
    rt.stop()


def test_block_exception_faults_and_names_the_block():
    def boom(ctx):
        if ctx.cycle == 3:
            raise ZeroDivisionError("division by zero")

    rt = Runtime(cycle_time=0.010, clock=VirtualClock())
    rt.add_task("main", [Probe(lambda ctx: None), Probe(boom)])
    rt.start()
    assert rt.step(10) == 4
    assert rt.fault_reason == "task main: block 1:Probe raised ZeroDivisionError: division by zero"
    assert "ZeroDivisionError" in rt.fault_traceback
    with pytest.raises(StateError):
        rt.run(cycles=5)
    rt.stop()


def test_startup_is_not_monitored():
    def slow_startup(ctx):
        Busy(0.060).cycle(ctx)

    rt = Runtime(cycle_time=0.010, clock=VirtualClock(), watchdog=0.020)
    rt.add_task("main", [Probe(lambda ctx: None, slow_startup)])
    rt.start()
    assert rt.state == "RUN"
    rt.step(3)
    assert rt.state == "RUN"
    rt.stop()


def test_startup_failure_raises_and_faults():
    def bad(ctx):
        raise KeyError("recipe table")

    rt = Runtime(cycle_time=0.010, clock=VirtualClock())
    rt.add_task("main", [Probe(lambda ctx: None, bad)])
    with pytest.raises(StartupError, match="startup of main/0:Probe raised KeyError"):
        rt.start()
    assert rt.state == "FAULT"
    rt.stop()


def test_minimum_cycle_time_spaces_catch_up_ticks():
    starts = []
    rt = Runtime(cycle_time=0.010, clock=VirtualClock(charge_execution=True), min_cycle_time=0.008)
    rt.add_task(
        "main",
        [Probe(lambda ctx: starts.append(rt.clock.now_ns())), Busy(0.035, scans={0})],
        overrun="catch_up",
    )
    rt.start()
    rt.step(20)
    gaps = [b - a for a, b in zip(starts, starts[1:], strict=False)]
    assert min(gaps[1:]) >= 8 * MS  # after the overrun, ticks are at least 8 ms apart
    assert rt.stats["main"].cycles == 20
    rt.stop()


def test_default_virtual_clock_stays_deterministic_through_an_overrun():
    """Without charging, an overrun is counted but does not change the schedule."""
    times = []
    rt = Runtime(cycle_time=0.010, clock=VirtualClock())
    rt.add_task("main", [Busy(0.035, scans={0}), Probe(lambda ctx: times.append(ctx.time_ns))])
    rt.start()
    rt.step(10)
    stats = rt.stats["main"]
    assert stats.overruns == 1 and stats.omitted == 0 and stats.cycles == 10
    assert times == [k * 10 * MS for k in range(10)]
    assert rt.clock.now_ns() == 9 * 10 * MS
    rt.stop()


def test_deadlines_are_absolute_no_drift():
    """Scans that take time must not push later releases: the clock is asked for
    exactly t0 + k * tick, whatever the execution time was."""

    class RecordingClock(VirtualClock):
        def __init__(self):
            super().__init__(charge_execution=True)
            self.deadlines = []

        def wait_until(self, deadline_ns):
            self.deadlines.append(deadline_ns)
            super().wait_until(deadline_ns)

    clock = RecordingClock()
    rt = Runtime(cycle_time=0.010, clock=clock)
    rt.add_task("main", [Busy(0.003)])
    rt.start()
    rt.step(20)
    assert clock.deadlines == [k * 10 * MS for k in range(20)]
    rt.stop()


def test_retain_save_costs_lateness_not_scan_time(tmp_path, monkeypatch):
    from plc_runtime.retain import RetainFile

    real_save = RetainFile.save

    def slow_save(self, layout, values):  # a disk whose fsync takes 60 ms
        Busy(0.060).cycle(None)
        real_save(self, layout, values)

    monkeypatch.setattr(RetainFile, "save", slow_save)
    rt = Runtime(
        cycle_time=0.010,
        clock=VirtualClock(),
        watchdog=0.040,
        retain_file=tmp_path / "r",
        retain_interval=0.02,
    )
    rt.add_task("main", [Probe(lambda ctx: None)])
    rt.start()
    rt.step(6)
    assert rt.state == "RUN", rt.fault_reason
    rt.stop()


def test_min_cycle_time_longer_than_the_cycle_is_rejected():
    from plc_runtime import ConfigError

    with pytest.raises(ConfigError, match="min_cycle_time"):
        Runtime(cycle_time=0.010, min_cycle_time=0.020)


def test_stop_from_another_thread_waits_for_the_scan():
    import threading

    in_scan = threading.Event()

    def cycle(ctx):
        ctx.image.write("%QX0.0", True)
        in_scan.set()
        Busy(0.050).cycle(ctx)

    rt = Runtime(cycle_time=0.010, clock=VirtualClock(), watchdog=1.0)
    rt.add_task("main", [Probe(cycle)])
    rt.start()
    stopper = threading.Thread(target=lambda: (in_scan.wait(), rt.stop()))
    stopper.start()
    try:
        rt.step(100)  # the other thread stops it during the first scan
    finally:
        stopper.join()
    assert rt.state == "STOP"
    assert rt.image.read("%QX0.0") is False  # the safe state, not the scan's copy-out
    with pytest.raises(StateError):
        rt.step()


def test_stop_from_inside_a_scan_is_refused():
    rt = Runtime(cycle_time=0.010, clock=VirtualClock())
    rt.add_task("main", [Probe(lambda ctx: rt.stop())])
    rt.start()
    rt.step()
    assert rt.state == "FAULT" and "use request_stop()" in rt.fault_reason
    rt.stop()


def test_a_swallowed_watchdog_interrupt_comes_again():
    def stubborn(ctx):
        try:
            while True:
                pass
        except BaseException:  # swallows even the watchdog once...
            pass
        while True:  # ...and hangs again: interrupted again
            pass

    rt = Runtime(cycle_time=1.0, clock=VirtualClock(), watchdog=0.050)
    rt.add_task("main", [Probe(stubborn)])
    rt.start()
    rt.step()
    assert rt.state == "FAULT" and "was aborted" in rt.fault_reason
    rt.stop()


def test_the_safe_state_is_published_whole_after_a_watchdog_fault(monkeypatch):
    """A machine so busy that publishing the safe state takes longer than the watchdog's
    repeat (10 ms): the repeat used to interrupt the fault handling itself, and the
    WatchdogTimeout escaped the runtime as a traceback, with the safe state half written.
    Once the fault is being handled, no alarm interrupts it."""
    from plc_runtime.image import ProcessImage

    publish = ProcessImage.publish_safe_state
    published = []

    def slow_publish(image, safe_outputs):
        Busy(0.040).cycle(None)  # Python busy-waiting: the alarm's handler runs in here
        publish(image, safe_outputs)
        published.append(True)

    monkeypatch.setattr(ProcessImage, "publish_safe_state", slow_publish)
    rt = Runtime(cycle_time=1.0, clock=VirtualClock(), watchdog=0.005)
    rt.add_task("main", [Busy(0.050, scans={0})])
    rt.start()
    rt.step()
    assert rt.state == "FAULT" and "was aborted" in rt.fault_reason
    assert published == [True]
    rt.stop()


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")  # (as intended)
def test_the_cleanup_of_a_failed_scan_is_still_interrupted():
    """What a failed block leaves behind runs when its exception is released, after the
    fault: a generator's ``finally`` here, waiting for an answer that never comes. The
    watchdog holds off only while the safe state is published, so that hang is still cut."""
    finished = []

    def fail(ctx):
        def transfer():
            try:
                yield b"frame"
            finally:
                end = time.perf_counter() + 30.0  # stands in for a hang: bounded, for a test
                while time.perf_counter() < end:
                    pass
                finished.append(True)

        pending = transfer()
        next(pending)
        raise OSError("bus error")

    rt = Runtime(cycle_time=1.0, clock=VirtualClock(), watchdog=0.050)
    rt.add_task("main", [Probe(fail)])
    rt.start()
    rt.step()
    assert rt.state == "FAULT" and "raised OSError: bus error" in rt.fault_reason
    assert finished == []  # the wait was interrupted, not waited out
    rt.stop()


def test_second_runtime_falls_back_to_the_after_the_fact_check():
    first = Runtime(cycle_time=1.0, clock=VirtualClock())
    first.add_task("main", [Probe(lambda ctx: None)])
    second = Runtime(cycle_time=1.0, clock=VirtualClock(), watchdog=0.020)
    second.add_task("main", [Busy(0.030, scans={0})])
    first.start()
    with pytest.warns(RuntimeWarning, match="watchdog interrupt not available"):
        second.start()
    second.step()
    assert second.state == "FAULT" and "took" in second.fault_reason  # still caught, after the scan
    second.stop()
    first.stop()


def test_min_cycle_time_does_not_space_skipped_ticks():
    def omitted(min_cycle):
        rt = Runtime(
            cycle_time=0.010, clock=VirtualClock(charge_execution=True), min_cycle_time=min_cycle
        )
        rt.add_task("main", [Busy(0.035, scans={0})], overrun="skip")
        rt.start()
        rt.step(10)
        rt.stop()
        return rt.stats["main"].omitted, rt.stats["main"].exec_max_ns

    skipped, exec_ns = omitted(0.008)
    assert skipped == exec_ns // (10 * MS) - 1  # the same releases as without a minimum


def test_stop_request_in_the_last_tick_is_not_lost():
    rt = Runtime(cycle_time=0.010, clock=VirtualClock())
    rt.add_task("main", [Probe(lambda ctx: ctx.cycle == 4 and rt.request_stop())])
    rt.start()
    assert rt.run(cycles=5) == 5  # the request came in the last tick of this chunk
    assert rt.run(cycles=5) == 0  # and ends the next run at once
    assert rt.run(cycles=5) == 5
    rt.stop()


def test_a_stats_copy_freezes_the_counters_and_may_share_the_window():
    from plc_runtime.stats import ScanStats

    live = ScanStats("main", window=4)
    for ns in (10, 20, 30, 40):
        live.record(ns, 0)
    frozen, shared = live.copy(), live.copy(share_window=True)
    live.record(1000, 7)  # overwrites the oldest slot in place
    for copy in (frozen, shared):
        assert copy.cycles == 4 and copy.exec_max_ns == 40 and copy.exec_mean_ns == 25
    assert frozen.exec_percentile_ns(100) == 40  # its own arrays: the window at the copy
    assert shared.exec_percentile_ns(100) == 1000  # the live window, moved on by one scan
    assert shared.late_percentile_ns(100) == 7
    assert live.cycles == 5 and live.exec_max_ns == 1000


class Field:
    """A driver that pushes %QX0.0 out whenever it is asked (a coupler, a bus): what the
    field saw, and the times the runtime handed it."""

    name = "field"

    def __init__(self) -> None:
        self.sent: list[bool] = []
        self.times: list[tuple[str, int]] = []

    def open(self, image) -> None:
        self._q = image.output_reader("%QX0.0")

    def read_inputs(self, image, now_ns: int) -> None:
        self.times.append(("in", now_ns))

    def write_outputs(self, image, now_ns: int) -> None:
        self.sent.append(self._q())
        self.times.append(("out", now_ns))

    def close(self) -> None: ...

    def stats(self) -> dict[str, object]:
        return {}


def test_a_fault_sends_the_safe_state_to_the_field_at_once():
    """A CPU going to STOP drives its outputs to their substitute values at once; a driver
    that pushes outputs must not hold the last scan's until someone calls stop()."""

    def cycle(ctx):
        ctx.image.write("%QX0.0", True)
        if ctx.cycle == 2:
            raise ValueError("sensor table empty")

    rt = Runtime(cycle_time=0.010, clock=VirtualClock(), watchdog=1.0)
    field = Field()
    rt.add_driver(field)
    rt.add_task("main", [Probe(cycle)])
    rt.start()
    rt.step(5)
    assert rt.state == "FAULT" and field.sent == [True, True, False]
    rt.stop()
    assert field.sent == [True, True, False, False]


def test_a_scan_over_the_watchdog_never_sends_its_outputs():
    """Without the interrupt (a runtime outside the main thread, or a block swallowing it)
    the limit is checked after the tasks: the late scan's outputs are not copied out, the
    field gets the safe state."""
    rt = Runtime(cycle_time=1.0, clock=VirtualClock(), watchdog=0.020, watchdog_interrupt=False)
    field = Field()
    rt.add_driver(field)
    rt.add_task("main", [Probe(lambda ctx: ctx.image.write("%QX0.0", ctx.cycle == 1))])
    rt.add_task("busy", [Busy(0.030, scans={1})], priority=1)
    rt.start()
    rt.step(3)
    assert rt.state == "FAULT" and "its outputs were not copied out" in rt.fault_reason
    assert field.sent == [False, False] and rt.image.read("%QX0.0") is False
    rt.stop()


def test_drivers_get_the_tick_s_iec_time_on_both_sides():
    """read_inputs and write_outputs get the same time base (the tick's release since the
    start), whichever task ran and whatever the clock's own time: a driver times its
    heartbeats and repeats from it."""
    rt = Runtime(cycle_time=0.010, clock=VirtualClock(start=100.0), watchdog=1.0)
    field = Field()
    rt.add_driver(field)
    rt.add_task("slow", [Probe(lambda ctx: None)], interval=0.020)
    rt.start()
    rt.step(4)
    tick = 10_000_000
    assert field.times == [(side, k * tick) for k in range(4) for side in ("in", "out")]
    rt.stop()
    assert field.times[-1] == ("out", 3 * tick)  # the safe state at stop: the same base


def test_run_until_is_no_success_when_the_runtime_faulted():
    """The safe state may satisfy the predicate (an output gone off); that is a fault."""

    def cycle(ctx):
        ctx.image.write("%QX0.0", True)
        if ctx.cycle == 3:
            raise ValueError("sensor table empty")

    rt = Runtime(cycle_time=0.010, clock=VirtualClock(), watchdog=1.0)
    rt.add_task("main", [Probe(cycle)])
    rt.start()
    rt.step()
    assert rt.run_until(lambda: not rt.image.read("%QX0.0"), max_cycles=100) is False
    assert rt.state == "FAULT"
    rt.stop()
