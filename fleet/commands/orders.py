"""``plc-runtime order add|withdraw|list|show``: the transport orders of a running controller.

The controller is ``plc-runtime run CONFIG --web HOST:PORT``; these commands talk to its
HTTP API (fleet/web) with the standard library's urllib, so scripts need nothing else.
``add`` and ``withdraw`` need the token the run was given (``--token``, or the environment
variable ``PLC_RUNTIME_TOKEN``); reading needs none.

Every failure is one line on stderr and exit code 2: ``--url`` names no controller, the
controller cannot be reached, the token is missing or wrong, there is no such order, or the
controller refused the order (the line names the field and what is wrong, as the order book
says it), or the answer is not what the API sends (checked against the API's own models,
so a server that is not a controller cannot make the command fail with a traceback).
A request is given up 15 s after it connected, however slowly the server sends. Requests go
straight to the URL given: no proxy from the environment sees the token, and a redirect is
not followed. Numbers are read as order files read them (ASCII digits only),
and the tables show ids, reasons and every other text of the answer literally, never as
rich markup, with control characters (line breaks included) written as escapes: the answer
may come from any server the URL names, an ESC in it would drive the operator's terminal
and a line break would start a table line of the server's making.
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import socket
import sys
import threading
import urllib.error
import urllib.request
from collections.abc import Callable
from typing import Any, TypeVar
from urllib.parse import SplitResult, quote, urlsplit

from pydantic import BaseModel, ValidationError
from rich.console import Console
from rich.table import Table
from rich.text import Text

from plc_runtime.cli import CliError, one_line, terminal_text
from topology.formats.numbers import not_an_integer, parse_float, parse_int, shown

from ..web.models import OrderOut, OrderPage
from ..web.options import TOKEN_ENV, bearer_token

Answer = TypeVar("Answer", bound=BaseModel)
Watch = Callable[[socket.socket], None]  # told each connection's socket once connected

DEFAULT_URL = "http://127.0.0.1:8080"
PREFIX = "/api/v1"
PAGE = 500  # orders per request of ``list`` (the API's largest page)
TIMEOUT_S = 15.0  # the controller answers within two of its 5 s waits for the scan
# the largest answer read: a page of 500 orders with the longest ids and a long history is
# a few MB, so this only stops a server that would fill the memory
MAX_ANSWER_BYTES = 64 * 2**20
# what ``list`` reads in all: some 600,000 orders of a real book; past it the book is
# better read page by page from the API than as one table
MAX_LIST_BYTES = 256 * 2**20
MAX_ERROR_CHARS = 500  # of a text of the server's in a line: the API's are one short line


def integer(text: str) -> int:
    """An argparse type: an integer as an order file spells it (``int()`` would also take
    ``1_0`` and other scripts' digits, which an order file refuses)."""
    value = parse_int(text)
    if value is None:
        raise argparse.ArgumentTypeError(f"{not_an_integer(text)}: {shown(text)}")
    return value


def seconds(text: str) -> float:
    """An argparse type: a time >= 0 as an order file spells it (ASCII decimal, finite)."""
    value = parse_float(text)
    if value is None:
        raise argparse.ArgumentTypeError(f"not a finite decimal number: {shown(text)}")
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0: {shown(text)}")
    return value


def add_parsers(sub: argparse._SubParsersAction) -> None:
    order = sub.add_parser(
        "order", help="add, withdraw, list or show transport orders of a running controller"
    )
    commands = order.add_subparsers(dest="order_command", required=True)
    add = commands.add_parser("add", help="add a transport order (needs the token)")
    withdraw = commands.add_parser("withdraw", help="withdraw an open order (needs the token)")
    listing = commands.add_parser("list", help="every order of the run: a table")
    show = commands.add_parser("show", help="one order with its history and sections")
    for parser in (add, withdraw, listing, show):
        parser.add_argument(
            "--url",
            default=DEFAULT_URL,
            help=f"the controller's HTTP API, as run --web serves it (default {DEFAULT_URL})",
        )
    for parser in (add, withdraw):
        parser.add_argument("--token", help=f"the run's token for writes (default: ${TOKEN_ENV})")
    for parser in (add, withdraw, listing, show):
        parser.add_argument("--json", action="store_true", help="print the answer as JSON")
    add.add_argument("--id", required=True, help="the order's id, unique in the run")
    add.add_argument("--get", type=integer, required=True, help="Get station (node id)")
    add.add_argument("--put", type=integer, required=True, help="Put station (node id)")
    add.add_argument(
        "--start", type=seconds, metavar="S", help="earliest pickup, simulated s (default 0)"
    )
    add.add_argument(
        "--end", type=seconds, metavar="S", help="latest delivery, simulated s (default none)"
    )
    add.add_argument("--priority", type=integer, help="larger is more urgent (default 0)")
    add.add_argument("--vehicle", type=integer, help="the only vehicle that may take the order")
    for parser in (withdraw, show):
        parser.add_argument("id", help="the order's id")


def order_command(args: argparse.Namespace) -> int:
    api = Api(args.url, getattr(args, "token", None))
    kind = args.order_command
    if kind == "list":
        orders = api.all_orders()
        if args.json:
            print(json.dumps([o.model_dump(mode="json") for o in orders]))
        else:
            # a file or a pipe gets whole rows, as a wide terminal does
            Console(width=None if sys.stdout.isatty() else 200).print(
                orders_table(orders, args.url)
            )
        return 0
    if kind in ("show", "withdraw"):
        try:
            args.id.encode()
        except UnicodeEncodeError:  # bytes of the shell that are not UTF-8 (surrogate escapes)
            raise CliError(f"order id {terminal_text(repr(args.id))}: not UTF-8 text") from None
    if kind == "show":
        order = api.call("GET", f"/orders/{quote(args.id, safe='')}", OrderOut)
    elif kind == "add":
        body = {"id": args.id, "get": args.get, "put": args.put}
        optional = {
            "start_s": args.start,
            "end_s": args.end,
            "priority": args.priority,
            "vehicle": args.vehicle,
        }
        body.update({k: v for k, v in optional.items() if v is not None})
        order = api.call("POST", "/orders", OrderOut, body)
    else:
        order = api.call("DELETE", f"/orders/{quote(args.id, safe='')}", OrderOut)
    if args.json:
        print(json.dumps(order.model_dump(mode="json")))
    elif kind == "show":
        Console().print(order_table(order))
    else:
        print(
            f"order {one_line(repr(order.id), MAX_ERROR_CHARS)}: {one_line(order.state, MAX_ERROR_CHARS)}"
        )
    return 0


class Api:
    """The controller's API at ``url`` (its root, or the ``/api/v1`` it announces)."""

    def __init__(self, url: str, token: str | None) -> None:
        check_url(url)
        self.base = url.rstrip("/").removesuffix(PREFIX)
        where = "--token" if token is not None else TOKEN_ENV
        self.token = token if token is not None else os.environ.get(TOKEN_ENV)
        if self.token is not None and not bearer_token(self.token):
            raise CliError(
                f"{where}: not a bearer token (A-Z a-z 0-9 - . _ ~ + / only, and = at its end)"
            )
        self._open = urllib.request.build_opener(
            urllib.request.ProxyHandler({}),
            _NoRedirect,
            _DeadlineHTTPHandler(self._watch),
            _DeadlineHTTPSHandler(self._watch),
        ).open
        self._expired = threading.Event()
        self._timer: threading.Timer | None = None  # the running request's deadline
        self._read = 0  # bytes of answers read by this Api

    def all_orders(self) -> list[OrderOut]:
        """Every order in the book, page by page (pages are by position, which never
        changes, so they do not shift when old orders leave the book). Each page must
        answer the offset asked, hold at most PAGE orders and, unless it is the last (not
        full), move the offset on; all of them hold at most MAX_LIST_BYTES: a server that is
        not the API cannot keep the command paging for ever."""
        orders: list[OrderOut] = []
        offset = 0
        while True:
            path = f"/orders?offset={offset}&limit={PAGE}"
            page = self.call("GET", path, OrderPage)
            if (
                page.offset != offset
                or len(page.orders) > PAGE
                or (len(page.orders) == PAGE and page.next_offset <= offset)
            ):
                raise CliError(
                    f"GET {self.base}{PREFIX}{path}: a page of {len(page.orders)} orders from "
                    f"offset {page.offset}, the next at {page.next_offset}, in the answer "
                    "(not a plc-runtime HTTP API?)"
                )
            orders += page.orders
            if len(page.orders) < PAGE:
                return orders
            offset = page.next_offset
            if self._read > MAX_LIST_BYTES:
                raise CliError(
                    f"{self.base}: more than {MAX_LIST_BYTES:,} bytes of orders "
                    f"({len(orders):,} of {page.total:,}); read the book page by page: "
                    f"GET {PREFIX}/orders?offset=N&limit={PAGE}"
                )

    def _watch(self, sock: socket.socket) -> None:
        """Bound the whole request, not each read: a server that sends a byte every few
        seconds would pass every read's timeout. When TIMEOUT_S has passed since the
        connection was made, the socket is shut down, which ends any read at once."""

        def expire() -> None:
            self._expired.set()
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass  # already closed: the request is over

        self._timer = threading.Timer(TIMEOUT_S, expire)
        self._timer.daemon = True
        self._timer.start()

    def call(
        self,
        method: str,
        path: str,
        answer: type[Answer],
        body: dict[str, Any] | None = None,
    ) -> Answer:
        """The answer of ``method path`` as the API's model ``answer``; CliError with one
        line for every failure."""
        url = f"{self.base}{PREFIX}{path}"
        headers = {"Accept": "application/json"}
        data = None
        if body is not None:
            data = json.dumps(body).encode()
            headers["Content-Type"] = "application/json"
        if method != "GET" and self.token is not None:
            headers["Authorization"] = f"Bearer {self.token}"
        request = urllib.request.Request(url, data, headers, method=method)
        self._timer = None
        self._expired.clear()
        try:
            raw = self._exchange(request)
        except CliError:
            if not self._expired.is_set():
                raise
        finally:
            if self._timer is not None:
                self._timer.cancel()
        if self._expired.is_set():  # whatever broke or came back: cut short by the deadline
            raise CliError(f"{self.base}: no complete answer within {TIMEOUT_S:g} s")
        if len(raw) > MAX_ANSWER_BYTES:
            raise CliError(
                f"{method} {url}: the answer is longer than {MAX_ANSWER_BYTES:,} bytes "
                "(not a plc-runtime HTTP API?)"
            )
        self._read += len(raw)
        return self._answer(raw, f"{method} {url}", answer)

    def _exchange(self, request: urllib.request.Request) -> bytes:
        """The answer's body, at most MAX_ANSWER_BYTES + 1 of it; CliError with one line
        for every failure on the way."""
        try:
            with self._open(request, timeout=TIMEOUT_S) as reply:
                return reply.read(MAX_ANSWER_BYTES + 1)
        except urllib.error.HTTPError as exc:
            raise CliError(self._refusal(exc)) from None
        except urllib.error.URLError as exc:
            reason = exc.reason
            if isinstance(reason, TimeoutError):
                raise CliError(f"{self.base}: no answer within {TIMEOUT_S:g} s") from None
            why = reason.strerror if isinstance(reason, OSError) and reason.strerror else reason
            raise CliError(
                f"{self.base}: cannot reach the controller ({why}); is "
                "`plc-runtime run CONFIG --web HOST:PORT` running there?"
            ) from None
        except TimeoutError:
            raise CliError(f"{self.base}: no complete answer within {TIMEOUT_S:g} s") from None
        except ValueError as exc:  # http.client: a URL with characters a request cannot hold
            raise CliError(f"--url {self.base!r}: {exc}") from None
        except (OSError, http.client.HTTPException) as exc:
            # the connection broke mid-answer, or what came back is not HTTP
            why = exc.strerror if isinstance(exc, OSError) and exc.strerror else repr(exc)
            raise CliError(
                f"{self.base}: {one_line(why, MAX_ERROR_CHARS)} (not a plc-runtime HTTP API?)"
            ) from None

    def _refusal(self, exc: urllib.error.HTTPError) -> str:
        """One line for an error answer: the API's own message where it gave one."""
        try:
            message = _json(exc.read(MAX_ANSWER_BYTES))["error"]
            if not isinstance(message, str):
                raise TypeError
            message = one_line(message, MAX_ERROR_CHARS)
        except (ValueError, KeyError, TypeError, OSError, http.client.HTTPException):
            message = f"{one_line(str(exc.reason), MAX_ERROR_CHARS)} ({self.base} is not a plc-runtime HTTP API?)"
        line = f"{message} (HTTP {exc.code})"
        if exc.code == 401:
            line += f": give --token or set {TOKEN_ENV}"
        return line

    def _answer(self, raw: bytes, what: str, answer: type[Answer]) -> Answer:
        try:
            data = _json(raw)
        except ValueError:
            raise CliError(
                f"{what}: the answer is not JSON (not a plc-runtime HTTP API?)"
            ) from None
        try:
            return answer.model_validate(data, strict=True)
        except ValidationError as exc:
            first = exc.errors()[0]
            where = ".".join(str(part) for part in first["loc"]) or "the answer"
            raise CliError(
                f"{what}: {one_line(where, MAX_ERROR_CHARS)}: {first['msg']} in the answer "
                f"({exc.error_count()} such; not a plc-runtime HTTP API?)"
            ) from None


def _json(raw: bytes) -> Any:
    """``raw`` as JSON, strictly: NaN and Infinity are not JSON (the API never sends them,
    and ``--json`` must print valid JSON), and nesting too deep to parse is refused like any
    other text that is not JSON (ValueError)."""

    def refuse(name: str) -> None:
        raise ValueError(f"{name} is not JSON")

    try:
        return json.loads(raw, parse_constant=refuse)
    except RecursionError:
        raise ValueError("nested too deeply") from None


def check_url(url: str) -> None:
    """CliError unless ``url`` can name a controller: http(s), a host, a port 0-65535 in ASCII
    digits if any, and nothing a request path cannot follow: the API's paths are appended
    to it, so a query or a fragment would swallow them (``?x=1/api/v1/orders`` asks for
    ``/``), and urllib takes user info for part of the host name. urllib would find a bad
    port or bracket only when it connects, and raise an exception of its own."""
    expected = f"expected http://HOST:PORT, e.g. {DEFAULT_URL}"
    try:
        parts = urlsplit(url)
    except ValueError as exc:  # an unclosed "[": "Invalid IPv6 URL"
        raise CliError(f"--url {url!r}: {exc}; {expected}") from None
    wrong = _url_problem(url, parts)
    if wrong is None:
        return
    shown = url
    if "@" in parts.netloc:  # a password in it is not repeated on the screen
        shown = url.replace(parts.netloc.rpartition("@")[0], "...", 1)
    raise CliError(f"--url {shown!r}: {wrong}; {expected}")


def _url_problem(url: str, parts: SplitResult) -> str | None:
    """What keeps ``url`` (split into ``parts``) from naming a controller; None: nothing."""
    if parts.scheme not in ("http", "https"):
        return "not http or https"
    if not parts.hostname:
        return "no host"
    try:
        _ = parts.port  # raises unless ASCII digits 0-65535 (or none)
    except ValueError:
        return "the port is not a number 0-65535"
    if "@" in parts.netloc:
        return "user info (USER:PASSWORD@) is not taken: the token is the only credential"
    if "?" in url.partition("#")[0]:
        return "a query (?...) is not taken"
    if "#" in url:
        return "a fragment (#...) is not taken"
    return None


class _DeadlineHTTPHandler(urllib.request.HTTPHandler):
    """Plain HTTP whose connections tell ``watch`` their socket once connected."""

    def __init__(self, watch: Watch) -> None:
        super().__init__()
        self._connection = _watched(http.client.HTTPConnection, watch)

    def http_open(self, req: urllib.request.Request) -> http.client.HTTPResponse:
        return self.do_open(self._connection, req)


class _DeadlineHTTPSHandler(urllib.request.HTTPSHandler):
    """HTTPS whose connections tell ``watch`` their socket once connected."""

    def __init__(self, watch: Watch) -> None:
        super().__init__()
        self._connection = _watched(http.client.HTTPSConnection, watch)

    def https_open(self, req: urllib.request.Request) -> http.client.HTTPResponse:
        return self.do_open(
            self._connection, req, context=self._context, check_hostname=self._check_hostname
        )


def _watched(base: type[http.client.HTTPConnection], watch: Watch) -> type:
    class Watched(base):  # type: ignore[valid-type, misc]
        def connect(self) -> None:
            super().connect()
            watch(self.sock)

    return Watched


class _NoRedirect(urllib.request.HTTPRedirectHandler):
    """A redirect is an error: the token must not follow it to another address."""

    def redirect_request(self, *args: Any, **kwargs: Any) -> None:
        return None


def _time(value: float | None) -> str:
    return "-" if value is None else f"{value:g}"


def _maybe(value: object) -> str:
    return "-" if value is None else str(value)


def _row(table: Table, *cells: object) -> None:
    """A row shown literally: an id like ``[red]x`` or ``[/oops]`` is not rich markup, and
    control characters are escapes, line breaks included: a cell is one line, so a server's
    text cannot start a row of its own making."""
    table.add_row(*(Text(one_line(str(cell))) for cell in cells))


def orders_table(orders: list[OrderOut], url: str) -> Table:
    """Every order, a row each. The id and the state are what a reader looks for: they
    keep their width on a narrow terminal (the reason folds instead)."""
    table = Table(title=Text(terminal_text(f"{len(orders)} orders at {url}")))
    longest = max((len(one_line(o.id)) for o in orders), default=2)
    for name in ("id", "get", "put", "start s", "end s", "prio", "vehicle", "state", "assigned"):
        whole = {"id": longest, "state": len("BEING_PROCESSED")}.get(name)
        table.add_column(
            name,
            justify="left" if whole else "right",
            no_wrap=whole is not None,
            min_width=whole,
        )
    table.add_column("reason", overflow="fold")
    for o in orders:
        _row(
            table,
            o.id,
            o.get,
            o.put,
            _time(o.start_s),
            _time(o.end_s),
            o.priority,
            _maybe(o.vehicle),
            o.state,
            _maybe(o.assigned),
            o.reason,
        )
    return table


def order_table(o: OrderOut) -> Table:
    """One order: its fields, then its history and its sections."""
    table = Table(title=Text(terminal_text(f"order {o.id!r}")), show_header=False)
    table.add_column("field")
    table.add_column("value")
    for name in ("get", "put", "priority", "vehicle", "state", "assigned", "reason"):
        _row(table, name, _maybe(getattr(o, name)))
    _row(table, "start_s", _time(o.start_s))
    _row(table, "end_s", _time(o.end_s))
    entries = [f"{h.time_s:g} s {h.state}" for h in o.history]
    if o.history_dropped:
        entries[2:2] = [f"... {o.history_dropped} earlier transitions not kept ..."]
    _row(table, "history", ", ".join(entries))
    for name, times in o.sections.items():
        _row(
            table, name, " .. ".join(f"{t:g} s" for t in times) + (" .." if len(times) == 1 else "")
        )
    return table
