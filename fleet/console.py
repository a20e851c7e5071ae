"""The ``plc-runtime`` console script.

A Ctrl-C can come at any moment, also while the command's modules are still being imported
(a second or more on a busy machine, before any command has set up its own handling): the
command then ends with one line and exit code 130 (128 + SIGINT, as shells report it),
never a traceback. Nothing heavy is imported before the handler is in place."""

from __future__ import annotations

import sys

EXIT_INTERRUPTED = 130


def main() -> int:
    try:
        from .cli import main as command

        return command()
    except KeyboardInterrupt:
        print("plc-runtime: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
