"""Spec: the cost bench's cycle intervals count each state for the arm cycles it covers
(braked, the arm reports every 10 cycles), so monitor mode is not read as jitter; its
margin rows name the watch nearest its deadline and count every trip of a healthy run
as a false one."""

import pytest

from framework.messages import ArmState
from fw_bench.cost import cycle_intervals, tightest_watch
from fw_bench.experiments import _margin_rows


def state(cycle, stamp):
    return ArmState(stamp=stamp, cycle=cycle)


def test_an_interval_is_divided_by_the_cycles_it_covers():
    states = [state(10, 0.0), state(20, 0.0105), state(21, 0.0115), state(22, 0.0140)]
    assert cycle_intervals(states) == pytest.approx([1.05, 1.0, 2.5])


def test_repeated_or_reordered_states_are_skipped():
    assert cycle_intervals([state(5, 0.0), state(5, 0.001), state(4, 0.002)]) == []


SAFETY = {
    "trips": 0,
    "watches": {
        "supervisor": {"age_ms": 3.0, "worst_ms": 35.0, "deadline_ms": 50.0},
        "kinect_0.users": {"age_ms": 9.0, "worst_ms": 120.0, "deadline_ms": 200.0},
        "process cameras": {"age_ms": 1.0, "worst_ms": 41.0, "deadline_ms": 50.0},
        "process robot": {"age_ms": 0.0, "worst_ms": 0.0, "deadline_ms": 50.0},
    },
}


def test_the_tightest_watch_is_the_one_nearest_its_deadline_not_the_longest_silence():
    assert tightest_watch(SAFETY) == ("process cameras", 41.0, 50.0)
    assert tightest_watch({"watches": {}}) is None


def test_a_healthy_run_is_met_with_no_trip_and_every_silence_within_its_deadline():
    trips, margin = _margin_rows("moving", SAFETY)
    assert (trips.fw, trips.met) == (0.0, True)
    assert (margin.fw, margin.target, margin.met) == (41.0, 50.0, True)
    assert "process cameras" in margin.quantity


def test_a_false_trip_or_a_silence_past_its_deadline_is_missed():
    late = {**SAFETY, "trips": 2}
    late["watches"] = {**SAFETY["watches"], "supervisor": {"worst_ms": 61.0, "deadline_ms": 50.0}}
    trips, margin = _margin_rows("moving", late)
    assert not trips.met and trips.fw == 2.0
    assert not margin.met and "supervisor" in margin.quantity
    assert _margin_rows("moving", {}) == []
