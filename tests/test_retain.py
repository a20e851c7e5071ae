"""Retentive memory: warm and cold restarts, the crash-safe file and its failure modes."""

import json
import os
import re
import zlib
from pathlib import Path

import pytest

from blocks.standard import CTU
from fleet.config import load_config
from plc_runtime import FunctionBlock, RetainError, Runtime, Static, TagTable, VirtualClock
from plc_runtime.errors import ConfigError
from topology import TopologyError, load


class Machine(FunctionBlock):
    """Counts scans into retentive and non-retentive state, and into two marker tags."""

    total = Static(0, retain=True)
    since_start = Static(0)

    def __init__(self) -> None:
        super().__init__()
        self.parts = CTU(retain=True)

    def cycle(self, ctx) -> None:
        self.total += 1
        self.since_start += 1
        self.parts(ctx, CU=ctx.cycle % 2 == 0, PV=100)
        ctx.image.write("kept", self.total)
        ctx.image.write("lost", self.since_start)


def build(path=None, extra_retain=False, **kwargs) -> tuple[Runtime, Machine]:
    tags = TagTable()
    tags.add("kept", "%MW0", "INT", retain=True)
    tags.add("lost", "%MW1", "INT")
    if extra_retain:
        tags.add("extra", "%MW2", "INT", retain=True)
    rt = Runtime(cycle_time=0.01, clock=VirtualClock(), tags=tags, retain_file=path, **kwargs)
    machine = Machine()
    rt.add_task("main", [machine])
    return rt, machine


def values(rt, machine):
    return (
        machine.total,
        machine.since_start,
        machine.parts.CV,
        rt.image.read("kept"),
        rt.image.read("lost"),
    )


def test_warm_restart_keeps_retain_and_resets_the_rest():
    rt, m = build()
    rt.start()
    rt.step(10)
    rt.stop()
    rt.start()
    assert values(rt, m) == (10, 0, 5, 10, 0)
    rt.step(1)
    assert values(rt, m) == (11, 1, 6, 11, 1)
    rt.stop()


def test_cold_restart_clears_retain():
    rt, m = build()
    rt.start()
    rt.step(10)
    rt.stop()
    rt.start(mode="cold")
    assert values(rt, m) == (0, 0, 0, 0, 0)
    rt.stop()


def test_process_restart_through_the_file(tmp_path):
    path = tmp_path / "plc.retain"
    rt, m = build(path)
    rt.start()
    assert "does not exist yet" in rt.start_info
    rt.step(7)
    rt.stop()
    assert path.exists() and not (tmp_path / "plc.retain.tmp").exists()
    rt2, m2 = build(path)  # a new process: a new runtime and new blocks
    rt2.start()
    assert values(rt2, m2) == (7, 0, 4, 7, 0)
    assert "retain data from" in rt2.start_info
    rt2.stop()


def _saved(tmp_path, steps=5):
    path = tmp_path / "plc.retain"
    rt, _ = build(path)
    rt.start()
    rt.step(steps)
    rt.stop()
    return path


@pytest.mark.parametrize(
    "damage,message",
    [
        (lambda raw: raw[:-3] + bytes([raw[-3] ^ 0x01]) + raw[-2:], "corrupted (CRC mismatch)"),
        (lambda raw: raw[:-5], "truncated retain file"),
        (lambda raw: raw + b"\n", "wrong length: 1 trailing byte(s) after the"),
        (lambda raw: b"\x00\xff garbage \x13" * 10, "not a retain file"),
        (lambda raw: b"", "not a retain file"),
    ],
)
def test_damaged_file_gives_a_message_and_a_cold_start(tmp_path, damage, message):
    path = _saved(tmp_path)
    path.write_bytes(damage(path.read_bytes()))
    rt, m = build(path)
    with pytest.warns(RuntimeWarning, match=re.escape(message)):
        rt.start()
    assert rt.start_info.startswith("cold:") and message in rt.start_info
    assert values(rt, m) == (0, 0, 0, 0, 0)
    rt.stop()


def _with_body(path, body: bytes) -> None:
    """The file with this body under a valid header (a hand edit or another tool)."""
    magic, version, layout, _crc, _length = path.read_bytes().split(b"\n", 1)[0].split(b" ")
    head = b" ".join([magic, version, layout, b"%08x" % zlib.crc32(body), b"%d" % len(body)])
    path.write_bytes(head + b"\n" + body)


def _rewritten(path, change) -> None:
    """The file with its values changed and its header made valid again (a hand edit)."""
    _with_body(path, json.dumps(change(json.loads(path.read_bytes().split(b"\n", 1)[1]))).encode())


def _refused_at_start(tmp_path, path, message: str) -> None:
    """A start on the edited file: one warning naming the file and why, a cold start, and
    the file set aside as it was, as a damaged file is."""
    edited = path.read_bytes()
    rt, m = build(path)
    with pytest.warns(RuntimeWarning, match=re.escape(f"{path}: {message}")):
        rt.start()
    assert rt.start_info.startswith("cold:") and values(rt, m) == (0, 0, 0, 0, 0)
    assert (tmp_path / "plc.retain.rejected").read_bytes() == edited
    rt.stop()


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("tag:kept", 70000, "tag:kept: 70000 is outside the INT range -32768..32767"),
        ("tag:kept", "x", "tag:kept: INT expects an integer, got 'x'"),
        ("tag:kept", True, "tag:kept: INT expects an integer, got True"),
    ],
)
def test_a_value_its_variable_cannot_take_gives_a_cold_start_and_keeps_the_file(
    tmp_path, key, value, message
):
    """A checksum that holds over a value the tag cannot take (a file edited by hand and
    its header redone): one warning naming the file and the key, a cold start, and the
    file kept aside, as a damaged file is."""
    path = _saved(tmp_path)
    assert key in json.loads(path.read_bytes().split(b"\n", 1)[1])  # a key the program uses
    _rewritten(path, lambda values: {**values, key: value})
    _refused_at_start(tmp_path, path, message)


@pytest.mark.parametrize(
    ("body", "message"),
    [
        (
            lambda kept: kept[:-1] + b', "junk": 5}',
            "'junk' is no retentive variable of this program",
        ),
        (lambda kept: kept[:-1] + b', "tag:kept": 7}', "retain file gives 'tag:kept' twice"),
        (lambda kept: b"[" * 100_000 + b"]" * 100_000, "retain file body is nested too deeply"),
    ],
)
def test_a_file_with_other_keys_or_a_key_twice_gives_a_cold_start(tmp_path, body, message):
    """Values a program does not have would be written back for ever unnoticed, and of a key
    given twice nobody can tell which was meant: both are refused as damage is, with the
    file set aside, and so is a body nested too deeply to read."""
    path = _saved(tmp_path)
    _with_body(path, body(path.read_bytes().split(b"\n", 1)[1]))
    _refused_at_start(tmp_path, path, message)


class Odometer(FunctionBlock):
    """Declared with an int, holds a float: nothing fixes a block variable's type."""

    km = Static(0, retain=True)

    def cycle(self, ctx) -> None:
        self.km += 0.5


def test_a_block_variable_comes_back_as_it_was_saved(tmp_path):
    path = tmp_path / "plc.retain"
    for expected in (0, 1.5):
        rt = Runtime(cycle_time=0.01, clock=VirtualClock(), retain_file=path)
        odometer = Odometer()
        rt.add_task("main", [odometer])
        rt.start()
        assert odometer.km == expected and rt.start_info.startswith("warm")
        rt.step(3)
        rt.stop()


def test_layout_mismatch_gives_a_cold_start(tmp_path):
    path = _saved(tmp_path)
    rt, m = build(path, extra_retain=True)
    with pytest.warns(RuntimeWarning, match="different program layout"):
        rt.start()
    assert values(rt, m)[0] == 0
    rt.stop()


def test_crash_during_write_keeps_the_previous_file(tmp_path, monkeypatch):
    path = _saved(tmp_path, steps=5)
    before = path.read_bytes()
    rt, m = build(path)
    rt.start()
    rt.step(3)

    def crash(src, dst):
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(RetainError, match="cannot write retain file"):
        rt.save_retain()
    assert path.read_bytes() == before
    monkeypatch.undo()
    rt.stop()
    rt2, m2 = build(path)
    rt2.start()
    assert m2.total == 8
    rt2.stop()


def test_periodic_save_survives_a_crash(tmp_path):
    path = tmp_path / "plc.retain"
    # this runtime "crashes" (is never stopped): it must not keep the process's SIGALRM
    rt = Runtime(
        cycle_time=0.01,
        clock=VirtualClock(),
        retain_file=path,
        retain_interval=0.05,
        watchdog_interrupt=False,
    )
    rt.image.tags.add("kept", "%MW0", "INT", retain=True)
    rt.image.tags.add("lost", "%MW1", "INT")
    rt.add_task("main", [Machine()])
    rt.start()
    rt.step(12)  # saved at the quiet point before ticks 5 and 10: the state after 10 scans
    # the process dies here, without stop(); a new one starts from the file
    rt2, m2 = build(path)
    rt2.start()
    assert values(rt2, m2) == (10, 0, 5, 10, 0)
    rt2.stop()


def test_unserialisable_retain_value_is_a_clear_error(tmp_path):
    class Bad(FunctionBlock):
        thing = Static(None, retain=True)

        def cycle(self, ctx):
            self.thing = object()

    path = tmp_path / "x.retain"
    rt = Runtime(cycle_time=0.01, clock=VirtualClock(), retain_file=path)
    rt.add_task("main", [Bad()])
    rt.start()
    rt.step()
    with pytest.raises(
        RetainError, match="retain value fb:main/0:Bad.thing cannot be stored: type object"
    ):
        rt.save_retain()
    with pytest.warns(RuntimeWarning, match="retain file not saved"):
        rt.stop()
    assert rt.state == "STOP" and not path.exists()


def test_cold_start_clears_the_file(tmp_path):
    path = _saved(tmp_path, steps=5)
    rt, m = build(path, watchdog_interrupt=False)  # crashes below: never stopped
    rt.start(mode="cold")
    rt.step(2)
    del rt  # the process crashes: no stop()
    rt2, m2 = build(path)
    rt2.start()
    assert m2.total == 0  # not the 5 from before the cold start
    rt2.stop()


def test_changed_variable_type_gives_a_cold_start(tmp_path):
    path = tmp_path / "plc.retain"

    def program(default):
        cls = type(
            "Keeper",
            (FunctionBlock,),
            {"value": Static(default, retain=True), "cycle": lambda self, ctx: None},
        )
        rt = Runtime(cycle_time=0.01, clock=VirtualClock(), retain_file=path)
        block = cls()
        rt.add_task("main", [block])
        return rt, block

    rt, block = program(0)
    rt.start()
    block.value = 41
    rt.stop()
    rt, block = program([])  # the new program version keeps a list there
    with pytest.warns(RuntimeWarning, match="different program layout"):
        rt.start()
    assert block.value == []
    rt.stop()


def test_values_that_would_change_in_the_file_are_refused(tmp_path):
    class Table(FunctionBlock):
        by_id = Static({}, retain=True)
        pair = Static((0, 0), retain=True)

    path = tmp_path / "t.retain"
    rt = Runtime(cycle_time=0.01, clock=VirtualClock(), retain_file=path)
    block = Table()
    rt.add_task("main", [block])
    rt.start()
    block.pair = (3, 4)
    block.by_id = {7: "x"}  # int keys would come back as strings
    with pytest.raises(RetainError, match="dict keys must be strings"):
        rt.save_retain()
    with pytest.warns(RuntimeWarning, match="retain file not saved"):
        rt.stop()
    assert rt.state == "STOP"
    block.by_id = {"7": "x"}
    rt.start()  # warm, from memory
    block.pair, block.by_id = (3, 4), {"7": "x"}
    rt.stop()
    rt2 = Runtime(cycle_time=0.01, clock=VirtualClock(), retain_file=path)
    again = Table()
    rt2.add_task("main", [again])
    rt2.start()
    assert again.pair == (3, 4) and isinstance(again.pair, tuple)  # tuples come back as tuples
    rt2.stop()


def test_retain_file_that_is_a_directory_is_a_config_error(tmp_path):
    from plc_runtime import ConfigError

    with pytest.raises(ConfigError, match="is a directory"):
        Runtime(retain_file=tmp_path)


def test_a_retain_file_that_could_never_be_saved_is_refused_before_the_start(tmp_path):
    """A save comes at stop, maybe months later: a place it can never write is a
    configuration error now, not a warning then. A missing folder is made (as --out's)."""
    (tmp_path / "afile").write_text("")
    with pytest.raises(ConfigError, match=r"afile/x.retain: cannot write retain file there: not a"):
        Runtime(retain_file=tmp_path / "afile" / "x.retain")
    Runtime(retain_file=tmp_path / "new" / "x.retain")
    assert (tmp_path / "new").is_dir() and not list((tmp_path / "new").iterdir())
    (tmp_path / "new" / "x.retain.tmp").write_text("a save cut short")  # written over later
    Runtime(retain_file=tmp_path / "new" / "x.retain")
    if os.geteuid() != 0:  # root may write anywhere
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o555)
        with pytest.raises(ConfigError, match="locked/x.retain: cannot write retain file there"):
            Runtime(retain_file=locked / "x.retain")


def test_block_referring_back_to_its_parent(tmp_path):
    class Child(FunctionBlock):
        n = Static(0, retain=True)

    class Parent(FunctionBlock):
        def __init__(self):
            super().__init__()
            self.child = Child()
            self.child.parent = self  # a back reference must not recurse forever

    rt = Runtime(cycle_time=0.01, clock=VirtualClock())
    rt.add_task("main", [Parent()])
    rt.start()
    assert rt.state == "RUN"
    rt.stop()


def test_counter_held_input_does_not_count_again_after_restart():
    rt = Runtime(cycle_time=0.01, clock=VirtualClock())
    ctu = CTU(retain=True)

    class Press(FunctionBlock):
        def cycle(self, ctx):
            ctu(ctx, CU=True, PV=100)  # the part sensor stays TRUE

    rt.add_task("main", [Press()])
    for _ in range(3):
        rt.start()
        rt.step(3)
        rt.stop()
    assert ctu.CV == 1


def test_blocks_created_in_startup_are_reported_not_silently_dropped():
    class Late(FunctionBlock):
        def startup(self, ctx):
            self.counter = CTU(retain=True)

    rt = Runtime(cycle_time=0.01, clock=VirtualClock())
    rt.add_task("main", [Late()])
    with pytest.warns(RuntimeWarning, match="blocks created in startup\\(\\) are not kept"):
        rt.start()
    rt.stop()


def test_a_device_or_pipe_is_never_read_renamed_or_replaced(tmp_path):
    """A retain path naming a named pipe (opening it would wait for ever) or a device
    (renaming it would take it from the system) is refused before anything touches it;
    the same for a fleet configuration or a plant file named so."""
    pipe = tmp_path / "pipe.toml"
    os.mkfifo(pipe)
    for special, what in ((pipe, "a named pipe"), (Path("/dev/null"), "a device")):
        with pytest.raises(ConfigError, match=f"is {what}, not a file"):
            Runtime(cycle_time=0.01, retain_file=special)
    assert pipe.exists() and Path("/dev/null").is_char_device()
    with pytest.raises(ConfigError, match=r"not a regular file \(a named pipe\)"):
        load_config(pipe)
    with pytest.raises(ConfigError, match=r"not a regular file \(a device\)"):
        load_config("/dev/zero")
    with pytest.raises(TopologyError, match="not a regular file"):
        load(pipe)
