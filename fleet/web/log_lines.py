"""The web server's log lines on stderr: prefixed as the command line's other messages, and
bounded where a client can cause them cheaply.

uvicorn logs some requests it answers itself, one line each: a request that is not HTTP
(``Invalid HTTP request received.``) and a request asking to upgrade the connection
(``Unsupported upgrade request.``, then advice to install a WebSocket library). The
server serves no WebSocket on purpose, so that advice is dropped; the other lines, like
the guard's own refusals, come at most once a second each, with a count of those left out,
so a flood of such requests cannot flood the log.
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Callable

# a client's upgrade request is answered as plain HTTP: no library is missing
DROPPED = ("No supported WebSocket library detected",)
LOGGERS = ("fleet.web", "uvicorn.error")
INTERVAL_S = 1.0


class OncePerSecond(logging.Filter):
    """Lets a message through at most once per ``INTERVAL_S`` (per text), and says how many
    were left out since the last one."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__()
        self.clock = clock
        self._last: dict[str, float] = {}
        self._left_out: dict[str, int] = {}

    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
        if text.startswith(DROPPED):
            return False
        now = self.clock()
        if now - self._last.get(text, -INTERVAL_S) < INTERVAL_S:
            self._left_out[text] = self._left_out.get(text, 0) + 1
            return False
        if len(self._last) > 1000:  # texts quote clients: keep the memory bounded
            self._last.clear()
            self._left_out.clear()
        self._last[text] = now
        left_out = self._left_out.pop(text, 0)
        if left_out:
            record.msg, record.args = f"{text} ({left_out} more like it left out)", None
        return True


class _Prefixed(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        level = "warning" if record.levelno < logging.ERROR else "error"
        return f"plc-runtime: {level}: {record.getMessage()}"


def install() -> None:
    """Give the web server's loggers their handler and uvicorn's the filter (once)."""
    for name in LOGGERS:
        logger = logging.getLogger(name)
        if any(isinstance(h, _Handler) for h in logger.handlers):
            continue
        handler = _Handler(sys.stderr)
        handler.setFormatter(_Prefixed())
        logger.addHandler(handler)
        if name == "uvicorn.error":
            logger.addFilter(OncePerSecond())


class _Handler(logging.StreamHandler):
    """stderr as it is when a line is written (a test may have replaced it)."""

    def emit(self, record: logging.LogRecord) -> None:
        self.stream = sys.stderr
        super().emit(record)
