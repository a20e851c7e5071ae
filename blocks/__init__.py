"""Function blocks, grouped by concern as fleet managers split them.

- ``blocks.standard``: the IEC 61131-3 standard library (timers, edges, counters, flip-flops).
- ``blocks.routing``: the router: the heuristic table, the incremental A*, routing constraints.
- ``blocks.traffic``: the scheduler of shared space: node reservations, per-vehicle control,
  deadlock resolution, and the record views through which they see the vehicles.
- ``blocks.jobs``: what vehicles are sent to do: the recipe sequencer and station choice.

Dependencies point one way: ``routing`` needs only the standard library, ``traffic`` uses
``routing``, ``jobs`` uses both.
"""
