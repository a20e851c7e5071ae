"""IEC 61131-3 elementary data types as they are stored in the process image.

Each type knows its storage size (the address size letter it needs), its numpy dtype and
how to check a Python value before it is written, so a bad value is rejected at the call
that tried to write it, with the address in the message, never silently wrapped.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

from .errors import ValueRangeError


@dataclass(frozen=True, slots=True)
class DataType:
    name: str
    size: str  # address size letter: X B W D L
    dtype: str  # numpy dtype of the element (little-endian); "bit" for BOOL
    kind: str  # "bool" | "int" | "float"
    low: float = 0
    high: float = 0

    def check(self, value: object, where: str) -> bool | int | float:
        """Return ``value`` as the Python value to store, or raise naming ``where``."""
        if self.kind == "bool":
            if isinstance(value, bool | int) and value in (0, 1):
                return bool(value)
            raise ValueRangeError(
                f"{where}: {self.name} expects True/False (or 0/1), got {value!r}"
            )
        if self.kind == "int":
            if isinstance(value, bool) or not isinstance(value, numbers.Integral):
                raise ValueRangeError(f"{where}: {self.name} expects an integer, got {value!r}")
            value = int(value)
            if not self.low <= value <= self.high:
                raise ValueRangeError(
                    f"{where}: {value} is outside the {self.name} range {int(self.low)}..{int(self.high)}"
                )
            return value
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise ValueRangeError(f"{where}: {self.name} expects a number, got {value!r}")
        value = float(value)
        if self.name == "REAL" and math.isfinite(value) and abs(value) > 3.4028234663852886e38:
            raise ValueRangeError(f"{where}: {value} does not fit a REAL (32-bit float)")
        return value


def _unsigned(name: str, size: str, dtype: str, bits: int) -> DataType:
    return DataType(name, size, dtype, "int", 0, 2**bits - 1)


def _signed(name: str, size: str, dtype: str, bits: int) -> DataType:
    return DataType(name, size, dtype, "int", -(2 ** (bits - 1)), 2 ** (bits - 1) - 1)


TYPES: dict[str, DataType] = {
    t.name: t
    for t in (
        DataType("BOOL", "X", "bit", "bool"),
        _unsigned("BYTE", "B", "u1", 8),
        _unsigned("USINT", "B", "u1", 8),
        _signed("SINT", "B", "i1", 8),
        _unsigned("WORD", "W", "<u2", 16),
        _unsigned("UINT", "W", "<u2", 16),
        _signed("INT", "W", "<i2", 16),
        _unsigned("DWORD", "D", "<u4", 32),
        _unsigned("UDINT", "D", "<u4", 32),
        _signed("DINT", "D", "<i4", 32),
        DataType("REAL", "D", "<f4", "float"),
        _unsigned("LWORD", "L", "<u8", 64),
        _unsigned("ULINT", "L", "<u8", 64),
        _signed("LINT", "L", "<i8", 64),
        DataType("LREAL", "L", "<f8", "float"),
    )
}

# The type a bare direct address is read and written as (bit strings, unsigned).
RAW_TYPE_OF_SIZE = {
    "X": TYPES["BOOL"],
    "B": TYPES["BYTE"],
    "W": TYPES["WORD"],
    "D": TYPES["DWORD"],
    "L": TYPES["LWORD"],
}
