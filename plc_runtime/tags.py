"""The symbol (tag) table: names for direct addresses, with a data type, a retain flag and
an access flag.

Programs and HMIs should not hard-code ``%MD4``; they use ``conveyor_speed``. A tag table
can be built in code or loaded from a TOML file; every problem is reported with the file
and the tag it is in.

Tags are read-only for clients (an HMI, SCADA) unless declared ``writable``: a server on
the network accepts writes only to what the program declared it expects a client to set,
so a status value or an output the program computes cannot be overwritten from outside.
The program itself, tests and the force table are not restricted by the flag.
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from .address import Address, parse_address
from .datatypes import TYPES, DataType
from .errors import AddressError, ConfigError
from .files import FileProblem, read_limited

_NAME_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_.]*")  # fullmatch: $ would allow a trailing newline

MAX_TAG_FILE_BYTES = 4 * 2**20  # far above any tag table


@dataclass(frozen=True, slots=True)
class Tag:
    name: str
    address: Address
    type: DataType
    retain: bool = False
    comment: str = ""
    writable: bool = False  # a client such as an HMI may write it


class TagTable:
    """Symbolic names for process-image locations."""

    def __init__(self) -> None:
        self._tags: dict[str, Tag] = {}

    def add(
        self,
        name: str,
        address: str,
        type: str | None = None,
        *,
        retain: bool = False,
        comment: str = "",
        writable: bool = False,
    ) -> Tag:
        """Declare a tag; the type defaults to the raw type of the address size (BOOL, BYTE, WORD, ...).

        ``writable``: a client (an HMI over Modbus) may write it; every other tag is read-only
        for clients."""
        if not isinstance(name, str) or not _NAME_RE.fullmatch(name) or name.startswith("%"):
            raise ConfigError(f"tag name {name!r} is not a valid identifier")
        if name in self._tags:
            raise ConfigError(f"tag {name!r} is declared twice")
        addr = parse_address(address)
        if type is None:
            type = {"X": "BOOL", "B": "BYTE", "W": "WORD", "D": "DWORD", "L": "LWORD"}[addr.size]
        dt = TYPES.get(str(type).upper())
        if dt is None:
            raise ConfigError(
                f"tag {name!r}: unknown data type {type!r} (known: {', '.join(TYPES)})"
            )
        if dt.size != addr.size:
            raise ConfigError(
                f"tag {name!r}: type {dt.name} needs a {dt.size}-sized address, but {address} is {addr.size}-sized"
            )
        if retain and addr.area != "M":
            raise ConfigError(
                f"tag {name!r}: only marker (%M) tags can be retentive, {address} is in area {addr.area}"
            )
        tag = Tag(name, addr, dt, bool(retain), comment, bool(writable))
        self._tags[name] = tag
        return tag

    def get(self, name: str) -> Tag:
        try:
            return self._tags[name]
        except KeyError:
            raise AddressError(
                f"unknown tag {name!r} (not an IEC address and not in the tag table)"
            ) from None

    def __contains__(self, name: object) -> bool:
        return name in self._tags

    def __iter__(self) -> Iterator[Tag]:
        return iter(self._tags.values())

    def __len__(self) -> int:
        return len(self._tags)

    def writable(self) -> list[Tag]:
        """The tags a client may write."""
        return [t for t in self._tags.values() if t.writable]

    @classmethod
    def from_toml(cls, path: str | Path) -> TagTable:
        """Load ``[tags.<name>]`` tables with keys address, type, retain, writable, comment."""
        path = Path(path)
        try:
            data = tomllib.loads(read_limited(path, MAX_TAG_FILE_BYTES).decode("utf-8"))
        except FileProblem as exc:
            raise ConfigError(f"{path}: {exc}, not a tag file") from None
        except OSError as exc:
            raise ConfigError(f"{path}: cannot read tag file: {exc.strerror}") from None
        except UnicodeDecodeError:
            raise ConfigError(f"{path}: not a UTF-8 text file") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{path}: invalid TOML: {exc}") from None
        tags = data.get("tags")
        if not isinstance(tags, dict):
            raise ConfigError(f"{path}: expected a [tags.<name>] table per tag")
        table = cls()
        for name, spec in tags.items():
            where = f"{path}: [tags.{name}]"
            if not isinstance(spec, dict):
                raise ConfigError(f"{where}: expected a table with at least 'address'")
            unknown = set(spec) - {"address", "type", "retain", "writable", "comment"}
            if unknown:
                raise ConfigError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}")
            if "address" not in spec:
                raise ConfigError(f"{where}: missing 'address'")
            for flag in ("retain", "writable"):
                if not isinstance(spec.get(flag, False), bool):
                    raise ConfigError(f"{where}: '{flag}' must be true or false")
            try:
                table.add(
                    name,
                    spec["address"],
                    spec.get("type"),
                    retain=spec.get("retain", False),
                    comment=str(spec.get("comment", "")),
                    writable=spec.get("writable", False),
                )
            except (ConfigError, AddressError) as exc:
                raise ConfigError(f"{where}: {exc}") from None
        return table
