"""``plc-runtime order add|withdraw|list|show`` and ``plc-runtime run --web``, end to end.

The order commands run in this process against a controller scanning in a background
thread (web_controller.py); ``run --web`` runs as a reader would start it: in a child
process (Ctrl-C included), and in this process for the cases that end by themselves. Every
failure must be one line on stderr, exit code 2, no traceback; every run must leave no
server thread and nothing listening behind.
"""

from __future__ import annotations

import argparse
import http.server
import io
import json
import math
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest
from web_controller import (
    CONFIG,
    ROOT,
    TOKEN,
    Controller,
    assert_port_closed,
    assert_server_gone,
)

from fleet.cli import main
from fleet.commands import orders as order_cli
from fleet.config import load_config
from fleet.web import options as web_options_module
from fleet.web.options import TOKEN_ENV, web_options
from plc_runtime.cli import CliError

ERROR = "plc-runtime: error: "
ANNOUNCE = re.compile(
    r"plc-runtime: operator page on http://127\.0\.0\.1:\d+/, "
    r"HTTP API on (http://127\.0\.0\.1:(\d+))/api/v1(.*)"
)
FINISH_WALL_S = 120.0
START_WALL_S = 60.0


@pytest.fixture(scope="module")
def ctl():
    with Controller() as controller:
        yield controller


@pytest.fixture(autouse=True)
def wide_and_tokenless(monkeypatch):
    """Tables as wide as they need (rich reads COLUMNS); no token from the test's shell."""
    monkeypatch.setenv("COLUMNS", "200")
    monkeypatch.delenv(TOKEN_ENV, raising=False)


def order(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(["order", *argv])
    out, err = capsys.readouterr()
    return code, out, err


SERVER_LOG = "plc-runtime: warning: web "


def error_line(code: int, err: str) -> str:
    """The one error line of a failed command, without its prefix."""
    assert code == 2, err
    assert "Traceback" not in err
    # (the controller runs in this process: its own log of a refusal is not the command's)
    lines = [x for x in err.strip().splitlines() if not x.startswith(SERVER_LOG)]
    assert len(lines) == 1 and lines[0].startswith(ERROR), err
    return lines[0][len(ERROR) :]


def closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# ----- the order commands -----------------------------------------------------------------------
def test_add_show_list_withdraw(ctl, capsys):
    url = ["--url", ctl.url]
    code, out, err = order(
        capsys, "add", *url, "--token", TOKEN, "--id", "cli-1", "--get", "21", "--put", "23",
        "--start", "5000", "--end", "9000", "--priority", "3", "--vehicle", "2",
    )  # fmt: skip
    assert (code, err) == (0, "")
    assert re.fullmatch(r"order 'cli-1': (DISPATCHABLE|BEING_PROCESSED)\n", out)

    code, out, _ = order(capsys, "show", *url, "cli-1", "--json")
    shown = json.loads(out)
    assert code == 0
    assert {k: shown[k] for k in ("get", "put", "start_s", "end_s", "priority", "vehicle")} == {
        "get": 21,
        "put": 23,
        "start_s": 5000.0,
        "end_s": 9000.0,
        "priority": 3,
        "vehicle": 2,
    }
    code, out, _ = order(capsys, "show", *url, "cli-1")
    assert code == 0
    assert "order 'cli-1'" in out and "9000" in out and "history" in out

    code, out, _ = order(capsys, "list", *url)
    assert code == 0
    assert "cli-1" in out and "saw-1" in out and "orders at" in out
    code, out, _ = order(capsys, "list", *url, "--json")
    listed = json.loads(out)
    assert [o["id"] for o in listed][:2] == ["saw-1", "weld-1"] and "cli-1" in {
        o["id"] for o in listed
    }

    code, out, err = order(capsys, "withdraw", *url, "--token", TOKEN, "cli-1")
    assert (code, out, err) == (0, "order 'cli-1': WITHDRAWN\n", "")
    code, out, _ = order(capsys, "withdraw", *url, "--token", TOKEN, "cli-1", "--json")
    assert "the order is final (WITHDRAWN) and cannot be withdrawn (HTTP 409)" in error_line(
        code, _
    )


def test_an_order_added_from_the_command_line_is_delivered(ctl, capsys, monkeypatch):
    monkeypatch.setenv(TOKEN_ENV, TOKEN)  # the token from the environment
    code, out, err = order(
        capsys, "add", "--url", f"{ctl.url}/api/v1/", "--id", "cli-2", "--get", "25", "--put",
        "27", "--json",
    )  # fmt: skip
    assert code == 0, err
    assert json.loads(out)["id"] == "cli-2"
    deadline = time.monotonic() + FINISH_WALL_S
    while time.monotonic() < deadline:
        _, out, _ = order(capsys, "show", "--url", ctl.url, "cli-2", "--json")
        if json.loads(out)["state"] == "FINISHED":
            break
        time.sleep(0.05)
    assert json.loads(out)["state"] == "FINISHED"


def test_list_reads_every_page(ctl, capsys, monkeypatch):
    code, out, _ = order(capsys, "list", "--url", ctl.url, "--json")
    whole = [o["id"] for o in json.loads(out)]
    monkeypatch.setattr(order_cli, "PAGE", 2)
    code, out, _ = order(capsys, "list", "--url", ctl.url, "--json")
    assert code == 0
    assert [o["id"] for o in json.loads(out)][: len(whole)] == whole


@pytest.mark.parametrize(
    ("argv", "line"),
    [
        (
            ["add", "--id", "e1", "--get", "21", "--put", "23"],
            "this request needs the token: Authorization: Bearer TOKEN (HTTP 401): "
            f"give --token or set {TOKEN_ENV}",
        ),
        (
            [
                "add",
                "--token",
                "wrong-token-0123456789",
                "--id",
                "e1",
                "--get",
                "21",
                "--put",
                "23",
            ],
            "wrong token (HTTP 403)",
        ),
        (["withdraw", "saw-1"], "this request needs the token"),
        (["show", "e1"], "order 'e1': field 'id': no such order (HTTP 404)"),
        (["withdraw", "--token", TOKEN, "e1"], "order 'e1': field 'id': no such order (HTTP 404)"),
        (
            ["add", "--token", TOKEN, "--id", "e1", "--get", "99", "--put", "23"],
            "order 'e1': field 'get': node 99 is not a Get/Put station (HTTP 422)",
        ),
        (
            ["add", "--token", TOKEN, "--id", "e1", "--get", "21", "--put", "21"],
            "order 'e1': field 'put': Put station 21 is the Get station (HTTP 422)",
        ),
        (
            [
                "add",
                "--token",
                TOKEN,
                "--id",
                "e1",
                "--get",
                "21",
                "--put",
                "23",
                "--start",
                "60",
                "--end",
                "30",
            ],
            "order 'e1': field 'end_s': end 30.0 s is before the start 60.0 s (HTTP 422)",
        ),  # fmt: skip
        (
            ["add", "--token", TOKEN, "--id", "saw-1", "--get", "21", "--put", "23"],
            "order 'saw-1': field 'id': already used by an order that is",
        ),
        (
            ["add", "--token", "bad\ntoken", "--id", "e1", "--get", "21", "--put", "23"],
            "--token: not a bearer token (A-Z a-z 0-9 - . _ ~ + / only, and = at its end)",
        ),
    ],
)
def test_refusals_are_one_line(ctl, capsys, argv, line):
    code, out, err = order(capsys, argv[0], "--url", ctl.url, *argv[1:])
    assert line in error_line(code, err) and out == ""
    code, out, _ = order(capsys, "show", "--url", ctl.url, "e1")
    assert code == 2  # nothing was added


def test_an_unreachable_controller_is_one_line(capsys):
    port = closed_port()
    for argv in (["list"], ["show", "x"], ["add", "--token", TOKEN, "--id", "x", "--get", "1",
                 "--put", "2"], ["withdraw", "--token", TOKEN, "x"]):  # fmt: skip
        code, _, err = order(capsys, argv[0], "--url", f"http://127.0.0.1:{port}", *argv[1:])
        assert error_line(code, err) == (
            f"http://127.0.0.1:{port}: cannot reach the controller (Connection refused); is "
            "`plc-runtime run CONFIG --web HOST:PORT` running there?"
        )


@pytest.mark.parametrize(
    ("url", "wrong"),
    [
        ("file:///etc/passwd", "not http or https"),
        ("http://:8080", "no host"),
        ("http://[::1", "Invalid IPv6 URL"),
        ("http://127.0.0.1:abc", "the port is not a number 0-65535"),
        ("http://127.0.0.1:65536", "the port is not a number 0-65535"),
        ("http://127.0.0.1:-1", "the port is not a number 0-65535"),
        ("http://127.0.0.1:\u0668\u0660", "the port is not a number 0-65535"),  # Arabic-Indic 80
        ("http://127.0.0.1:80_80", "the port is not a number 0-65535"),
        ("http://127.0.0.1:18080?x=1", "a query (?...) is not taken"),
        ("http://127.0.0.1:18080/api/v1?", "a query (?...) is not taken"),
        ("http://127.0.0.1:18080#top", "a fragment (#...) is not taken"),
        ("http://127.0.0.1:18080/#?x", "a fragment (#...) is not taken"),
    ],
)
def test_a_url_that_names_no_controller_is_one_line(capsys, url, wrong):
    for argv in (["list"], ["show", "x"], ["withdraw", "--token", TOKEN, "x"]):
        code, _, err = order(capsys, argv[0], "--url", url, *argv[1:])
        assert error_line(code, err) == (
            f"--url {url!r}: {wrong}; expected http://HOST:PORT, e.g. http://127.0.0.1:8080"
        )


@pytest.mark.parametrize("url", ["http://user:secret@127.0.0.1:18080", "http://secret@[::1]:1"])
def test_a_url_with_user_info_is_one_line_without_the_password(capsys, url):
    """urllib would take the user info for part of the host name ("Name or service not
    known"); the line names it instead, and does not repeat what may be a password."""
    argv = ["add", "--url", url, "--token", TOKEN, "--id", "a", "--get", "21", "--put", "23"]
    line = error_line(*order(capsys, *argv)[::2])
    assert line.startswith("--url 'http://...@")
    assert "user info (USER:PASSWORD@) is not taken: the token is the only credential" in line
    assert "secret" not in line


@pytest.mark.parametrize(
    ("option", "value", "wrong"),
    [
        ("--get", "\u0663", "not an integer: '\u0663'"),  # Arabic-Indic 3: int() takes it
        ("--put", "2_5", "not an integer: '2_5'"),
        ("--priority", "1.5", "not an integer: '1.5'"),
        ("--get", "9" * 19, "not an integer of at most 18 digits: '9999999999999999999'"),
        ("--vehicle", "\uff12", "not an integer: '\uff12'"),  # fullwidth 2
        ("--start", "1_0", "not a finite decimal number: '1_0'"),
        ("--end", "\u0661\u0660", "not a finite decimal number: '\u0661\u0660'"),
        ("--end", "nan", "not a finite decimal number: 'nan'"),
        ("--start", "-5", "must be >= 0: '-5'"),
    ],
)
def test_numbers_are_read_as_order_files_read_them(capsys, option, value, wrong):
    argv = {"--id": "x", "--get": "21", "--put": "23", option: value}
    with pytest.raises(SystemExit) as exc:
        main(["order", "add", "--url", f"http://127.0.0.1:{closed_port()}",
              *(part for pair in argv.items() for part in pair)])  # fmt: skip
    assert exc.value.code == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.endswith(f"argument {option}: {wrong} (see plc-runtime order add --help)")


def test_ids_that_look_like_markup_are_shown_literally(ctl, capsys):
    """An id is the user's text, not rich markup: no MarkupError, no red "x"."""
    url = ["--url", ctl.url]
    for oid in ("[/oops]", "[red]x"):
        code, out, err = order(capsys, "add", *url, "--token", TOKEN, "--id", oid, "--get",
                               "21", "--put", "23", "--start", "9000")  # fmt: skip
        assert (code, err) == (0, "") and out.startswith(f"order {oid!r}: ")
        code, out, err = order(capsys, "show", *url, oid)
        assert (code, err) == (0, "") and f"order {oid!r}" in out
    code, out, err = order(capsys, "list", *url)
    assert (code, err) == (0, "")
    assert " [/oops] " in out and " [red]x " in out


class _Quiet(http.server.BaseHTTPRequestHandler):
    """Serves nothing (501 in HTML to every GET) and logs nothing."""

    def log_message(self, *args: object) -> None:
        pass


def test_a_server_that_is_not_the_api_is_one_line(capsys):
    """Something else on the port answers, in HTML."""
    server = http.server.HTTPServer(("127.0.0.1", 0), _Quiet)
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05})
    thread.start()
    try:
        code, _, err = order(capsys, "show", "--url", f"http://127.0.0.1:{server.server_port}", "x")
    finally:
        server.shutdown()
        server.server_close()
        thread.join()
    assert "(HTTP 501)" in error_line(code, err) and "not a plc-runtime HTTP API?" in err


class _RawServer:
    """A loopback server that answers every connection with ``respond(conn)``: bytes that
    need not be HTTP, sent as slowly as the test likes. Closed, with its threads, on exit."""

    def __init__(self, respond) -> None:
        self.respond = respond
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.listener.settimeout(0.05)
        self.url = f"http://127.0.0.1:{self.listener.getsockname()[1]}"
        self.stop = threading.Event()
        self.threads = [threading.Thread(target=self._accept)]
        self.requests: list[bytes] = []  # each request's head, in the order they came

    def __enter__(self) -> _RawServer:
        self.threads[0].start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        for thread in list(self.threads):
            thread.join(10)
        self.listener.close()

    def _accept(self) -> None:
        while not self.stop.is_set():
            try:
                conn, _ = self.listener.accept()
            except TimeoutError:
                continue
            thread = threading.Thread(target=self._serve, args=(conn,))
            self.threads.append(thread)
            thread.start()

    def _serve(self, conn: socket.socket) -> None:
        with conn:
            conn.settimeout(5)
            request = b""
            try:
                while b"\r\n\r\n" not in request:
                    chunk = conn.recv(65536)
                    if not chunk:
                        return
                    request += chunk
                self.requests.append(request)
                self.respond(conn, self.stop)
            except OSError:
                pass  # the command gave up and closed: as intended


def _http(body: bytes, status: str = "200 OK", **headers: str) -> bytes:
    fields = {"Content-Type": "application/json", "Content-Length": str(len(body))} | headers
    head = "".join(f"{k}: {v}\r\n" for k, v in fields.items())
    return f"HTTP/1.1 {status}\r\n{head}Connection: close\r\n\r\n".encode() + body


def _sent(capsys, raw: bytes, *argv: str) -> tuple[int, str, str]:
    """``plc-runtime order ARGV`` against a loopback server that sends ``raw``."""
    with _RawServer(lambda conn, stop: conn.sendall(raw)) as server:
        return order(capsys, *argv, "--url", server.url)


def _answered(capsys, body: object, *argv: str) -> tuple[int, str, str]:
    """``plc-runtime order ARGV`` against a loopback server that answers ``body`` as JSON."""
    return _sent(capsys, _http(json.dumps(body).encode()), *argv)


def _answer_order(**changes: object) -> dict:
    base = {"id": "o1", "get": 21, "put": 23, "start_s": 0, "end_s": None, "priority": 0,
            "vehicle": None, "state": "RAW", "assigned": None, "reason": "", "history": [],
            "sections": {}, "position": 0}  # fmt: skip
    return base | changes


@pytest.mark.parametrize(
    ("argv", "body", "where"),
    [
        (
            ["list"],
            {"orders": [{}], "total": 1, "offset": 0, "next_offset": 1, "added": 1},
            "orders.0.id: Field required",
        ),
        (["list"], [1, 2], "the answer: Input should be a valid dictionary"),
        (["list"], {"orders": "x", "total": "y", "offset": 0}, "total: Input should be"),
        (["show", "o1"], {"id": "o1"}, "get: Field required"),
        (["show", "o1"], _answer_order(history=[{"time_s": "soon"}]), "history.0.time_s: "),
        (
            ["list", "--json"],
            {"orders": [{}], "total": 1, "offset": 0, "next_offset": 1, "added": 1},
            "orders.0.id: ",
        ),
    ],
)
def test_an_answer_that_is_not_the_apis_is_one_line(capsys, argv, body, where):
    """A server that answers JSON of another shape: one line naming the first field that is
    wrong, never a KeyError or TypeError traceback."""
    line = error_line(*_answered(capsys, body, *argv)[::2])
    assert where in line and line.endswith("such; not a plc-runtime HTTP API?)"), line


def test_an_answer_longer_than_the_limit_is_one_line(capsys, monkeypatch):
    """A server that would send without end is read only up to the limit."""
    monkeypatch.setattr(order_cli, "MAX_ANSWER_BYTES", 1000)
    line = error_line(*_answered(capsys, {"pad": "x" * 2000}, "list")[::2])
    assert "the answer is longer than" in line


def test_control_characters_in_an_answer_do_not_reach_the_terminal(capsys):
    """Whatever server the URL names, an ESC or a bidirectional control in its answer is
    printed as an escape: it cannot recolour, retitle or reorder the operator's screen."""
    hostile = _answer_order(id="\x1b]0;pwned\x07x", reason="late \u202ereversed\x1b[2J")
    for argv in (["list"], ["show", "o1"]):
        code, out, err = _answered(capsys, {"orders": [hostile], "total": 1, "offset": 0, "next_offset": 1, "added": 1}
                                   if argv == ["list"] else hostile, *argv)  # fmt: skip
        assert (code, err) == (0, "")
        assert "\x1b" not in out and "\u202e" not in out and "\x07" not in out
        assert "\\x1b]0;pwned" in out and "\\u202e" in out


def test_line_breaks_in_an_answer_do_not_start_table_lines(capsys):
    """A table cell is one line: a line break a server puts in an id or a reason is shown
    as its escape, so it cannot start a forged row in ``order list`` or ``order show``."""
    hostile = _answer_order(id="a\nFORGED", reason="r\r\nFORGED\u2028FORGED")
    for argv in (["list"], ["show", "o1"]):
        code, out, err = _answered(capsys, {"orders": [hostile], "total": 1, "offset": 0, "next_offset": 1, "added": 1}
                                   if argv == ["list"] else hostile, *argv)  # fmt: skip
        assert (code, err) == (0, "")
        assert "r\\r\\nFORGED\\u2028FORGED" in out, out
        assert all("\\nFORGED" in line for line in out.splitlines() if "FORGED" in line), out


@pytest.mark.parametrize(
    ("raw", "where"),
    [
        (b"garbage\r\n\r\n", "BadStatusLine("),
        (b"HTTP/1.1 1000 X\r\n\r\n", "BadStatusLine("),
        (b"HTTP/1.1 200 OK\r\n" + b"X: y\r\n" * 200 + b"\r\n", "got more than 100 headers"),
        (_http(b"", **{"Transfer-Encoding": "chunked"})[:-2] + b"zz\r\n", "IncompleteRead("),
        (b"", "Remote end closed connection without response"),
        (_http(b"[" * 100_000), "the answer is not JSON"),
        (_http(json.dumps(_answer_order(start_s=math.nan)).encode()), "the answer is not JSON"),
        (_http(json.dumps(_answer_order(end_s=math.inf)).encode()), "the answer is not JSON"),
        (_http(b"[" * 100_000, "500 Oops"), "Oops (http://127.0.0.1:"),
    ],
)
def test_a_server_that_does_not_speak_the_api_is_one_line(capsys, raw, where):
    """Whatever comes back (not HTTP, broken chunks, JSON nested too deep for the parser,
    NaN, which JSON does not have and --json could not print), one line, no traceback."""
    assert where in error_line(*_sent(capsys, raw, "show", "o1")[::2])


def test_a_refusal_from_a_server_stays_one_short_line(capsys):
    """An error answer's message is the server's text: a newline in it must not print a
    second, forged line, and a long one is cut short."""
    forged = {"error": "bad\nplc-runtime: error: forged"}
    line = error_line(*_sent(capsys, _http(json.dumps(forged).encode(), "400 Bad"), "list")[::2])
    assert line == "bad\\nplc-runtime: error: forged (HTTP 400)"
    huge = {"error": "x" * 100_000}
    line = error_line(*_sent(capsys, _http(json.dumps(huge).encode(), "400 Bad"), "list")[::2])
    assert line == "x" * order_cli.MAX_ERROR_CHARS + "... (HTTP 400)"


def test_an_added_orders_line_cannot_be_forged(capsys):
    """``order add`` prints one line: a newline in the state the server gives is an escape."""
    answer = _http(json.dumps(_answer_order(id="a\nb", state="RAW\nFAKE")).encode(), "201 Created")
    code, out, err = _sent(capsys, answer, "add", "--token", TOKEN, "--id", "a", "--get", "21",
                           "--put", "23")  # fmt: skip
    assert (code, err) == (0, "") and out == "order 'a\\nb': RAW\\nFAKE\n"


@pytest.mark.parametrize(
    ("page", "where"),
    [
        ({"orders": [_answer_order()] * 2, "total": 9, "offset": 0, "next_offset": 0, "added": 9}, "a page of 2 orders from offset 0, the next at 0"),
        ({"orders": [_answer_order()] * 3, "total": 9, "offset": 0, "next_offset": 3, "added": 9}, "a page of 3 orders from offset 0"),
        ({"orders": [_answer_order()], "total": 1, "offset": 7, "next_offset": 8, "added": 8}, "a page of 1 orders from offset 7"),
    ],
)  # fmt: skip
def test_list_stops_at_pages_that_do_not_add_up(capsys, monkeypatch, page, where):
    """A server whose full pages do not move the offset on (it would keep ``list`` paging
    for ever), a page larger than asked, or a page from elsewhere: one line naming it."""
    monkeypatch.setattr(order_cli, "PAGE", 2)
    assert where in error_line(*_answered(capsys, page, "list")[::2])


def test_list_reads_at_most_its_limit(capsys, monkeypatch):
    """A server that sends full pages of a book without end: ``list`` stops at its limit."""
    monkeypatch.setattr(order_cli, "PAGE", 2)
    monkeypatch.setattr(order_cli, "MAX_LIST_BYTES", 5000)

    def pages(conn: socket.socket, stop: threading.Event) -> None:
        pages.served += 1  # (each page on its own connection, one after the other)
        offset = 2 * (pages.served - 1)
        orders = [_answer_order(id=f"o{offset + k}") for k in range(2)]
        conn.sendall(
            _http(
                json.dumps(
                    {
                        "orders": orders,
                        "total": 10**9,
                        "offset": offset,
                        "next_offset": offset + 2,
                        "added": 10**9,
                    }
                ).encode()
            )
        )

    pages.served = 0
    with _RawServer(pages) as server:
        line = error_line(*order(capsys, "list", "--url", server.url)[::2])
    assert "more than 5,000 bytes of orders" in line and "read the book page by page" in line
    assert pages.served < 20


def test_a_server_that_sends_slowly_is_given_up_in_time(capsys, monkeypatch):
    """The timeout bounds the whole request: a byte every 0.2 s passes every single read's
    timeout, and would take 20 s for this body."""
    monkeypatch.setattr(order_cli, "TIMEOUT_S", 1.0)

    def drip(conn: socket.socket, stop: threading.Event) -> None:
        conn.sendall(_http(b"", **{"Content-Length": "100"})[: -0 or None])
        while not stop.wait(0.2):
            conn.sendall(b" ")

    with _RawServer(drip) as server:
        begin = time.monotonic()
        line = error_line(*order(capsys, "list", "--url", server.url)[::2])
    assert line.endswith("no complete answer within 1 s")
    assert time.monotonic() - begin < 19  # (the drip would take 20 s)


def test_an_id_that_is_not_utf8_is_one_line(capsys):
    """Bytes of the shell that are not UTF-8 reach argv as surrogate escapes."""
    line = error_line(*order(capsys, "show", "--url", "http://127.0.0.1:9", "\udcff")[::2])
    assert line == "order id '\\udcff': not UTF-8 text"


# ----- run --web --------------------------------------------------------------------------------
def test_run_serves_until_ctrl_c_and_closes(tmp_path, capsys):
    """As a reader starts it: a generated token printed once, an order added with it is
    delivered, Ctrl-C ends the run (130) and the port is closed."""
    err_file = tmp_path / "run.err"
    cmd = [sys.executable, "-m", "fleet", "run", str(CONFIG), "--web", "127.0.0.1:0",
           "--speed", "20", "--duration", "1000", "--watchdog", "30000", "--json",
           "--out", str(tmp_path / "out")]  # fmt: skip
    env = {k: v for k, v in os.environ.items() if k != TOKEN_ENV}
    with err_file.open("w") as err:
        proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=err)
    try:
        deadline = time.monotonic() + START_WALL_S
        found = None
        while found is None and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.1)
            found = ANNOUNCE.search(err_file.read_text())
        assert found, f"no announcement: {err_file.read_text()}"
        url, port, rest = found.group(1), int(found.group(2)), found.group(3)
        token = rest.removeprefix("; token for writes: ")
        assert len(token) >= 32
        code, out, err = order(capsys, "add", "--url", url, "--token", token, "--id", "run-1",
                               "--get", "21", "--put", "23")  # fmt: skip
        assert code == 0, err
        deadline = time.monotonic() + FINISH_WALL_S
        while time.monotonic() < deadline:
            _, out, _ = order(capsys, "show", "--url", url, "run-1", "--json")
            if json.loads(out)["state"] == "FINISHED":
                break
            time.sleep(0.1)
        assert json.loads(out)["state"] == "FINISHED"
        proc.send_signal(signal.SIGINT)
        stdout, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err_file.read_text()
    assert json.loads(stdout)["interrupted"] is True
    assert err_file.read_text().count(token) == 1  # printed once
    assert_port_closed(port)
    code, _, err = order(capsys, "list", "--url", url)
    assert "cannot reach the controller (Connection refused)" in error_line(code, err)


def run_in_process(capsys, tmp_path, *extra: str) -> tuple[int, int | None, str]:
    """``plc-runtime run --web`` here, to its end; (exit code, the port it served, stderr)."""
    before = set(threading.enumerate())
    code = main(["run", str(CONFIG), "--web", "127.0.0.1:0", "--web-token", TOKEN,
                 "--json", "--out", str(tmp_path), *extra])  # fmt: skip
    _, err = capsys.readouterr()
    found = ANNOUNCE.search(err)
    port = int(found.group(2)) if found else None
    assert_server_gone(port, before)
    return code, port, err


def test_run_closes_the_server_at_its_end(tmp_path, capsys):
    code, port, err = run_in_process(capsys, tmp_path, "--duration", "2", "--watchdog", "30000")
    assert code == 0 and port is not None
    assert ANNOUNCE.search(err).group(3) == ""  # a given token is not printed
    assert TOKEN not in err


@pytest.mark.watchdog
def test_run_closes_the_server_after_a_fault(tmp_path, capsys):
    code, port, err = run_in_process(capsys, tmp_path, "--duration", "2", "--watchdog", "0.001")
    assert code == 1 and port is not None
    assert json.loads((tmp_path / "summary.json").read_text())["state"] == "FAULT"


def test_run_with_the_port_in_use_is_one_line(tmp_path, capsys):
    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        before = set(threading.enumerate())
        code = main(["run", str(CONFIG), "--web", f"127.0.0.1:{port}", "--web-token", TOKEN,
                     "--duration", "1", "--out", str(tmp_path)])  # fmt: skip
        _, err = capsys.readouterr()
        assert_server_gone(None, before)
    assert error_line(code, err) == (
        f"driver web: cannot open: HTTP API on 127.0.0.1:{port}: Address already in use"
    )
    assert list(tmp_path.iterdir()) == []  # the run's lock file is gone with the failed start


@pytest.mark.parametrize(
    ("argv", "line"),
    [
        (
            [str(CONFIG), "--web", "8080"],
            "--web: expected HOST:PORT, e.g. 127.0.0.1:8080, got '8080'",
        ),
        ([str(CONFIG), "--web", "127.0.0.1:99999"], "expected HOST:PORT"),
        (
            [str(CONFIG), "--web", "[::1"],
            "--web: expected HOST:PORT, e.g. 127.0.0.1:8080, got '[::1'",
        ),
        (
            [str(CONFIG), "--web", "::1:8080"],
            "--web: an IPv6 host goes in brackets, e.g. [::1]:8080",
        ),
        (
            [str(CONFIG), "--web", "[::g]:8080"],
            "--web: '::g' is no IPv6 address (brackets hold one), in '[::g]:8080'",
        ),
        ([str(CONFIG), "--web", "[127.0.0.1]:8080"], "'127.0.0.1' is no IPv6 address (brackets"),
        (
            [str(CONFIG), "--web", "127.0.0.1:0", "--web-token", "short"],
            "--web-token: a bearer token needs 16 characters or more of A-Z a-z 0-9 - . _ ~ + /, "
            "and = only at its end (got 5 characters)",
        ),
        (
            [str(CONFIG), "--web", "127.0.0.1:0", "--web-token", "with spaces in the token"],
            "some not allowed",
        ),
        (
            [str(CONFIG), "--web", "127.0.0.1:0", "--web-token", "a" + "=" * 15],
            "and = only at its end (got 1 characters)",
        ),
        ([str(CONFIG), "--web-token", TOKEN], "--web-token is the token of the HTTP API"),
        (
            ["--program", "demo", "--web", "127.0.0.1:0"],
            "--web serves the fleet program's API and page",
        ),
    ],
)
def test_run_refuses_bad_web_options_in_one_line(tmp_path, capsys, argv, line):
    code = main(["run", *argv, "--duration", "1", "--out", str(tmp_path)])
    assert line in error_line(code, capsys.readouterr().err)


def test_run_takes_the_token_from_the_environment(monkeypatch):
    cfg = load_config(CONFIG)
    args = argparse.Namespace(web="127.0.0.1:0", web_token=None)
    monkeypatch.setenv(TOKEN_ENV, TOKEN)
    options = web_options(args, cfg)
    assert (options.token, options.generated) == (TOKEN, False)
    monkeypatch.setenv(TOKEN_ENV, "x")
    with pytest.raises(CliError, match=f"^{TOKEN_ENV}: a bearer token needs 16 characters"):
        web_options(args, cfg)
    monkeypatch.delenv(TOKEN_ENV)
    generated = web_options(args, cfg)
    assert generated.generated and len(generated.token) == 32
    assert generated.token != web_options(args, cfg).token


def test_a_generated_token_never_starts_with_a_dash(monkeypatch):
    """It is given back as ``--token TOKEN``; one starting with "-" would read as an option
    (a generated token did, 1 draw in 64, and failed a run of this suite)."""
    draws = iter(["-" + "a" * 31, "-" + "b" * 31, "c" * 32])
    monkeypatch.setattr(web_options_module.secrets, "token_urlsafe", lambda n: next(draws))
    assert web_options_module.new_token() == "c" * 32


def test_the_order_list_keeps_ids_and_states_whole_on_a_narrow_terminal():
    """At 80 columns "paint-1" and "paint-2" both read "paint…" and every state four
    letters, while the reason, mostly empty, kept its width."""
    from rich.console import Console

    from fleet.commands.orders import orders_table
    from fleet.web.models import OrderOut

    def order(oid, state, reason=""):
        return OrderOut(
            id=oid, get=25, put=26, start_s=15.0, end_s=400.0, priority=0, vehicle=None,
            state=state, assigned=1, reason=reason, history=[], sections={}, position=0,
        )  # fmt: skip

    orders = [
        order("paint-1", "BEING_PROCESSED"),
        order("paint-2", "FINISHED", "a reason long enough to need folding, twice over at that"),
    ]
    console = Console(width=80, record=True, file=io.StringIO())
    console.print(orders_table(orders, "http://127.0.0.1:8080"))
    text = console.export_text()
    for whole in ("paint-1", "paint-2", "BEING_PROCESSED", "FINISHED"):
        assert whole in text


def test_show_says_where_transitions_were_dropped_from_a_history():
    """An order taken back again and again keeps its release and its newest transitions;
    ``show`` marks the gap with the count, after the release."""
    from rich.console import Console

    from fleet.commands.orders import order_table
    from fleet.web.models import OrderOut

    history = [(0.0, "RAW"), (0.0, "DISPATCHABLE"), (905.0, "BEING_PROCESSED")]
    o = OrderOut.model_validate(
        _answer_order(
            state="BEING_PROCESSED",
            history=[{"time_s": t, "state": state} for t, state in history],
            history_dropped=140,
        )
    )
    console = Console(width=200, record=True, file=io.StringIO())
    console.print(order_table(o))
    text = console.export_text()
    assert (
        "0 s RAW, 0 s DISPATCHABLE, ... 140 earlier transitions not kept ..., "
        "905 s BEING_PROCESSED" in text
    )
    assert OrderOut.model_validate(_answer_order()).history_dropped == 0  # an older server


def test_list_pages_on_from_next_offset_over_orders_that_have_left_the_book(capsys, monkeypatch):
    """Positions of orders that left the book are gaps: ``list`` asks from each page's
    ``next_offset`` and shows every order once."""
    monkeypatch.setattr(order_cli, "PAGE", 2)
    book = {0: "a", 1: "b", 5: "c", 6: "d", 9: "e"}  # position -> id; the rest were swept
    asked = []

    def pages(conn: socket.socket, stop: threading.Event) -> None:
        offset = int(server.requests[-1].decode().split("offset=")[1].split("&")[0])
        asked.append(offset)
        held = [p for p in sorted(book) if p >= offset][:2]
        body = {"orders": [_answer_order(id=book[p]) for p in held], "total": len(book),
                "offset": offset, "next_offset": held[-1] + 1 if held else offset, "added": 10}  # fmt: skip
        conn.sendall(_http(json.dumps(body).encode()))

    with _RawServer(pages) as server:
        code, out, err = order(capsys, "list", "--json", "--url", server.url)
    assert (code, err) == (0, ""), err
    assert [o["id"] for o in json.loads(out)] == ["a", "b", "c", "d", "e"]
    assert asked == [0, 2, 7]
