"""SectionEstimates: how long an order's sections take, learned from the orders already run.

The seed's allocation prices every (vehicle, order) pair by the time the vehicle would idle,
so it needs estimates of every section: the travel time between two nodes (to the Get
station, Get -> Put, Put -> next Get) and the dwell time of a Get or Put at each station. It
learns them from history: the mean (or, as the seed suggests, the more robust median) of the
recorded times per pair of nodes and per station and kind. Before the first record of a key,
travel falls back to distance / mean speed (the seed's fallback; the fleet passes the
heuristic table's route distance) and dwell to a default.

The mean speed of that fallback is learned too: every recorded travel also counts as
metres driven in seconds, and the fallback's speed is the total distance over the total
time of the last ``window`` travels (``mean_speed``, the configured one, only until then).
Most (vehicle position, station) pairs are driven rarely or never, so the fallback prices
most pairs; a configured top-speed figure would make every trip look shorter than it is
(acceleration, turn stops, waits in traffic), every section "deviate" from its estimate
and the allocation recompute over and over. A trip of no distance says nothing about
speed and is left out of it.

A vehicle stuck behind a blockade records a travel time that says nothing about the route,
so a sample above ``outlier`` x the current estimate is ignored (and counted in
``ignored``) -- but only once a key has 3 samples, so the first ones can establish an
estimate even if the fallback was far off. Only the last ``window`` samples of a key count:
memory stays bounded over a long run, and the estimates follow a plant that changes. The
keys are bounded too: travel is learned from wherever a vehicle took an order, so a large
plant could hold a key for nearly every (node, station) pair. Only the ``keys`` most
recently recorded keys are kept (``KEYS_KEPT`` by default, more than a plant of a few
hundred nodes ever fills); a key not recorded for longer is priced by the fallback again
until it is driven anew.

:meth:`SectionEstimates.deviates` is the seed's re-planning trigger: a section deviates when
``|(now - planned start) / estimated duration| > 1 + threshold`` (30 % by default).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Hashable
from numbers import Real
from statistics import fmean, median
from typing import Literal

from .arguments import finite_number

KINDS = ("Get", "Put")
MIN_SAMPLES_FOR_OUTLIERS = 3
KEYS_KEPT = 10_000  # keys with samples kept, the most recently recorded ones


def _number(where: str, name: str, value: float, minimum: float = -math.inf) -> float:
    return finite_number("SectionEstimates", where, name, value, minimum)


class SectionEstimates:
    """Learned travel and dwell times per key, with fallbacks before the first sample.

    Keys are ``(a, b)`` node pairs for travel and ``(station, kind)`` for dwell. The outlier
    rule needs 3 samples in the window, so a ``window`` below 3 switches it off.
    """

    def __init__(
        self,
        distance: Callable[[int, int], float],
        dwell_default_s: float,
        mean_speed: float = 1.0,
        outlier: float = 1.5,
        method: Literal["median", "mean"] = "median",
        window: int = 50,
        keys: int = KEYS_KEPT,
    ) -> None:
        if not callable(distance):
            raise ValueError("SectionEstimates: distance must be callable (a, b) -> metres")
        self.dwell_default_s = _number("__init__", "dwell_default_s", dwell_default_s, 0.0)
        self.configured_speed = _number("__init__", "mean_speed", mean_speed, 0.0)
        if self.configured_speed == 0:
            raise ValueError("SectionEstimates: mean_speed must be > 0 m/s, got 0")
        # inf switches the outlier rule off; a factor <= 1 would reject every slower sample
        if not isinstance(outlier, Real) or math.isnan(outlier) or outlier <= 1:
            raise ValueError(f"SectionEstimates: outlier must be a number > 1, got {outlier!r}")
        if method not in ("median", "mean"):
            raise ValueError(f"SectionEstimates: method must be 'median' or 'mean', got {method!r}")
        if isinstance(window, bool) or not isinstance(window, int) or window < 1:
            raise ValueError(f"SectionEstimates: window must be an integer >= 1, got {window!r}")
        if isinstance(keys, bool) or not isinstance(keys, int) or keys < 1:
            raise ValueError(f"SectionEstimates: keys must be an integer >= 1, got {keys!r}")
        self.distance = distance
        self.outlier = float(outlier)
        self.method = method
        self.window = window
        self.keys = keys
        self.ignored = 0  # samples dropped by the outlier rule
        # per key, the newest samples; the dict's order is the keys' last record, oldest
        # first: what is forgotten first once ``keys`` are held
        self._samples: dict[Hashable, deque[float]] = {}
        self._learned: dict[Hashable, float] = {}  # cached estimate per key with samples
        self._trips: deque[tuple[float, float]] = deque(maxlen=window)  # (metres, seconds)
        self.mean_speed = self.configured_speed
        """The fallback's speed in m/s: learned from the recorded travels, else configured."""

    def travel(self, a: int, b: int) -> float:
        """Seconds from node ``a`` to node ``b``: learned, else distance / mean speed."""
        learned = self._learned.get(("travel", a, b))
        return learned if learned is not None else float(self.distance(a, b)) / self.mean_speed

    def dwell(self, station: int, kind: str) -> float:
        """Seconds a Get or Put (``kind``) takes at ``station``: learned, else the default."""
        return self._learned.get((_kind("dwell", kind), station), self.dwell_default_s)

    def record_travel(self, a: int, b: int, seconds: float) -> bool:
        """Learn one driven time from ``a`` to ``b``; False if ignored as an outlier."""
        seconds = _number("record_travel", "seconds", seconds, 0.0)
        if not self._record(("travel", a, b), seconds):
            return False
        metres = float(self.distance(a, b))
        if 0 < metres < math.inf and seconds > 0:
            self._trips.append((metres, seconds))
            self.mean_speed = sum(m for m, _ in self._trips) / sum(s for _, s in self._trips)
        return True

    def record_dwell(self, station: int, kind: str, seconds: float) -> bool:
        """Learn one Get/Put time at ``station``; False if ignored as an outlier."""
        key = (_kind("record_dwell", kind), station)
        return self._record(key, _number("record_dwell", "seconds", seconds, 0.0))

    def travel_samples(self, a: int, b: int) -> tuple[float, ...]:
        """The samples behind :meth:`travel` (at most ``window``, oldest first)."""
        return tuple(self._samples.get(("travel", a, b), ()))

    def dwell_samples(self, station: int, kind: str) -> tuple[float, ...]:
        """The samples behind :meth:`dwell` (at most ``window``, oldest first)."""
        return tuple(self._samples.get((_kind("dwell_samples", kind), station), ()))

    def _record(self, key: Hashable, seconds: float) -> bool:
        samples = self._samples.pop(key, None)
        if samples is None:
            samples = deque(maxlen=self.window)
            if len(self._samples) >= self.keys:
                oldest = next(iter(self._samples))
                del self._samples[oldest], self._learned[oldest]
        self._samples[key] = samples  # the newest record last
        if len(samples) >= MIN_SAMPLES_FOR_OUTLIERS and seconds > self.outlier * self._learned[key]:
            self.ignored += 1
            return False
        samples.append(seconds)
        self._learned[key] = median(samples) if self.method == "median" else fmean(samples)
        return True

    @staticmethod
    def deviates(
        planned_start_s: float, estimated_s: float, now_s: float, threshold: float = 0.3
    ) -> bool:
        """The seed's trigger: ``|(now - planned start) / estimated| > 1 + threshold``.

        A zero estimate deviates as soon as any time has passed (the ratio is infinite).
        """
        start = _number("deviates", "planned_start_s", planned_start_s)
        estimated = _number("deviates", "estimated_s", estimated_s, 0.0)
        now = _number("deviates", "now_s", now_s)
        limit = 1 + _number("deviates", "threshold", threshold, 0.0)
        if estimated == 0:
            return now != start
        return abs((now - start) / estimated) > limit


def _kind(where: str, kind: str) -> str:
    if kind not in KINDS:
        raise ValueError(f"SectionEstimates.{where}: kind must be 'Get' or 'Put', got {kind!r}")
    return kind
