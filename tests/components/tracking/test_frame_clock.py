"""Spec: a frame's capture time from the device's frame counter, whatever the delays."""

from hypothesis import given
from hypothesis import strategies as st

from components.tracking.frame_clock import FrameClock

RATE = 20.0
ORIGIN = 1_800_000_000.0  # when the device's counter was 0, on the host's clock


def replies(draw_delays, quick_every: int = 0):
    """(frame, asked, arrived) for frames captured at ORIGIN + k/RATE, each asked for
    just before its capture and held `delay` s after it."""
    for k, delay in enumerate(draw_delays):
        if quick_every and k % quick_every == 0:
            delay = 0.001
        captured = ORIGIN + k / RATE
        yield k, captured - 0.0005, captured + delay


delays = st.lists(st.floats(0.0005, 3.0), min_size=1, max_size=300)


@given(delays)
def test_a_stamp_lies_between_one_frame_before_the_request_and_the_arrival(held):
    clock = FrameClock(RATE)
    for frame, asked, arrived in replies(held):
        stamp = clock.stamp(frame, asked, arrived)
        assert asked - 1.0 / RATE <= stamp <= arrived


@given(delays)
def test_one_quick_reply_in_the_window_gives_every_later_frame_its_capture_time(held):
    """A reply held for seconds is stamped within the quickest reply's delay (1 ms),
    whatever fraction of a second the quick replies' frames fall on."""
    clock = FrameClock(RATE, window=10.0)
    for frame, asked, arrived in replies(held, quick_every=37):  # one quick per 1.85 s
        stamp = clock.stamp(frame, asked, arrived)
        assert abs(stamp - (ORIGIN + frame / RATE)) <= 0.001 + 1e-6


def test_a_counter_that_starts_again_is_followed():
    clock = FrameClock(RATE)
    for k in range(40):
        clock.stamp(k, ORIGIN + k / RATE, ORIGIN + k / RATE + 0.001)
    later = ORIGIN + 5.0  # INIT: the counter is 0 again, 5 s on (inside the window)
    assert abs(clock.stamp(0, later - 0.0005, later + 0.001) - (later + 0.001)) < 1e-9
    held = later + 3 / RATE
    assert abs(clock.stamp(3, held - 0.0005, held + 0.8) - held) <= 0.001 + 1e-6


def test_a_device_clock_that_drifts_is_followed_through_the_window():
    """A crystal 100 ppm slow: over an hour the counter falls 0.36 s behind the host;
    the stamps stay within a millisecond of the truth."""
    clock = FrameClock(RATE, window=10.0)
    worst = 0.0
    for k in range(0, 72_000, 7):  # an hour at 20 Hz
        captured = ORIGIN + k / (RATE * 0.9999)
        delay = 0.001 if k % 5 == 0 else 0.4
        stamp = clock.stamp(k, captured - 0.0005, captured + delay)
        worst = max(worst, abs(stamp - captured))
    assert worst < 0.002, worst


def test_the_same_frame_twice_is_not_a_counter_that_started_again():
    """Asked twice within one frame, the device sends the same number twice."""
    clock = FrameClock(RATE)
    for k in range(10):
        clock.stamp(k, ORIGIN + k / RATE, ORIGIN + k / RATE + 0.001)
    again = ORIGIN + 10 / RATE
    clock.stamp(10, again, again + 0.001)
    assert abs(clock.stamp(10, again + 0.01, again + 0.7) - again) <= 0.001 + 1e-9


def test_a_counter_slower_than_declared_is_held_at_one_frame_before_the_request():
    """A device counting at 10 Hz, declared 20 Hz: the estimate falls behind, and the
    stamp stays at the earliest its request allows, never earlier."""
    clock = FrameClock(RATE)
    stamps = []
    for k in range(100):
        captured = ORIGIN + k / 10.0
        asked = captured - 0.0005
        stamps.append((clock.stamp(k, asked, captured + 0.001), asked))
    assert all(stamp >= asked - 1.0 / RATE - 1e-9 for stamp, asked in stamps)
    assert abs(stamps[-1][0] - (stamps[-1][1] - 1.0 / RATE)) < 1e-9


def test_the_quickest_reply_sets_the_clock_whatever_frame_it_was():
    """30 s of replies held 0.4 s, but for two quick ones at frames 250 and 251 (12.5 s
    in, mid-second): every frame arriving within the window after them is stamped
    within 1 ms."""
    clock = FrameClock(RATE)
    for k in range(600):
        captured = ORIGIN + k / RATE
        delay = 0.001 if k in (250, 251) else 0.4
        stamp = clock.stamp(k, captured - 0.0005, captured + delay)
        quick = ORIGIN + 251 / RATE + 0.001  # the newest quick arrival
        if k >= 251 and captured + delay <= quick + 10.0:  # it is still in the window
            assert abs(stamp - captured) <= 0.001 + 1e-9, k


def test_a_quick_reply_older_than_ten_seconds_no_longer_sets_the_clock():
    """The window is 10 s by default: a device clock that drifts is followed from what
    its recent replies say. A frame 10.5 s after the last quick reply, held 0.3 s on
    the line, is stamped from its own reply (the only recent one), not from the quick
    reply that has left the window."""
    clock = FrameClock(RATE)
    clock.stamp(0, ORIGIN - 0.0005, ORIGIN + 0.001)
    frame = 210  # 10.5 s later
    captured = ORIGIN + frame / RATE
    stamp = clock.stamp(frame, captured - 0.0005, captured + 0.3)
    assert stamp == captured + 0.3  # the one bound left: this reply's own arrival
