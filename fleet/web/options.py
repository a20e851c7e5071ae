"""``plc-runtime run CONFIG --web HOST:PORT [--web-token TOKEN]``: the options and their checks.

The address comes from ``--web``, else from the configuration's ``[web] address``; without
either nothing is served.
The token for writes comes from ``--web-token``, else from the environment variable
``PLC_RUNTIME_TOKEN`` (not shown by ``ps`` to other users, unlike a command line), else it
is generated and printed once on stderr. Everything is checked before the program is built:
a bad address or token is one line and nothing runs.
"""

from __future__ import annotations

import argparse
import os
import re
import secrets
import sys
from dataclasses import dataclass
from typing import TYPE_CHECKING

from plc_runtime.cli import CliError

from ..config import FleetConfig, host_port

if TYPE_CHECKING:
    from ..program import FleetProgram
    from .server import WebServer

TOKEN_ENV = "PLC_RUNTIME_TOKEN"
MIN_TOKEN_CHARS = 16
# RFC 6750's b64token: what a bearer token may hold, so it goes into a header unchanged
_TOKEN = re.compile(r"[A-Za-z0-9\-._~+/]+=*")


@dataclass(frozen=True)
class WebOptions:
    host: str
    port: int
    token: str
    generated: bool  # nobody knows the token yet: it is printed once


def add_options(run: argparse.ArgumentParser) -> None:
    run.add_argument(
        "--web",
        metavar="HOST:PORT",
        help="fleet: serve the HTTP API and the operator's page (e.g. 127.0.0.1:8080; "
        "overrides [web] address; docs/operator-guide.md); writes need a token",
    )
    run.add_argument(
        "--web-token",
        metavar="TOKEN",
        help=f"with --web: the bearer token for writes (default: ${TOKEN_ENV}, else a new "
        "one printed on stderr)",
    )


def web_options(args: argparse.Namespace, cfg: FleetConfig) -> WebOptions | None:
    """The checked web options (``--web``, else ``[web] address``), None without either."""
    if args.web is None and cfg.web_address is None:
        if args.web_token is not None:
            raise CliError(
                "--web-token is the token of the HTTP API that --web HOST:PORT (or [web] "
                "address) starts"
            )
        return None
    if args.web is not None:
        try:
            host, port = host_port(args.web)
        except ValueError as exc:
            raise CliError(f"--web: {exc}") from None
    else:
        host, port = cfg.web_address
    token, where = args.web_token, "--web-token"
    if token is None:
        token, where = os.environ.get(TOKEN_ENV), TOKEN_ENV
    if token is None:
        return WebOptions(host, port, new_token(), True)
    if not token:
        raise CliError(f"{where} is empty: give a token, or unset it for a new one")
    counted = len(token.rstrip("="))  # padding adds nothing to guess
    if counted < MIN_TOKEN_CHARS or not bearer_token(token):
        raise CliError(
            f"{where}: a bearer token needs {MIN_TOKEN_CHARS} characters or more of "
            "A-Z a-z 0-9 - . _ ~ + /, and = only at its end (got "
            f"{counted} characters{'' if bearer_token(token) else ', some not allowed'})"
        )
    return WebOptions(host, port, token, False)


def bearer_token(text: str) -> bool:
    """Whether ``text`` can be a bearer token: RFC 6750's characters, nothing else."""
    return _TOKEN.fullmatch(text) is not None


def web_server(options: WebOptions, program: FleetProgram) -> WebServer:
    """The server, announcing where it listens (and a generated token) on stderr."""
    from .server import WebServer  # FastAPI and uvicorn: only for a run that serves HTTP

    def announce(url: str) -> None:
        line = f"plc-runtime: operator page on {url}/, HTTP API on {url}/api/v1"
        if options.generated:
            line += f"; token for writes: {options.token}"
        print(line, file=sys.stderr, flush=True)

    return WebServer(program, options.host, options.port, token=options.token, announce=announce)


def new_token() -> str:
    """A random bearer token for the run. It is printed once and given back on command lines
    (``plc-runtime order add --token TOKEN``), where one starting with ``-`` would be read as
    an option, so such draws are discarded (1 in 64 of them)."""
    while True:
        token = secrets.token_urlsafe(24)
        if not token.startswith("-"):
            return token
