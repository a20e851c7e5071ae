"""The AGV fleet application: the one package that sees everything.

It assembles the soft-PLC (``plc_runtime``), the fleet's function blocks (``blocks``), the
plant (``topology``), the vehicle links (``io_drivers``) and the simulator (``vehicles``)
into the fleet control program, reads its configuration, writes its reports, and offers
all of it as the ``plc-runtime`` command line.

- ``fleet.config``: the fleet configuration file (TOML) and its checks.
- ``fleet.program``: :class:`FleetProgram`, the control program on a runtime.
- ``fleet.report``: the summary, the CSV of completed recipes, the drawing of routes.
- ``fleet.route``: the path-finding blocks as a one-off program (``plc-runtime route``).
- ``fleet.demo_program``: a small PLC program of standard blocks (``--program demo``).
- ``fleet.cli`` and ``fleet.commands``: the command line.
"""
