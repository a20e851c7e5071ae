"""IEC standard blocks against their timing diagrams, on a 100 ms virtual tick."""

import pytest
from conftest import Probe
from hypothesis import given, settings
from hypothesis import strategies as st

from blocks.standard import CTD, CTU, CTUD, F_TRIG, R_TRIG, RS, SR, TOF, TON, TP
from plc_runtime import ConfigError, FunctionBlock, Runtime, VirtualClock

TICK = 0.1


def drive(
    fb: FunctionBlock, inputs: dict[str, list], outputs: tuple[str, ...], preset=None
) -> dict[str, list]:
    """Call ``fb`` once per tick with the k-th value of every input; record its outputs.

    ``preset(fb)`` runs in the startup phase (a start re-initialises the block's variables)."""
    length = len(next(iter(inputs.values())))
    record = {name: [] for name in outputs}
    returned = []

    def cycle(ctx):
        returned.append(fb(ctx, **{name: values[ctx.cycle] for name, values in inputs.items()}))
        for name in outputs:
            value = getattr(fb, name)
            record[name].append(round(value, 6) if isinstance(value, float) else value)

    rt = Runtime(cycle_time=TICK, clock=VirtualClock())
    rt.add_task("main", [Probe(cycle, (lambda ctx: preset(fb)) if preset else None)])
    rt.start()
    rt.step(length)
    assert rt.state == "RUN", rt.fault_reason
    rt.stop()
    assert returned == record[outputs[0]]  # the call returns the main output
    return record


def bits(text: str) -> list[bool]:
    return [c == "1" for c in text.split()]


def test_ton():
    out = drive(TON(), {"IN": bits("0 1 1 1 1 1 0 1 1 0"), "PT": [0.3] * 10}, ("Q", "ET"))
    assert out["Q"] == bits("0 0 0 0 1 1 0 0 0 0")
    assert out["ET"] == [0, 0, 0.1, 0.2, 0.3, 0.3, 0, 0, 0.1, 0]


def test_ton_zero_preset_is_immediate():
    out = drive(TON(), {"IN": bits("0 1 0"), "PT": [0.0] * 3}, ("Q",))
    assert out["Q"] == bits("0 1 0")


def test_ton_stays_on_while_in_stays_true_when_pt_is_raised():
    """Raising PT after Q rose (a recipe's longer delay) does not drop Q mid-run: it stays
    on until IN falls, as MatIEC's TON does; the next rise times the new PT."""
    out = drive(
        TON(),
        {"IN": bits("1 1 1 1 1 0 1 1 1 1"), "PT": [0.1, 0.1, 0.1, 0.5, 0.5] + [0.3] * 5},
        ("Q", "ET"),
    )
    assert out["Q"] == bits("0 1 1 1 1 0 0 0 0 1")
    assert out["ET"] == [0, 0.1, 0.1, 0.1, 0.1, 0, 0, 0.1, 0.2, 0.3]


def test_tp_zero_preset_is_a_pulse_of_one_call():
    out = drive(TP(), {"IN": bits("0 1 1 0 1 0"), "PT": [0.0] * 6}, ("Q", "ET"))
    assert out["Q"] == bits("0 1 0 0 1 0")
    assert out["ET"] == [0] * 6


def test_tof():
    out = drive(TOF(), {"IN": bits("0 1 1 0 0 0 0 0 1 0 0 1"), "PT": [0.3] * 12}, ("Q", "ET"))
    assert out["Q"] == bits("0 1 1 1 1 1 0 0 1 1 1 1")
    assert out["ET"] == [0, 0, 0, 0, 0.1, 0.2, 0.3, 0.3, 0, 0, 0.1, 0]


def test_tp():
    out = drive(TP(), {"IN": bits("0 1 0 0 0 0 1 1 1 1 1 0 1"), "PT": [0.3] * 13}, ("Q", "ET"))
    assert out["Q"] == bits("0 1 1 1 0 0 1 1 1 0 0 0 1")
    assert out["ET"] == [0, 0, 0.1, 0.2, 0, 0, 0, 0.1, 0.2, 0.3, 0.3, 0, 0]


def test_tp_is_not_retriggerable():
    out = drive(TP(), {"IN": bits("1 0 1 0 0"), "PT": [0.3] * 5}, ("Q",))
    assert out["Q"] == bits("1 1 1 0 0")


def test_r_trig():
    assert drive(R_TRIG(), {"CLK": bits("1 1 0 1 0")}, ("Q",))["Q"] == bits("1 0 0 1 0")


def test_f_trig_documented_first_scan_choice():
    clk = bits("0 0 1 0 0 1 1 0")
    assert drive(F_TRIG(), {"CLK": clk}, ("Q",))["Q"] == bits("0 0 0 1 0 0 0 1")
    assert drive(F_TRIG(first_scan_edge=True), {"CLK": clk}, ("Q",))["Q"] == bits("1 0 0 1 0 0 0 1")
    assert drive(F_TRIG(), {"CLK": bits("1 0")}, ("Q",))["Q"] == bits("0 1")


def test_ctu():
    out = drive(
        CTU(),
        {"CU": bits("1 0 1 0 1 0 1 1 0 0"), "R": bits("0 0 0 0 0 0 0 1 0 0"), "PV": [3] * 10},
        ("Q", "CV"),
    )
    assert out["CV"] == [1, 1, 2, 2, 3, 3, 4, 0, 0, 0]
    assert out["Q"] == bits("0 0 0 0 1 1 1 0 0 0")


def test_ctu_saturates_at_int_max():
    preset = lambda fb: setattr(fb, "CV", 32767)  # noqa: E731
    assert (
        drive(CTU(), {"CU": bits("1 0 1"), "PV": [10] * 3}, ("Q", "CV"), preset)["CV"]
        == [32767] * 3
    )


def test_ctd():
    out = drive(
        CTD(), {"CD": bits("0 1 0 1 0 1"), "LD": bits("1 0 0 0 0 0"), "PV": [2] * 6}, ("Q", "CV")
    )
    assert out["CV"] == [2, 1, 1, 0, 0, -1]
    assert out["Q"] == bits("0 0 0 1 1 1")


def test_ctud():
    out = drive(
        CTUD(),
        {
            "CU": bits("1 0 1 1 0 0 0 1 0"),
            "CD": bits("0 0 0 1 0 1 0 1 0"),
            "R": bits("0 0 0 0 0 0 0 0 1"),
            "LD": bits("0 0 0 0 0 0 1 0 1"),
            "PV": [2] * 9,
        },
        ("QU", "QD", "CV"),
    )
    assert out["CV"] == [1, 1, 2, 1, 1, 0, 2, 2, 0]  # simultaneous edges cancel; R beats LD
    assert out["QU"] == bits("0 0 1 0 0 0 1 1 0")
    assert out["QD"] == bits("0 0 0 0 0 1 0 0 1")


def test_sr_set_dominant_and_rs_reset_dominant():
    assert drive(SR(), {"S1": bits("1 0 0 1 0"), "R": bits("0 0 1 1 1")}, ("Q1",))["Q1"] == bits(
        "1 1 0 1 0"
    )
    assert drive(RS(), {"S": bits("1 0 0 1 0"), "R1": bits("0 0 1 1 0")}, ("Q1",))["Q1"] == bits(
        "1 1 0 0 0"
    )


def test_omitted_inputs_keep_their_value_and_interface():
    out = drive(TON(), {"IN": bits("1 1 1 1")}, ("Q",))  # PT keeps its default 0.0
    assert out["Q"] == bits("1 1 1 1")
    assert TON.interface() == {
        "inputs": ["IN", "PT"],
        "outputs": ["Q", "ET"],
        "static": ["start_ns"],
    }


@pytest.mark.parametrize(
    "fb,call,message",
    [
        (TON(), {"IN": True, "PT": bad}, "TON: PT must be a time >= 0 in seconds")
        for bad in (-0.1, float("nan"), "1s", True)
    ]
    + [
        (CTU(), {"CU": True, "PV": 40000}, "CTU: PV must be an INT"),
        (CTD(), {"PV": 1.5}, "CTD: PV must be an INT"),
    ],
)
def test_bad_preset_is_a_clear_error(fb, call, message):
    with pytest.raises(ConfigError, match=message):
        fb(None, **call)
    rt = Runtime(cycle_time=TICK, clock=VirtualClock())
    rt.add_task("main", [Probe(lambda ctx: fb(ctx, **call))])
    rt.start()
    rt.step()
    assert rt.state == "FAULT" and message in rt.fault_reason
    rt.stop()


@settings(max_examples=100, deadline=None)
@given(st.lists(st.booleans(), min_size=1, max_size=40), st.integers(0, 6))
def test_timers_against_a_model(inputs, preset_ticks):
    pt = preset_ticks * TICK
    ton = drive(TON(), {"IN": inputs, "PT": [pt] * len(inputs)}, ("Q",))["Q"]
    tof = drive(TOF(), {"IN": inputs, "PT": [pt] * len(inputs)}, ("Q",))["Q"]
    for k in range(len(inputs)):
        run_on = 0  # how long IN has been TRUE, in ticks
        while run_on <= k and inputs[k - run_on]:
            run_on += 1
        assert ton[k] == (inputs[k] and run_on - 1 >= preset_ticks)
        last_true = max((j for j in range(k + 1) if inputs[j]), default=None)
        assert tof[k] == (inputs[k] or (last_true is not None and k - last_true <= preset_ticks))
