"""Copy-in / copy-out, the quiet point and forcing, seen through a running runtime."""

import pytest
from conftest import Probe
from hypothesis import given, settings
from hypothesis import strategies as st

from plc_runtime import AddressError, Runtime, VirtualClock, WritesBacklogged


def started(*blocks, **kwargs) -> Runtime:
    rt = Runtime(cycle_time=0.010, clock=VirtualClock(), **kwargs)
    rt.add_task("main", list(blocks))
    rt.start()
    return rt


def test_input_written_during_a_cycle_is_invisible_until_next_cycle_start():
    seen = []
    rt = None

    def cycle(ctx):
        seen.append(ctx.image.read("%IX0.3"))
        if ctx.cycle == 0:
            rt.image.write("%IX0.3", True)  # the field changes mid-scan
            seen.append(ctx.image.read("%IX0.3"))

    rt = started(Probe(cycle))
    rt.step()
    assert seen == [False, False]
    rt.step()
    assert seen[-1] is True


def test_external_input_write_between_cycles_is_seen_at_next_cycle():
    seen = []
    rt = started(Probe(lambda ctx: seen.append(ctx.image.read("%IW2"))))
    rt.step()
    rt.image.write("%IW2", 1234)
    assert rt.image.read("%IW2") == 0  # not applied before the quiet point
    rt.step()
    assert seen == [0, 1234]
    assert rt.image.read("%IW2") == 1234


def test_outputs_appear_only_after_the_cycle_and_last_write_wins():
    during = []
    rt = None

    def cycle(ctx):
        ctx.image.write("%QW2", 7)
        ctx.image.write("%QW2", 42)  # the last assignment counts
        during.append(rt.image.read("%QW2"))
        during.append(ctx.image.read("%QW2"))  # the program sees its own working image

    rt = started(Probe(cycle))
    rt.step()
    assert during == [0, 42]
    assert rt.image.read("%QW2") == 42


def test_program_cannot_write_inputs():
    rt = started(Probe(lambda ctx: ctx.image.write("%IX0.0", True)))
    rt.step()
    assert rt.state == "FAULT"
    assert "%IX0.0: inputs are read-only" in rt.fault_reason


def test_bad_address_in_a_block_faults_with_the_address():
    rt = started(Probe(lambda ctx: ctx.image.read("%QW99999")))
    rt.step()
    assert rt.state == "FAULT" and "%QW99999" in rt.fault_reason
    with pytest.raises(AddressError):
        rt.image.read("%QW99999")


def test_input_force_wins_over_field_value():
    seen = []
    rt = started(Probe(lambda ctx: seen.append(ctx.image.read("%IX0.0"))))
    rt.image.write("%IX0.0", False)
    rt.image.force("%IX0.0", True)
    assert rt.image.forces == {}  # applied at the quiet point, not before
    rt.step()
    assert rt.image.forces == {"%IX0.0": True}
    assert rt.stats.to_dict()["forces"] == {"%IX0.0": True}
    rt.image.write("%IX0.0", False)
    rt.step()
    assert seen == [True, True]
    rt.image.unforce("%IX0.0")
    rt.step()
    assert seen[-1] is False and rt.image.forces == {}


def test_output_force_wins_over_program_write():
    rt = started(Probe(lambda ctx: ctx.image.write("%QX0.1", False)))
    rt.image.force("%QX0.1", True)
    rt.step()
    assert rt.image.read("%QX0.1") is True
    rt.image.unforce_all()
    rt.step()
    assert rt.image.read("%QX0.1") is False


def test_marker_force_is_reapplied_at_cycle_end():
    seen = []

    def cycle(ctx):
        seen.append(ctx.image.read("%MW0"))
        ctx.image.write("%MW0", 1)

    rt = started(Probe(cycle))
    rt.image.force("%MW0", 500)
    rt.step(2)
    assert seen == [500, 500] and rt.image.read("%MW0") == 500


def test_external_output_write_lands_in_working_image():
    rt = started(Probe(lambda ctx: None))
    rt.image.write("%QW0", 9)
    assert rt.image.read("%QW0") == 0
    rt.step()
    assert rt.image.read("%QW0") == 9  # program did not overwrite it


def test_startup_sees_zero_inputs_and_outputs_are_copied_after_first_cycle():
    seen = []

    def startup(ctx):
        seen.append(ctx.image.read("%IW0"))
        ctx.image.write("%QX0.0", True)

    rt = Runtime(cycle_time=0.01, clock=VirtualClock())
    rt.image.write("%IW0", 5)
    rt.add_task("main", [Probe(lambda ctx: None, startup)])
    rt.start()
    assert seen == [0] and rt.image.read("%QX0.0") is False
    rt.step()
    assert rt.image.read("%QX0.0") is True
    rt.stop()


ops = st.lists(
    st.one_of(
        st.tuples(st.just("field"), st.integers(0, 3), st.integers(0, 255)),
        st.tuples(st.just("force"), st.integers(0, 3), st.integers(0, 255)),
        st.tuples(st.just("unforce"), st.integers(0, 3), st.just(0)),
        st.tuples(st.just("step"), st.just(0), st.just(0)),
    ),
    max_size=40,
)


@settings(max_examples=150, deadline=None)
@given(ops)
def test_image_semantics_against_a_model(operations):
    """Random field writes, forces and cycles: each cycle the program copies %IB0..3 to
    %QB0..3; what it saw and what was published must match a plain model of the rules."""
    seen = []

    def cycle(ctx):
        values = [ctx.image.read(f"%IB{i}") for i in range(4)]
        seen.append(values)
        for i, v in enumerate(values):
            ctx.image.write(f"%QB{i}", v)

    rt = started(Probe(cycle))
    field, forces, pending = [0] * 4, {}, []
    for op, i, value in operations:
        if op == "field":
            rt.image.write(f"%IB{i}", value)
            pending.append(("field", i, value))
        elif op == "force":
            rt.image.force(f"%IB{i}", value)
            pending.append(("force", i, value))
        elif op == "unforce":
            rt.image.unforce(f"%IB{i}")
            pending.append(("unforce", i, 0))
        else:
            for kind, j, v in pending:  # the quiet point, in order
                if kind == "field":
                    field[j] = v
                elif kind == "force":
                    forces[j] = v
                else:
                    forces.pop(j, None)
            pending.clear()
            expected = [forces.get(j, field[j]) for j in range(4)]
            rt.step()
            assert seen[-1] == expected
            assert [rt.image.read(f"%QB{j}") for j in range(4)] == expected
    rt.stop()


def test_writes_from_another_thread_never_change_inputs_mid_scan():
    """A writer thread races the scan; blocks must still see one constant snapshot per
    scan, and every value they see must be one the writer wrote, in order."""
    import threading

    seen = []

    def cycle(ctx):
        first = ctx.image.read("%ID0")
        for _ in range(50):
            assert ctx.image.read("%ID0") == first
        seen.append(first)

    # the writer holds the GIL against the scan: on a busy machine a scan can take long
    rt = started(Probe(cycle), watchdog=5.0)
    stop = threading.Event()

    def writer():
        value = 0
        while not stop.is_set() and value < 200_000:
            try:
                rt.image.write("%ID0", value + 1)
            except WritesBacklogged:  # the scan has not taken the queue yet: nothing queued
                stop.wait(0.001)  # (a busy machine: give the scan the processor)
            else:
                value += 1

    thread = threading.Thread(target=writer)
    thread.start()
    try:
        rt.step(300)
    finally:
        stop.set()
        thread.join()
    rt.step()
    assert rt.state == "RUN", rt.fault_reason
    assert seen == sorted(seen)  # applied in order, never going back
    assert seen[-1] > 0


def test_a_force_is_one_per_location_whatever_its_name():
    from plc_runtime import TagTable

    tags = TagTable()
    tags.add("lamp", "%QX0.0")
    rt = started(Probe(lambda ctx: ctx.image.write("lamp", False)), tags=tags)
    rt.image.force("lamp", True)
    rt.step()
    assert rt.image.read("%QX0.0") is True and rt.image.forces == {"lamp": True}
    rt.image.force("%QX0.0", False)  # the same output: replaces, does not add
    rt.image.unforce("lamp")  # and released by either name
    rt.step()
    assert rt.image.forces == {}
    rt.stop()
