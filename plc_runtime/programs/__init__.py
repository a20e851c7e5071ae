"""Program assembly: the ready-made programs the CLI can run.

This layer (with the CLI) is the only place allowed to import ``blocks``, ``io_drivers``
and ``vehicles`` together with the runtime core.
"""

from . import demo

PROGRAMS = {"demo": demo.build}
