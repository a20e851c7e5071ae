"""The one check every time and duration argument of the dispatch layer passes: a finite
real number (not NaN, not infinite, not a string), at least a minimum, returned as a plain
float. Plain floats everywhere keep computations that must agree (a station slot found
and the same slot booked) rounding the same way."""

from __future__ import annotations

import math
from numbers import Real


def finite_number(
    owner: str, where: str, name: str, value: float, minimum: float = -math.inf
) -> float:
    """``value`` as a float, or a ValueError naming the class, the call, the argument and
    the value (``StationSchedule.reserve: dwell_s must be a finite number >= 0, got -1``)."""
    if not isinstance(value, Real) or not math.isfinite(value) or value < minimum:
        bound = "" if minimum == -math.inf else f" >= {minimum:g}"
        raise ValueError(f"{owner}.{where}: {name} must be a finite number{bound}, got {value!r}")
    return float(value)
