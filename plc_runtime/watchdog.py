"""The watchdog interrupt: abort a scan that runs past the maximum cycle time.

A hardware PLC's watchdog stops a hung program; Python cannot preempt a loop, but a
SIGALRM handler runs between two bytecodes and can raise there. The timer is one-shot and
re-armed from its own handler, so there is no system call per tick (two ``setitimer``
calls per tick cost about 10 us on a cold cache after a sleep), detection happens exactly
at the limit (an alarm that comes early re-arms for the rest of the current scan), and the
chain ends by itself once no scan began since the last alarm, so an idle or abandoned
runtime leaves no timer running. Signals can only be handled in the main thread: a runtime
started elsewhere keeps the after-the-fact check of the measured scan time only.
"""

from __future__ import annotations

import atexit
import signal
import threading
import warnings
from time import perf_counter_ns
from types import CodeType, FrameType

from .errors import WatchdogTimeout

_RETRY_NS = 1_000_000  # an alarm that landed in unsafe code looks again this much later
_REPEAT_NS = 10_000_000  # a swallowed interrupt is raised again this much later


class WatchdogAlarm:
    def __init__(self, limit_ns: int) -> None:
        self.limit_ns = limit_ns
        self.in_scan = False
        self._scan_start_ns = 0
        self._scans = 0
        self._scans_at_alarm = 0
        self._pending = False
        self._thread: int | None = None  # the main thread, once installed
        self._previous_handler: object = signal.SIG_DFL
        self._unsafe_codes: frozenset[CodeType] = frozenset()
        # set by the runtime while it must not be interrupted anywhere (publishing the safe
        # state): an alarm then looks again a millisecond later, as in unsafe code
        self.held = False

    def install(self, unsafe_codes: frozenset[CodeType]) -> bool:
        """Take over SIGALRM if this is the main thread and nobody else uses it.

        ``unsafe_codes``: functions in which an exception would escape the caller's guard
        (its try/finally itself); an alarm landing there looks again a millisecond later.
        Another SIGALRM handler (the application's, or another runtime's watchdog) is left
        alone: this runtime then keeps only the after-the-fact check, with a warning.
        """
        if threading.current_thread() is not threading.main_thread():
            return False
        if self._thread is None:
            current = signal.getsignal(signal.SIGALRM)
            if current not in (signal.SIG_DFL, signal.SIG_IGN, None):
                warnings.warn(
                    "watchdog interrupt not available: SIGALRM is already handled in this process "
                    "(another runtime, or the application); overruns are detected after the scan",
                    RuntimeWarning,
                    stacklevel=3,
                )
                return False
            self._previous_handler = signal.signal(signal.SIGALRM, self._on_alarm)
            # a program that ends without stop(): at interpreter exit the handler is gone
            # while the timer may still be armed, and SIGALRM would kill the process
            atexit.register(self.uninstall)
        own = (self.begin_scan, self.end_scan, self._arm)
        self._unsafe_codes = unsafe_codes | {f.__code__ for f in own}
        self._thread = threading.get_ident()
        self._pending = False
        return True

    def uninstall(self) -> None:
        """Cancel the timer; restore the previous handler (only possible from the main thread)."""
        self.in_scan = False
        if self._thread is not None:
            signal.setitimer(signal.ITIMER_REAL, 0)
            if threading.current_thread() is threading.main_thread():
                signal.signal(signal.SIGALRM, self._previous_handler)
                self._thread = None
                atexit.unregister(self.uninstall)
        self._pending = False

    def begin_scan(self, start_ns: int) -> None:
        self._scan_start_ns = start_ns
        self._scans += 1
        # Only a scan in the thread that owns the handler can be interrupted: the signal
        # is delivered to the main thread, whatever thread armed the timer.
        self.in_scan = self._thread is not None and threading.get_ident() == self._thread
        if self.in_scan and not self._pending:
            self._arm(self.limit_ns)

    def end_scan(self) -> None:
        self.in_scan = False

    def _arm(self, delay_ns: int) -> None:
        self._pending = True
        self._scans_at_alarm = self._scans
        signal.setitimer(signal.ITIMER_REAL, max(delay_ns, 1000) / 1e9)

    def _on_alarm(self, signum: int, frame: FrameType | None) -> None:
        self._pending = False
        if self.in_scan:
            overdue = perf_counter_ns() - self._scan_start_ns - self.limit_ns
            if self.held or (frame is not None and frame.f_code in self._unsafe_codes):
                self._arm(_RETRY_NS)
            elif overdue >= 0:
                # Armed again first: a block that swallows the exception (a bare except,
                # a __del__) is interrupted again 10 ms later, and again, until it gives up.
                self._arm(_REPEAT_NS)
                raise WatchdogTimeout()
            else:
                self._arm(-overdue)
        elif self._scans != self._scans_at_alarm:
            self._arm(self.limit_ns)
