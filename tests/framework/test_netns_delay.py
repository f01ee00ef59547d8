"""Spec: the delaying wire of framework/netns_delay.py on a simulated clock: a frame the
host sends leaves after its delay, never more than the jitter off it and never before
the one sent before it; a lossy wire loses about the share asked; with no delay a
frame is due at once; a TAP that gives an error says so (the wire waits instead of
spinning) and one whose device is gone ends the wire. (Over real TAP devices:
tests/framework/test_netns.py.)"""

import errno
import os
import random

import pytest
from hypothesis import given
from hypothesis import strategies as st

from framework import netns_delay
from framework.netns_delay import Wire


class Clock:
    """A clock the spec moves."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


@given(
    delay=st.floats(0.0, 0.2),
    jitter=st.floats(0.0, 0.05),
    gaps=st.lists(st.floats(0.0, 0.01), min_size=1, max_size=60),
    seed=st.integers(0, 2**32 - 1),
)
def test_frames_leave_after_their_delay_within_the_jitter_and_in_the_order_sent(
    delay, jitter, gaps, seed
):
    clock, draws = Clock(), random.Random(seed)
    wire = Wire(delay, jitter, now=clock, draw=draws.random)
    sent, left = {}, []
    # frames whose bytes fall as they are sent: equal times must not be ordered by content
    frame, number = (
        (lambda k: (60000 - k).to_bytes(2, "big")),
        (lambda f: 60000 - int.from_bytes(f, "big")),
    )

    def run_until(t):
        """Carry frames as the wire's loop does: at each frame's time, until `t`."""
        while wire.next_in() is not None and clock.t + wire.next_in() <= t:
            clock.t += wire.next_in()
            left.extend((number(f), clock.t) for f in wire.due())
        clock.t = t

    for k, gap in enumerate(gaps):
        run_until(clock.t + gap)
        sent[k] = clock.t
        wire.send(frame(k))
        left.extend((number(f), clock.t) for f in wire.due())
    run_until(clock.t + delay + jitter + 1.0)
    assert [k for k, _ in left] == list(range(len(gaps))), "every frame, in the order sent"
    for k, t in left:
        assert t >= sent[k] + delay - jitter - 1e-12, "never sooner than the delay allows"
    # a frame waits its own delay (at most delay + jitter) or for the one before it
    previous = -1.0
    for k, t in left:
        assert t <= max(sent[k] + delay + jitter, previous) + 1e-9
        previous = t


def test_a_lossy_wire_loses_about_the_share_asked_either_way():
    clock, draws = Clock(), random.Random(7)
    wire = Wire(0.0, loss=0.3, now=clock, draw=draws.random)
    for _ in range(2000):
        wire.send(b"x")
    through = len(wire.due())
    lost_back = sum(wire.lost() for _ in range(2000))
    # five standard deviations of 2000 draws at 30%
    assert 1300 <= through <= 1500 and 500 <= lost_back <= 700
    assert wire.dropped == (2000 - through) + lost_back


def test_without_delay_a_frame_is_due_at_once_and_none_waits_after():
    wire = Wire(0.0, now=Clock())
    wire.send(b"a")
    assert wire.next_in() == 0.0
    assert wire.due() == [b"a"] and wire.next_in() is None


def failing_read(code):
    def read(fd, size):
        raise OSError(code, os.strerror(code))

    return read


def test_a_tap_whose_device_is_down_is_a_failed_read_not_a_frame(monkeypatch):
    monkeypatch.setattr(netns_delay.os, "read", failing_read(errno.EIO))
    assert netns_delay._drain(3) == ([], True)
    monkeypatch.setattr(netns_delay.os, "read", failing_read(errno.EAGAIN))
    assert netns_delay._drain(3) == ([], False), "nothing queued is not a failure"


@pytest.mark.parametrize("code", netns_delay.GONE)
def test_a_tap_whose_device_is_gone_ends_the_wire(monkeypatch, code):
    monkeypatch.setattr(netns_delay.os, "read", failing_read(code))
    with pytest.raises(SystemExit):
        netns_delay._drain(3)
