"""The HTTP API, version 1 (FastAPI), and the operator's page.

    GET    /api/v1/plant                       the plant model and the closed segments
    GET    /api/v1/vehicles                    every vehicle (list)
    GET    /api/v1/vehicles/{id}               one vehicle (404: no such vehicle)
    GET    /api/v1/orders?offset=0&limit=100   a page of the order book, in the order added
    GET    /api/v1/orders/{id}                 one order (404: no such order)
    POST   /api/v1/orders                      add an order (201; needs the token)
    DELETE /api/v1/orders/{id}                 withdraw an order (needs the token)
    GET    /api/v1/blockades                   the closed segments
    PUT    /api/v1/blockades/{a}/{b}           close a segment, both ways (needs the token)
    DELETE /api/v1/blockades/{a}/{b}           reopen it (needs the token)
    GET    /api/v1/tags                        every tag: name, address, type, writable
    GET    /api/v1/tags/values?names=a,b       the watch table: values, forced or not
    GET    /api/v1/tags/{name}                 one tag's value
    PUT    /api/v1/tags/{name}                 write a writable tag (needs the token)
    PUT    /api/v1/tags/{name}/force           force a writable tag (needs the token)
    DELETE /api/v1/tags/{name}/force           unforce it (needs the token)
    GET    /api/v1/stats                       cycle statistics and the fleet's counters
    GET    /api/v1/events?after=0&limit=100    the event log, oldest first
    GET    /api/v1/stream                      server-sent events: snapshots at 10 Hz at most
    GET    /openapi.json                       the schema of all of it
    GET    /                                   the operator's page (static files, no build step)

Every answer comes from the scan through a desk (:class:`~fleet.web.desk.OrderDesk`,
:class:`~fleet.web.fleet_desk.FleetDesk`; why: their docstrings), the stream from the
:class:`~fleet.web.feed.LiveFeed`. A handler never blocks the event loop, let alone the scan: it waits for
the desk's Future for at most ``answer_timeout`` seconds, then answers 503 "controller not
scanning". A request the scan had not taken by then is cancelled and never applied; one
it had taken is decided within that scan, so the handler waits once more for it.

Errors are JSON, ``{"error": "one line", "field": "get"}`` (``field`` null when the error
is about no field): 400 unreadable JSON, 422 a field is wrong, 404 no such order, vehicle,
node, segment or tag (or path), 403 a tag that is read-only, 409 the id is in use, the
order cannot be withdrawn in its state, no vehicle takes orders, or the book holds as many
open orders as it takes from outside, 503 the controller is
not scanning, the run has ended or every stream place is taken, 500 a bug (its traceback
is logged); 400/401/403/408/413/429/503 from the guard (:mod:`fleet.web.guard`). On every
error nothing has changed.

Integers in paths and query strings are decimal digits only, and a query parameter or a
key of a JSON body may be given once: what the parsers would read otherwise (``1_0`` as
10, ``1.0`` as 1, the last of two values) is refused, 422 naming it.
"""

from __future__ import annotations

import asyncio
import json
import sys
from concurrent.futures import Future
from pathlib import Path as FilePath
from typing import Annotated, Any
from urllib.parse import quote

from fastapi import Depends, FastAPI, Path, Query, Request, Security
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, StreamingResponse
from fastapi.security import HTTPBearer
from fastapi.staticfiles import StaticFiles
from pydantic import BeforeValidator
from pydantic_core import PydanticCustomError
from starlette.exceptions import HTTPException
from starlette.types import Receive, Scope, Send

from blocks.dispatch.orders import OrderError, check_order

from . import views
from .desk import MAX_OFFSET, MAX_PAGE, ControllerStopped, OrderDesk
from .feed import Busy, LiveFeed, Stream
from .fleet_desk import MAX_WATCH, FleetDesk, Refusal
from .gate import ScanGate
from .models import (
    BlockadeOut,
    ErrorOut,
    EventPage,
    OrderIn,
    OrderOut,
    OrderPage,
    PlantOut,
    StatsOut,
    TagInfo,
    TagOut,
    TagValueIn,
    VehicleOut,
)
from .views import MAX_EVENTS

PREFIX = "/api/v1"
ANSWER_TIMEOUT = 5.0  # seconds a request waits for the scan before 503
DEFAULT_PAGE = 100

# documents the token in the schema; the guard enforces it before a request gets here
_BEARER = HTTPBearer(auto_error=False, description="the token given at start (--web-token)")
_ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorOut} for code in (400, 404, 409, 413, 422, 429, 503)
}
_WRITE_ERRORS = {**_ERRORS, 401: {"model": ErrorOut}, 403: {"model": ErrorOut}}
# a body sent as other than JSON (415), or too slowly (408)
_BODY_ERRORS = {**_WRITE_ERRORS, 408: {"model": ErrorOut}, 415: {"model": ErrorOut}}


def _digits(value: object) -> object:
    """An integer in a path or query string must be written in the digits 0-9 only: pydantic
    (like int()) would also read ``1_0`` as 10, ``+1``, `` 1`` and ``1.0`` as 1, so a typo
    would name another vehicle or segment instead of being refused."""
    if isinstance(value, str) and not (value.isascii() and value.isdigit()):
        raise PydanticCustomError("int_digits", "expected a whole number in the digits 0-9 only")
    return value


Digits = BeforeValidator(_digits)
OrderId = Annotated[str, Path(description="the order's id (URL-encoded)")]
NodeId = Annotated[
    int, Path(ge=0, le=0xFFFF, description="a node at one end of the segment"), Digits
]
TagName = Annotated[str, Path(min_length=1, max_length=100, description="the tag's name")]
PAGE_DIR = FilePath(__file__).with_name("page")
# the page loads nothing from elsewhere, and no other site may frame it
_PAGE_HEADERS = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff",
    "Cache-Control": "no-cache",
}


class ApiError(Exception):
    """An error answer: HTTP status, one line, the field it is about."""

    def __init__(self, status: int, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.status, self.message, self.field = status, message, field


def build_app(
    fleet: FleetDesk,
    orders: OrderDesk | None,
    feed: LiveFeed,
    gate: ScanGate,
    answer_timeout: float = ANSWER_TIMEOUT,
) -> FastAPI:
    """The application: ``orders`` is None when no vehicle of the run takes orders (the
    order book is then empty, and adding an order is refused)."""
    app = FastAPI(
        title="plc-runtime fleet API",
        version="1",
        description="A running fleet controller: plant, vehicles, transport orders, "
        "blockades, tags, statistics, events (docs/api.md, docs/operator-guide.md).",
        docs_url=None,  # the interactive pages load scripts from a CDN; openapi.json is enough
        redoc_url=None,
        redirect_slashes=False,
        dependencies=[Depends(_given_once)],
    )
    tag_catalogue: list[dict[str, Any]] = []  # the tag table does not change while running
    plant_model: dict[str, Any] = {}  # nor does the plant

    async def ask(future: Future, action: str) -> Any:
        """The desk's answer, or ApiError."""
        try:
            try:
                return await _outcome(future, answer_timeout, gate)
            except TimeoutError:
                if future.cancel():
                    raise ApiError(
                        503,
                        f"controller not scanning: no answer within {answer_timeout:g} s; "
                        "nothing was changed",
                    ) from None
            try:  # the scan took it just now: its answer comes within this scan
                return await _outcome(future, answer_timeout, gate)
            except TimeoutError:
                raise ApiError(
                    503,
                    "controller not scanning: the request was taken but not decided within "
                    f"{answer_timeout:g} s; read it back to see whether it was applied",
                ) from None
        except Refusal as exc:
            raise ApiError(exc.status, exc.message, exc.field) from None
        except (OrderError, ControllerStopped) as exc:
            raise _error(exc, action) from None

    def order_desk() -> OrderDesk:
        if orders is None:
            raise ApiError(
                409,
                "no vehicle of this run takes transport orders (every one runs recipes; "
                "docs/orders.md)",
            )
        return orders

    # ----- plant and vehicles ---------------------------------------------------------------
    @app.get(f"{PREFIX}/plant", response_model=PlantOut, responses=_ERRORS)
    async def show_plant() -> JSONResponse:
        """The plant model: nodes with their position in metres and role, segments,
        stations, chargers, parking and queue positions, and the segments closed now."""
        closed = await ask(fleet.ask_plant(), "plant")
        if not plant_model:  # built once, here: the plant does not change while running
            plant_model.update(views.plant(fleet.plant, []))
        return JSONResponse({**plant_model, "blockades": closed})

    @app.get(f"{PREFIX}/vehicles", response_model=list[VehicleOut], responses=_ERRORS)
    async def list_vehicles() -> JSONResponse:
        """Every vehicle as the controller knows it: its reports, its released and
        planned route, its job, its flags."""
        return JSONResponse(views.render_vehicles(await ask(fleet.ask_vehicles(), "vehicles")))

    @app.get(f"{PREFIX}/vehicles/{{vehicle}}", response_model=VehicleOut, responses=_ERRORS)
    async def show_vehicle(
        vehicle: Annotated[int, Path(ge=0, le=0xFFFF, description="the vehicle's id"), Digits],
    ) -> JSONResponse:
        """One vehicle (404: no such vehicle)."""
        copied = await ask(fleet.ask_vehicle(vehicle), "vehicle")
        return JSONResponse(views.render_vehicles(copied)[0])

    # ----- orders ---------------------------------------------------------------------------
    @app.get(f"{PREFIX}/orders", response_model=OrderPage, responses=_ERRORS)
    async def list_orders(
        offset: Annotated[
            int,
            Query(
                ge=0,
                le=MAX_OFFSET,
                description="the position to start at (0: the run's first order; the last "
                "page's next_offset)",
            ),
            Digits,
        ] = 0,
        limit: Annotated[int, Query(ge=1, le=MAX_PAGE, description="orders at most"), Digits] = (
            DEFAULT_PAGE
        ),
    ) -> OrderPage:
        """A page of the order book, in the order the orders were added."""
        if orders is None:
            return OrderPage(total=0, offset=offset, orders=[], next_offset=offset, added=0)
        return OrderPage.of(await ask(orders.ask_page(offset, limit), "list"))

    @app.get(f"{PREFIX}/orders/{{order_id:path}}", response_model=OrderOut, responses=_ERRORS)
    async def show_order(order_id: OrderId) -> OrderOut:
        """One transport order with its history and sections (404: no such order)."""
        if orders is None:
            raise ApiError(404, f"order {order_id!r}: no such order", "id")
        return OrderOut.of(await ask(orders.ask_order(order_id), "show"))

    @app.post(
        f"{PREFIX}/orders",
        status_code=201,
        response_model=OrderOut,
        responses=_BODY_ERRORS,
        dependencies=[Security(_BEARER)],
    )
    async def add_order(new: OrderIn) -> JSONResponse:
        """Add a transport order (checked like an order file; 201 and its Location).
        Needs the token."""
        desk = order_desk()
        order = new.order()
        try:
            check_order(order)  # what needs no plant: get = put, the time window, the id
        except OrderError as exc:
            raise _error(exc, "check") from None
        added = OrderOut.of(await ask(desk.ask_add(order), "add"))
        return JSONResponse(
            added.model_dump(mode="json"),
            status_code=201,
            headers={"Location": f"{PREFIX}/orders/{quote(added.id, safe='')}"},
        )

    @app.delete(
        f"{PREFIX}/orders/{{order_id:path}}",
        response_model=OrderOut,
        responses=_WRITE_ERRORS,
        dependencies=[Security(_BEARER)],
    )
    async def withdraw_order(order_id: OrderId) -> OrderOut:
        """Withdraw an open order (409 if it is final). Needs the token."""
        return OrderOut.of(await ask(order_desk().ask_withdraw(order_id), "withdraw"))

    # ----- blockades ------------------------------------------------------------------------
    @app.get(f"{PREFIX}/blockades", response_model=list[list[int]], responses=_ERRORS)
    async def list_blockades() -> JSONResponse:
        """The closed segments, each as [a, b] with a < b."""
        return JSONResponse(await ask(fleet.ask_blockades(), "blockades"))

    @app.put(
        f"{PREFIX}/blockades/{{a}}/{{b}}",
        response_model=BlockadeOut,
        responses=_WRITE_ERRORS,
        dependencies=[Security(_BEARER)],
    )
    async def close_segment(a: NodeId, b: NodeId) -> JSONResponse:
        """Close the segment a-b both ways, as the blockade command of the Modbus map
        does: vehicles replan around it. Needs the token."""
        return JSONResponse(await ask(fleet.ask_blockade(a, b, True), "blockade"))

    @app.delete(
        f"{PREFIX}/blockades/{{a}}/{{b}}",
        response_model=BlockadeOut,
        responses=_WRITE_ERRORS,
        dependencies=[Security(_BEARER)],
    )
    async def reopen_segment(a: NodeId, b: NodeId) -> JSONResponse:
        """Reopen the segment a-b, whoever closed it (a scheduled blockade too). Needs the
        token."""
        return JSONResponse(await ask(fleet.ask_blockade(a, b, False), "blockade"))

    # ----- tags: watch, write, force -------------------------------------------------------
    @app.get(f"{PREFIX}/tags", response_model=list[TagInfo], responses=_ERRORS)
    async def list_tags() -> JSONResponse:
        """Every tag: name, address, type, whether clients may write and force it."""
        if not tag_catalogue:
            tag_catalogue.extend(fleet.tag_catalogue())
        return JSONResponse(tag_catalogue)

    @app.get(f"{PREFIX}/tags/values", response_model=list[TagOut], responses=_ERRORS)
    async def watch_tags(
        names: Annotated[
            str, Query(min_length=1, description="tag names, comma-separated (at most 200)")
        ],
    ) -> JSONResponse:
        """The watch table: the values of the named tags as the last scan left them, and
        their forces."""
        wanted = [n.strip() for n in names.split(",")]
        if len(wanted) > MAX_WATCH:
            raise ApiError(422, f"{len(wanted)} tags: at most {MAX_WATCH} at once", "names")
        return JSONResponse(await ask(fleet.ask_tags(wanted), "tags"))

    @app.get(f"{PREFIX}/tags/{{name}}", response_model=TagOut, responses=_ERRORS)
    async def read_tag(name: TagName) -> JSONResponse:
        """One tag's value (404: no such tag)."""
        return JSONResponse(await ask(fleet.ask_tag(name), "tag"))

    @app.put(
        f"{PREFIX}/tags/{{name}}",
        response_model=TagOut,
        responses=_BODY_ERRORS,
        dependencies=[Security(_BEARER)],
    )
    async def write_tag(name: TagName, new: TagValueIn) -> JSONResponse:
        """Write a writable tag at the next quiet point (403: the tag is read-only).
        Needs the token."""
        return JSONResponse(await ask(fleet.ask_write(name, new.value), "write"))

    @app.put(
        f"{PREFIX}/tags/{{name}}/force",
        response_model=TagOut,
        responses=_BODY_ERRORS,
        dependencies=[Security(_BEARER)],
    )
    async def force_tag(name: TagName, new: TagValueIn) -> JSONResponse:
        """Force a writable tag until unforced: the program sees the forced value every
        scan (CODESYS semantics). Needs the token."""
        return JSONResponse(await ask(fleet.ask_force(name, new.value), "force"))

    @app.delete(
        f"{PREFIX}/tags/{{name}}/force",
        response_model=TagOut,
        responses=_WRITE_ERRORS,
        dependencies=[Security(_BEARER)],
    )
    async def unforce_tag(name: TagName) -> JSONResponse:
        """Remove a tag's force. The tag keeps the forced value until the program or a
        write changes it: a command word nobody else writes (a vehicle's hold) stays as
        forced, so write the value wanted after unforcing. Needs the token."""
        return JSONResponse(await ask(fleet.ask_unforce(name), "unforce"))

    # ----- statistics, events, the stream --------------------------------------------------
    @app.get(f"{PREFIX}/stats", response_model=StatsOut, responses=_ERRORS)
    async def show_stats() -> JSONResponse:
        """Cycle statistics of the runtime (execution time and lateness in microseconds:
        last, min, max, mean, p50, p99 over the recent scans), per task and whole scans,
        the drivers' counters and the fleet's."""
        return JSONResponse(views.render_stats(await ask(fleet.ask_stats(), "stats")))

    @app.get(f"{PREFIX}/events", response_model=EventPage, responses=_ERRORS)
    async def list_events(
        after: Annotated[
            int, Query(ge=0, le=MAX_OFFSET, description="the last event seen"), Digits
        ] = 0,
        limit: Annotated[int, Query(ge=1, le=MAX_EVENTS, description="events at most"), Digits] = (
            100
        ),
    ) -> JSONResponse:
        """The event log, oldest first: events numbered after `after`, at most `limit`."""
        return JSONResponse(
            views.render_events(await ask(fleet.ask_events(after, limit), "events"))
        )

    @app.get(
        f"{PREFIX}/stream",
        response_class=StreamingResponse,
        responses={
            200: {
                "content": {"text/event-stream": {}},
                "description": "server-sent events 'snapshot', at most 10 per second: "
                "vehicles, blockades, scan statistics, order counts and the orders changed",
            },
            503: {"model": ErrorOut},
        },
    )
    async def stream() -> StreamingResponse:
        """Server-sent events: a `snapshot` at most 10 times a second while the client
        stays (vehicles, closed segments, the scan's counters, order counts and the
        orders that changed)."""
        try:
            return _EventStream(feed.open_stream())
        except Busy as exc:
            raise ApiError(503, f"stream: {exc}; retry later") from None

    # ----- the operator's page ---------------------------------------------------------------
    @app.get("/", include_in_schema=False)
    async def page() -> FileResponse:
        return FileResponse(PAGE_DIR / "index.html", headers=_PAGE_HEADERS)

    app.mount("/static", _Static(directory=PAGE_DIR), name="static")

    @app.exception_handler(ApiError)
    async def api_error(request: Request, exc: ApiError) -> JSONResponse:
        return _json(exc.status, exc.message, exc.field)

    @app.exception_handler(RequestValidationError)
    async def invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        return _invalid(exc, request)

    @app.exception_handler(Exception)
    async def failure(request: Request, exc: Exception) -> JSONResponse:
        """A bug: the request gets one line (uvicorn logs the traceback)."""
        return _json(500, f"internal error: {type(exc).__name__}: {exc}")

    @app.exception_handler(HTTPException)
    async def http_error(request: Request, exc: HTTPException) -> JSONResponse:
        unreadable = _unparsable(exc.__cause__)
        if unreadable is not None:
            return _json(400, f"request body is not JSON this server reads: {unreadable}")
        return _json(exc.status_code, f"{request.method} {request.url.path}: {exc.detail}")

    return app


def _unparsable(cause: BaseException | None) -> str | None:
    """Why valid JSON could not be read, where the parser met one of Python's limits
    (FastAPI answers those with a bare "error parsing the body"); None for other causes."""
    if isinstance(cause, RecursionError):
        return "nested too deeply"
    if isinstance(cause, ValueError) and "integer string conversion" in str(cause):
        return f"an integer of more than {sys.get_int_max_str_digits()} digits"
    return None


def openapi_schema() -> dict[str, Any]:
    """The API's OpenAPI schema, as ``/openapi.json`` serves it, without a running program:
    the routes need their desks only when a request comes."""
    unused: Any = None
    return build_app(unused, unused, unused, unused).openapi()


class _EventStream(StreamingResponse):
    """The live feed's response: it closes its stream however it ends, also when it never
    started (the client went away first), so the stream's place is always given back."""

    def __init__(self, stream: Stream) -> None:
        super().__init__(
            stream.events,
            media_type="text/event-stream",
            headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"},
        )
        self._stream = stream

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        try:
            await super().__call__(scope, receive, send)
        finally:
            await self._stream.close()


class _Repeated(Exception):
    """A key given twice in one JSON object."""


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """json's ``object_pairs_hook``: the object, or _Repeated naming the first key given twice."""
    obj: dict[str, Any] = {}
    for key, value in pairs:
        if key in obj:
            raise _Repeated(key)
        obj[key] = value
    return obj


async def _given_once(request: Request) -> None:
    """Every route's dependency: a query parameter a route that takes some does not take (a
    typo such as ``offest`` would be ignored, and the client served what it did not ask for), or a
    query parameter or a key of the JSON body given twice, is refused (422 naming it).
    The parsers would keep the last value silently, and the client may have meant the
    first. A body is JSON only as RFC 8259 has it: sent as ``application/json`` (415
    otherwise, a ``+json`` type included), in UTF-8 without a byte order mark (400). Runs
    after FastAPI has read the body (it is cached) and before the route's own checks, so
    nothing is changed."""
    seen: set[str] = set()
    route = request.scope.get("route")
    dependant = getattr(route, "dependant", None)
    taken = _query_names(dependant) if dependant is not None else None
    for name, _ in request.query_params.multi_items():
        # a read that takes none may carry one for a cache (a link to the page, the
        # plant); a write never: it must not be carried out with a parameter unheard
        if (taken or request.method not in ("GET", "HEAD")) and name not in taken:
            known = ", ".join(sorted(taken)) or "none"
            raise ApiError(422, f"field '{name}': not a parameter of this request ({known})", name)
        if not taken or name not in taken:
            continue  # a read's parameter for a cache: ignored, however often it is given
        if name in seen:
            raise ApiError(422, f"field '{name}': given more than once in the query", name)
        seen.add(name)
    if not _body_fields(request):
        return
    media, _, params = request.headers.get("content-type", "").partition(";")
    charset = params.strip().lower().replace(" ", "").replace('"', "")
    if media.strip().lower() != "application/json" or charset not in ("", "charset=utf-8"):
        sent = request.headers.get("content-type") or "no Content-Type"
        raise ApiError(
            415,
            "request body: send it as JSON with the header Content-Type: application/json "
            f"(got {sent})",
        )
    body = await request.body()
    try:
        if body.startswith(b"\xef\xbb\xbf"):
            raise UnicodeDecodeError("utf-8", body, 0, 3, "a byte order mark")
        body.decode("utf-8")
    except UnicodeDecodeError:
        raise ApiError(400, "request body: JSON must be UTF-8, without a byte order mark") from None
    try:
        json.loads(body, object_pairs_hook=_unique_keys)
    except _Repeated as exc:
        key = str(exc)
        raise ApiError(422, f"field '{key}': given more than once in the JSON", key) from None
    except ValueError:  # not JSON: the route's body check says so
        pass


def _query_names(dependant: Any) -> set[str]:
    """The query parameters a route takes, its dependencies' included (FastAPI's Dependant
    tree: ``query_params`` and ``dependencies`` at each level)."""
    names = {q.alias for q in dependant.query_params}
    for sub in dependant.dependencies:
        names |= _query_names(sub)
    return names


class _Static(StaticFiles):
    """The page's files, with the page's security headers."""

    async def get_response(self, path: str, scope: Any) -> Any:
        response = await super().get_response(path, scope)
        response.headers.update(_PAGE_HEADERS)
        return response


async def _outcome(future: Future, timeout: float, gate: ScanGate) -> Any:
    """Wait for a Future the scan thread ends, without blocking the loop; TimeoutError after
    ``timeout`` s. Giving up never touches ``future`` (only the caller may cancel it).

    The scan does not wake the loop for each answer: it wakes it once, at the end of the
    scan, through the gate (each wake-up would hand the interpreter to this thread in the
    middle of the scan's work), and every waiting handler looks at its Future then."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not future.done():
        left = deadline - loop.time()
        if left <= 0:
            raise TimeoutError
        if not await gate.wait(left):
            await asyncio.sleep(min(left, 0.01))  # the run is ending: its desks end the Future
    return future.result()


def _error(exc: OrderError | ControllerStopped, action: str) -> ApiError:
    """The HTTP answer to the book's refusal of ``action`` (or the run's end)."""
    if isinstance(exc, ControllerStopped):
        return ApiError(503, f"controller stopped: {exc}")
    field = exc.field
    if action == "show" or (action == "withdraw" and field == "id"):
        status = 404  # the book's only id error for these: no such order
    elif action == "withdraw" or (action == "add" and field in ("id", "book")):
        # a final order, an id in use, a full book: the request is well-formed, the book's
        # state says no
        status = 409
    else:
        status = 422  # "check" (the order on its own) or a station or vehicle the plant lacks
    return ApiError(status, str(exc), field)


def _invalid(exc: RequestValidationError, request: Request) -> JSONResponse:
    """Pydantic's first complaint, as one line naming the field (and the fields the
    route's body takes, where the body is not an object of them)."""
    first = exc.errors()[0]
    kind, loc, msg = first.get("type", ""), tuple(first.get("loc", ())), first.get("msg", "")
    if kind == "json_invalid":
        return _json(
            400, f"request body is not valid JSON: {first.get('ctx', {}).get('error', msg)}"
        )
    where, names = (loc[0] if loc else "body"), [str(p) for p in loc[1:]]
    fields = ", ".join(_body_fields(request))
    if not names:
        if where == "body":
            sent = request.headers.get("content-type", "")
            if sent.split(";")[0].strip().lower() != "application/json":
                return _json(
                    415,
                    "request body: send it as JSON with the header Content-Type: "
                    f"application/json (got {sent or 'no Content-Type'})",
                )
            return _json(422, f"request body: expected a JSON object with the fields {fields}")
        return _json(422, f"request {where}: {msg}")
    field = ".".join(names)
    if kind == "extra_forbidden":
        return _json(422, f"field '{field}': unknown (fields: {fields})", field)
    text = f"field '{field}': {msg}"
    if kind != "missing" and "input" in first and ", got " not in msg:
        text += f", got {_short(first['input'])}"
    return _json(422, text, field)


def _body_fields(request: Request) -> list[str]:
    """The fields of the body model of the route ``request`` matched (none: no body)."""
    body = getattr(request.scope.get("route"), "body_field", None)
    model = getattr(getattr(body, "field_info", None), "annotation", None)
    return list(getattr(model, "model_fields", {}))


def _short(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _json(status: int, message: str, field: str | None = None) -> JSONResponse:
    return JSONResponse(
        ErrorOut(error=message, field=field).model_dump(),
        status_code=status,
        headers={"WWW-Authenticate": "Bearer"} if status == 401 else None,
    )
