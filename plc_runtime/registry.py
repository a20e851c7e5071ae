"""Registries of what a user plugs in by name (a function of one's own that a configuration
then names): one rule for registering, so that every kind of plug-in behaves the same."""

from __future__ import annotations

from collections.abc import Collection
from typing import TypeVar

T = TypeVar("T")


def register(
    plugged: dict[str, T], kind: str, built_in: Collection[str], name: str, value: T, replace: bool
) -> None:
    """Put ``value`` into ``plugged`` under ``name``: a new identifier, not a built-in's
    name, and one registered already only with ``replace`` (a second experiment must not
    change the first one's ``kind`` unnoticed; the same value again changes nothing)."""
    if not isinstance(name, str) or not name.isidentifier() or name in built_in:
        raise ValueError(f"a plugged {kind} needs a new name (an identifier), got {name!r}")
    if not callable(value):
        raise TypeError(f"{kind} {name!r}: not callable")
    if name in plugged and not replace and plugged[name] is not value:
        raise ValueError(
            f"{kind} {name!r} is registered already; register_{kind}(..., replace=True) replaces it"
        )
    plugged[name] = value
