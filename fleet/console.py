"""The ``plc-runtime`` console script.

A Ctrl-C can come at any moment, also while the command's modules are still being imported
(a second or more on a busy machine, before any command has set up its own handling): the
command then ends with one line and exit code 130 (128 + SIGINT, as shells report it),
never a traceback. SIGTERM (a service manager, ``docker stop``) in those moments ends the
command the same way, with exit code 143: its ``finally`` clauses run, so a run's output
lock and open buses go, where the default action would kill the process on the spot.
Commands that run (``run``, ``vehicles``) put their own handling in place while they do.
Nothing heavy is imported before the handlers are in place."""

from __future__ import annotations

import signal
import sys

EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 128 + signal.SIGTERM


class Terminated(KeyboardInterrupt):
    """SIGTERM outside a run's own handling. A kind of KeyboardInterrupt so that code that
    must pass an operator's interrupt on (the runtime after faulting a cut scan) passes
    this on too."""


def _terminate(_number: int, _frame: object) -> None:
    raise Terminated


def main(argv: list[str] | None = None) -> int:
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        from .cli import main as command

        return command(argv)
    except Terminated:
        print("plc-runtime: stopped by SIGTERM", file=sys.stderr)
        return EXIT_TERMINATED
    except KeyboardInterrupt:
        print("plc-runtime: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        signal.signal(signal.SIGTERM, previous)
