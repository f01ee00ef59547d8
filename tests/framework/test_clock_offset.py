"""Spec: another host's clock offset is measured as an interval that holds the truth,
so a peer's stamp never looks fresher than it is."""

import math

from hypothesis import given
from hypothesis import strategies as st

from framework.clock_offset import DRIFT, Exchange, OffsetEstimate

delays = st.floats(0.0, 0.05)  # one way, s
offsets = st.floats(-1.0, 1.0)  # the peer's clock minus ours at time 0, s
rates = st.floats(-DRIFT, DRIFT)  # how fast it drifts


def asked_of(offset, rate, asked, there, back):
    """An exchange with a peer whose clock reads `t + offset + rate * t` at our `t`."""
    read = asked + there
    return Exchange(asked, read + offset + rate * read, read + back)


@given(
    offset=offsets,
    rate=rates,
    trips=st.lists(st.tuples(st.floats(0.1, 2.0), delays, delays), min_size=1, max_size=20),
    later=st.floats(0.0, 30.0),
    sent_ago=st.floats(0.0, 0.5),
)
def test_the_interval_holds_the_true_offset_and_ages_are_never_too_young(
    offset, rate, trips, later, sent_ago
):
    estimate = OffsetEstimate()
    t = 0.0
    for gap, there, back in trips:
        t += gap
        assert estimate.add(asked_of(offset, rate, t, there, back))
        t += there + back
    now = t + later
    low, high = estimate.interval(now)
    truth = offset + rate * now
    assert low - 1e-9 <= truth <= high + 1e-9
    # a sample the peer stamped `sent_ago` s before our `now`, by its own clock
    made = now - sent_ago
    stamp = made + offset + rate * made
    assert estimate.age(stamp, now) >= sent_ago - 1e-9


def test_the_narrowest_round_trip_sets_the_interval():
    estimate = OffsetEstimate(drift=0.0)
    estimate.add(Exchange(0.0, 10.050, 0.040))  # 40 ms round trip
    estimate.add(Exchange(1.0, 11.0502, 1.0004))  # 0.4 ms
    low, high = estimate.interval(2.0)
    assert high - low <= 0.0004 + 1e-9
    assert math.isclose(estimate.local_time(20.05, 2.0), 10.0, abs_tol=0.0003)


def test_a_stepped_clock_restarts_the_estimate_from_the_newest_exchange():
    estimate = OffsetEstimate()
    estimate.add(Exchange(0.0, 0.0505, 0.001))  # +50 ms
    estimate.add(Exchange(1.0, 0.9505, 1.001))  # stepped to -50 ms
    low, high = estimate.interval(1.001)
    assert low <= -0.0495 <= high and high < 0


def test_unmeasured_there_is_no_age_and_impossible_exchanges_are_refused():
    estimate = OffsetEstimate()
    assert estimate.age(0.0, 1.0) is None and estimate.local_time(0.0, 1.0) is None
    assert not estimate.add(Exchange(2.0, 5.0, 1.0))  # answered before asked
    assert not estimate.add(Exchange(0.0, math.nan, 1.0))
    assert estimate.refused == 2 and not estimate.measured
