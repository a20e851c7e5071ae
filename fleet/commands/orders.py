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
Requests go straight to the URL given: no proxy from the environment sees the token, and a
redirect is not followed. Numbers are read as order files read them (ASCII digits only),
and the tables show ids, reasons and every other text of the answer literally, never as
rich markup, with control characters written as escapes: the answer may come from any
server the URL names, and an ESC in it would drive the operator's terminal.
"""

from __future__ import annotations

import argparse
import json
import os
import urllib.error
import urllib.request
from typing import Any, TypeVar
from urllib.parse import quote, urlsplit

from pydantic import BaseModel, ValidationError
from rich.console import Console
from rich.table import Table
from rich.text import Text

from plc_runtime.cli import CliError, terminal_text
from topology.formats.numbers import not_an_integer, parse_float, parse_int, shown

from ..web.models import OrderOut, OrderPage
from ..web.options import TOKEN_ENV, bearer_token

Answer = TypeVar("Answer", bound=BaseModel)

DEFAULT_URL = "http://127.0.0.1:8080"
PREFIX = "/api/v1"
PAGE = 500  # orders per request of ``list`` (the API's largest page)
TIMEOUT_S = 15.0  # the controller answers within two of its 5 s waits for the scan
# the largest answer read: a page of 500 orders with the longest ids and a long history is
# a few MB, so this only stops a server that would fill the memory
MAX_ANSWER_BYTES = 64 * 2**20


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
            Console().print(orders_table(orders, args.url))
        return 0
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
        print(terminal_text(f"order {order.id!r}: {order.state}"))
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
        self._open = urllib.request.build_opener(urllib.request.ProxyHandler({}), _NoRedirect).open

    def all_orders(self) -> list[OrderOut]:
        """Every order, page by page (the book only grows, so pages do not shift)."""
        orders: list[OrderOut] = []
        while True:
            page = self.call("GET", f"/orders?offset={len(orders)}&limit={PAGE}", OrderPage)
            orders += page.orders
            if not page.orders or len(orders) >= page.total:
                return orders

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
        try:
            with self._open(request, timeout=TIMEOUT_S) as reply:
                raw = reply.read(MAX_ANSWER_BYTES + 1)
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
            raise CliError(f"{self.base}: no answer within {TIMEOUT_S:g} s") from None
        except ValueError as exc:  # http.client: a URL with characters a request cannot hold
            raise CliError(f"--url {self.base!r}: {exc}") from None
        except OSError as exc:  # the connection broke mid-answer
            raise CliError(f"{self.base}: {exc.strerror or exc}") from None
        if len(raw) > MAX_ANSWER_BYTES:
            raise CliError(
                f"{method} {url}: the answer is longer than {MAX_ANSWER_BYTES:,} bytes "
                "(not a plc-runtime HTTP API?)"
            )
        return self._answer(raw, f"{method} {url}", answer)

    def _refusal(self, exc: urllib.error.HTTPError) -> str:
        """One line for an error answer: the API's own message where it gave one."""
        try:
            message = json.loads(exc.read())["error"]
        except (ValueError, KeyError, TypeError, OSError):
            message = f"{exc.reason} ({self.base} is not a plc-runtime HTTP API?)"
        line = f"{message} (HTTP {exc.code})"
        if exc.code == 401:
            line += f": give --token or set {TOKEN_ENV}"
        return line

    def _answer(self, raw: bytes, what: str, answer: type[Answer]) -> Answer:
        try:
            data = json.loads(raw)
        except ValueError:
            raise CliError(
                f"{what}: the answer is not JSON (not a plc-runtime HTTP API?)"
            ) from None
        try:
            return answer.model_validate(data)
        except ValidationError as exc:
            first = exc.errors()[0]
            where = ".".join(str(part) for part in first["loc"]) or "the answer"
            raise CliError(
                f"{what}: {where}: {first['msg']} in the answer "
                f"({exc.error_count()} such; not a plc-runtime HTTP API?)"
            ) from None


def check_url(url: str) -> None:
    """CliError unless ``url`` can name a controller: http(s), a host, a port 0-65535 in ASCII
    digits if any. urllib would find a bad port or bracket only when it connects, and raise
    an exception of its own."""
    expected = f"expected http://HOST:PORT, e.g. {DEFAULT_URL}"
    try:
        parts = urlsplit(url)
    except ValueError as exc:  # an unclosed "[": "Invalid IPv6 URL"
        raise CliError(f"--url {url!r}: {exc}; {expected}") from None
    if parts.scheme not in ("http", "https"):
        wrong = "not http or https"
    elif not parts.hostname:
        wrong = "no host"
    else:
        try:
            _ = parts.port  # raises unless ASCII digits 0-65535 (or none)
            return
        except ValueError:
            wrong = "the port is not a number 0-65535"
    raise CliError(f"--url {url!r}: {wrong}; {expected}")


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
    control characters are escapes."""
    table.add_row(*(Text(terminal_text(str(cell))) for cell in cells))


def orders_table(orders: list[OrderOut], url: str) -> Table:
    table = Table(title=Text(terminal_text(f"{len(orders)} orders at {url}")))
    for name in ("id", "get", "put", "start s", "end s", "prio", "vehicle", "state", "assigned"):
        table.add_column(name, justify="left" if name in ("id", "state") else "right")
    table.add_column("reason")
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
    history = ", ".join(f"{h.time_s:g} s {h.state}" for h in o.history)
    _row(table, "history", history)
    for name, times in o.sections.items():
        _row(
            table, name, " .. ".join(f"{t:g} s" for t in times) + (" .." if len(times) == 1 else "")
        )
    return table
