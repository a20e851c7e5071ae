"""What every request passes before the API sees it (an ASGI middleware).

In this order, each refusal one JSON error (``{"error": ..., "field": null}``) and nothing
changed:

1. **Rate**: at most ``max_rate`` requests per second from one client (a token bucket
   holding one second's worth; a client is an address, every loopback address together,
   an IPv6 /64), else 429 with ``Retry-After``. First, so every
   refusal below costs a client its rate too, and guessing tokens is as slow as
   everything else.
2. **Host** (only when the server listens on loopback): the ``Host`` header must name a
   loopback address or ``localhost``, else 400. A web page that rebinds its own DNS name to
   127.0.0.1 could otherwise read the API from a browser on this machine.
3. **Token** for the methods that change something (POST, PUT, DELETE): ``Authorization: Bearer
   TOKEN``; none (or another scheme) is 401, a wrong one 403. Compared in constant time.
   Checked before the body is read, so no unauthenticated body is even parsed.
4. **Body size**: at most ``max_body`` bytes (a declared ``Content-Length`` over it is
   refused before reading; a chunked body is counted while it arrives), else 413.
5. **Body time**: the whole body within ``body_timeout`` seconds of the headers, else 408
   and the connection is closed: a client that declares a body and sends it slowly (or
   never) holds nothing but its own connection, and that only for so long.
6. **Requests in flight**: at most ``max_in_flight`` at once (each may wait up to the
   answer timeout for the scan), else 503. A request counts only once its body is in,
   so clients that are still sending cannot take the places of those that have sent. A
   stream (``unmetered`` paths) lasts as long as its client stays, so it is not counted
   here; the live feed limits streams itself.

A request that passed waits for the end of the next scan before the application sees it
(``gate``, :mod:`fleet.web.gate` says why).

Refusals are logged, one warning line each (who, what, why), like the Modbus server's,
and like them once a second per client at most (``plc_runtime.throttle``), the next line
saying how many were left out: every refusal, a wrong or missing token as much as the
rate, is one a client can repeat as fast as it can send, so a flood of them cannot flood
the log too.
"""

from __future__ import annotations

import asyncio
import ipaddress
import json
import logging
import secrets
import time
from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any

from plc_runtime.cli import one_line
from plc_runtime.throttle import LineThrottle, client_of, left_out

from .gate import ScanGate

log = logging.getLogger(__name__)
# headers a request may carry once only: with two, one check would read one and another the other
SINGLE_HEADERS = ("authorization", "host", "content-type", "content-length")

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

WRITE_METHODS = frozenset({"POST", "DELETE", "PUT", "PATCH"})
MAX_BODY = 16 * 1024
MAX_IN_FLIGHT = 32
MAX_RATE = 100.0  # requests per second from one client address
BODY_TIMEOUT = 5.0  # seconds for the request body to arrive once the headers have
MAX_CLIENTS = 1024  # addresses whose rate is tracked; the idlest is forgotten beyond


class Guard:
    def __init__(
        self,
        app: ASGIApp,
        *,
        token: str,
        where: str,
        loopback: bool,
        max_body: int = MAX_BODY,
        max_in_flight: int = MAX_IN_FLIGHT,
        max_rate: float = MAX_RATE,
        body_timeout: float = BODY_TIMEOUT,
        unmetered: tuple[str, ...] = (),
        gate: ScanGate | None = None,
    ) -> None:
        self.app = app
        self._token = token.encode()
        self.where = where  # "web 127.0.0.1:8080", for the log
        self.loopback = loopback
        self.max_body = max_body
        self.max_in_flight = max_in_flight
        self.max_rate = max_rate
        self.body_timeout = body_timeout
        self.unmetered = frozenset(unmetered)
        self.gate = gate
        self.in_flight = 0  # only touched in the server's event loop
        self.receiving = 0  # requests whose body is arriving (not in flight yet)
        self.refused = 0  # requests refused, for the statistics
        self.clock: Callable[[], float] = time.monotonic  # seconds, for the rate and the log
        # client address -> (tokens, monotonic time of the last refill)
        self._buckets: dict[str, list[float]] = {}
        self._lines = LineThrottle()  # the warnings, per client address

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        if not self._admit(scope):
            self.refused += 1
            await reply(
                send,
                429,
                f"too many requests: the limit is {self.max_rate:g} per second per client",
                [(b"retry-after", b"1")],
            )
            return
        names = [k.decode("latin-1").lower() for k, _ in scope["headers"]]
        twice = sorted({n for n in SINGLE_HEADERS if names.count(n) > 1})
        if twice:  # which one counts would be the server's guess, not the client's intent
            why = f"header {twice[0]!r} given more than once"
            await self._refuse(scope, send, 400, why)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
        if self.loopback and not _loopback_host(headers.get("host")):
            why = f"Host header {headers.get('host')!r} not accepted"
            await self._refuse(scope, send, 400, why)
            return
        if scope["method"] in WRITE_METHODS:
            scheme, _, given = headers.get("authorization", "").partition(" ")
            if scheme.lower() != "bearer" or not given.strip():
                await self._refuse(
                    scope, send, 401, "this request needs the token: Authorization: Bearer TOKEN"
                )
                return
            if not secrets.compare_digest(given.strip().encode(), self._token):
                await self._refuse(scope, send, 403, "wrong token")
                return
        declared = headers.get("content-length", "")
        if declared.isascii() and declared.isdigit() and int(declared) > self.max_body:
            await self._refuse(
                scope,
                send,
                413,
                f"request body of {int(declared):,} bytes: the limit is {self.max_body:,} bytes",
            )
            return
        self.receiving += 1
        try:
            async with asyncio.timeout(self.body_timeout):
                body = await self._body(receive)
        except TimeoutError:
            why = f"request body not received within {self.body_timeout:g} s"
            await self._refuse(scope, send, 408, why, close=True)
            return
        finally:
            self.receiving -= 1
        if body is None:
            await self._refuse(
                scope, send, 413, f"request body over the limit of {self.max_body:,} bytes"
            )
            return
        metered = scope["path"] not in self.unmetered
        if metered and self.in_flight >= self.max_in_flight:
            self.refused += 1
            await reply(
                send, 503, f"too many requests in flight (the limit is {self.max_in_flight}): retry"
            )
            return
        self.in_flight += metered
        try:
            if self.gate is not None:
                await self.gate.wait()
            await self.app(scope, _replay(body, receive), send)
        finally:
            self.in_flight -= metered

    async def _body(self, receive: Receive) -> bytes | None:
        """The whole request body, or None once it passes ``max_body``."""
        chunks, size, more = [], 0, True
        while more:
            message = await receive()
            if message["type"] != "http.request":
                break  # the client went away; the app sees an empty body and its answer is lost
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > self.max_body:
                return None
            chunks.append(chunk)
            more = message.get("more_body", False)
        return b"".join(chunks)

    def _admit(self, scope: Scope) -> bool:
        """Take a token from the client address's bucket; False (and a warning, once a
        second at most) when it is empty."""
        address = client_key(scope)
        now = self.clock()
        bucket = self._buckets.get(address)
        if bucket is None:
            if len(self._buckets) >= MAX_CLIENTS:
                idlest = min(self._buckets, key=lambda a: self._buckets[a][1])
                del self._buckets[idlest]
            bucket = self._buckets[address] = [self.max_rate, now]
        tokens = min(self.max_rate, bucket[0] + (now - bucket[1]) * self.max_rate)
        bucket[1] = now
        if tokens >= 1.0:
            bucket[0] = tokens - 1.0
            return True
        bucket[0] = tokens
        self._warn(
            scope,
            "%s: refused %s %s from %s: 429, over %g requests per second",
            self.where,
            scope["method"],
            one_line(scope["path"]),  # decoded: %1b would be an ESC, %0a a forged line
            address,
            self.max_rate,
        )
        return False

    def _warn(self, scope: Scope, form: str, *args: object) -> None:
        """A warning about a refused request, once a second per client at most; the next
        one written says how many were left out."""
        count = self._lines.admit(client_key(scope), self.clock())
        if count is not None:
            log.warning(form + "%s", *args, left_out(count, "from this client"))

    async def _refuse(
        self,
        scope: Scope,
        send: Send,
        status: int,
        why: str,
        *,
        close: bool = False,
    ) -> None:
        """Answer ``status`` and log it (``_warn``); ``close``: the connection is closed
        after the answer (its request is unfinished)."""
        self.refused += 1
        client = scope.get("client")
        self._warn(
            scope,
            "%s: refused %s %s from %s: %d, %s",
            self.where,
            scope["method"],
            one_line(scope["path"]),  # decoded: %1b would be an ESC, %0a a forged line
            f"{client[0]}:{client[1]}" if client else "?",
            status,
            why,
        )
        await reply(send, status, why, [(b"connection", b"close")] if close else None)


async def reply(
    send: Send, status: int, error: str, extra: list[tuple[bytes, bytes]] | None = None
) -> None:
    """A refusal as the API's other errors are: one JSON line, about no field."""
    body = json.dumps({"error": error, "field": None}, separators=(",", ":")).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
    headers += extra or []
    if status == 401:
        headers.append((b"www-authenticate", b"Bearer"))
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": body})


def _replay(body: bytes, receive: Receive) -> Receive:
    """The app's ``receive``: the body read already, then the client's own messages."""
    sent = False

    async def replay() -> Message:
        nonlocal sent
        if sent:
            return await receive()
        sent = True
        return {"type": "http.request", "body": body, "more_body": False}

    return replay


def client_key(scope: Scope) -> str:
    """Who a request's rate and warnings count against (``plc_runtime.throttle.client_of``:
    every loopback address together, an IPv6 /64 as one)."""
    client = scope.get("client")
    return client_of(client[0]) if client else "?"


def _loopback_host(host: str | None) -> bool:
    """Whether a Host header names this machine: localhost or a loopback address (with or
    without a port). No Host header at all (HTTP/1.0) is accepted: browsers always send one."""
    if host is None:
        return True
    name = host.strip().lower()
    if name.startswith("["):
        name = name[1 : name.find("]")]
    elif name.count(":") == 1:
        name = name.partition(":")[0]
    if name == "localhost":
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False
