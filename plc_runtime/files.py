"""Reading a file a user named, without trusting what the name leads to.

A path given on a command line or in a configuration may name a device (``/dev/zero``
never ends), a named pipe (opening it waits for a writer for ever) or a file far larger
than any the reader expects. ``read_limited`` refuses anything but a regular file before
opening it and reads at most ``limit`` bytes, so such a name gets a one-line error instead
of a hang or a process that eats the machine's memory.
"""

from __future__ import annotations

import fcntl
import os
import stat
from pathlib import Path
from typing import IO

from .errors import ConfigError


class FileProblem(ValueError):
    """The path names no regular file, or one larger than the reader's limit."""


def read_limited(path: str | os.PathLike[str], limit: int) -> bytes:
    """The bytes of the regular file ``path`` (symbolic links followed), at most ``limit``.

    FileProblem if it is no regular file or is larger; OSError if it cannot be read
    (FileNotFoundError when there is none)."""
    path = Path(path)
    mode = os.stat(path).st_mode
    if not stat.S_ISREG(mode):
        raise FileProblem(f"not a regular file ({kind(mode)})")
    with open(path, "rb") as fh:
        raw = fh.read(limit + 1)
    if len(raw) > limit:
        raise FileProblem(f"larger than {limit:,} bytes")
    return raw


def is_special(path: str | os.PathLike[str]) -> str | None:
    """What ``path`` is if it exists and is no regular file or directory (a device, a pipe,
    a socket), else None: a file this program would write must not replace such a node."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return None
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode):
        return None
    return kind(mode)


def kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a named pipe"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a file"


def same_path(a: Path, b: Path) -> bool:
    """Do the two paths name one file: one existing file (links and relative paths
    included), or, where one does not exist yet, one place."""
    try:
        return a.samefile(b)
    except OSError:
        return a.resolve() == b.resolve()


def lock_file(path: Path, cannot: str, taken: str) -> IO[bytes]:
    """An exclusive lock on the file ``path`` (made, with its folder, if missing), for as
    long as a run uses what it guards: held until :func:`release_lock`, or the process's
    end however it ends. ConfigError ``cannot: why`` if the file cannot be made, ``taken``
    if another process holds the lock."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        lock = open(path, "ab")
    except OSError as exc:
        raise ConfigError(f"{cannot}: {exc.strerror or exc}") from None
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        lock.close()
        raise ConfigError(taken) from None
    return lock


def release_lock(lock: IO[bytes]) -> None:
    """The run is over: the lock file goes (a run leaves only its results behind), then
    the lock."""
    try:
        Path(lock.name).unlink(missing_ok=True)
    except OSError:
        pass  # the folder went read-only or away during the run: the lock goes with close
    lock.close()
