"""Spec: another host's clock is measured over the bus as an interval that holds its
real offset. The other host is a real process whose wall clock is set apart
(tests/support/clock_apart.py: the clock the process reads, as on a host set
differently)."""

import json
import os
import subprocess
import sys
import time

import pytest

from framework.peer_clocks import PeerClocks
from tests.conftest import REPO, wait_until
from tests.support import clock_apart

PEER = """
import json, sys, time
from framework.bus import Bus, BusConfig
from framework.peer_clocks import answer_clock
bus = Bus(BusConfig.from_dict(json.loads(sys.argv[1])))
answering = answer_clock(bus, "cameras")
print("up", flush=True)
sys.stdin.read()
answering.undeclare()
bus.close()
"""


@pytest.mark.skipif(clock_apart.library() is None, reason=clock_apart.MISSING)
@pytest.mark.parametrize("offset", [0.05, -0.05])
def test_a_host_whose_clock_is_off_by_50_ms_is_measured_so(hub, bus_config, offset):
    env = dict(os.environ, **clock_apart.environment(offset))
    peer = subprocess.Popen(
        [sys.executable, "-c", PEER, json.dumps(bus_config.to_dict())],
        cwd=REPO,
        env=env,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert peer.stdout.readline().strip() == "up"
        clocks = PeerClocks(hub, {"cameras": "cameras"})
        assert wait_until(lambda: clocks.measure("cameras"), 10), "the peer never answered"
        for _ in range(4):
            clocks.measure("cameras")
        estimate = clocks.of("cameras")
        low, high = estimate.interval(time.time())
        assert low <= offset <= high, (low, high)
        assert (low > 0) == (offset > 0) and (high < 0) == (offset < 0), (
            "ahead and behind told apart"
        )
    finally:
        peer.stdin.close()
        peer.wait(10)


def test_a_peer_that_never_answers_leaves_its_clock_unmeasured(hub):
    clocks = PeerClocks(hub, {"cameras": "cameras"})
    assert not clocks.measure("cameras")
    assert clocks.unanswered["cameras"] == 1
    assert clocks.of("cameras").age(0.0, 1.0) is None
