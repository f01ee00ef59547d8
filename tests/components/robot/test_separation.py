"""Spec: speed and separation monitoring. The protective distance grows with the
robot's speed and the envelope's age; the speed it allows is the largest that keeps
it; the cap slows the arm down as people approach and is 0 where standing is the only
safe speed; the stop is said exactly when the separation is under the protective
distance. And what it is for: a person walking straight at the arm at 1.6 m/s never
reaches it while it moves."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from components.robot.separation import SeparationMonitor, SsmParams

P = SsmParams()
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


def test_nobody_in_the_room_is_no_constraint():
    verdict = SeparationMonitor(P, 0.075).check(arm(), None, 0.0, 0.0)
    assert verdict.separation == math.inf and verdict.cap == math.inf and not verdict.stop


@settings(max_examples=80, deadline=None)
@given(
    start=st.floats(0.3, 3.0),
    walk=st.floats(0.2, 1.6),
    age=st.floats(0.0, 0.1),
    cruise=st.floats(0.0, 0.075),
)
def test_a_person_walking_at_the_arm_never_reaches_it_while_it_moves(start, walk, age, cruise):
    """1 ms cycles: a person walks straight at the arm, which heads toward them at its
    cruise speed, slowed by the cap at the procedure's acceleration, braked at once on
    a stop (then decelerating at the stop's rate after `engage`). The envelope seen is
    `age` old. Whenever the arm still moves, they have not met."""
    dt, accel = 0.001, 0.25
    monitor = SeparationMonitor(P, max_speed=0.075)
    x_arm, v_arm, x_person = 0.0, cruise, 0.2 + start
    braking_since = None
    seen: list[float] = []
    for cycle in range(int(6.0 / dt)):
        t = cycle * dt
        seen.append(x_person)
        delayed = seen[max(0, len(seen) - 1 - round(age / dt))]
        verdict = monitor.check(arm(x_arm), person(delayed), age, t)
        if verdict.stop and braking_since is None:
            braking_since = t
        if braking_since is not None:
            if t - braking_since >= P.engage:
                v_arm = max(0.0, v_arm - P.deceleration * dt)
        else:
            target = min(cruise, verdict.cap)
            v_arm = max(target, v_arm - accel * dt) if v_arm > target else target
        x_arm += v_arm * dt
        x_person -= walk * dt
        gap = (x_person - x_arm) - 0.2
        if v_arm > 0.0:
            assert gap > 0.0, f"met at {t:.3f}s while the arm moved at {v_arm:.3f} m/s"
        if v_arm == 0.0 and braking_since is not None:
            break


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
