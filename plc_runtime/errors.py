"""Exceptions of the runtime.

Every error a user can cause by configuration or by a bad address is a ``PlcError``
subclass with a message that names the offending thing, so the CLI can print it as one
line instead of a traceback.
"""


class PlcError(Exception):
    """Base class of every error the runtime raises on purpose."""


class AddressError(PlcError, ValueError):
    """An IEC address or tag name is malformed, unknown or outside its area."""


class ValueRangeError(PlcError, ValueError):
    """A value does not fit the data type of the address or tag it is written to."""


class ConfigError(PlcError, ValueError):
    """A runtime, task or block configuration is inconsistent."""


class StateError(PlcError, RuntimeError):
    """An operation is not allowed in the runtime's current operating state."""


class WritesBacklogged(PlcError, RuntimeError):
    """As many external writes wait for the next quiet point as the image queues: the
    runtime is not scanning (stopped, or between ``run`` calls), or a client writes faster
    than it scans. Refused, so a client cannot fill the memory or stretch the next scan."""


class StartupError(PlcError, RuntimeError):
    """A block's startup failed; the runtime went to FAULT."""


class RetainError(PlcError):
    """A retain file is unreadable, corrupted or belongs to another program layout."""


class WatchdogTimeout(BaseException):
    """Raised inside a scan by the watchdog timer when the maximum cycle time expires.

    A BaseException so a block's ``except Exception`` cannot swallow it: the scan must
    be aborted, exactly as a hardware watchdog would stop a hung PLC program.
    """
