"""IEC 61131-3 standard function blocks: timers, edge detectors, counters, bistables.

Called from a block's cycle like an FB call in Structured Text::

    q = self.ton(ctx, IN=start, PT=0.5)     # returns the main output
    self.ton.ET                             # every output is an attribute

Inputs left out of a call keep their previous value (as in ST). Times are seconds; timers
measure with the scan's IEC time ``ctx.time_ns``, so they are exact and deterministic on
the virtual clock and never read the wall clock. Semantics follow IEC 61131-3 ed. 3
(section 6.6.3.5), with one documented choice: ``F_TRIG`` does not fire on its first call
when CLK is already FALSE (the literal standard text, where M starts FALSE, fires there;
pass ``first_scan_edge=True`` to get that).
"""

from __future__ import annotations

import math

from plc_runtime import ConfigError, CycleContext, FunctionBlock, Input, Output, Static

INT_MIN, INT_MAX = -32768, 32767


def _invoke(block: FunctionBlock, ctx: CycleContext, **inputs: object) -> object:
    """An FB call: inputs given (not None) are set, omitted ones keep their value, then one
    cycle runs and the main output is returned."""
    for name, value in inputs.items():
        if value is not None:
            setattr(block, name, value)
    block.cycle(ctx)
    return getattr(block, block.main_output)


def _duration_ns(block: FunctionBlock, pt: object) -> int:
    if isinstance(pt, bool) or not isinstance(pt, int | float) or not math.isfinite(pt) or pt < 0:
        raise ConfigError(f"{type(block).__name__}: PT must be a time >= 0 in seconds, got {pt!r}")
    return round(pt * 1e9)


class TON(FunctionBlock):
    """On-delay: Q goes TRUE once IN has been TRUE for PT; IN FALSE resets Q and ET."""

    IN = Input(False)
    PT = Input(0.0, doc="delay in seconds")
    Q = Output(False)
    ET = Output(0.0, doc="elapsed time in seconds, stops at PT")
    start_ns = Static(None, doc="IEC time at which IN went TRUE")

    def __call__(self, ctx: CycleContext, IN: bool | None = None, PT: float | None = None) -> bool:
        return _invoke(self, ctx, IN=IN, PT=PT)

    def cycle(self, ctx: CycleContext) -> None:
        pt_ns = _duration_ns(self, self.PT)
        if not self.IN:
            self.start_ns, self.Q, self.ET = None, False, 0.0
            return
        if self.Q:
            return  # on until IN falls, whatever PT does now (docs/runtime.md)
        if self.start_ns is None:
            self.start_ns = ctx.time_ns
        elapsed = ctx.time_ns - self.start_ns
        if elapsed >= pt_ns:
            self.Q, self.ET = True, pt_ns / 1e9
        else:
            self.Q, self.ET = False, elapsed / 1e9


class TOF(FunctionBlock):
    """Off-delay: Q follows IN up, and stays TRUE for PT after IN went FALSE."""

    IN = Input(False)
    PT = Input(0.0)
    Q = Output(False)
    ET = Output(0.0)
    start_ns = Static(None, doc="IEC time at which IN went FALSE while Q was TRUE")

    def __call__(self, ctx: CycleContext, IN: bool | None = None, PT: float | None = None) -> bool:
        return _invoke(self, ctx, IN=IN, PT=PT)

    def cycle(self, ctx: CycleContext) -> None:
        pt_ns = _duration_ns(self, self.PT)
        if self.IN:
            self.start_ns, self.Q, self.ET = None, True, 0.0
            return
        if not self.Q:
            return  # idle, or timed out: ET stays (0 before the first pulse, PT after)
        if self.start_ns is None:
            self.start_ns = ctx.time_ns
        elapsed = ctx.time_ns - self.start_ns
        if elapsed >= pt_ns:
            self.start_ns, self.Q, self.ET = None, False, pt_ns / 1e9
        else:
            self.ET = elapsed / 1e9


class TP(FunctionBlock):
    """Pulse: a rising edge of IN gives a Q pulse of exactly PT; not retriggerable."""

    IN = Input(False)
    PT = Input(0.0)
    Q = Output(False)
    ET = Output(0.0)
    start_ns = Static(None)
    in_prev = Static(False)

    def __call__(self, ctx: CycleContext, IN: bool | None = None, PT: float | None = None) -> bool:
        return _invoke(self, ctx, IN=IN, PT=PT)

    def cycle(self, ctx: CycleContext) -> None:
        pt_ns = _duration_ns(self, self.PT)
        rising = not self.Q and self.IN and not self.in_prev and self.start_ns is None
        if rising:
            self.start_ns, self.Q = ctx.time_ns, True
        if self.start_ns is not None:
            elapsed = ctx.time_ns - self.start_ns
            if elapsed >= pt_ns and not rising:  # (PT = 0: a pulse of the one call)
                self.Q, self.ET = False, pt_ns / 1e9
                if not self.IN:
                    self.start_ns, self.ET = None, 0.0
            else:
                self.ET = elapsed / 1e9
        self.in_prev = bool(self.IN)


class R_TRIG(FunctionBlock):
    """Rising edge: Q is TRUE for one call when CLK goes FALSE -> TRUE."""

    CLK = Input(False)
    Q = Output(False)
    M = Static(False)

    def __call__(self, ctx: CycleContext, CLK: bool | None = None) -> bool:
        return _invoke(self, ctx, CLK=CLK)

    def cycle(self, ctx: CycleContext) -> None:
        self.Q = bool(self.CLK) and not self.M
        self.M = bool(self.CLK)


class F_TRIG(FunctionBlock):
    """Falling edge: Q is TRUE for one call when CLK goes TRUE -> FALSE."""

    CLK = Input(False)
    Q = Output(False)
    M = Static(None, doc="NOT CLK of the previous call; None before the first call")

    def __init__(self, first_scan_edge: bool = False) -> None:
        super().__init__()
        self.first_scan_edge = first_scan_edge

    def __call__(self, ctx: CycleContext, CLK: bool | None = None) -> bool:
        return _invoke(self, ctx, CLK=CLK)

    def cycle(self, ctx: CycleContext) -> None:
        if self.M is None:
            self.M = False if self.first_scan_edge else not self.CLK
        self.Q = not self.CLK and not self.M
        self.M = not self.CLK


class _Counter(FunctionBlock):
    """Shared by the counters: PV validation and the optional retentive CV."""

    def __init__(self, retain: bool = False) -> None:
        super().__init__()
        if retain:  # with the edge memory, or a held input counts again after each restart
            self.mark_retain("CV", *(n for n in ("cu_prev", "cd_prev") if n in self._vars))

    def _pv(self) -> int:
        pv = self.PV
        if isinstance(pv, bool) or not isinstance(pv, int) or not INT_MIN <= pv <= INT_MAX:
            raise ConfigError(
                f"{type(self).__name__}: PV must be an INT ({INT_MIN}..{INT_MAX}), got {pv!r}"
            )
        return pv


class CTU(_Counter):
    """Up counter: CV += 1 on each rising edge of CU (up to 32767); R resets; Q = CV >= PV."""

    CU = Input(False)
    R = Input(False)
    PV = Input(0)
    Q = Output(False)
    CV = Output(0)
    cu_prev = Static(False)

    def __call__(
        self,
        ctx: CycleContext,
        CU: bool | None = None,
        R: bool | None = None,
        PV: int | None = None,
    ) -> bool:
        return _invoke(self, ctx, CU=CU, R=R, PV=PV)

    def cycle(self, ctx: CycleContext) -> None:
        pv = self._pv()
        edge = bool(self.CU) and not self.cu_prev
        self.cu_prev = bool(self.CU)
        if self.R:
            self.CV = 0
        elif edge and self.CV < INT_MAX:
            self.CV += 1
        self.Q = self.CV >= pv


class CTD(_Counter):
    """Down counter: CV -= 1 on each rising edge of CD (down to -32768); LD loads PV; Q = CV <= 0."""

    CD = Input(False)
    LD = Input(False)
    PV = Input(0)
    Q = Output(False)
    CV = Output(0)
    cd_prev = Static(False)

    def __call__(
        self,
        ctx: CycleContext,
        CD: bool | None = None,
        LD: bool | None = None,
        PV: int | None = None,
    ) -> bool:
        return _invoke(self, ctx, CD=CD, LD=LD, PV=PV)

    def cycle(self, ctx: CycleContext) -> None:
        pv = self._pv()
        edge = bool(self.CD) and not self.cd_prev
        self.cd_prev = bool(self.CD)
        if self.LD:
            self.CV = pv
        elif edge and self.CV > INT_MIN:
            self.CV -= 1
        self.Q = self.CV <= 0


class CTUD(_Counter):
    """Up/down counter: R resets (dominant), LD loads PV; simultaneous CU and CD edges cancel."""

    CU = Input(False)
    CD = Input(False)
    R = Input(False)
    LD = Input(False)
    PV = Input(0)
    QU = Output(False)
    QD = Output(False)
    CV = Output(0)
    cu_prev = Static(False)
    cd_prev = Static(False)

    def __call__(
        self,
        ctx: CycleContext,
        CU: bool | None = None,
        CD: bool | None = None,
        R: bool | None = None,
        LD: bool | None = None,
        PV: int | None = None,
    ) -> bool:
        return _invoke(self, ctx, CU=CU, CD=CD, R=R, LD=LD, PV=PV)

    def cycle(self, ctx: CycleContext) -> None:
        pv = self._pv()
        up = bool(self.CU) and not self.cu_prev
        down = bool(self.CD) and not self.cd_prev
        self.cu_prev, self.cd_prev = bool(self.CU), bool(self.CD)
        if self.R:
            self.CV = 0
        elif self.LD:
            self.CV = pv
        elif not (up and down):
            if up and self.CV < INT_MAX:
                self.CV += 1
            elif down and self.CV > INT_MIN:
                self.CV -= 1
        self.QU = self.CV >= pv
        self.QD = self.CV <= 0


class SR(FunctionBlock):
    """Set-dominant bistable: Q1 = S1 OR (NOT R AND Q1)."""

    S1 = Input(False)
    R = Input(False)
    Q1 = Output(False)

    def __call__(self, ctx: CycleContext, S1: bool | None = None, R: bool | None = None) -> bool:
        return _invoke(self, ctx, S1=S1, R=R)

    def cycle(self, ctx: CycleContext) -> None:
        self.Q1 = bool(self.S1) or (not self.R and self.Q1)


class RS(FunctionBlock):
    """Reset-dominant bistable: Q1 = NOT R1 AND (S OR Q1)."""

    S = Input(False)
    R1 = Input(False)
    Q1 = Output(False)

    def __call__(self, ctx: CycleContext, S: bool | None = None, R1: bool | None = None) -> bool:
        return _invoke(self, ctx, S=S, R1=R1)

    def cycle(self, ctx: CycleContext) -> None:
        self.Q1 = not self.R1 and (bool(self.S) or self.Q1)


__all__ = ["CTD", "CTU", "CTUD", "F_TRIG", "R_TRIG", "RS", "SR", "TOF", "TON", "TP"]
