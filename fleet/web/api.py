"""The HTTP API, version 1: transport orders (FastAPI).

    GET    /api/v1/orders?offset=0&limit=100   a page of the order book, in the order added
    GET    /api/v1/orders/{id}                 one order (404: no such order)
    POST   /api/v1/orders                      add an order (201; needs the token)
    DELETE /api/v1/orders/{id}                 withdraw an order (needs the token)
    GET    /openapi.json                       the schema of all of it

Every answer comes from the scan through the :class:`~fleet.web.desk.OrderDesk` (why:
its docstring). A handler never blocks the event loop, let alone the scan: it waits for
the desk's Future for at most ``answer_timeout`` seconds, then answers 503 "controller not
scanning". A request the scan had not taken by then is cancelled and never applied; one
it had taken is decided within that scan, so the handler waits once more for it.

Errors are JSON, ``{"error": "one line", "field": "get"}`` (``field`` null when the error
is about no field): 400 unreadable JSON, 422 a field is wrong, 404 no such order (or
path), 409 the id is in use or the order cannot be withdrawn in its state, 503 the
controller is not scanning or the run has ended, 500 a bug (its traceback is logged); 400/401/403/413 from the guard
(:mod:`fleet.web.guard`). On every error the book is as before.
"""

from __future__ import annotations

import asyncio
from concurrent.futures import Future
from typing import Annotated, Any
from urllib.parse import quote

from fastapi import FastAPI, Path, Query, Request, Security
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.security import HTTPBearer
from starlette.exceptions import HTTPException

from blocks.dispatch.orders import OrderError, check_order

from .desk import MAX_OFFSET, MAX_PAGE, ControllerStopped, OrderDesk
from .models import ErrorOut, OrderIn, OrderOut, OrderPage

PREFIX = "/api/v1"
ANSWER_TIMEOUT = 5.0  # seconds a request waits for the scan before 503
DEFAULT_PAGE = 100

# documents the token in the schema; the guard enforces it before a request gets here
_BEARER = HTTPBearer(auto_error=False, description="the token given at start (--web-token)")
_ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorOut} for code in (400, 404, 409, 413, 422, 503)
}
_WRITE_ERRORS = {**_ERRORS, 401: {"model": ErrorOut}, 403: {"model": ErrorOut}}
OrderId = Annotated[str, Path(description="the order's id (URL-encoded)")]


class ApiError(Exception):
    """An error answer: HTTP status, one line, the field it is about."""

    def __init__(self, status: int, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.status, self.message, self.field = status, message, field


def build_app(desk: OrderDesk, answer_timeout: float = ANSWER_TIMEOUT) -> FastAPI:
    app = FastAPI(
        title="plc-runtime fleet API",
        version="1",
        description="Transport orders of a running fleet controller (docs/orders.md).",
        docs_url=None,  # the interactive pages load scripts from a CDN; openapi.json is enough
        redoc_url=None,
        redirect_slashes=False,
    )

    async def ask(future: Future, action: str) -> Any:
        """The desk's answer, or ApiError."""
        try:
            try:
                return await _outcome(future, answer_timeout)
            except TimeoutError:
                if future.cancel():
                    raise ApiError(
                        503,
                        f"controller not scanning: no answer within {answer_timeout:g} s; "
                        "nothing was changed",
                    ) from None
            try:  # the scan took it just now: its answer comes within this scan
                return await _outcome(future, answer_timeout)
            except TimeoutError:
                raise ApiError(
                    503,
                    "controller not scanning: the request was taken but not decided within "
                    f"{answer_timeout:g} s; GET the order to see whether it was applied",
                ) from None
        except (OrderError, ControllerStopped) as exc:
            raise _error(exc, action) from None

    @app.get(f"{PREFIX}/orders", response_model=OrderPage, responses=_ERRORS)
    async def list_orders(
        offset: Annotated[int, Query(ge=0, le=MAX_OFFSET, description="first order, from 0")] = 0,
        limit: Annotated[int, Query(ge=1, le=MAX_PAGE, description="orders at most")] = (
            DEFAULT_PAGE
        ),
    ) -> OrderPage:
        return OrderPage.of(await ask(desk.ask_page(offset, limit), "list"))

    @app.get(f"{PREFIX}/orders/{{order_id:path}}", response_model=OrderOut, responses=_ERRORS)
    async def show_order(order_id: OrderId) -> OrderOut:
        return OrderOut.of(await ask(desk.ask_order(order_id), "show"))

    @app.post(
        f"{PREFIX}/orders",
        status_code=201,
        response_model=OrderOut,
        responses=_WRITE_ERRORS,
        dependencies=[Security(_BEARER)],
    )
    async def add_order(new: OrderIn) -> JSONResponse:
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
        return OrderOut.of(await ask(desk.ask_withdraw(order_id), "withdraw"))

    @app.exception_handler(ApiError)
    async def api_error(request: Request, exc: ApiError) -> JSONResponse:
        return _json(exc.status, exc.message, exc.field)

    @app.exception_handler(RequestValidationError)
    async def invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        return _invalid(exc)

    @app.exception_handler(Exception)
    async def failure(request: Request, exc: Exception) -> JSONResponse:
        """A bug: the request gets one line (uvicorn logs the traceback)."""
        return _json(500, f"internal error: {type(exc).__name__}: {exc}")

    @app.exception_handler(HTTPException)
    async def http_error(request: Request, exc: HTTPException) -> JSONResponse:
        return _json(exc.status_code, f"{request.method} {request.url.path}: {exc.detail}")

    return app


async def _outcome(future: Future, timeout: float) -> Any:
    """Wait for a Future the scan thread ends, without blocking the loop; TimeoutError after
    ``timeout`` s. Giving up never touches ``future`` (only the caller may cancel it)."""
    loop = asyncio.get_running_loop()
    arrived = loop.create_future()

    def wake(_: Future) -> None:
        try:
            loop.call_soon_threadsafe(_set_arrived, arrived)
        except RuntimeError:  # the server's loop has closed: nobody waits any more
            pass

    future.add_done_callback(wake)
    await asyncio.wait_for(arrived, timeout)
    return future.result()


def _set_arrived(arrived: asyncio.Future) -> None:
    if not arrived.done():  # not given up on meanwhile
        arrived.set_result(None)


def _error(exc: OrderError | ControllerStopped, action: str) -> ApiError:
    """The HTTP answer to the book's refusal of ``action`` (or the run's end)."""
    if isinstance(exc, ControllerStopped):
        return ApiError(503, f"controller stopped: {exc}")
    field = exc.field
    if action == "show" or (action == "withdraw" and field == "id"):
        status = 404  # the book's only id error for these: no such order
    elif action == "withdraw" or (action == "add" and field == "id"):
        # a final order, or an id in use: the request is well-formed, the book's state says no
        status = 409
    else:
        status = 422  # "check" (the order on its own) or a station or vehicle the plant lacks
    return ApiError(status, str(exc), field)


def _invalid(exc: RequestValidationError) -> JSONResponse:
    """Pydantic's first complaint, as one line naming the field."""
    first = exc.errors()[0]
    kind, loc, msg = first.get("type", ""), tuple(first.get("loc", ())), first.get("msg", "")
    if kind == "json_invalid":
        return _json(
            400, f"request body is not valid JSON: {first.get('ctx', {}).get('error', msg)}"
        )
    where, names = (loc[0] if loc else "body"), [str(p) for p in loc[1:]]
    if not names:
        if where == "body":
            fields = ", ".join(OrderIn.model_fields)
            return _json(422, f"request body: expected a JSON object with the fields {fields}")
        return _json(422, f"request {where}: {msg}")
    field = ".".join(names)
    if kind == "extra_forbidden":
        return _json(
            422, f"field '{field}': unknown (fields: {', '.join(OrderIn.model_fields)})", field
        )
    text = f"field '{field}': {msg}"
    if kind != "missing" and "input" in first:
        text += f", got {_short(first['input'])}"
    return _json(422, text, field)


def _short(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _json(status: int, message: str, field: str | None = None) -> JSONResponse:
    return JSONResponse(
        ErrorOut(error=message, field=field).model_dump(),
        status_code=status,
        headers={"WWW-Authenticate": "Bearer"} if status == 401 else None,
    )
