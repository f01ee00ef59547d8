"""Spec: the cost bench's cycle intervals count each state for the arm cycles it covers
(braked, the arm reports every 10 cycles), so monitor mode is not read as jitter."""

import pytest

from framework.messages import ArmState
from fw_bench.cost import cycle_intervals


def state(cycle, stamp):
    return ArmState(stamp=stamp, cycle=cycle)


def test_an_interval_is_divided_by_the_cycles_it_covers():
    states = [state(10, 0.0), state(20, 0.0105), state(21, 0.0115), state(22, 0.0140)]
    assert cycle_intervals(states) == pytest.approx([1.05, 1.0, 2.5])


def test_repeated_or_reordered_states_are_skipped():
    assert cycle_intervals([state(5, 0.0), state(5, 0.001), state(4, 0.002)]) == []
