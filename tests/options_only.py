"""Run a script as far as its command line only: ``python tests/options_only.py SCRIPT
ARGS...`` parses ARGS with the script's own parser, as running ``python SCRIPT ARGS...``
would, and exits 0 once they are parsed; an unknown option or a value the parser refuses
exits 2 with the script's own message.

The documented benchmark commands take minutes to hours, so the documentation's tests
check them this way: every option a page gives must still exist and take the value shown.
"""

from __future__ import annotations

import argparse
import runpy
import sys
from pathlib import Path

_parse_args = argparse.ArgumentParser.parse_args


def _parse_then_stop(self, args=None, namespace=None):  # type: ignore[no-untyped-def]
    _parse_args(self, args, namespace)  # exits 2 on a bad command line
    raise SystemExit(0)


def main() -> None:
    if len(sys.argv) < 2:
        raise SystemExit("usage: python tests/options_only.py SCRIPT [ARGS...]")
    script = Path(sys.argv[1])
    sys.argv = sys.argv[1:]
    sys.path[0] = str(script.resolve().parent)  # as when the script is run itself
    argparse.ArgumentParser.parse_args = _parse_then_stop  # type: ignore[method-assign]
    runpy.run_path(str(script), run_name="__main__")
    raise SystemExit(f"{script}: ended without parsing a command line")


if __name__ == "__main__":
    main()
