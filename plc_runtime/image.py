"""The process image: input (I), output (Q) and marker (M) areas, numpy-backed.

Two views exist of the same memory, because a PLC program and the outside world must not
see each other mid-scan:

* ``ProcessImage`` (``rt.image``) is the outside view used by tests, drivers and HMIs.
  Its writes and forces are *queued* and applied by the runtime at one quiet point
  between cycles, so a value can never change while blocks are running, whichever thread
  wrote it. Its reads show the image as the program last left it: inputs as copied in
  (what the program saw), outputs as last copied out, markers as they are.
* ``ProgramImage`` (``ctx.image``) is what blocks use during a scan: inputs come from the
  snapshot taken at cycle start, outputs go to the working output image that is copied out
  only after every block of the cycle ran (so the last assignment wins), markers are
  direct memory.

Forces follow CODESYS semantics: a forced value is written into the program's image at
cycle start and again at cycle end before copy-out, so the program may compute with its
own value during the scan but the forced value is what the field sees.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from .address import AREAS, Address, parse_address
from .datatypes import RAW_TYPE_OF_SIZE, DataType
from .errors import AddressError, WritesBacklogged
from .tags import TagTable

DEFAULT_SIZES: dict[str, int] = {"I": 2048, "Q": 2048, "M": 8192}


class Memory:
    """One area's bytes plus typed little-endian views of them (all views share the bytes)."""

    __slots__ = ("bytes", "_views")

    def __init__(self, size: int) -> None:
        self.bytes = np.zeros(size, dtype=np.uint8)
        self._views: dict[str, np.ndarray] = {}

    def view(self, dtype: str) -> np.ndarray:
        view = self._views.get(dtype)
        if view is None:
            usable = len(self.bytes) - len(self.bytes) % np.dtype(dtype).itemsize
            view = self._views[dtype] = self.bytes[:usable].view(dtype)
        return view


@dataclass(frozen=True, slots=True)
class Location:
    """A resolved reference: where a value lives and how it is typed."""

    ref: str  # what the user wrote: an address or a tag name
    address: Address
    type: DataType

    @property
    def area(self) -> str:
        return self.address.area

    @property
    def key(self) -> tuple[str, str, int, int]:
        """The storage location, whatever name it was reached by."""
        a = self.address
        return (a.area, a.size, a.index, a.bit)

    def reader(self, mem: Memory) -> Callable[[], bool | int | float]:
        if self.address.is_bit:
            u8, offset, bit = mem.bytes, self.address.byte_offset, self.address.bit
            return lambda: bool((u8[offset] >> bit) & 1)
        view, element = mem.view(self.type.dtype), self.address.index
        return lambda: view[element].item()

    def writer(self, mem: Memory) -> Callable[[bool | int | float], None]:
        """A function storing an already checked value."""
        if self.address.is_bit:
            u8, offset = mem.bytes, self.address.byte_offset
            mask = 1 << self.address.bit
            clear = 0xFF ^ mask

            def write_bit(value: bool | int | float) -> None:
                u8[offset] = (u8[offset] | mask) if value else (u8[offset] & clear)

            return write_bit
        view, element = mem.view(self.type.dtype), self.address.index

        def write(value: bool | int | float) -> None:
            view[element] = value

        return write


# external writes and force changes that may wait for the quiet point at once: far more
# than clients of a scanning runtime queue in a cycle, and few enough that applying them
# all stays a small part of a scan (some 2 us each)
MAX_PENDING = 10_000


class ProcessImage:
    """The I/Q/M image as seen from outside the scan (``rt.image``)."""

    def __init__(
        self, sizes: Mapping[str, int] | None = None, tags: TagTable | None = None
    ) -> None:
        self.sizes = dict(DEFAULT_SIZES)
        for area, size in (sizes or {}).items():
            if area not in AREAS:
                raise AddressError(f"unknown image area {area!r}: areas are I, Q and M")
            if not isinstance(size, int) or size < 8 or size % 8:
                raise AddressError(
                    f"image area {area}: size must be a multiple of 8 bytes >= 8, got {size!r}"
                )
            self.sizes[area] = size
        self.tags = tags if tags is not None else TagTable()
        self.field_inputs = Memory(self.sizes["I"])  # what the field (drivers, tests) last wrote
        self.inputs = Memory(self.sizes["I"])  # snapshot the program sees during a cycle
        self.outputs = Memory(self.sizes["Q"])  # working output image the program writes
        self.published_outputs = Memory(self.sizes["Q"])  # as last copied out
        self.markers = Memory(self.sizes["M"])
        self._locations: dict[str, Location] = {}
        self._pending: deque[tuple[str, Location, object]] = deque()
        self._forces: dict[tuple[str, str, int, int], tuple[Location, object]] = {}
        self._force_writers: list[tuple[str, Callable, object]] = []
        self._lock = threading.Lock()
        self._readers: dict[str, Callable[[], object]] = {}
        self._external_writers: dict[str, Callable[[object], None]] = {}
        for tag in self.tags:
            self._check_in_area(tag.address, tag.name)

    # ----- resolution -------------------------------------------------------------
    def resolve(self, ref: str) -> Location:
        """Turn an address or tag name into a Location; raise AddressError naming it."""
        loc = self._locations.get(ref)
        if loc is not None:
            return loc
        if isinstance(ref, str) and ref.lstrip().startswith("%"):
            address = parse_address(ref)
            self._check_in_area(address, ref)
            loc = Location(ref, address, RAW_TYPE_OF_SIZE[address.size])
        elif isinstance(ref, str):
            tag = self.tags.get(ref)
            self._check_in_area(tag.address, f"tag {ref} ({tag.address.text})")
            loc = Location(ref, tag.address, tag.type)
        else:
            raise AddressError(f"address or tag name must be a string, got {ref!r}")
        self._locations[ref] = loc
        return loc

    def _check_in_area(self, address: Address, ref: str) -> None:
        size = self.sizes[address.area]
        if address.byte_offset + address.nbytes > size:
            last = size // address.nbytes - 1
            raise AddressError(
                f"{ref}: outside the {address.area} area ({size} bytes; "
                f"%{address.area}{address.size}0..%{address.area}{address.size}{last}"
                + (".7" if address.is_bit else "")
                + ")"
            )

    def field_writer(self, ref: str) -> Callable[[object], None]:
        """For drivers, in the scan thread at the quiet point: a checked writer of a field input."""
        loc = self.resolve(ref)
        if loc.area != "I":
            raise AddressError(f"{ref}: drivers write field inputs (%I), not area {loc.area}")
        store, check, kind = loc.writer(self.field_inputs), loc.type.check, loc.type.kind
        # Drivers write every field of every frame they receive, and nearly all of those
        # values are plain ints in range (or True/False), which ``check`` would return
        # unchanged: those skip the generic check; anything else still goes through it.
        if kind == "int":
            low, high = loc.type.low, loc.type.high

            def write_int(value: object) -> None:
                in_range = value.__class__ is int and low <= value <= high
                store(value if in_range else check(value, ref))

            return write_int
        if kind == "bool":

            def write_bool(value: object) -> None:
                store(value if value is True or value is False else check(value, ref))

            return write_bool
        return lambda value: store(check(value, ref))

    def output_reader(self, ref: str) -> Callable[[], bool | int | float]:
        """For drivers, in the scan thread after copy-out: a reader of a published output."""
        loc = self.resolve(ref)
        if loc.area != "Q":
            raise AddressError(f"{ref}: drivers read outputs (%Q), not area {loc.area}")
        return loc.reader(self.published_outputs)

    def memory_for_program(self, area: str) -> Memory:
        return {"I": self.inputs, "Q": self.outputs, "M": self.markers}[area]

    # ----- outside view -----------------------------------------------------------
    def read(self, ref: str) -> bool | int | float:
        """Inputs as the program last saw them, outputs as last copied out, markers as they are."""
        reader = self._readers.get(ref)
        if reader is None:
            loc = self.resolve(ref)
            mem = {"I": self.inputs, "Q": self.published_outputs, "M": self.markers}[loc.area]
            reader = self._readers[ref] = loc.reader(mem)
        with self._lock:
            return reader()

    def write(self, ref: str, value: object) -> None:
        """Queue a write; it takes effect at the next quiet point (before the next cycle).

        Inputs become visible to the program at the next cycle start; an output written
        from outside lands in the working output image (the program may overwrite it);
        a marker is set before the next cycle.
        """
        loc = self.resolve(ref)
        self._queue(("write", loc, loc.type.check(value, ref)))

    def write_many(self, values: Mapping[str, object]) -> None:
        """Queue several writes that take effect together, at the same quiet point
        (e.g. the two words of a setpoint). Nothing is queued if any value is invalid."""
        batch = []
        for ref, value in values.items():
            loc = self.resolve(ref)
            batch.append((loc, loc.type.check(value, ref)))
        self._queue(("batch", None, batch))

    def force(self, ref: str, value: object) -> None:
        """Force a location to a value until unforced (applied at the next quiet point)."""
        loc = self.resolve(ref)
        self._queue(("force", loc, loc.type.check(value, ref)))

    def unforce(self, ref: str) -> None:
        loc = self.resolve(ref)
        self._queue(("unforce", loc, None))

    def unforce_all(self) -> None:
        self._queue(("unforce_all", None, None))

    @property
    def forces(self) -> dict[str, object]:
        """The active force table: reference -> forced value."""
        with self._lock:
            return {loc.ref: value for loc, value in self._forces.values()}

    @property
    def pending_writes(self) -> int:
        return len(self._pending)

    def _queue(self, item: tuple) -> None:
        """Queue a write or force change for the quiet point, unless ``MAX_PENDING`` wait
        already (WritesBacklogged: nothing is queued)."""
        if len(self._pending) >= MAX_PENDING:
            raise WritesBacklogged(
                f"{MAX_PENDING:,} writes wait for the next scan already (is the runtime "
                "scanning?): this one is refused"
            )
        self._pending.append(item)  # type: ignore[arg-type]

    # ----- runtime side -----------------------------------------------------------
    def apply_quiet_point(self) -> None:
        """Apply every queued external write and force change (called between cycles)."""
        pending = self._pending
        if not pending:
            return
        with self._lock:
            changed = False
            while pending:
                op, loc, value = pending.popleft()
                if op == "write":
                    self._write_external(loc, value)
                elif op == "batch":
                    for batch_loc, batch_value in value:  # type: ignore[attr-defined]
                        self._write_external(batch_loc, batch_value)
                elif op == "force":  # keyed by location: a tag and its address are one force
                    self._forces.pop(loc.key, None)
                    self._forces[loc.key] = (loc, value)
                    changed = True
                elif op == "unforce":
                    changed |= self._forces.pop(loc.key, None) is not None
                else:
                    changed |= bool(self._forces)
                    self._forces.clear()
            if changed:
                self._force_writers = [
                    (loc.area, loc.writer(self.memory_for_program(loc.area)), value)
                    for loc, value in self._forces.values()
                ]

    def _write_external(self, loc: Location, value: object) -> None:
        write = self._external_writers.get(loc.ref)
        if write is None:
            mem = {"I": self.field_inputs, "Q": self.outputs, "M": self.markers}[loc.area]
            write = self._external_writers[loc.ref] = loc.writer(mem)
        write(value)

    def copy_in(self) -> None:
        """Cycle start: snapshot the field inputs, then apply forces to the program image.

        Under the lock, so an outside reader never sees a forced input at its field value."""
        with self._lock:
            np.copyto(self.inputs.bytes, self.field_inputs.bytes)
            for _area, write, value in self._force_writers:
                write(value)

    def copy_out(self) -> None:
        """Cycle end: re-apply output and marker forces, then publish the output image."""
        with self._lock:
            for area, write, value in self._force_writers:
                if area != "I":
                    write(value)
            np.copyto(self.published_outputs.bytes, self.outputs.bytes)

    def reset(self) -> None:
        """Clear program memory for a (re)start: inputs read 0 in startup, outputs and markers 0."""
        for mem in (self.inputs, self.outputs, self.markers):
            mem.bytes.fill(0)
        with self._lock:
            self.published_outputs.bytes.fill(0)

    def publish_safe_state(self, safe_outputs: Mapping[str, object]) -> None:
        """On FAULT: every output 0 except the configured safe values (forces are not honoured)."""
        staged = Memory(self.sizes["Q"])
        for ref, value in safe_outputs.items():
            loc = self.resolve(ref)
            loc.writer(staged)(loc.type.check(value, f"safe output {ref}"))
        with self._lock:
            np.copyto(self.published_outputs.bytes, staged.bytes)
            np.copyto(self.outputs.bytes, staged.bytes)


class ProgramImage:
    """The image as blocks see it during a scan (``ctx.image``)."""

    __slots__ = ("_image", "_readers", "_writers")

    def __init__(self, image: ProcessImage) -> None:
        self._image = image
        self._readers: dict[str, Callable[[], object]] = {}
        self._writers: dict[str, Callable[[object], None]] = {}

    def read(self, ref: str) -> bool | int | float:
        reader = self._readers.get(ref)
        if reader is None:
            loc = self._image.resolve(ref)
            reader = self._readers[ref] = loc.reader(self._image.memory_for_program(loc.area))
        return reader()

    def write(self, ref: str, value: object) -> None:
        writer = self._writers.get(ref)
        if writer is None:
            writer = self._writers[ref] = self._make_writer(ref)
        writer(value)

    def _make_writer(self, ref: str) -> Callable[[object], None]:
        loc = self._image.resolve(ref)
        if loc.area == "I":
            raise AddressError(
                f"{ref}: inputs are read-only for the program (write outputs %Q or markers %M)"
            )
        store = loc.writer(self._image.memory_for_program(loc.area))
        check = loc.type.check
        if loc.type.kind == "bool":

            def write_bool(value: object) -> None:
                store(value if value is True or value is False else check(value, ref))

            return write_bool

        def write_checked(value: object) -> None:
            store(check(value, ref))

        return write_checked

    def record_view(self, area: str, start: int, length: int) -> np.ndarray:
        """The raw bytes ``start .. start + length`` of an area, as a numpy view.

        For blocks that handle many same-shaped records at once (one per machine or drive): they
        reinterpret the bytes with a structured dtype instead of resolving an address per
        field. The view follows the program's image, so inputs are the cycle's snapshot and
        read-only; writes to outputs bypass tag range checks, as a raw byte area should."""
        mem = self._image.memory_for_program(area)
        if start < 0 or length < 0 or start + length > mem.bytes.size:
            raise AddressError(
                f"area {area}: bytes {start}..{start + length} outside its {mem.bytes.size} bytes"
            )
        view = mem.bytes[start : start + length]
        if area == "I":
            view = view.view()
            view.flags.writeable = False
        return view

    @property
    def tags(self) -> TagTable:
        return self._image.tags
