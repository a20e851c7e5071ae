"""Function blocks: the IEC standard library (timers, edges, counters, flip-flops) and, later, the fleet blocks."""
