"""Opening a python-can bus with one clear error, whatever the interface; what a bus carries.

python-can's interfaces fail in their own ways when they cannot open: a missing vendor
library is a NameError in one, a missing argument a TypeError in another, a bad address
an OSError, and a bus that failed half-way logs "was not properly shut down" when it is
collected. Both ends of the vehicle link (the controller's driver and the simulated
vehicles) open their bus here, so a user sees one line naming the interface, the channel
and the cause.
"""

from __future__ import annotations

import logging
import math
import os
import socket
import sys
import warnings
from collections.abc import Mapping
from typing import Any, TypeVar

import can

from .protocol import MAX_VEHICLE_ID

T = TypeVar("T")

# A classic CAN bus at 1 Mbit/s carries about 9,000 frames of 8 data bytes a second (some
# 111 bits each with stuffing): more than that in a while cannot come from a real bus.
CAN_FRAMES_PER_S = 10_000
MIN_FRAMES_PER_READ = 32


def frames_carried(seconds: float) -> int:
    """The frames a 1 Mbit/s bus carries in ``seconds`` (at least 32): what one read of a
    bus without a bit rate (virtual, UDP) should take at most, so a flood on it costs no
    more than a real bus's worth."""
    return max(MIN_FRAMES_PER_READ, math.ceil(seconds * CAN_FRAMES_PER_S))


def interface_problem(interface: str) -> str | None:
    """Why ``interface`` is no python-can interface, or None: a typo is told at once, with
    the names that exist, not as a failure to open it once the run is set up."""
    if interface in can.interfaces.VALID_INTERFACES:
        return None
    known = ", ".join(sorted(can.interfaces.VALID_INTERFACES))
    return f"unknown CAN interface {interface!r} (python-can has: {known})"


def bus_of(vehicle: int) -> tuple[int, int]:
    """(bus, id on that bus) of a vehicle of a fleet on several buses: a bus carries ids
    1..126 (7 bits, docs/protocol.md), so vehicles go 126 to a bus in id order."""
    return (vehicle - 1) // MAX_VEHICLE_ID, (vehicle - 1) % MAX_VEHICLE_ID + 1


def by_bus(values: Mapping[int, T]) -> dict[int, dict[int, T]]:
    """``values`` by vehicle id, split by bus and keyed by the ids on each bus."""
    out: dict[int, dict[int, T]] = {}
    for v, value in values.items():
        k, local = bus_of(v)
        out.setdefault(k, {})[local] = value
    return out


def bus_channels(channel: str) -> list[str]:
    """The channels of a link of several buses, one per bus, comma-separated:
    ``vcan0,vcan1`` carries vehicles 1..126 on vcan0 and 127..252 on vcan1."""
    return [c.strip() for c in channel.split(",")]


# python-can's udp_multicast binds its socket to this port on every address. On Linux
# such a socket receives, by default, the datagrams of every group any socket of the
# machine joined on that port, so two buses on two groups would hear each other's
# vehicles; open_can_bus turns that off (own_groups_only). Elsewhere a socket hears only
# the groups it joined. The buses of one link also take a port each (bus_options).
UDP_MULTICAST_PORT = 43113
# Linux socket options (linux/in.h, linux/in6.h), which Python's socket module lacks
IP_MULTICAST_ALL, IPV6_MULTICAST_ALL = 49, 29


def bus_options(interface: str | None, bus: int) -> dict[str, Any]:
    """Options that keep bus number ``bus`` of a link of several buses apart from the
    others: on udp_multicast a port of its own (the default for the first). Both ends of
    the link open their buses with them."""
    if interface == "udp_multicast" and bus > 0:
        return {"port": UDP_MULTICAST_PORT + bus}
    return {}


class BusOpenError(ValueError):
    """The bus could not be opened; the message names interface, channel and cause."""


def open_can_bus(interface: str | None, channel: str | None, **kwargs: Any) -> can.BusABC:
    """``can.Bus(interface, channel, receive_own_messages=False, **kwargs)``, or
    BusOpenError. The half-made bus of a failed attempt is collected while python-can's
    bus log is quiet: its warning would be a second line about the same failure."""
    log = logging.getLogger("can.bus")
    quiet = log.disabled
    log.disabled = True
    try:
        bus = _construct(interface, channel, kwargs)
    finally:
        log.disabled = quiet
    if interface == "udp_multicast" and sys.platform.startswith("linux"):
        own_groups_only(bus, channel)
    return bus


def own_groups_only(bus: can.BusABC, group: str | None) -> None:
    """Let a udp_multicast bus receive only the datagrams of its own group: two fleets on
    two groups of one machine are then two buses, as their channels say. A kernel that
    refuses the option keeps hearing every group on the port, with a warning."""
    try:
        # a second handle on the bus's socket (fileno() is python-can's public way to it;
        # the family is read from the socket): an option set through it holds for the bus
        fd = os.dup(bus.fileno())
        try:
            handle = socket.socket(fileno=fd)
        except OSError:
            os.close(fd)
            raise
        with handle:
            if handle.family == socket.AF_INET6:
                handle.setsockopt(socket.IPPROTO_IPV6, IPV6_MULTICAST_ALL, 0)
            else:
                handle.setsockopt(socket.IPPROTO_IP, IP_MULTICAST_ALL, 0)
    except OSError as exc:
        warnings.warn(
            f"udp_multicast channel {group!r}: cannot limit the bus to its own group ({exc}); "
            "it also hears other groups on its port",
            RuntimeWarning,
            stacklevel=3,
        )


def _construct(interface: str | None, channel: str | None, kwargs: dict[str, Any]) -> can.BusABC:
    try:
        return can.Bus(interface=interface, channel=channel, receive_own_messages=False, **kwargs)
    except Exception as exc:  # noqa: BLE001 - any failure of any interface: "cannot open"
        cause = str(exc) or type(exc).__name__
        if not isinstance(exc, can.CanError | OSError | ValueError):
            cause = f"{type(exc).__name__}: {cause}"
    # raised here, not in the except block: the failed bus, which the exception's traceback
    # holds, is then already collected (quietly)
    raise BusOpenError(f"CAN interface {interface!r} channel {channel!r}: {cause}")
