"""Crash-safe storage of retentive data.

The file is written to a temporary file in the same directory, fsynced, renamed over the
old one and the directory fsynced, so a crash at any moment leaves either the old or the
new file, never a mix. A header carries a CRC32 of the body and a hash of the program's
retain layout (which variables exist, with which types): a file that was damaged, or that
belongs to a different program version, is rejected with a reason instead of loading a
silently wrong value.
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import IO

from .errors import ConfigError, RetainError
from .files import FileProblem, is_special, lock_file, read_limited

MAGIC = "PLCRETAIN"
VERSION = 1
# far above any program's retentive values; a larger file is not one of ours
MAX_RETAIN_BYTES = 64 * 2**20


def _unstorable(value: object) -> str | None:
    """Why a value would not come back from the file as it went in, None if it would."""
    if value is None or isinstance(value, bool | int | float | str):
        return None
    if isinstance(value, list | tuple):
        return next((p for p in map(_unstorable, value) if p), None)
    if isinstance(value, dict):
        if not all(isinstance(k, str) for k in value):
            return "dict keys must be strings (JSON would turn them into strings)"
        return next((p for p in map(_unstorable, value.values()) if p), None)
    return (
        f"type {type(value).__name__} (retain numbers, strings, booleans and lists/dicts of them)"
    )


def layout_hash(entries: list[tuple[str, str]]) -> str:
    """Hash of the sorted (key, type) pairs that make up the retain layout."""
    digest = hashlib.sha256()
    for key, typ in sorted(entries):
        digest.update(f"{key}\0{typ}\n".encode())
    return digest.hexdigest()[:16]


class RetainFile:
    """Reads and writes one retain file."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)

    def check_writable(self) -> None:
        """RetainError unless a save could write here: the folder is made if missing, and the
        temporary file a save writes first is tried. A program that runs for months must not
        learn only at its first save that its retain data can never be kept."""
        folder, tmp = self.path.parent, self.path.with_name(self.path.name + ".tmp")
        try:
            folder.mkdir(parents=True, exist_ok=True)
            if tmp.exists():  # a save's leftover (written over), or another's save right now
                writable = os.access(folder, os.W_OK | os.X_OK)
            else:
                tmp.touch(exist_ok=False)
                tmp.unlink()
                writable = True
        except OSError as exc:
            why = "not a folder" if isinstance(exc, FileExistsError) else exc.strerror or exc
            raise RetainError(f"{self.path}: cannot write retain file there: {why}") from None
        if not writable:
            raise RetainError(f"{self.path}: cannot write retain file there: folder not writable")

    def save(self, layout: str, values: dict[str, object]) -> None:
        for key, value in values.items():
            problem = _unstorable(value)
            if problem:
                raise RetainError(f"retain value {key} cannot be stored: {problem}")
        what = is_special(self.path)
        if what is not None:  # (the rename below would replace the node: a device, a pipe)
            raise RetainError(f"{self.path}: cannot write retain file: it is {what}")
        body = json.dumps(values, sort_keys=True, allow_nan=True).encode()
        header = f"{MAGIC} {VERSION} {layout} {zlib.crc32(body):08x} {len(body)}\n".encode()
        try:
            tmp = self.path.with_name(self.path.name + ".tmp")
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with open(tmp, "wb") as fh:
                fh.write(header + body)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, self.path)
            dir_fd = os.open(self.path.parent, os.O_RDONLY)
            try:
                os.fsync(dir_fd)
            finally:
                os.close(dir_fd)
        except (OSError, ValueError) as exc:
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
            raise RetainError(f"{self.path}: cannot write retain file: {reason}") from None

    def load(self, layout: str) -> dict[str, object] | None:
        """The stored values, None if there is no file; RetainError if it cannot be trusted."""
        try:
            raw = read_limited(self.path, MAX_RETAIN_BYTES)
        except FileNotFoundError:
            return None
        except FileProblem as exc:
            raise RetainError(f"{self.path}: not a retain file: {exc}") from None
        except OSError as exc:
            raise RetainError(
                f"{self.path}: cannot read retain file: {exc.strerror or exc}"
            ) from None
        head, sep, body = raw.partition(b"\n")
        parts = head.decode("ascii", errors="replace").split(" ")
        if not sep or len(parts) != 5 or parts[0] != MAGIC:
            raise RetainError(f"{self.path}: not a retain file (bad header)")
        _, version, file_layout, crc, length = parts
        if version != str(VERSION):
            raise RetainError(
                f"{self.path}: retain file version {version} is not supported (expected {VERSION})"
            )
        if not (length.isascii() and length.isdigit()):
            raise RetainError(
                f"{self.path}: not a retain file (bad header: body length {length!r})"
            )
        expected = int(length)
        if len(body) < expected:
            raise RetainError(
                f"{self.path}: truncated retain file ({len(body)} of {expected} body bytes)"
            )
        if len(body) > expected:
            raise RetainError(
                f"{self.path}: wrong length: {len(body) - expected} trailing byte(s) after the "
                f"{expected}-byte body the header declares"
            )
        if f"{zlib.crc32(body):08x}" != crc:
            raise RetainError(f"{self.path}: retain file is corrupted (CRC mismatch)")
        if file_layout != layout:
            raise RetainError(
                f"{self.path}: retain file was written by a different program layout "
                f"({file_layout}, this program is {layout})"
            )
        try:
            values = json.loads(body, object_pairs_hook=_without_duplicates)
        except _DuplicateKey as exc:
            raise RetainError(f"{self.path}: retain file gives {exc} twice") from None
        except ValueError:
            raise RetainError(f"{self.path}: retain file body is not valid JSON") from None
        except RecursionError:
            raise RetainError(f"{self.path}: retain file body is nested too deeply") from None
        if not isinstance(values, dict):
            raise RetainError(f"{self.path}: retain file body is not an object")
        return values

    def set_aside(self) -> Path:
        """Rename the file to the first free ``<name>.rejected``, ``<name>.rejected.1``, ...:
        the next save would otherwise overwrite values that may still be wanted (a file of
        another program version, one damaged in a way a person can repair). OSError if the
        rename fails."""
        what = is_special(self.path)
        if what is not None:  # (renaming a device node would take it from the system)
            raise OSError(f"it is {what}")
        aside = self.path.with_name(self.path.name + ".rejected")
        number = 0
        while aside.exists():
            number += 1
            aside = self.path.with_name(f"{self.path.name}.rejected.{number}")
        os.rename(self.path, aside)
        return aside


def check_retain_path(path: str | os.PathLike[str]) -> None:
    """ConfigError if ``path`` can never be a retain file: a folder, a device or a pipe."""
    if Path(path).is_dir():
        raise ConfigError(f"retain file {path} is a directory; give a file path")
    if (what := is_special(path)) is not None:
        raise ConfigError(f"retain file {path} is {what}, not a file; give a file path")


# how much of a file is read to tell a user's text document from a damaged retain file
SNIFF_BYTES = 4096


def check_retain_header(path: str | os.PathLike[str]) -> None:
    """ConfigError if ``path`` is a text file that does not begin with a retain file's
    header: a mistyped name (a configuration, a log) is refused before the run, not moved
    aside and replaced by retain data. Anything else is left to the start: an empty file
    holds nothing to keep (a cold start), and a retain file damaged on disk (binary
    garbage, zeros after a crash, a header damaged further on) is set aside there with a
    warning and the start is cold, so that a plant controller still starts unattended."""
    magic = f"{MAGIC} ".encode()
    try:
        with open(path, "rb") as f:
            head = f.read(SNIFF_BYTES)
    except OSError:  # missing (a first run), or for the start's own checks to name
        return
    if not head or head.startswith(magic) or b"\0" in head or not _text(head):
        return
    raise ConfigError(
        f"retain file {path}: not a retain file (a text file that does not begin with "
        f"{MAGIC}); it was left as it is: give a new file name, or the file of an earlier run"
    )


def _text(head: bytes) -> bool:
    """Does ``head`` read as UTF-8 text (its last character may be cut off)?"""
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as err:
        return err.start >= len(head) - 3 and err.reason == "unexpected end of data"
    return True


def claim_retain_file(path: str | os.PathLike[str]) -> IO[bytes]:
    """An exclusive lock on ``PATH.lock`` beside the retain file ``path``, for a command
    that runs a program with it: two runs saving into one retain file would each write its
    values over the other's, and one run's retained data (a lifetime counter) would be lost
    without a word. Held until :func:`plc_runtime.files.release_lock`, or the process's end.
    (The retain file itself is replaced on every save, so it cannot hold the lock.)
    ConfigError if another process holds it, or if the file is none of ours."""
    check_retain_path(path)
    check_retain_header(path)
    retain = Path(path)
    return lock_file(
        retain.with_name(retain.name + ".lock"),
        f"retain file {retain}: cannot lock it",
        f"retain file {retain}: another run is using it; give another file",
    )


class RetainStore:
    """The retentive values of one program: in memory across stop()/start(), and in an
    optional file across processes. Failures to write never stop the PLC: they are
    recorded in ``error`` and reported with a RuntimeWarning.

    A file that cannot be used is set aside before anything is saved, so nothing that was
    stored is lost; when it cannot be moved, this store never writes over it (the values
    then live in memory only, and every save reports why)."""

    def __init__(self, path: str | os.PathLike[str] | None) -> None:
        self.file = RetainFile(path) if path is not None else None
        self.memory: dict[str, object] | None = None
        self.layout = ""
        self.start_info: str | None = None
        self.error: str | None = None
        self.blocked: str | None = None  # why the file must not be written, if it must not

    def forget(self) -> None:
        """The program changed: values kept in memory no longer fit it."""
        self.memory = None

    def load(
        self,
        mode: str,
        layout: list[tuple[str, str]],
        problem: Callable[[dict[str, object]], str | None] = lambda values: None,
    ) -> dict[str, object]:
        """The values to restore for a start in ``mode`` ("warm" or "cold").

        ``problem`` names what is wrong with a file's values, or None: a file whose checksum
        holds can still carry a value its tag cannot take (edited by hand, written by another
        tool), which is rejected as a damaged file is."""
        self.layout = layout_hash(layout)
        if mode == "cold":
            self.memory = None
            self.start_info = "cold"
            return {}
        if self.memory is not None:
            self.start_info = "warm (retain data from memory)"
            return self.memory
        if self.file is None:
            self.start_info = "warm (no retain data yet)"
            return {}
        try:
            loaded = self.file.load(self.layout)
            if loaded is not None and (why := problem(loaded)) is not None:
                raise RetainError(f"{self.file.path}: {why}")
        except RetainError as exc:
            kept = self._set_aside()
            self.start_info = f"cold: {exc}; {kept}"
            warnings.warn(
                f"retain data not used, cold start: {exc}; {kept}", RuntimeWarning, stacklevel=4
            )
            return {}
        if loaded is None:
            self.start_info = f"warm ({self.file.path} does not exist yet)"
            return {}
        self.start_info = f"warm (retain data from {self.file.path})"
        return loaded

    def _set_aside(self) -> str:
        """Move the rejected file out of the way (or block writing); what became of it."""
        assert self.file is not None
        try:
            aside = self.file.set_aside()
        except FileNotFoundError:  # gone meanwhile: nothing left to protect
            self.blocked = None
            return "the file is gone"
        except OSError as exc:
            self.blocked = (
                f"{self.file.path} was rejected and cannot be moved aside "
                f"({exc.strerror or exc}); it is not overwritten"
            )
            return self.blocked
        self.blocked = None
        return f"the file was kept as {aside}"

    def save(self, values: dict[str, object]) -> None:
        """Keep ``values`` in memory and write the file; RetainError if the file write fails."""
        self.memory = values
        if self.file is not None:
            if self.blocked:
                self._set_aside()  # retried on every save: it may be possible by now
                if self.blocked:
                    raise RetainError(self.blocked)
            self.file.save(self.layout, values)
        self.error = None

    def save_or_warn(self, values: dict[str, object], action: str = "saved") -> None:
        try:
            self.save(values)
        except RetainError as exc:
            if self.error != str(exc):  # once per distinct problem, not once per tick
                warnings.warn(f"retain file not {action}: {exc}", RuntimeWarning, stacklevel=4)
            self.error = str(exc)


class _DuplicateKey(Exception):
    """A key given twice in one JSON object: the file was not written by save (which
    cannot write one), and which of the two a person meant cannot be told."""


def _without_duplicates(pairs: list[tuple[str, object]]) -> dict[str, object]:
    values: dict[str, object] = {}
    for key, value in pairs:
        if key in values:
            raise _DuplicateKey(repr(key))
        values[key] = value
    return values
