"""Spec: speed and separation monitoring. The protective distance grows with the
robot's speed and the envelope's age; the speed it allows is the largest that keeps
it; the cap slows the arm down as people approach and is 0 where standing is the only
safe speed; the stop is said exactly when the separation is under the protective
distance. What it is for (a person walking at the arm never reaches it while it moves)
is tests/components/domain/test_separation_walking.py: a slow property of its own, so
mutation testing can run these fast specs first.

Every spec runs twice: on the compiled kernel's monitor (what the robot's loop runs) and
on the Python one (the reference, which mutation testing mutates); and a property holds
the kernel's verdicts to the reference's over random motions, crowds and clocks
(tests/components/domain/test_kernel.py)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from components.domain.kernel import COMPILED
from components.domain.separation import (
    CLEAR,
    FASTEST_LINK,
    MAX_QUIET,
    SeparationMonitor,
    SsmParams,
    Verdict,
    link_speed,
)

P = SsmParams()


@pytest.fixture(autouse=True, params=["kernel", "python"])
def monitors(request, monkeypatch):
    """Monitors built in a spec run the kernel, then the Python reference."""
    if request.param == "kernel" and not COMPILED:
        pytest.skip("the compiled kernel was not built (pip install -e .)")
    monkeypatch.setattr(SeparationMonitor, "COMPILED", request.param == "kernel")
    assert SeparationMonitor(P, 0.075).compiled == (request.param == "kernel")
    assert SeparationMonitor(P, 0.075, compiled=False).compiled is False
    assert SeparationMonitor(P, 0.075, compiled=True).compiled is COMPILED
    return request.param


speeds = st.floats(0.0, 0.25)
ages = st.floats(0.0, 0.5)
separations = st.floats(-0.5, 3.0)


def arm(x=0.0):
    """One link capsule along z at x (radius 0.05)."""
    return np.array([[x, 0.0, 0.0]]), np.array([[x, 0.0, 0.5]]), np.array([0.05])


def person(x):
    """A torso capsule along z at x (radius 0.15)."""
    return np.array([[x, 0.0, 0.0]]), np.array([[x, 0.0, 0.5]]), np.array([0.15])


def test_the_protective_distance_spells_out_its_terms():
    """v_h (T_r + T_s) + v_r T_r + S_s + C + Z_d + Z_r, with T_r = age + reaction."""
    v, age = 0.075, 0.05
    t_r, t_s = age + P.reaction, P.engage + v / P.deceleration
    s_s = v * P.engage + v * v / (2 * P.deceleration)
    expected = 1.6 * (t_r + t_s) + v * t_r + s_s + 0.0 + 0.02 + 0.005
    assert P.protective_distance(v, age) == pytest.approx(expected, rel=1e-12)


@given(v1=speeds, v2=speeds, age1=ages, age2=ages)
def test_faster_or_older_needs_more_room(v1, v2, age1, age2):
    if v1 <= v2 and age1 <= age2:
        assert P.protective_distance(v1, age1) <= P.protective_distance(v2, age2)


@given(separation=separations, age=ages)
def test_the_allowed_speed_is_the_largest_that_keeps_the_protective_distance(separation, age):
    v = P.allowed_speed(separation, age)
    assert v >= 0.0
    if P.protective_distance(0.0, age) > separation:
        assert v == 0.0, "too close even to stand: no speed is allowed"
    else:
        assert P.protective_distance(v, age) == pytest.approx(separation, abs=1e-9)
        assert P.protective_distance(v * 1.001 + 1e-9, age) > separation


@settings(max_examples=200)
@given(gap=st.floats(-0.2, 2.5), age=ages, v=st.floats(0.0, 0.1))
def test_stop_exactly_when_closer_than_the_protective_distance(gap, age, v):
    monitor = SeparationMonitor(P, max_speed=0.075)
    monitor.check(arm(0.0), person(5.0), age, now=0.0)
    verdict = monitor.check(arm(v * 0.001), person(v * 0.001 + 0.2 + gap), age, now=0.001)
    assert verdict.separation == pytest.approx(gap, abs=1e-9)
    assert verdict.robot_speed == pytest.approx(v, abs=1e-6)
    assert verdict.protective == pytest.approx(P.protective_distance(verdict.robot_speed, age))
    assert verdict.stop is (verdict.separation < verdict.protective)


@given(near=st.floats(0.0, 1.5), far=st.floats(0.0, 1.5), age=ages)
def test_the_cap_falls_as_people_approach_and_is_zero_where_only_standing_is_safe(near, far, age):
    near, far = sorted((near, far))
    monitor = SeparationMonitor(P, max_speed=0.075)
    cap_near = monitor.check(arm(), person(0.2 + near), age, 0.0).cap
    cap_far = monitor.check(arm(), person(0.2 + far), age, 0.0).cap
    assert 0.0 <= cap_near <= cap_far
    if near <= P.protective_distance(0.0, age):
        assert cap_near == 0.0
    if near >= P.protective_distance(0.0, age) + P.slow_band:
        assert cap_near == math.inf, "far from everyone: no cap"


@given(gap=st.floats(0.0, 1.0), age=ages, ahead=st.floats(0.0, 0.1), v=st.floats(0.0, 0.1))
def test_a_cap_for_the_age_the_envelope_will_have_holds_until_then_and_never_above(
    gap, age, ahead, v
):
    """The cap for an envelope `cap_age` old is the one of that age, for any age it has
    until then never above the cap of its true age; the stop is still judged at its
    true age (a cap looking ahead never delays a stop)."""

    def verdict(at_age, cap_age=0.0):
        monitor = SeparationMonitor(P, max_speed=0.075)
        monitor.check(arm(0.0), person(5.0), at_age, now=0.0)
        return monitor.check(arm(v * 0.001), person(0.2 + gap), at_age, 0.001, cap_age)

    ahead_of_time = verdict(age, age + ahead)
    assert ahead_of_time.cap == verdict(age + ahead).cap
    assert ahead_of_time.cap <= verdict(age).cap
    assert (ahead_of_time.stop, ahead_of_time.protective) == (
        verdict(age).stop,
        verdict(age).protective,
    )
    assert verdict(age, age - 0.01).cap == verdict(age).cap, "never for a younger one"


def test_nobody_in_the_room_is_no_constraint():
    verdict = SeparationMonitor(P, 0.075).check(arm(), None, 0.0, 0.0)
    assert verdict.separation == math.inf and verdict.cap == math.inf and not verdict.stop


@settings(max_examples=200)
@given(gap=st.floats(0.0, 3.0), age=ages, dt=st.sampled_from([0.001, 0.002]))
def test_a_far_person_need_not_be_checked_every_cycle_but_nothing_is_missed(gap, age, dt):
    """Between checks the person closes in at v_h and the envelope ages; the robot at
    the fastest link speed. After the quiet cycles, the verdict is still no stop and
    no cap: skipping them changed nothing."""
    monitor = SeparationMonitor(P, max_speed=0.075)
    verdict = monitor.check(arm(), person(0.2 + gap), age, 0.0)
    quiet = monitor.quiet_cycles(verdict, age, dt)
    assert 0 <= quiet <= 100
    if quiet == 0:
        return
    skipped = quiet * dt  # simulated seconds without a check (no clock is read here)
    closed = (P.person_speed + 0.25) * skipped
    later = SeparationMonitor(P, max_speed=0.075)
    aged = age + skipped
    worst = later.check(arm(), person(0.2 + gap - closed), aged, 0.0)
    assert not worst.stop and worst.cap == math.inf
    assert P.protective_distance(0.25, aged) <= worst.separation


def test_nobody_or_someone_within_the_band_is_checked_every_cycle():
    monitor = SeparationMonitor(P, max_speed=0.075)
    assert monitor.quiet_cycles(monitor.check(arm(), None, 0.0, 0.0), 0.0, 0.001) == 0
    close = monitor.check(arm(), person(0.2 + P.protective_distance(0.0, 0.0) + 0.1), 0.0, 0.0)
    assert monitor.quiet_cycles(close, 0.0, 0.001) == 0


@given(v=st.floats(0.0, 0.25), jolt=st.floats(0.0, 0.001))
def test_the_robot_speed_is_its_links_displacement_over_ten_milliseconds(v, jolt):
    """Steady motion reads as its speed; a one-cycle settling jolt (brakes released)
    reads as that displacement over 10 ms, not over 1 ms."""
    monitor = SeparationMonitor(P, max_speed=0.075)
    x = 0.0
    for cycle in range(30):
        speed = monitor.robot_speed(*arm(x)[:2], now=cycle * 0.001)
        x += v * 0.001
    assert speed == pytest.approx(v, rel=1e-6, abs=1e-9)
    still = SeparationMonitor(P, max_speed=0.075)
    for cycle in range(30):
        speed = still.robot_speed(*arm(jolt if cycle >= 29 else 0.0)[:2], now=cycle * 0.001)
    assert speed == pytest.approx(jolt / 0.01, abs=1e-9)


# -- what mutation testing found unpinned (tools/mutation.py) ------------------------------
def test_the_terms_have_their_documented_values():
    """docs/safety.md's table: v_h, the robot's reaction, the brakes' engagement, the
    stop's deceleration, C, Z_d, Z_r and the slowing band."""
    assert (P.person_speed, P.reaction, P.engage, P.deceleration) == (1.6, 0.002, 0.010, 2.0)
    assert (P.intrusion, P.detection_uncertainty, P.robot_uncertainty) == (0.0, 0.02, 0.005)
    assert P.slow_band == 0.4
    with pytest.raises(AttributeError):
        P.person_speed = 1.0  # one set of terms for the whole run


@pytest.mark.parametrize("deceleration", [1.0, 3.0, 5.0])
def test_stopping_takes_the_brakes_engagement_then_the_deceleration(deceleration):
    p = SsmParams(deceleration=deceleration, intrusion=0.1)
    v = 0.2
    assert p.stopping_time(v) == pytest.approx(0.010 + v / deceleration)
    assert p.stopping_distance(v) == pytest.approx(v * 0.010 + v * v / (2 * deceleration))
    assert p.protective_distance(v, 0.0) == pytest.approx(
        1.6 * (0.002 + p.stopping_time(v)) + v * 0.002 + p.stopping_distance(v) + 0.1 + 0.025
    ), "C adds"
    allowed = p.allowed_speed(0.5, 0.03)
    assert p.protective_distance(allowed, 0.03) == pytest.approx(0.5)


def test_an_envelope_from_the_future_counts_as_fresh_not_as_time_in_hand():
    """A clock step between the cameras and the robot must never shrink S_p."""
    assert P.protective_distance(0.1, -0.5) == P.protective_distance(0.1, 0.0)
    assert P.allowed_speed(0.5, -0.5) == P.allowed_speed(0.5, 0.0)


def test_the_cap_as_a_tool_speed_shrinks_by_the_tools_share_of_the_fastest_point():
    def verdict(cap, robot, tcp):
        return Verdict(1.0, robot, 0.5, cap, False, tcp)

    assert verdict(0.05, 0.1, 0.05).tcp_cap == pytest.approx(0.025), "an elbow twice as fast"
    assert verdict(0.05, 0.1, 0.1).tcp_cap == pytest.approx(0.05)
    assert verdict(0.05, 0.1, 0.2).tcp_cap == pytest.approx(0.05), "never above the cap"
    assert verdict(0.05, 0.1, 0.0).tcp_cap == 0.05, "a tool standing still: the cap itself"
    assert verdict(math.inf, 0.1, 0.05).tcp_cap == math.inf, "no cap stays none"
    assert verdict(0.0, 0.1, 0.05).tcp_cap == 0.0
    with pytest.raises(AttributeError):
        verdict(0.05, 0.1, 0.05).stop = True


def test_clear_is_nobody_in_the_room():
    assert Verdict(math.inf, 0.0, 0.0, math.inf, False, 0.0) == CLEAR
    empty = np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)
    monitor = SeparationMonitor(P, 0.075)
    assert monitor.check(arm(), empty, 0.0, 0.0) == CLEAR, "no capsule is nobody"
    assert monitor.check(arm(), None, 0.0, 0.001) == CLEAR
    assert monitor.tcp_speed == 0.0


def test_a_links_speed_is_its_fastest_capsule_end():
    before = (
        np.array([[1.0, 2.0, 3.0], [0.5, 0.5, 0.5]]),
        np.array([[1.0, 2.0, 4.0], [2.0, 2.0, 2.0]]),
    )
    after = (
        before[0] + [[0.003, 0.004, 0.0], [0.0, 0.0, 0.0]],
        before[1] + [[0, 0, 0], [0, 0.002, 0]],
    )
    assert link_speed(before, after, 0.01) == pytest.approx(0.5), "5 mm of the first a"
    after = before[0], before[1] - np.array([[0.0, 0.0, 0.0], [0.0036, 0.0048, 0.0]])
    assert link_speed(before, after, 0.01) == pytest.approx(0.6), "6 mm of the second b"


def test_the_tool_speed_is_the_last_capsules_end_over_the_same_window():
    monitor = SeparationMonitor(P, 0.075)
    assert monitor.tcp_speed == 0.0, "before any sample"
    a, b = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.5]]), np.array([[0.0, 0.0, 0.5], [0.3, 0, 0.5]])
    assert monitor.robot_speed(a, b, now=2.0) == 0.0 and monitor.tcp_speed == 0.0, "first"
    moved = b + np.array([[0.0, 0.0, 0.0], [0.0, 0.0005, 0.0]])
    elbow = a + np.array([[0.0, 0.0, 0.0], [0.001, 0.0, 0.0]])
    assert monitor.robot_speed(elbow, moved, now=2.001) == pytest.approx(1.0)
    assert monitor.tcp_speed == pytest.approx(0.5), "the tool's 0.5 mm in that millisecond"


def test_a_clock_that_steps_back_gives_no_speed_rather_than_a_negative_one():
    monitor = SeparationMonitor(P, 0.075)
    monitor.robot_speed(*arm(0.0)[:2], now=1.0)
    assert monitor.robot_speed(*arm(0.01)[:2], now=0.5) == 0.0
    assert monitor.tcp_speed == 0.0
    stepped = SeparationMonitor(P, 0.075)  # back, but not beyond the window's base
    stepped.robot_speed(*arm(0.0)[:2], now=1.0)
    stepped.robot_speed(*arm(0.002)[:2], now=1.008)
    assert stepped.robot_speed(*arm(0.001)[:2], now=1.004) == pytest.approx(0.25)


def test_the_speed_window_drops_samples_older_than_ten_milliseconds_but_keeps_one():
    """Samples every 4 ms: the base of the speed is the newest one at least 10 ms old."""
    monitor = SeparationMonitor(P, 0.075)
    positions = {0.0: 0.0, 0.004: 0.0, 0.008: 0.001, 0.012: 0.002, 0.016: 0.002}
    speeds = [monitor.robot_speed(*arm(x)[:2], now=t) for t, x in positions.items()]
    # at 0.016 the base is 0.004 (0.012 ms old), not 0.0 (0.016 old): 2 mm in 12 ms
    assert speeds[-1] == pytest.approx(0.002 / 0.012)
    assert speeds[3] == pytest.approx(0.002 / 0.012), "at 0.012 the base is 0.0"
    sparse = SeparationMonitor(P, 0.075)  # one sample in the window: the one before it
    for t, x in ((0.0, 0.0), (0.02, 0.0)):
        sparse.robot_speed(*arm(x)[:2], now=t)
    assert sparse.robot_speed(*arm(0.002)[:2], now=0.04) == pytest.approx(0.1)
    exact = SeparationMonitor(P, 0.075)  # a sample exactly 10 ms old is the base
    for t, x in ((-0.02, 0.0), (0.0, 0.001)):
        exact.robot_speed(*arm(x)[:2], now=t)
    assert exact.robot_speed(*arm(0.002)[:2], now=0.01) == pytest.approx(0.1)


def test_the_cap_is_the_slowing_band_or_the_allowed_speed_whichever_is_lower():
    monitor = SeparationMonitor(P, max_speed=0.075)
    age = 0.03
    standing = P.protective_distance(0.0, age)
    for into_band in (0.0, 0.1, 0.2, 0.35, 0.399):
        gap = standing + into_band
        verdict = monitor.check(arm(), person(0.2 + gap), age, 0.0)
        expected = min(0.075 * into_band / 0.4, P.allowed_speed(verdict.separation, age))
        assert verdict.cap == pytest.approx(expected, abs=1e-9), into_band
        assert verdict.protective == pytest.approx(P.protective_distance(0.0, age))
    beyond = monitor.check(arm(), person(0.2 + standing + 0.41), age, 0.0)
    assert beyond.cap == math.inf


def test_without_a_slowing_band_the_cap_is_the_allowed_speed_alone():
    p = SsmParams(slow_band=0.0)
    monitor = SeparationMonitor(p, max_speed=0.075)
    standing = p.protective_distance(0.0, 0.0)
    near = monitor.check(arm(), person(0.2 + standing + 0.01), 0.0, 0.0)
    assert near.cap == pytest.approx(p.allowed_speed(near.separation, 0.0), abs=1e-12)
    assert 0.0 < near.cap < 0.075
    far = monitor.check(arm(), person(0.2 + standing + 0.5), 0.0, 0.0)
    assert far.cap == math.inf, "room for more than the motion's speed: no cap"


@pytest.mark.parametrize("dt", [0.001, 0.002])
def test_quiet_cycles_are_the_margin_over_how_fast_it_can_close(dt):
    """Margin beyond max(S_p at the fastest link, S_p standing + band), over the closing
    speed (the person and the envelope's ageing, 2 v_h, plus the fastest link), in
    cycles; at most MAX_QUIET; none without a margin."""
    monitor = SeparationMonitor(P, max_speed=0.075)
    age = 0.02
    guard = max(
        P.protective_distance(FASTEST_LINK, age), P.protective_distance(0.0, age) + P.slow_band
    )
    assert FASTEST_LINK == 0.25 and MAX_QUIET == 100
    for margin in (0.0005, 0.01, 0.05, 0.2):
        verdict = Verdict(guard + margin, 0.0, 0.0, math.inf, False)
        expected = min(100, int(margin / ((2 * 1.6 + 0.25) * dt)))
        assert monitor.quiet_cycles(verdict, age, dt) == expected, margin
    assert monitor.quiet_cycles(Verdict(guard + 5.0, 0, 0, math.inf, False), age, dt) == 100
    assert monitor.quiet_cycles(Verdict(guard, 0, 0, math.inf, False), age, dt) == 0
    assert monitor.quiet_cycles(Verdict(guard - 0.1, 0, 0, 0.0, False), age, dt) == 0


@pytest.mark.parametrize(
    "term",
    ["person_speed", "reaction", "engage", "intrusion", "detection_uncertainty", "slow_band"],
)
def test_a_negative_term_is_refused(term):
    with pytest.raises(ValueError, match=term):
        SsmParams(**{term: -0.01})
    with pytest.raises(ValueError, match="deceleration"):
        SsmParams(deceleration=0.0)


def test_a_separation_that_is_not_a_number_is_a_stop():
    """A NaN anywhere in the envelopes makes the distance NaN: no clear verdict, so the
    arm stops (the interface refuses such envelopes before; this is the backstop)."""
    monitor = SeparationMonitor(P, 0.075)
    a, b, radius = person(1.0)
    verdict = monitor.check(arm(), (a, b * math.nan, radius), 0.0, 0.0)
    assert math.isnan(verdict.separation) and verdict.stop


def test_capsules_given_as_other_numbers_are_judged_as_the_same_floats():
    """Integer arrays, lists, a non-contiguous view: the verdict (and the quiet cycles)
    of their float64 copies, a person far (quiet cycles) and one in the slowing band (a
    cap)."""
    for far in (1.0, 0.3):
        floats = SeparationMonitor(P, 0.075)
        others = SeparationMonitor(P, 0.075)
        b, radius = np.array([[0, 0, 1]]), [0]
        person_a = [[far, 0, 0], [far, 0, 1]]
        person_b = np.array([[far, 0.0, 0.5, 9.0], [far, 0.5, 1.0, 9.0]])[:, :3]
        assert not person_b.flags.c_contiguous
        for t, x in ((0.0, 0), (0.004, 0), (0.012, 1)):
            a = np.array([[x * 0.001, 0, 0]])
            want = floats.check_cycle(
                (a.astype(float), b.astype(float), np.array(radius, dtype=float)),
                (np.array(person_a, dtype=float), person_b.copy(), np.array([0.2, 0.1])),
                0.01, t, 0.02, 0.0005,
            )  # fmt: skip
            got = others.check_cycle(
                (a, b, radius), (person_a, person_b, [0.2, 0.1]), 0.01, t, 0.02, 0.0005
            )
            assert got == want and others.tcp_speed == floats.tcp_speed
            assert got[0].robot_speed == (0.0 if x == 0 else pytest.approx(0.001 / 0.012))
        assert (got[1] > 0) is (far == 1.0) and math.isfinite(got[0].cap) is (far == 0.3)


def test_a_speed_between_different_arms_is_none():
    """Capsules of another count than the last ones (another arm model): the window
    starts again, no speed from comparing the two."""
    monitor = SeparationMonitor(P, 0.075)
    one = arm(0.0)[:2]
    two = tuple(np.vstack((end, end + 0.5)) for end in arm(0.0)[:2])
    assert monitor.robot_speed(*one, now=0.0) == 0.0
    assert monitor.robot_speed(*two, now=0.02) == 0.0 and monitor.tcp_speed == 0.0
    moved = tuple(end + np.array([0.001, 0.0, 0.0]) for end in two)
    assert monitor.robot_speed(*moved, now=0.04) == pytest.approx(0.05)
    assert monitor.max_speed == 0.075
