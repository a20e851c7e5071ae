"""Strict numbers for the whitespace-separated formats (.map, .scen, .nodes).

Python's ``int()`` and ``float()`` accept more than a plant file should: digits of any script
(``int("٣")`` is 3), underscores (``1_0``), and ``nan``/``inf``. A file that says ``٣`` did not
mean node 3 on purpose, so only ASCII decimal numbers are read; anything else is an error the
caller reports with the file, line and field.
"""

from __future__ import annotations

import math
import re

MAX_DIGITS = 18  # far beyond any id or size a limit admits, and an int64 still
INTEGER = re.compile(rf"[+-]?[0-9]{{1,{MAX_DIGITS}}}", re.ASCII)
DECIMAL = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?", re.ASCII)


def parse_int(text: str) -> int | None:
    """The integer ``text`` spells in ASCII digits (optional sign), None if it is not one."""
    return int(text) if INTEGER.fullmatch(text) else None


TOO_LONG = f"not an integer of at most {MAX_DIGITS} digits"  # the wording for a longer one
_DIGITS = re.compile(r"[+-]?[0-9]+", re.ASCII)


def not_an_integer(text: str) -> str:
    """Why :func:`parse_int` refused ``text``: too many digits, or not an integer at all."""
    return TOO_LONG if _DIGITS.fullmatch(text) else "not an integer"


def parse_float(text: str) -> float | None:
    """The finite number ``text`` spells in ASCII decimal notation, None if it is not one
    (``nan``, ``inf`` and ``1e999``, which overflows to infinity, are not)."""
    if not DECIMAL.fullmatch(text):
        return None
    value = float(text)
    return value if math.isfinite(value) else None


def shown(text: str) -> str:
    """A token quoted for a message, shortened: a 5000-digit number must not flood the terminal."""
    return repr(text) if len(text) <= 30 else repr(text[:20] + "...")
