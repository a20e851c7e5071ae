"""plc_runtime: a soft-PLC scan-cycle runtime.

A fixed-cycle scheduler runs function blocks against a process image, with copy-in at
cycle start and copy-out at cycle end, a startup phase, cycle monitoring and retentive
memory. Step it one cycle at a time on the ``VirtualClock`` in tests, or run it on the
``WallClock`` in real time.
"""

from .address import Address, parse_address
from .clock import PacedClock, VirtualClock, WallClock
from .context import CycleContext
from .errors import (
    AddressError,
    ConfigError,
    PlcError,
    RetainError,
    StartupError,
    StateError,
    ValueRangeError,
    WritesBacklogged,
)
from .fb import FunctionBlock, Input, Output, Static
from .image import ProcessImage, ProgramImage
from .io import IoDriver
from .runtime import FAULT, RUN, STARTUP, STOP, Runtime
from .tags import Tag, TagTable

__all__ = [
    "FAULT",
    "RUN",
    "STARTUP",
    "STOP",
    "Address",
    "AddressError",
    "ConfigError",
    "CycleContext",
    "FunctionBlock",
    "IoDriver",
    "Input",
    "Output",
    "PlcError",
    "ProcessImage",
    "ProgramImage",
    "RetainError",
    "Runtime",
    "StartupError",
    "StateError",
    "Static",
    "Tag",
    "TagTable",
    "ValueRangeError",
    "WritesBacklogged",
    "PacedClock",
    "VirtualClock",
    "WallClock",
    "parse_address",
]
