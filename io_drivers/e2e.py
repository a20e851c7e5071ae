"""End-to-end protection of the vehicle messages, as automotive and CANopen-safety links do it.

Two checks guard every safety-relevant frame (AUTOSAR E2E profiles use the same two):

* **CRC-8 SAE J1850** (polynomial 0x1D, initial value 0xFF, final XOR 0xFF, no reflection)
  over the frame's *data id* (its 11-bit frame id, two bytes little endian) followed by the
  payload after the CRC byte. The bus's own CRC protects one hop; this one protects the
  whole path, from the sending application to the receiving one (gateways, drivers, the
  register copy of a Modbus server), and the data id binds the payload to its frame id, so
  a frame copied to another id (another vehicle) fails the check. The CRC detects every
  error burst of up to 8 bits, so every change of a single byte.
* **A 4-bit counter** the sender increments per frame, which the receiver checks per data id
  (:class:`CounterCheck`): repeated, lost and out-of-sequence frames are detected, and a
  stale frame too unless it is exactly 16k+1..16k+3 frames old (a 4-bit counter's limit).

The CRC is written from the standard's definition (the table is computed from the
polynomial) and checked against the published test vectors of the AUTOSAR CRC library
specification in tests/test_e2e_protection.py.
"""

from __future__ import annotations

POLY, INIT, XOR_OUT = 0x1D, 0xFF, 0xFF
COUNTER_MODULO = 16  # a 4-bit counter
MAX_DELTA = 3  # counter steps still accepted: up to two frames lost in between


def _table(poly: int) -> tuple[int, ...]:
    """The register after shifting each byte value through the polynomial division."""
    table = []
    for byte in range(256):
        reg = byte
        for _ in range(8):
            reg = ((reg << 1) ^ poly) & 0xFF if reg & 0x80 else (reg << 1) & 0xFF
        table.append(reg)
    return tuple(table)


TABLE = _table(POLY)


def crc8_update(register: int, data: bytes) -> int:
    """Feed ``data`` into a CRC register (no final XOR): lets a fixed prefix such as the
    data id be computed once per frame id."""
    table = TABLE
    for byte in data:
        register = table[register ^ byte]
    return register


def crc8(data: bytes) -> int:
    """CRC-8 SAE J1850 of ``data``."""
    return crc8_update(INIT, data) ^ XOR_OUT


def data_id(frame_id: int) -> bytes:
    """The data id the CRC starts with: the frame id, two bytes little endian."""
    return frame_id.to_bytes(2, "little")


# what CounterCheck.check answers
ACCEPTED, REPEATED, OUT_OF_SEQUENCE, RESYNC = "accepted", "repeated", "out_of_sequence", "resync"


class CounterCheck:
    """The receiver's side of the counters: one reference per data id (sender and kind).

    For a frame with counter ``c`` and the reference ``r`` (the last accepted counter),
    ``delta = (c - r) mod 16``:

    * 0: a **repeated** frame (a babbling sender, a replayed frame): dropped;
    * 1..3: **accepted**; ``delta - 1`` frames were **lost** in between;
    * otherwise **out of sequence** (stale, replayed, or from another sender): dropped, and
      the reference stays. But if the very next frame of that data id continues from the
      dropped one (its counter is the dropped one + 1), the sender really jumped: it
      restarted, a second sender uses the same id (its two frames in a row), or more than
      two frames in a row were lost. The check **resynchronises** to it and accepts it,
      and the caller is told so (``RESYNC``): the controller counts a jump of that
      vehicle (it becomes suspect), the vehicle side obeys nothing but a stop from it. A
      false frame whose counter is outside the window cannot cause this by itself: the
      real sender's
      next frame is in the window of the reference, and a counter in the window is
      accepted before anything else is looked at.

    The first frame of a data id is accepted and becomes the reference. The counts of every
    outcome are in ``counters`` (added to the dict given, so a link keeps one set of counts).
    """

    def __init__(self, counters: dict[str, int] | None = None) -> None:
        self._reference: dict[int, int] = {}
        self._dropped: dict[int, int] = {}  # data id -> its last frame's counter, if dropped
        self.counters = counters if counters is not None else {}
        self.counters.update(repeated=0, lost=0, out_of_sequence=0, resyncs=0)

    def check(self, key: int, counter: int) -> str:
        reference = self._reference.get(key)
        dropped = self._dropped.pop(key, None)
        if reference is None:
            self._reference[key] = counter
            return ACCEPTED
        delta = (counter - reference) % COUNTER_MODULO
        if delta == 0:
            self.counters["repeated"] += 1
            return REPEATED
        if delta <= MAX_DELTA:
            self.counters["lost"] += delta - 1
            self._reference[key] = counter
            return ACCEPTED
        if dropped is not None and counter == (dropped + 1) % COUNTER_MODULO:
            self.counters["resyncs"] += 1
            self._reference[key] = counter
            return RESYNC
        self.counters["out_of_sequence"] += 1
        self._dropped[key] = counter
        return OUT_OF_SEQUENCE
