"""The web server's log lines on stderr: prefixed as the command line's other messages, and
bounded where a client can cause them cheaply.

uvicorn logs some requests it answers itself, one line each: a request that is not HTTP
(``Invalid HTTP request received.``) and a request asking to upgrade the connection
(``Unsupported upgrade request.``, then advice to install a WebSocket library). The
server serves no WebSocket on purpose, so that advice is dropped; the other two come at
most once a second each, with a count of those left out, so a flood of such requests
cannot flood the log (the guard throttles what a client can repeat cheaply itself).
Anything else, an error with its traceback above all, is written whole.
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Callable

from plc_runtime.throttle import LineThrottle, left_out

# a client's upgrade request is answered as plain HTTP: no library is missing
DROPPED = ("No supported WebSocket library detected",)
# what any client can make uvicorn log, one line a request
THROTTLED = frozenset({"Invalid HTTP request received.", "Unsupported upgrade request."})
LOGGERS = ("fleet.web", "uvicorn.error")


class OncePerSecond(logging.Filter):
    """Lets each of the THROTTLED messages through at most once a second, saying how many
    were left out since the last one; drops the DROPPED; passes the others."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__()
        self.clock = clock
        self._lines = LineThrottle()

    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
        if text.startswith(DROPPED):
            return False
        if text not in THROTTLED:
            return True
        count = self._lines.admit(text, self.clock())
        if count:
            record.msg, record.args = text + left_out(count, "like it"), None
        return count is not None


class _Prefixed(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        level = "warning" if record.levelno < logging.ERROR else "error"
        text = f"plc-runtime: {level}: {record.getMessage()}"
        if record.exc_info:  # a failure's traceback is what finds its cause
            text += "\n" + self.formatException(record.exc_info)
        return text


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
