import pytest

from blocks.standard import TON
from plc_runtime import ConfigError, FunctionBlock, Input, Output, Runtime, Static, VirtualClock


class Scale(FunctionBlock):
    raw = Input(0)
    gain = Input(2)
    value = Output(0)
    history = Static([])

    def cycle(self, ctx):
        self.value = self.raw * self.gain
        self.history.append(self.value)


class Early(FunctionBlock):
    """Assigns before calling super().__init__(): the declaration defaults must not win."""

    n = Static(0)

    def __init__(self, n):
        self.n = n
        super().__init__()


def test_defaults_are_per_instance():
    a, b = Scale(), Scale()
    a(None, raw=3)
    assert a.value == 6 and a.history == [6] and b.history == []


def test_call_returns_main_output_and_rejects_unknown_inputs():
    s = Scale()
    assert s(None, raw=2, gain=5) == 10
    with pytest.raises(ConfigError, match="Scale has no input 'value'"):
        s(None, value=1)


def test_subclass_may_set_state_before_super_init():
    assert Early(7).n == 7


def test_nested_blocks_and_mark_retain():
    class Parent(FunctionBlock):
        def __init__(self):
            super().__init__()
            self.timers = [TON(), TON()]
            self.scale = Scale()

    paths = [p for p, _ in Parent().walk("p")]
    assert paths == ["p", "p.timers[0]", "p.timers[1]", "p.scale"]
    s = Scale()
    s.mark_retain("value")
    assert s.retain_names() == ["value"]
    with pytest.raises(ConfigError, match="not a declared output or static"):
        s.mark_retain("raw")


def test_start_resets_declared_variables():
    s = Scale()
    rt = Runtime(cycle_time=0.01, clock=VirtualClock())
    rt.add_task("main", [s])
    s.raw = 4
    rt.start()
    assert s.raw == 0 and s.history == []
    rt.step(2)
    assert s.history == [0, 0]
    rt.stop()


def test_bad_main_output_declaration():
    with pytest.raises(ConfigError, match="main_output names undeclared variable 'Z'"):

        class Broken(FunctionBlock):
            main_output = "Z"
            Q = Output(False)
