"""Learned section times: fallbacks, mean vs median, the outlier rule, the window, deviation."""

import math

import pytest

from blocks.dispatch.estimates import SectionEstimates

DISTANCE_M = {(1, 2): 30.0, (2, 1): 45.0, (2, 3): 15.0}
MEAN_SPEED = 1.5  # the seed's maximum speed, m/s


def distance(a: int, b: int) -> float:
    return DISTANCE_M.get((a, b), math.inf)


def estimates(**kwargs) -> SectionEstimates:
    return SectionEstimates(distance, dwell_default_s=12.0, mean_speed=MEAN_SPEED, **kwargs)


def test_fallbacks_before_any_sample():
    e = estimates()
    assert e.travel(1, 2) == 20.0  # 30 m / 1.5 m/s
    assert e.dwell(5, "Get") == e.dwell(5, "Put") == 12.0
    assert e.travel_samples(1, 2) == () and e.dwell_samples(5, "Get") == ()


def test_the_fallback_learns_the_fleets_mean_speed():
    """Pairs never driven are priced at distance / the speed the fleet actually drove: a
    configured top speed would make every trip look short and every section deviate."""
    e = estimates()
    assert e.mean_speed == 1.5 and e.travel(2, 3) == 10.0  # 15 m at the configured 1.5 m/s
    assert e.record_travel(1, 2, 50.0)  # 30 m in 50 s
    assert e.mean_speed == pytest.approx(0.6)
    assert e.travel(2, 3) == pytest.approx(25.0)  # 15 m at 0.6 m/s
    assert e.travel(1, 2) == 50.0  # a driven pair keeps its own time
    assert e.record_travel(2, 1, 25.0)  # 45 m in 25 s: 75 m in 75 s over both
    assert e.mean_speed == pytest.approx(1.0)
    assert e.travel(2, 3) == pytest.approx(15.0)


def test_only_the_last_window_of_trips_sets_the_speed():
    e = estimates(window=2)
    for seconds in (300.0, 30.0, 30.0):  # a slow first trip of 1 -> 2, then two at 1 m/s
        e.record_travel(1, 2, seconds)
    assert e.mean_speed == pytest.approx(1.0)


def test_trips_that_say_nothing_about_speed_are_left_out():
    e = estimates()
    e.record_travel(1, 1, 5.0)  # no distance (unknown pair: inf)
    e.record_travel(1, 2, 0.0)  # no time
    assert e.mean_speed == 1.5
    for seconds in (10.0, 10.0, 10.0):
        e.record_travel(2, 3, seconds)
    assert not e.record_travel(2, 3, 100.0)  # an outlier teaches neither the pair nor the speed
    assert e.mean_speed == pytest.approx(1.5)


def test_each_key_learns_on_its_own():
    e = estimates()
    assert e.record_travel(1, 2, 26.0)
    assert e.travel(1, 2) == 26.0
    # the way back is another key: 45 m at the speed of the one trip driven, 30 m in 26 s
    assert e.travel(2, 1) == pytest.approx(39.0)
    assert e.record_dwell(5, "Get", 8.0)
    assert e.dwell(5, "Get") == 8.0
    assert e.dwell(5, "Put") == 12.0 and e.dwell(6, "Get") == 12.0


@pytest.mark.parametrize(("method", "expected"), [("median", 10.0), ("mean", 11.0)])
def test_mean_or_median(method, expected):
    """Samples 10, 10, 13: median 10, mean 11 (13 < 1.5 x either, and only 2 samples existed)."""
    e = estimates(method=method)
    for seconds in (10.0, 10.0, 13.0):
        assert e.record_travel(2, 3, seconds)
    assert e.travel(2, 3) == expected
    for seconds in (10.0, 10.0, 13.0):
        assert e.record_dwell(4, "Put", seconds)
    assert e.dwell(4, "Put") == expected


def test_the_first_three_samples_are_never_outliers():
    """The fallback may be far off, so the first samples establish the estimate."""
    e = estimates()
    for seconds in (10.0, 100.0, 1000.0):
        assert e.record_travel(1, 2, seconds)
    assert e.ignored == 0
    assert e.travel(1, 2) == 100.0


def test_an_outlier_is_ignored_and_counted():
    """Median of 10, 10, 10 is 10: 15 (= 1.5 x) is kept, 15.5 is not; then the median of
    10, 10, 10, 15 is 10 still, and 15.5 stays out."""
    e = estimates()
    for seconds in (10.0, 10.0, 10.0):
        e.record_dwell(3, "Get", seconds)
    assert e.record_dwell(3, "Get", 15.0)
    assert not e.record_dwell(3, "Get", 15.5)
    assert e.ignored == 1
    assert e.dwell_samples(3, "Get") == (10.0, 10.0, 10.0, 15.0)
    assert e.dwell(3, "Get") == 10.0
    for seconds in (10.0, 10.0, 10.0):
        e.record_travel(1, 2, seconds)
    assert not e.record_travel(1, 2, 300.0)  # stuck behind a blockade
    assert e.ignored == 2 and e.travel(1, 2) == 10.0


def test_the_outlier_rule_compares_with_the_mean_when_learning_means():
    """10, 10, 40: mean 20 (median 10), so 30 is kept and 31 is not."""
    e = estimates(method="mean")
    for seconds in (10.0, 10.0, 40.0):
        e.record_travel(2, 1, seconds)
    assert not e.record_travel(2, 1, 31.0)
    assert e.record_travel(2, 1, 30.0)
    assert e.ignored == 1 and e.travel(2, 1) == 22.5


def test_outlier_factor_is_configurable():
    e = estimates(outlier=3.0)
    for seconds in (10.0, 10.0, 10.0):
        e.record_travel(1, 2, seconds)
    assert e.record_travel(1, 2, 29.0)
    assert not e.record_travel(1, 2, 31.0)


def test_only_the_last_window_samples_count():
    """window 3: after 20, 18, 16, 14 the mean is (18 + 16 + 14) / 3 = 16, not 17."""
    e = estimates(method="mean", window=3)
    for seconds in (20.0, 18.0, 16.0, 14.0):
        e.record_travel(1, 2, seconds)
    assert e.travel_samples(1, 2) == (18.0, 16.0, 14.0)
    assert e.travel(1, 2) == 16.0


def test_memory_per_key_is_bounded():
    e = estimates(window=50)
    for n in range(1000):
        e.record_dwell(1, "Put", 10.0 + n % 7)
    assert len(e.dwell_samples(1, "Put")) == 50


def test_the_keys_kept_are_the_most_recently_recorded():
    """Travel is learned from wherever a vehicle took an order: on a large plant nearly
    every (node, station) pair could become a key. Past ``keys`` of them, the one recorded
    longest ago is forgotten and priced by the fallback again."""
    e = estimates(keys=2)
    e.record_travel(1, 2, 50.0)
    e.record_travel(2, 3, 30.0)
    e.record_travel(1, 2, 52.0)  # (1, 2) recorded again: now (2, 3) is the oldest
    e.record_dwell(5, "Get", 9.0)  # a third key: (2, 3) goes
    assert e.travel_samples(2, 3) == ()
    assert e.travel(2, 3) == pytest.approx(15.0 / e.mean_speed)  # the fallback again
    assert e.travel_samples(1, 2) == (50.0, 52.0) and e.travel(1, 2) == 51.0
    assert e.dwell(5, "Get") == 9.0
    e.record_travel(2, 3, 33.0)  # driven anew: learned from its new sample alone
    assert e.travel(2, 3) == 33.0 and e.travel_samples(1, 2) == ()
    assert e.dwell_samples(5, "Get") == (9.0,)


def test_an_outlier_counts_as_a_record_of_its_key():
    """A key whose samples are refused as outliers is still driven: it is not the one to
    forget."""
    e = estimates(keys=2)
    for seconds in (10.0, 10.0, 10.0):
        e.record_travel(1, 2, seconds)
    e.record_travel(2, 3, 30.0)
    assert not e.record_travel(1, 2, 100.0)  # refused, but (2, 3) is now the oldest
    e.record_travel(2, 1, 40.0)
    assert e.travel_samples(1, 2) == (10.0, 10.0, 10.0) and e.travel_samples(2, 3) == ()


@pytest.mark.parametrize(
    ("now", "expected"),
    [(229.0, False), (230.0, False), (231.0, True), (100.0, False), (-31.0, True)],
)
def test_deviation_trigger_at_30_percent(now, expected):
    """Planned start 100 s, estimated 100 s: 129 s elapsed is 29 %, 131 s is 31 % over."""
    assert SectionEstimates.deviates(100.0, 100.0, now) is expected


def test_deviation_threshold_and_zero_estimate():
    e = estimates()
    assert e.deviates(0.0, 10.0, 14.0, threshold=0.5) is False
    assert e.deviates(0.0, 10.0, 16.0, threshold=0.5) is True
    assert e.deviates(5.0, 0.0, 5.0) is False
    assert e.deviates(5.0, 0.0, 5.5) is True


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda e: e.record_travel(1, 2, -1.0), "record_travel: seconds must be a finite number"),
        (lambda e: e.record_travel(1, 2, math.nan), "seconds must be a finite number >= 0"),
        (lambda e: e.record_dwell(1, "Put", math.inf), "record_dwell: seconds must be"),
        (lambda e: e.record_dwell(1, "Drop", 5.0), "kind must be 'Get' or 'Put', got 'Drop'"),
        (lambda e: e.dwell(1, "get"), "dwell: kind must be 'Get' or 'Put'"),
        (lambda e: e.deviates(0.0, -1.0, 5.0), "deviates: estimated_s must be a finite number"),
        (lambda e: e.deviates(math.nan, 1.0, 5.0), "deviates: planned_start_s must be"),
        (lambda e: e.deviates(0.0, 1.0, 5.0, threshold=-0.1), "threshold must be"),
    ],
)
def test_bad_samples_and_queries_are_rejected(call, message):
    e = estimates()
    with pytest.raises(ValueError, match=message):
        call(e)
    assert e.ignored == 0 and e.travel_samples(1, 2) == () and e.dwell_samples(1, "Put") == ()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"dwell_default_s": -1.0}, "dwell_default_s must be a finite number >= 0"),
        ({"outlier": 1.0}, "outlier must be a number > 1, got 1.0"),
        ({"outlier": math.nan}, "outlier must be a number > 1"),
        ({"method": "mode"}, "method must be 'median' or 'mean', got 'mode'"),
        ({"window": 0}, "window must be an integer >= 1, got 0"),
        ({"window": 2.5}, "window must be an integer"),
        ({"keys": 0}, "keys must be an integer >= 1, got 0"),
        ({"keys": True}, "keys must be an integer >= 1, got True"),
        ({"distance": 20.0}, "distance must be callable"),
        ({"mean_speed": 0.0}, "mean_speed must be > 0 m/s, got 0"),
        ({"mean_speed": -1.0}, "mean_speed must be a finite number >= 0"),
    ],
)
def test_bad_configuration_is_rejected(kwargs, message):
    arguments = {"distance": distance, "dwell_default_s": 12.0, **kwargs}
    with pytest.raises(ValueError, match=message):
        SectionEstimates(**arguments)


def test_outlier_rule_can_be_switched_off():
    e = estimates(outlier=math.inf)
    for seconds in (10.0, 10.0, 10.0, 1e6):
        assert e.record_travel(1, 2, seconds)
    assert e.ignored == 0
