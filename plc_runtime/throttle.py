"""Log lines a network client can cause at will, at most one a second per client.

A refusal costs a client one request, and a server that logs every one gives any client
a way to fill the disk and bury the lines that matter: a pipelining Modbus client or an
HTTP client guessing tokens refuses itself thousands of times a second. So such lines go
through a :class:`LineThrottle`: the first of each key (a client, a kind of message) in a
second is written, the rest are counted, and the next line written says how many were
left out, so the log still tells how hard a client tried.
"""

from __future__ import annotations

import ipaddress

INTERVAL_S = 1.0
MAX_KEYS = 1024  # keys remembered; beyond, the one quiet longest is forgotten


class LineThrottle:
    """Which lines to write: per key, one every ``interval_s`` seconds at most.

    The caller passes the time, so a server keeps one clock for its rate and its log (and a
    test can hold it still)."""

    def __init__(self, interval_s: float = INTERVAL_S, max_keys: int = MAX_KEYS) -> None:
        self.interval_s = interval_s
        self.max_keys = max_keys
        self._last: dict[str, float] = {}  # key -> time of its last line written
        self._left_out: dict[str, int] = {}  # key -> lines left out since then

    def admit(self, key: str, now: float) -> int | None:
        """None if the line for ``key`` is to be left out (it is counted); else how many of
        ``key`` were left out since its last line (0: none), for the line to say."""
        last = self._last.get(key)
        if last is not None and now - last < self.interval_s:
            self._left_out[key] = self._left_out.get(key, 0) + 1
            return None
        if last is None and len(self._last) >= self.max_keys:
            self._forget(min(self._last, key=self._last.__getitem__))
        self._last[key] = now
        return self._left_out.pop(key, 0)

    def _forget(self, key: str) -> None:
        del self._last[key]
        self._left_out.pop(key, None)


def left_out(count: int, what: str) -> str:
    """The note a line written after ``count`` left out ends with ("" for none)."""
    return f" ({count} more {what} left out)" if count else ""


def client_of(host: str) -> str:
    """Who a connection from ``host`` counts as, for rates and log lines. Every loopback
    address is one client (on Linux a local process may send from any of 127.0.0.0/8, so
    one key per address would give it as many allowances as it likes), and so is an IPv6
    /64 (what one site is given: its hosts pick the rest of the address as they like)."""
    try:
        ip = ipaddress.ip_address(host.partition("%")[0])
    except ValueError:
        return host  # not an IP address (a Unix socket's path): itself
    if ip.is_loopback:
        return "loopback"
    if ip.version == 6:
        if ip.ipv4_mapped is not None:
            return str(ip.ipv4_mapped)
        return str(ipaddress.ip_network(f"{ip}/64", strict=False))
    return str(ip)
