"""The HTTP server's limits against clients that misbehave (fleet/web), on 127.0.0.1: a body
or headers sent slowly or never, many connections or streams at once, a flood of foreign
``Host`` headers, integers the parsers would read leniently, and values given twice.

Short server timeouts are parameters of the server, set small here rather than waited
out; every wait for the server polls or reads with a generous wall-clock deadline, and no
duration is asserted.
"""

from __future__ import annotations

import asyncio
import http.client
import json
import logging
import socket
import time
from typing import Any

import pytest
from web_controller import ROOT, TOKEN, WAIT_WALL_S, Controller, eventually

from fleet.config import load_config
from fleet.program import FleetProgram
from fleet.web import log_lines
from fleet.web.feed import Busy, LiveFeed
from fleet.web.log_lines import OncePerSecond

API = "/api/v1"
JSON = {"Content-Type": "application/json"}
HOLD = f"{API}/tags/agv1.hold"


@pytest.fixture(scope="module")
def ctl():
    with Controller() as controller:
        yield controller


def connect(port: int, data: bytes = b"") -> socket.socket:
    """A raw connection to the server that has sent ``data``."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=WAIT_WALL_S)
    if data:
        sock.sendall(data)
    return sock


def slow_body(port: int, write: bool = False) -> socket.socket:
    """A request that declares 1000 bytes of body and sends one of them: a read without a
    token, or (``write``) a write with the token."""
    head = (
        f"PUT {HOLD} HTTP/1.1\r\nAuthorization: Bearer {TOKEN}"
        if write
        else f"GET {API}/plant HTTP/1.1"
    )
    return connect(port, f"{head}\r\nHost: localhost\r\nContent-Length: 1000\r\n\r\nx".encode())


def read_reply(sock: socket.socket) -> tuple[int, Any]:
    """The status and JSON body of the next response on ``sock``."""
    reply = http.client.HTTPResponse(sock)
    reply.begin()
    return reply.status, json.loads(reply.read())


def closed_by_server(sock: socket.socket) -> bool:
    """Whether the server closes ``sock`` (reading whatever it sends until then)."""
    try:
        while sock.recv(4096):
            pass
    except ConnectionResetError:
        pass
    return True


def answers(ctl: Controller) -> bool:
    """Whether a plain read is answered 200 (a connection the server closed is a no)."""
    try:
        return ctl.call("GET", f"{API}/stats").status == 200
    except (ConnectionError, http.client.HTTPException):
        return False


# ----- slow bodies -------------------------------------------------------------------------------
def test_bodies_still_arriving_hold_no_place_in_flight():
    """Clients that declare a body and never send it take no place of the others."""
    with Controller(max_in_flight=2, body_timeout=600.0) as ctl:
        slow = [slow_body(ctl.port) for _ in range(3)]
        try:
            eventually(lambda: ctl.web.guard.receiving == 3, "three bodies arriving")
            assert ctl.call("GET", f"{API}/stats").status == 200
            write = ctl.call("PUT", HOLD, {"value": 0}, token=TOKEN)
            assert write.status == 200
        finally:
            for sock in slow:
                sock.close()


def test_a_body_not_in_by_the_deadline_is_408_and_its_connection_closed():
    with Controller(body_timeout=0.2) as ctl:
        sock = slow_body(ctl.port, write=True)
        try:
            assert read_reply(sock) == (
                408,
                {"error": "request body not received within 0.2 s", "field": None},
            )
            assert closed_by_server(sock)
        finally:
            sock.close()
        assert ctl.call("GET", HOLD).body["value"] == 0  # nothing was written


# ----- headers and connections ------------------------------------------------------------------
def test_headers_not_in_by_the_deadline_close_the_connection():
    """A connection that sends nothing, or part of its headers, first or after an answer."""
    with Controller(header_timeout=0.5) as ctl:
        request = b"GET /api/v1/stats HTTP/1.1\r\nHost: localhost\r\n"
        silent = connect(ctl.port)
        partial = connect(ctl.port, request + b"X-Slow: ")

        def answered_then_partial() -> socket.socket | None:
            sock = connect(ctl.port, request + b"\r\n")
            try:
                if read_reply(sock)[0] == 200:
                    sock.sendall(request)  # the next request's headers, never finished
                    return sock
            except (ConnectionError, http.client.HTTPException):
                pass  # closed before its request arrived: the machine is busy; again
            sock.close()
            return None

        kept = eventually(answered_then_partial, "a request answered on a new connection")
        try:
            for sock in (silent, partial, kept):
                assert closed_by_server(sock)
        finally:
            for sock in (silent, partial, kept):
                sock.close()
        eventually(lambda: answers(ctl), "a request answered afterwards")


def test_connections_beyond_the_cap_are_503_and_closed(caplog):
    with Controller(max_connections=3, header_timeout=600.0) as ctl:
        idle = [connect(ctl.port) for _ in range(3)]
        try:
            with caplog.at_level(logging.WARNING, logger="fleet.web.server"):
                extra = connect(
                    ctl.port, f"GET {API}/stats HTTP/1.1\r\nHost: localhost\r\n\r\n".encode()
                )
                try:
                    assert read_reply(extra) == (
                        503,
                        {"error": "too many connections (the limit is 3): retry", "field": None},
                    )
                    assert closed_by_server(extra)
                finally:
                    extra.close()
            assert any("(the limit)" in r.getMessage() for r in caplog.records)
            idle.pop().close()
            eventually(lambda: answers(ctl), "a request answered once a connection closed")
        finally:
            for sock in idle:
                sock.close()


# ----- streams ----------------------------------------------------------------------------------
def test_streams_opened_all_at_once_are_limited_too():
    with Controller(max_streams=2) as ctl:
        socks = [connect(ctl.port) for _ in range(8)]
        try:
            for sock in socks:  # every request is in before any stream starts
                sock.sendall(f"GET {API}/stream HTTP/1.1\r\nHost: localhost\r\n\r\n".encode())
            statuses = [int(sock.makefile("rb").readline().split()[1]) for sock in socks]
            assert sorted(statuses) == [200] * 2 + [503] * 6
        finally:
            for sock in socks:
                sock.close()
        eventually(lambda: ctl.web.feed.streams == 0, "every place given back")


def test_a_stream_that_never_started_gives_its_place_back():
    program = FleetProgram(load_config(ROOT / "examples" / "workshop.toml"))
    try:
        feed = LiveFeed(program, max_streams=1)
        stream = feed.open_stream()
        assert feed.streams == 1
        with pytest.raises(Busy):
            feed.open_stream()
        asyncio.run(stream.close())
        asyncio.run(stream.close())  # once only
        assert feed.streams == 0
        asyncio.run(feed.open_stream().close())  # the place is free again
    finally:
        program.close()


# ----- the Host header and the rate -------------------------------------------------------------
def test_foreign_hosts_count_against_the_rate_and_are_logged_once_a_second(caplog):
    with Controller(max_rate=5) as ctl:
        ctl.web.guard.clock = lambda: 1000.0  # held still: no token comes back
        with caplog.at_level(logging.WARNING, logger="fleet.web.guard"):
            replies = [
                ctl.call("GET", f"{API}/stats", headers={"Host": "evil.example"}) for _ in range(12)
            ]
        assert [r.status for r in replies] == [400] * 5 + [429] * 7
        assert replies[0].body["error"] == "Host header 'evil.example' not accepted"
        lines = [r.getMessage() for r in caplog.records if r.name == "fleet.web.guard"]
        assert len(lines) == 1 and "Host header 'evil.example'" in lines[0]


def test_refused_tokens_and_bodies_are_logged_once_a_second(caplog):
    """A client guessing tokens (a wrong one, none) or sending bodies over the limit is
    refused every time, but logged once a second: the next line says how many were left
    out. The guard's clock is held still (the rate allows 100 requests in that instant)."""
    with Controller() as ctl:
        ctl.web.guard.clock = lambda: 1000.0
        with caplog.at_level(logging.WARNING, logger="fleet.web.guard"):
            statuses = []
            for token in ("wrong", None) * 15:
                statuses.append(ctl.call("POST", f"{API}/orders", {}, token=token).status)
            big = {"Content-Length": "999999"}
            statuses.append(ctl.call("POST", f"{API}/orders", token=TOKEN, headers=big).status)
            assert statuses == [403, 401] * 15 + [413]
            lines = [r.getMessage() for r in caplog.records if r.name == "fleet.web.guard"]
            assert len(lines) == 1 and lines[0].endswith(": 403, wrong token")
            ctl.web.guard.clock = lambda: 1001.5
            assert ctl.call("POST", f"{API}/orders", {}, token="wrong").status == 403
        lines = [r.getMessage() for r in caplog.records if r.name == "fleet.web.guard"]
        assert len(lines) == 2
        assert lines[1].endswith(": 403, wrong token (30 more from this client left out)")


def test_requests_uvicorn_answers_itself_reach_the_log_once_a_second(ctl, capsys):
    """Upgrade requests (answered as plain HTTP: the server has no WebSocket) and requests
    that are not HTTP are logged by uvicorn, one line each: 30 of each kind within a
    second (the filter's clock held still) are one line each, prefixed as the run's other
    messages, and without advice to install a WebSocket library."""
    (once,) = [
        f for f in logging.getLogger("uvicorn.error").filters if isinstance(f, OncePerSecond)
    ]
    once.clock = lambda: 1000.0
    try:
        _flood(ctl, once, capsys)
    finally:
        once.clock = time.monotonic


def _flood(ctl, once, capsys):
    capsys.readouterr()
    upgrade = f"GET {API}/nothing HTTP/1.1\r\nHost: localhost\r\nConnection: Upgrade\r\n"
    upgrade += "Upgrade: websocket\r\n\r\n"
    for data in (upgrade.encode(), b"\x16\x03\x01 not http\r\n\r\n"):
        for _ in range(30):
            with connect(ctl.web.port, data) as sock:
                closed_by_server(sock) if data[0] == 0x16 else sock.recv(4096)
    lines = capsys.readouterr().err.splitlines()
    upgrades = [x for x in lines if "Unsupported upgrade request" in x]
    invalid = [x for x in lines if "Invalid HTTP request received" in x]
    assert len(upgrades) == 1 and len(invalid) == 1, lines
    assert all(x.startswith("plc-runtime: warning: ") for x in upgrades + invalid)
    assert not any("WebSocket library" in x for x in lines)
    once.clock = lambda: 1001.5  # a second later: the next says how many were left out
    with connect(ctl.web.port, upgrade.encode()) as sock:
        sock.recv(4096)
    assert "(29 more like it left out)" in capsys.readouterr().err


def test_an_error_in_the_web_server_log_keeps_its_traceback(capsys):
    """Only the lines any client can cause are throttled: two different failures within a
    second are both written, each with its traceback."""
    log_lines.install()
    for exc in (ZeroDivisionError("first"), KeyError("second")):
        try:
            raise exc
        except Exception:
            logging.getLogger("uvicorn.error").exception("Exception in ASGI application")
    err = capsys.readouterr().err
    assert err.count("plc-runtime: error: Exception in ASGI application") == 2
    assert "ZeroDivisionError: first" in err and "KeyError: 'second'" in err


def test_a_refused_path_reaches_the_log_escaped(caplog):
    """The path is logged as uvicorn decoded it: %1b would be an ESC on the operator's
    terminal."""
    with Controller() as ctl:
        with caplog.at_level(logging.WARNING, logger="fleet.web.guard"):
            reply = ctl.call("POST", f"{API}/orders%1b]0;owned%07%1b[2J", {}, token="wrong")
        assert reply.status == 403
    lines = [r.getMessage() for r in caplog.records if r.name == "fleet.web.guard"]
    assert len(lines) == 1 and "orders\\x1b]0;owned\\x07\\x1b[2J from" in lines[0]
    assert lines[0].isprintable()


def test_a_line_break_in_a_refused_path_cannot_forge_a_log_line(caplog):
    """%0a in the path is a line break once decoded: logged as it was, it would start a
    line of the client's making."""
    with Controller() as ctl:
        with caplog.at_level(logging.WARNING, logger="fleet.web.guard"):
            path = f"{API}/orders%0d%0aplc-runtime:%20error:%20forged"
            assert ctl.call("POST", path, {}, token="wrong").status == 403
    lines = [r.getMessage() for r in caplog.records if r.name == "fleet.web.guard"]
    assert len(lines) == 1 and "orders\\r\\nplc-runtime: error: forged from" in lines[0]
    assert lines[0].isprintable()


# ----- integers and repeats ---------------------------------------------------------------------
@pytest.mark.parametrize(
    ("method", "path", "field"),
    [
        ("PUT", f"{API}/blockades/1_5/0", "a"),
        ("PUT", f"{API}/blockades/15/0.0", "b"),
        ("DELETE", f"{API}/blockades/%2B15/0", "a"),
        ("PUT", f"{API}/blockades/15/%200", "b"),
        ("PUT", f"{API}/blockades/%D9%A1/0", "a"),  # an Arabic-Indic one
        ("GET", f"{API}/vehicles/1_0", "vehicle"),
        ("GET", f"{API}/vehicles/1.0", "vehicle"),
        ("GET", f"{API}/vehicles/1%20", "vehicle"),
        ("GET", f"{API}/orders?offset=1_0", "offset"),
        ("GET", f"{API}/orders?limit=+5", "limit"),  # "+" is a space in a query
        ("GET", f"{API}/orders?limit=%2B5", "limit"),
        ("GET", f"{API}/events?after=1.0", "after"),
        ("GET", f"{API}/events?limit=0x10", "limit"),
    ],
)
def test_integers_in_paths_and_queries_are_digits_only(ctl, method, path, field):
    before = set(ctl.program.blockades.blocked_segments())
    reply = ctl.call(method, path, token=TOKEN)
    assert (reply.status, reply.body["field"]) == (422, field)
    assert reply.body["error"].startswith(f"field '{field}': expected a whole number")
    assert set(ctl.program.blockades.blocked_segments()) == before


@pytest.mark.parametrize(
    ("path", "field"),
    [
        (f"{API}/orders?offset=1&offset=2", "offset"),
        (f"{API}/orders?limit=5&offset=0&limit=6", "limit"),
        (f"{API}/events?after=1&after=2", "after"),
        (f"{API}/tags/values?names=agv1.hold&names=agv2.hold", "names"),
    ],
)
def test_a_query_parameter_given_twice_is_refused(ctl, path, field):
    reply = ctl.call("GET", path)
    assert (reply.status, reply.body["field"]) == (422, field)
    assert reply.body["error"] == f"field '{field}': given more than once in the query"


def test_a_key_given_twice_in_a_json_body_is_refused_and_changes_nothing(ctl):
    before = ctl.call("GET", HOLD).body["value"]
    raw = json.dumps({"value": before}).encode()[:-1] + f',"value":{1 - before}}}'.encode()
    reply = ctl.call("PUT", HOLD, raw=raw, token=TOKEN, headers=JSON)
    assert (reply.status, reply.body) == (
        422,
        {"error": "field 'value': given more than once in the JSON", "field": "value"},
    )
    assert ctl.call("GET", HOLD).body["value"] == before
    order = b'{"id": "twice-1", "get": 21, "put": 23, "id": "twice-2"}'
    added = ctl.call("POST", f"{API}/orders", raw=order, token=TOKEN, headers=JSON)
    assert (added.status, added.body["field"]) == (422, "id")
    for order_id in ("twice-1", "twice-2"):
        assert ctl.call("GET", f"{API}/orders/{order_id}").status == 404


def test_connections_are_accepted_with_nagles_algorithm_off():
    """An answer goes out as headers, then body: with Nagle's algorithm on, the body of
    each answer on a kept-alive connection waited for the client's delayed ACK (some 40
    ms a request, measured at 60 against 20 ms). Accepted connections take the option
    from the listening socket."""
    from fleet.web.server import _bind

    listener = _bind("127.0.0.1", 0)
    client = socket.create_connection(listener.getsockname()[:2], timeout=30)
    accepted, _ = listener.accept()
    try:
        assert listener.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY)
        assert accepted.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY)
    finally:
        for sock in (accepted, client, listener):
            sock.close()
