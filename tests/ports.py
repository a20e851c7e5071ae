"""Free loopback ports for tests that start servers (one per vehicle, above a base port)."""

from __future__ import annotations

import socket


def free_base_port(vehicles: int) -> int:
    """A base port whose next ``vehicles`` ports are all free on 127.0.0.1 right now.

    Another process may still take one before the server binds it: a test that starts a
    server should start it again on a new base when it reports the address in use."""
    for _ in range(50):
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            base = s.getsockname()[1]
        if base + vehicles > 65535:
            continue
        socks = []
        try:
            for v in range(1, vehicles + 1):
                t = socket.socket()
                socks.append(t)
                t.bind(("127.0.0.1", base + v))
            return base
        except OSError:
            continue
        finally:
            for t in socks:
                t.close()
    raise RuntimeError("no free port range")
