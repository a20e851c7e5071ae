"""Typed access to one table of a TOML configuration, with errors that name the file and
the key (``fleet.toml: vehicles[2].start: ...``)."""

from __future__ import annotations

import difflib
import math
from typing import Any

from plc_runtime.errors import ConfigError


class TableReader:
    """Typed access to one TOML table, with errors that say where."""

    def __init__(self, source: str, table: dict[str, Any], where: str) -> None:
        self.source, self.table, self.where = source, table, where
        self.used: set[str] = set()

    def fail(self, key: str, message: str) -> ConfigError:
        return ConfigError(f"{self.source}: {self.where}{key}: {message}")

    def get(self, key: str, kind: type | tuple[type, ...], default: Any = ...) -> Any:
        self.used.add(key)
        if key not in self.table:
            if default is ...:
                near = difflib.get_close_matches(key, [str(k) for k in self.table], n=1)
                hint = f" (is {near[0]!r}, given, a misspelling of it?)" if near else ""
                raise self.fail(key, f"missing{hint}")
            return default
        value = self.table[key]
        kinds = kind if isinstance(kind, tuple) else (kind,)
        if isinstance(value, bool) and bool not in kinds:
            raise self.fail(key, f"expected {_names(kinds)}, got {value!r}")
        if float in kinds and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if not isinstance(value, kinds):
            raise self.fail(key, f"expected {_names(kinds)}, got {value!r}")
        if isinstance(value, float) and not math.isfinite(value):
            raise self.fail(key, f"must be finite, got {value!r}")
        return value

    def number(self, key: str, default: float, low: float, high: float = math.inf) -> float:
        value = self.get(key, float, default)
        if not low <= value <= high:
            raise self.fail(key, f"must be in {low}..{high}, got {value}")
        return value

    def positive(self, key: str, default: float, high: float) -> float:
        """The key's number in (0, high]: for a limit where any positive value is meaningful
        and 0 would mean none, as the command line's options of the same limit accept."""
        value = self.get(key, float, default)
        if not 0 < value <= high:
            raise self.fail(key, f"must be > 0 and <= {high:g}, got {value!r}")
        return value

    def integer(self, key: str, default: Any, low: int, high: int) -> int:
        """The key's integer in low..high; ``default`` ``...`` makes the key required."""
        value = self.get(key, int, default)
        if not low <= value <= high:
            raise self.fail(key, f"must be in {low}..{high}, got {value}")
        return value

    def finish(self) -> None:
        unknown = sorted(set(self.table) - self.used)
        if unknown:
            raise self.fail(unknown[0], "unknown key")


def _names(kinds: tuple[type, ...]) -> str:
    return " or ".join(
        {
            int: "an integer",
            float: "a number",
            str: "a string",
            list: "a list",
            dict: "a table",
            bool: "true/false",
        }[k]
        for k in kinds
    )
