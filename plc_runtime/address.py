"""IEC 61131-3 direct addresses: parsing ``%IX0.3``, ``%QW4``, ``%MD2`` into byte locations.

Addressing follows the CODESYS/OpenPLC convention, in which the index counts units of
the access size: ``%MW1`` is bytes 2-3, ``%MD1`` bytes 4-7, ``%MX1.3`` bit 3 of byte 1.
All sizes of one area overlap in the same byte memory, so ``%MB2`` is the low byte of
``%MW1`` (multi-byte values are little-endian). This makes Modbus register n the same
thing as ``%QWn``, which is what HMIs built for OpenPLC expect.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from .errors import AddressError

AREAS = ("I", "Q", "M")

# size letter -> bytes per unit (X is a bit inside a byte)
SIZE_BYTES = {"X": 1, "B": 1, "W": 2, "D": 4, "L": 8}

# matched whole (fullmatch) and with ASCII digits only: \d would take other scripts'
# digits (int() reads '%MW٩٠٠' as 900) and $ a trailing newline
_ADDRESS_RE = re.compile(r"%([IQM])([XBWDL]?)([0-9]+)(?:\.([0-9]+))?")


@dataclass(frozen=True, slots=True)
class Address:
    """A parsed direct address: area, access size, byte offset and (for bits) bit number."""

    text: str
    area: str
    size: str  # one of X B W D L
    index: int  # index in units of the size (byte index for X)
    bit: int  # 0..7 for X, -1 otherwise

    @property
    def byte_offset(self) -> int:
        return self.index * SIZE_BYTES[self.size]

    @property
    def nbytes(self) -> int:
        return SIZE_BYTES[self.size]

    @property
    def is_bit(self) -> bool:
        return self.size == "X"


def parse_address(text: str) -> Address:
    """Parse an IEC direct address; raise AddressError naming it when it is malformed.

    ``%I0.3`` (no size letter but a bit number) is accepted as ``%IX0.3``. Spaces around
    it are ignored; any other character that is not ASCII is an error, not read as the
    letter or digit it resembles (``str.upper`` makes a dotless i an I).
    """
    if not isinstance(text, str):
        raise AddressError(f"address must be a string like '%IX0.3', got {text!r}")
    if not text.isascii():
        raise AddressError(f"invalid IEC address {text!r}: ASCII letters and digits (0-9) only")
    match = _ADDRESS_RE.fullmatch(text.strip(" ").upper())
    if match is None:
        raise AddressError(
            f"invalid IEC address {text!r}: expected %<area><size><index>[.<bit>] "
            "with area I/Q/M and size X/B/W/D/L, e.g. %IX0.3, %QW4, %MD2"
        )
    area, size, index, bit = match.groups()
    if size == "" and bit is None:
        raise AddressError(f"invalid IEC address {text!r}: missing size letter (X/B/W/D/L)")
    size = size or "X"
    if size == "X":
        if bit is None:
            raise AddressError(f"invalid IEC address {text!r}: a bit address needs '.<bit>'")
        if int(bit) > 7:
            raise AddressError(f"invalid IEC address {text!r}: bit number must be 0..7")
        return Address(text, area, "X", int(index), int(bit))
    if bit is not None:
        raise AddressError(f"invalid IEC address {text!r}: only X (bit) addresses take '.<bit>'")
    return Address(text, area, size, int(index), -1)
