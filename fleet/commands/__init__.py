"""The commands of ``plc-runtime``: ``run`` (the fleet program), ``plant`` and ``route``,
``vehicles`` (simulated AGVs in their own process)."""
