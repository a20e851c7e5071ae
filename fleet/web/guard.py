"""What every request passes before the API sees it (an ASGI middleware).

In this order, each refusal one JSON error (``{"error": ..., "field": null}``) and nothing
changed:

1. **Host** (only when the server listens on loopback): the ``Host`` header must name a
   loopback address or ``localhost``, else 400. A web page that rebinds its own DNS name to
   127.0.0.1 could otherwise read the API from a browser on this machine.
2. **Token** for the methods that change something (POST, DELETE): ``Authorization: Bearer
   TOKEN``; none (or another scheme) is 401, a wrong one 403. Compared in constant time.
   Checked before the body is read, so no unauthenticated body is even parsed.
3. **Body size**: at most ``max_body`` bytes (a declared ``Content-Length`` over it is
   refused before reading; a chunked body is counted while it arrives), else 413.
4. **Requests in flight**: at most ``max_in_flight`` at once (each may wait up to the
   answer timeout for the scan), else 503.

Refusals of 1 to 3 are logged, one warning line each (who, what, why), like the Modbus
server's.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import secrets
from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any

log = logging.getLogger(__name__)

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

WRITE_METHODS = frozenset({"POST", "DELETE", "PUT", "PATCH"})
MAX_BODY = 16 * 1024
MAX_IN_FLIGHT = 32


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
    ) -> None:
        self.app = app
        self._token = token.encode()
        self.where = where  # "web 127.0.0.1:8080", for the log
        self.loopback = loopback
        self.max_body = max_body
        self.max_in_flight = max_in_flight
        self.in_flight = 0  # only touched in the server's event loop

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
        if self.loopback and not _loopback_host(headers.get("host")):
            await self._refuse(
                scope, send, 400, f"Host header {headers.get('host')!r} not accepted"
            )
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
        if declared.isdigit() and int(declared) > self.max_body:
            await self._refuse(
                scope,
                send,
                413,
                f"request body of {int(declared):,} bytes: the limit is {self.max_body:,} bytes",
            )
            return
        if self.in_flight >= self.max_in_flight:
            await _reply(
                send, 503, f"too many requests in flight (the limit is {self.max_in_flight}): retry"
            )
            return
        self.in_flight += 1
        try:
            body = await self._body(receive)
            if body is None:
                await self._refuse(
                    scope, send, 413, f"request body over the limit of {self.max_body:,} bytes"
                )
                return
            await self.app(scope, _replay(body, receive), send)
        finally:
            self.in_flight -= 1

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

    async def _refuse(self, scope: Scope, send: Send, status: int, why: str) -> None:
        client = scope.get("client")
        peer = f"{client[0]}:{client[1]}" if client else "?"
        log.warning(
            "%s: refused %s %s from %s: %d, %s",
            self.where,
            scope["method"],
            scope["path"],
            peer,
            status,
            why,
        )
        await _reply(send, status, why)


async def _reply(send: Send, status: int, error: str) -> None:
    body = json.dumps({"error": error, "field": None}, separators=(",", ":")).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
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
