"""Task scheduling: intervals, priorities and phase offsets on the virtual clock."""

import time

import pytest
from conftest import Probe
from hypothesis import given, settings
from hypothesis import strategies as st

from plc_runtime import ConfigError, Runtime, StateError, VirtualClock

task_specs = st.lists(
    st.tuples(st.integers(1, 6), st.integers(0, 5), st.integers(0, 3)).map(
        lambda t: (t[0], t[1] % t[0], t[2])  # (interval ticks, phase ticks < interval, priority)
    ),
    min_size=1,
    max_size=5,
)


@settings(max_examples=100, deadline=None)
@given(task_specs, st.integers(1, 40))
def test_due_tasks_run_in_priority_order(specs, ticks):
    # A 1 s base tick: no realistic scheduler stall can make these trivial scans overrun.
    tick = 1.0
    rt = Runtime(cycle_time=tick, clock=VirtualClock())
    log = []
    for n, (interval, phase, priority) in enumerate(specs):
        name = f"t{n}"
        rt.add_task(
            name,
            [Probe(lambda ctx, name=name: log.append((round(ctx.time / tick), name, ctx.cycle)))],
            interval=interval * tick,
            phase=phase * tick,
            priority=priority,
        )
    rt.start()
    rt.step(ticks)
    rt.stop()

    expected, counts = [], {}
    for k in range(ticks):
        due = [(p, n) for n, (i, ph, p) in enumerate(specs) if k >= ph and (k - ph) % i == 0]
        for _p, n in sorted(due):
            expected.append((k, f"t{n}", counts.get(n, 0)))
            counts[n] = counts.get(n, 0) + 1
    assert log == expected
    for n in range(len(specs)):
        assert rt.stats[f"t{n}"].cycles == counts.get(n, 0)


def test_virtual_time_advances_exactly_one_tick_per_step():
    times = []
    rt = Runtime(cycle_time=0.010, clock=VirtualClock())
    rt.add_task("main", [Probe(lambda ctx: times.append(ctx.time_ns))])
    rt.start()
    assert rt.step() == 1
    assert rt.step(99) == 99
    assert times == [k * 10_000_000 for k in range(100)]
    assert rt.clock_time == pytest.approx(1.0)
    assert rt.run(duration=0.5) == 50
    assert rt.run(cycles=7) == 7
    assert rt.stats.cycles == 157
    rt.stop()


def test_run_until():
    rt = Runtime(cycle_time=0.010, clock=VirtualClock())
    rt.add_task("main", [Probe(lambda ctx: ctx.image.write("%QX0.0", ctx.cycle >= 9))])
    rt.start()
    assert rt.run_until(lambda: rt.image.read("%QX0.0"), max_cycles=100) is True
    assert rt.ticks == 10
    assert rt.run_until(lambda: False, max_cycles=5) is False
    assert rt.ticks == 15
    with pytest.raises(ConfigError, match=r"duration 0.004 s is less than half a cycle \(0.01 s\)"):
        rt.run(duration=0.004)
    assert rt.run(duration=0) == 0 and rt.run(duration=0.006) == 1
    for bad in (True, False):  # a truth value is no count
        with pytest.raises(ConfigError, match="must be a non-negative integer"):
            rt.step(bad)
        with pytest.raises(ConfigError, match="must be a non-negative integer"):
            rt.run(cycles=bad)
    with pytest.raises(
        ConfigError, match=r"duration must be a finite number of seconds >= 0, got inf"
    ):
        rt.run(duration=float("inf"))
    for bad in (0, -1, 2.5, True):  # a count that can mean nothing is an error, not "never"
        with pytest.raises(ConfigError, match="max_cycles must be a positive integer"):
            rt.run_until(lambda: False, max_cycles=bad)
    assert rt.ticks == 16
    # the predicate is first asked after a scan: an output true before it is not enough
    assert rt.run_until(lambda: rt.image.read("%QX0.0"), max_cycles=5) is True
    assert rt.ticks == 17
    rt.stop()


def _burn(seconds: float) -> None:
    """Use real time on the CPU, as a slow block would."""
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


def _deadline_seen(clock) -> tuple[float, bool, float, float]:
    """What a block sees of its deadline after using 6 ms of a 5 ms budget."""
    seen = []

    def cycle(ctx):
        _burn(0.006)
        seen.append((ctx.remaining(), ctx.expired(), ctx.elapsed_ns() / 1e9, ctx.dt))

    # the watchdog is not what this tests: a busy machine may stretch the burn
    rt = Runtime(cycle_time=0.010, clock=clock, watchdog=60.0)
    rt.add_task("main", [Probe(cycle)], interval=0.020, budget=0.005)
    rt.start()
    rt.step()
    rt.stop()
    return seen[0]


def test_deadline_stands_still_on_the_virtual_clock():
    """Time does not pass during a scan on the virtual clock, so its deadline never comes:
    a block that stops at it does the same work however long the host takes."""
    left, expired, elapsed, dt = _deadline_seen(VirtualClock())
    assert left == 0.005 and not expired and dt == 0.020
    assert elapsed >= 0.006  # real execution time is still there to read


def test_deadline_passes_where_the_clock_charges_execution():
    left, expired, elapsed, _dt = _deadline_seen(VirtualClock(charge_execution=True))
    assert left <= -0.001 and expired and elapsed >= 0.006


@pytest.mark.parametrize(
    "kwargs,message",
    [
        ({"interval": 0.015}, "not a multiple of the base cycle time"),
        ({"interval": 0.020, "phase": 0.020}, "must be smaller than the interval"),
        ({"interval": 0.020, "phase": 0.005}, "phase 0.005 s is not a multiple"),
        ({"overrun": "ignore"}, "overrun policy 'ignore'"),
        ({"priority": 1.5}, "priority must be an integer"),
        ({"interval": -1}, "interval must be a finite number of seconds > 0"),
        ({"interval": float("inf")}, "interval must be a finite number of seconds > 0"),
        ({"budget": float("nan")}, "budget must be a finite number of seconds"),
    ],
)
def test_task_configuration_errors(kwargs, message):
    rt = Runtime(cycle_time=0.010, clock=VirtualClock())
    with pytest.raises(ConfigError, match=message):
        rt.add_task("main", [Probe(lambda ctx: None)], **kwargs)


def test_structural_errors():
    rt = Runtime(cycle_time=0.010, clock=VirtualClock())
    block = Probe(lambda ctx: None)
    with pytest.raises(ConfigError, match="no tasks"):
        rt.start()
    rt.add_task("a", [block])
    with pytest.raises(ConfigError, match="already exists"):
        rt.add_task("a", [Probe(lambda ctx: None)])
    with pytest.raises(ConfigError, match="already scheduled"):
        rt.add_task("b", [block])
    with pytest.raises(ConfigError, match="not a FunctionBlock"):
        rt.add_task("c", [object()])
    with pytest.raises(StateError, match="cannot step in state STOP"):
        rt.step()
    rt.start()
    with pytest.raises(StateError, match="cannot add a task in state RUN"):
        rt.add_task("d", [Probe(lambda ctx: None)])
    with pytest.raises(ConfigError):
        Runtime(cycle_time=0)
    rt.stop()
    assert rt.state == "STOP"


def test_request_stop_ends_an_open_ended_run():
    rt = Runtime(cycle_time=0.010, clock=VirtualClock())
    rt.add_task("main", [Probe(lambda ctx: ctx.cycle == 41 and rt.request_stop())])
    rt.start()
    assert rt.run() == 42  # returns after the tick in which the stop was requested
    assert rt.state == "RUN"
    assert rt.run(cycles=3) == 3  # the request does not stick
    rt.stop()
