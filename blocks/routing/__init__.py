"""The router: exact distances built at startup, an A* cut into bounded per-cycle steps,
and the run-time blockades and penalties both respect."""
