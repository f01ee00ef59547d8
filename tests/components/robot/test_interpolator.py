"""The Cartesian interpolator: trapezoidal path speed, live limits, STOP and return."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from components.domain.lwr4 import HOME, Kinematics
from components.robot.interpolator import InterpolatorCore, LimitError, Phase

KIN = Kinematics()
DT = 0.001


SEEG = {"velocity": 0.075, "acceleration": 0.25, "brake_acceleration": 2.0}


def core(**kwargs) -> InterpolatorCore:
    """A core at HOME with the SEEG procedure's limits unless told otherwise."""
    return InterpolatorCore(np.array(HOME), **{**SEEG, **kwargs})


def goal_at(offset: tuple[float, float, float]) -> np.ndarray:
    goal = KIN.tcp(np.array(HOME))
    goal[:3, 3] += offset
    return goal


def run(c: InterpolatorCore, until: Phase, limit: int = 40000) -> list[tuple[float, float]]:
    """Step until `until`; (s, speed) per cycle."""
    trace = []
    for _ in range(limit):
        c.step()
        trace.append((c.s, c.speed))
        if c.phase is until:
            return trace
    raise AssertionError(f"never reached {until}: {c.phase}")


def test_reaches_the_goal_on_a_straight_line_within_the_limits():
    c = core(velocity=0.075, acceleration=0.25)
    goal = goal_at((0.06, 0.0, -0.20))
    c.go_to(goal)
    start = KIN.tcp(np.array(HOME))[:3, 3]
    trace = run(c, Phase.REACHED)
    assert np.allclose(c.pose, goal, atol=1e-9)
    speeds = np.array([v for _, v in trace])
    assert speeds.max() <= 0.075 + 1e-12
    assert np.isclose(speeds.max(), 0.075)  # long path: cruises at the limit
    accelerations = np.abs(np.diff(speeds)) / DT
    assert accelerations.max() <= 0.25 + 1e-6
    # the joint-space result follows the Cartesian line
    tcp = KIN.tcp(c.q)[:3, 3]
    assert np.linalg.norm(tcp - goal[:3, 3]) < 1e-4
    direction = (goal[:3, 3] - start) / np.linalg.norm(goal[:3, 3] - start)
    assert np.linalg.norm(np.cross(c.pose[:3, 3] - start, direction)) < 1e-9


def test_lowering_the_velocity_while_moving_ramps_down_at_constant_acceleration():
    c = core(velocity=0.075, acceleration=0.25)
    c.go_to(goal_at((0.0, 0.0, -0.25)))
    for _ in range(600):
        c.step()
    assert np.isclose(c.speed, 0.075)
    c.set_limits(0.01)
    speeds = [c.speed]
    for _ in range(400):
        c.step()
        speeds.append(c.speed)
    decel = -np.diff(speeds) / DT
    ramp = decel[decel > 1e-6]
    assert np.allclose(ramp[:-1], 0.25, atol=1e-6), "a constant-acceleration ramp"
    assert np.isclose(speeds[-1], 0.01)


def test_stop_brakes_at_maximum_deceleration_then_returns_to_the_stop_point():
    c = core(velocity=0.075, acceleration=0.25, brake_acceleration=2.0)
    c.go_to(goal_at((0.0, 0.0, -0.25)))
    for _ in range(700):
        c.step()
    c.stop()
    stop_s, stop_pose = c.s, c.pose.copy()
    braking = run(c, Phase.RETURNING)
    assert c.phase is Phase.RETURNING, "the way back is a phase of its own (status says it)"
    trace = braking + run(c, Phase.STOPPED)
    overshoot = max(s for s, _ in trace) - stop_s
    assert np.isclose(overshoot, 0.075**2 / (2 * 2.0), rtol=0.05)  # v^2 / 2a
    assert np.allclose(c.pose, stop_pose, atol=1e-9)
    assert c.speed == 0.0


def test_a_second_stop_while_braking_keeps_the_first_stop_point():
    """The Supervisor's halt and the chart's stop configuration both stop the motion,
    a few milliseconds apart: the robot must return to where the first one hit."""
    c = core(velocity=0.075, acceleration=0.25, brake_acceleration=2.0)
    c.go_to(goal_at((0.0, 0.0, -0.25)))
    for _ in range(700):
        c.step()
    c.stop()
    first = c.pose.copy()
    for _ in range(5):
        c.step()
    c.stop()
    assert c.phase is Phase.STOPPING
    run(c, Phase.STOPPED)
    c.stop()
    assert c.phase is Phase.STOPPED
    assert np.allclose(c.pose, first, atol=1e-9)


def test_new_goal_while_moving_brakes_then_heads_for_it():
    c = core()
    c.go_to(goal_at((0.0, 0.0, -0.2)))
    for _ in range(500):
        c.step()
    second = goal_at((0.1, 0.1, -0.05))
    c.go_to(second)
    assert c.phase is Phase.STOPPING
    run(c, Phase.REACHED)
    assert np.allclose(c.pose, second, atol=1e-9)


def test_pure_rotation_takes_finite_time_and_ends_exactly():
    c = core()
    goal = KIN.tcp(np.array(HOME))
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 deg about z
    goal[:3, :3] = goal[:3, :3] @ rot
    c.go_to(goal)
    trace = run(c, Phase.REACHED)
    assert len(trace) > 100
    assert np.allclose(c.pose, goal, atol=1e-9)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf"), 10.0])
def test_bad_limits_are_refused_with_a_reason(bad):
    c = core()
    with pytest.raises(LimitError, match="velocity must be in"):
        c.set_limits(bad)


def test_bad_goal_is_refused():
    c = core()
    goal = goal_at((0.0, 0.0, -0.1))
    goal[0, 3] = np.nan
    with pytest.raises(ValueError, match="finite"):
        c.go_to(goal)


@settings(max_examples=25, deadline=None)
@given(
    dz=st.floats(-0.25, -0.02),
    velocity=st.floats(0.005, 0.1),
    acceleration=st.floats(0.05, 1.0),
    stop_after=st.integers(1, 3000),
)
def test_stop_anywhere_ends_at_rest_exactly_where_asserted(dz, velocity, acceleration, stop_after):
    c = core(velocity=velocity, acceleration=acceleration)
    c.go_to(goal_at((0.0, 0.0, dz)))
    for _ in range(stop_after):
        c.step()
        if c.phase is Phase.REACHED:
            break
    c.stop()
    where = c.pose.copy()
    speeds = [v for _, v in run(c, Phase.STOPPED)]
    assert max(abs(v) for v in speeds) <= velocity + 1e-9
    assert np.allclose(c.pose[:3, 3], where[:3, 3], atol=1e-9)
    assert c.speed == 0.0


def test_limits_up_to_the_sanity_ceilings_are_taken_and_beyond_are_refused():
    c = core(velocity=0.25, acceleration=5.0, brake_acceleration=5.0)
    assert (c.velocity, c.acceleration, c.brake_acceleration) == (0.25, 5.0, 5.0)
    for limit, value in [("velocity", 0.2501), ("acceleration", 5.001)]:
        with pytest.raises(LimitError, match=f"{limit} must be in"):
            core(**{limit: value})
    with pytest.raises(LimitError, match="brake_acceleration must be in"):
        core(brake_acceleration=5.001)
    c.set_limits(0.25, 5.0)
    with pytest.raises(LimitError, match="acceleration must be in"):
        c.set_limits(0.1, 5.001)
    assert (c.velocity, c.acceleration) == (0.25, 5.0), "a refused pair changes neither"


def test_a_rotation_counts_as_path_at_a_tenth_of_a_metre_per_radian():
    turn, shift = core(), core()
    goal = KIN.tcp(np.array(HOME))
    angle = 0.3
    about_z = np.array(
        [[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0, 0, 1]]
    )
    goal[:3, :3] = goal[:3, :3] @ about_z
    turn.go_to(goal)
    shift.go_to(goal_at((0.0, 0.0, -0.1 * angle)))
    assert turn.length == pytest.approx(0.03) and shift.length == pytest.approx(0.03)
    assert len(run(turn, Phase.REACHED)) == len(run(shift, Phase.REACHED))


@pytest.mark.parametrize("shape", [(3, 4), (4, 5), (3, 3), (16,)])
def test_a_goal_that_is_not_a_4x4_pose_is_refused(shape):
    c = core()
    with pytest.raises(ValueError, match="finite 4x4 pose"):
        c.go_to(np.ones(shape))
    assert c.phase is Phase.IDLE
    c.go_to(goal_at((0.0, 0.0, -0.02)))
    with pytest.raises(ValueError, match="finite 4x4 pose"):
        c.steer(np.ones(shape))


def test_a_new_goal_before_the_motion_has_started_replaces_the_old_one_without_braking():
    c = core()
    c.go_to(goal_at((0.0, 0.0, -0.2)))
    second = goal_at((0.05, 0.0, -0.1))
    c.go_to(second)
    assert c.phase is Phase.MOVING
    assert np.array_equal(c.goal, second)
    trace = run(c, Phase.REACHED)
    assert all(v >= 0.0 for _, v in trace)  # straight there: never slowed to turn
    assert np.allclose(c.pose, second, atol=1e-9)


def test_once_at_the_goal_the_joint_setpoint_settles_within_a_micrometre_of_it():
    c = core()
    goal = goal_at((0.06, 0.0, -0.20))
    c.go_to(goal)
    run(c, Phase.REACHED)
    for _ in range(50):
        q = c.step()
    assert np.abs(KIN.tcp(q) - goal).max() < 1e-6  # damped IK's fixed point, not exact
    assert np.array_equal(c.step(), q), "settled: the same setpoint every cycle"


def test_a_stop_at_rest_is_stopped_at_once_and_in_motion_brakes_first():
    c = core()
    c.stop()
    assert c.phase is Phase.STOPPED
    c = core()
    c.go_to(goal_at((0.0, 0.0, -0.2)))
    c.stop()  # asked to move, not moving yet: brakes all the same
    assert c.phase is Phase.STOPPING
    c = core()
    c.go_to(goal_at((0.0, 0.0, -0.01)))
    run(c, Phase.REACHED)
    c.stop()
    assert c.phase is Phase.STOPPED


def test_a_stop_while_braking_to_turn_to_a_new_goal_cancels_the_new_goal():
    c = core(brake_acceleration=0.5)
    c.go_to(goal_at((0.0, 0.0, -0.2)))
    for _ in range(500):
        c.step()
    c.go_to(goal_at((0.1, 0.1, -0.05)))  # brakes on this path, then would turn
    c.step()
    c.stop()
    assert c.phase is Phase.STOPPING, "still braking: a stop never halts the path at speed"
    where = c.pose.copy()
    speeds = [v for _, v in run(c, Phase.STOPPED)]
    assert speeds[0] > 0.0 and np.all(np.abs(np.diff(speeds)) <= 0.5 * DT + 1e-9)
    assert np.allclose(c.pose[:3, 3], where[:3, 3], atol=1e-9), "back where STOP was asserted"
    for _ in range(100):
        c.step()
    assert c.phase is Phase.STOPPED and np.allclose(c.pose[:3, 3], where[:3, 3], atol=1e-9)


def test_a_goal_where_the_tcp_already_is_is_reached_at_once():
    c = core()
    c.go_to(KIN.tcp(np.array(HOME)))
    assert c.phase is Phase.REACHED


def test_a_stop_before_the_motion_has_started_ends_stopped_with_no_return_leg():
    c = core()
    start = c.pose.copy()
    c.go_to(goal_at((0.0, 0.0, -0.2)))
    c.stop()
    c.step()
    assert c.phase is Phase.STOPPED, "nothing to brake, nowhere to return to"
    assert np.array_equal(c.pose, start)


# --- steering: the goal moves while the robot heads for it (navigation) -------------------


def moved(goal: np.ndarray, offset: tuple[float, float, float]) -> np.ndarray:
    out = goal.copy()
    out[:3, 3] += offset
    return out


def commanded_speeds(c: InterpolatorCore, cycles: int, on_cycle=None) -> np.ndarray:
    """The commanded TCP's speed (m/s) over `cycles` cycles."""
    previous, speeds = c.pose[:3, 3].copy(), []
    for k in range(cycles):
        if on_cycle is not None:
            on_cycle(k)
        c.step()
        speeds.append(np.linalg.norm(c.pose[:3, 3] - previous) / DT)
        previous = c.pose[:3, 3].copy()
    return np.array(speeds)


@settings(max_examples=40, deadline=None)
@given(
    when=st.integers(0, 2500),
    jump=st.tuples(*[st.floats(-0.01, 0.01)] * 3),
    velocity=st.sampled_from([0.01, 0.05, 0.075]),
)
def test_a_goal_that_jumps_never_makes_the_command_exceed_the_speed_limit(when, jump, velocity):
    c = core(velocity=velocity)
    goal = goal_at((0.03, 0.02, -0.05))
    c.go_to(goal)
    speeds = commanded_speeds(c, 4000, lambda k: k == when and c.steer(moved(goal, jump)))
    assert speeds.max() <= velocity * (1 + 1e-9) + 1e-9


@settings(max_examples=30, deadline=None)
@given(
    when=st.integers(0, 1500),
    jump=st.tuples(*[st.floats(-0.005, 0.005)] * 3),
)
def test_the_command_ends_on_the_goal_where_it_is_now(when, jump):
    c = core(velocity=0.05)
    goal = goal_at((0.02, -0.01, -0.04))
    c.go_to(goal)
    now = moved(goal, jump)
    commanded_speeds(c, 5000, lambda k: k == when and c.steer(now))
    assert c.phase is Phase.REACHED
    assert np.allclose(c.pose[:3, 3], now[:3, 3], atol=1e-9)
    assert np.linalg.norm(KIN.tcp(c.q)[:3, 3] - now[:3, 3]) < 1e-4  # the joints follow


def test_a_correction_is_cut_at_the_largest_one_allowed_and_says_by_how_much():
    c = core(velocity=0.05)
    c.max_correction = 0.015
    goal = goal_at((0.02, -0.01, -0.04))
    c.go_to(goal)
    commanded_speeds(c, 300)
    assert c.steer(moved(goal, (0.0, 0.04, 0.0))) == pytest.approx(0.025)
    commanded_speeds(c, 5000)
    assert c.phase is Phase.REACHED
    assert np.allclose(c.pose[:3, 3], goal[:3, 3] + (0.0, 0.015, 0.0), atol=1e-9)
    assert c.steer(moved(goal, (0.0, 0.01, 0.0))) == 0.0, "within it: followed in full"
    commanded_speeds(c, 2000)
    assert np.allclose(c.pose[:3, 3], goal[:3, 3] + (0.0, 0.01, 0.0), atol=1e-9)


def test_a_correction_pending_slows_the_path_to_keep_it_a_share_of_the_speed():
    c = core(velocity=0.05)
    goal = goal_at((0.0, 0.0, -0.15))
    c.go_to(goal)
    commanded_speeds(c, 600)  # cruising at the limit
    assert c.speed == pytest.approx(0.05)
    c.steer(moved(goal, (0.01, 0.0, 0.0)))
    commanded_speeds(c, 200)
    assert c.speed == pytest.approx(0.025)  # half the limit for the path...
    x = c.pose[0, 3]
    commanded_speeds(c, 100)
    assert (c.pose[0, 3] - x) / (100 * DT) == pytest.approx(0.025)  # ...the rest corrects
    commanded_speeds(c, 600)  # 10 mm at >= 25 mm/s: done
    assert c.speed == pytest.approx(0.05)  # the path cruises at the limit again


def test_a_correction_asked_before_the_path_starts_keeps_its_share_of_the_speed():
    c = core(velocity=0.05)
    goal = goal_at((0.0, 0.0, -0.15))
    c.go_to(goal)
    c.steer(moved(goal, (0.01, 0.0, 0.0)))  # before the first cycle
    commanded_speeds(c, 300)
    assert c.speed == pytest.approx(0.025), "the path leaves the correction half the limit"
    assert c.pose[0, 3] - goal[0, 3] > 0.002, "the correction is under way"
    assert c.pose.shape == (4, 4) and np.allclose(c.pose[3], [0, 0, 0, 1])
    assert np.allclose(c.pose[:3, :3] @ c.pose[:3, :3].T, np.eye(3), atol=1e-12)


def test_holding_a_goal_follows_it_when_it_moves_at_the_limit_and_no_faster():
    c = core(velocity=0.01)
    goal = goal_at((0.0, 0.0, -0.01))
    c.go_to(goal)
    run(c, Phase.REACHED)
    c.steer(moved(goal, (0.0, 0.005, 0.0)))  # the head was bumped by 5 mm
    speeds = commanded_speeds(c, 600)
    assert c.phase is Phase.REACHED
    assert speeds.max() == pytest.approx(0.01)
    assert int(np.sum(speeds > 0)) == 500  # 5 mm at 1 cm/s: half a second
    assert np.allclose(c.pose[:3, 3], moved(goal, (0.0, 0.005, 0.0))[:3, 3], atol=1e-9)


def test_a_stop_freezes_the_correction_and_returns_to_where_it_was_asserted():
    c = core(velocity=0.05)
    goal = goal_at((0.0, 0.0, -0.10))
    c.go_to(goal)
    commanded_speeds(c, 300)
    c.steer(moved(goal, (0.004, 0.0, 0.0)))
    commanded_speeds(c, 50)
    c.stop()
    stop_point = c.stop_pose.copy()
    c.steer(moved(goal, (-0.004, 0.0, 0.0)))  # ignored: the robot is stopping
    run(c, Phase.STOPPED)
    assert np.allclose(c.pose, stop_point, atol=1e-9)
    commanded_speeds(c, 100)
    assert np.allclose(c.pose, stop_point, atol=1e-9)


def test_a_new_goal_starts_from_the_command_with_its_correction():
    c = core(velocity=0.05)
    goal = goal_at((0.0, 0.0, -0.02))
    c.go_to(goal)
    c.steer(moved(goal, (0.003, 0.0, 0.0)))
    run(c, Phase.REACHED)
    commanded_speeds(c, 200)
    here = c.pose.copy()
    c.go_to(goal_at((0.0, 0.02, 0.0)))
    speeds = commanded_speeds(c, 3)
    assert speeds.max() < 0.001  # from rest, no jump back by the correction
    assert np.linalg.norm(c.pose[:3, 3] - here[:3, 3]) < 1e-5


def test_steering_is_ignored_when_not_heading_for_a_goal():
    c = core()
    c.max_correction = 0.005
    before = c.pose.copy()
    assert c.steer(moved(before, (0.01, 0.0, 0.0))) == 0.0, "ignored: nothing beyond"
    commanded_speeds(c, 100)
    assert np.array_equal(c.pose, before) and c.phase is Phase.IDLE
    c.go_to(goal_at((0.0, 0.0, -0.02)))
    commanded_speeds(c, 100)
    c.stop()
    run(c, Phase.STOPPED)
    here = c.pose.copy()
    assert c.steer(moved(here, (0.01, 0.0, 0.0))) == 0.0, "stopped: ignored too"
    commanded_speeds(c, 100)
    assert np.array_equal(c.pose, here)
    with pytest.raises(ValueError, match="finite 4x4"):
        c.steer(np.full((4, 4), np.nan))


def test_a_turned_goal_is_followed_at_a_tenth_of_a_metre_per_radian():
    """A correction that is a rotation costs its angle times 0.1 m of the speed budget:
    0.05 rad at 1 cm/s takes half a second."""
    import pinocchio as pin

    c = core(velocity=0.01)
    goal = goal_at((0.0, 0.0, -0.01))
    c.go_to(goal)
    run(c, Phase.REACHED)
    turned = goal.copy()
    turned[:3, :3] = goal[:3, :3] @ pin.exp3(np.array([0.05, 0.0, 0.0]))
    c.steer(turned)
    cycles = 0
    while np.linalg.norm(pin.log3(c.pose[:3, :3].T @ turned[:3, :3])) > 1e-9 and cycles < 2000:
        c.step()
        cycles += 1
    assert 495 <= cycles <= 505


def test_a_speed_cap_from_people_slows_the_motion_and_a_cap_of_zero_stands_it():
    """Speed and separation monitoring caps the path speed under the Supervisor's
    limit: the motion slows within the acceleration limit, stands (still moving, not
    at the goal) on a cap of 0, heads on when the cap rises, and reaches the goal."""
    c = core()
    goal = goal_at((0.06, 0.0, -0.20))
    c.go_to(goal)
    for _ in range(600):
        c.step()
    assert c.speed == pytest.approx(0.075, abs=1e-9)
    c.set_cap(0.02)
    speeds = []
    for _ in range(400):
        c.step()
        speeds.append(c.speed)
    assert np.all(np.abs(np.diff(speeds)) / DT <= 0.25 + 1e-6), "within the acceleration"
    assert c.speed == pytest.approx(0.02, abs=1e-9)
    c.set_cap(0.0)
    for _ in range(200):
        c.step()
    s = c.s
    for _ in range(500):
        c.step()
    assert c.phase is Phase.MOVING and c.speed == 0.0 and c.s == s, "it stands, unbraked"
    c.set_cap(float("nan"))
    assert c.cap == 0.0, "a cap that is not a number is no speed"
    c.set_cap(float("inf"))
    trace = run(c, Phase.REACHED)
    assert max(v for _, v in trace) == pytest.approx(0.075, abs=1e-9)
    assert np.allclose(c.pose, goal, atol=1e-9)


def test_a_motion_begun_under_a_cap_of_zero_waits_for_the_cap_to_rise():
    c = core()
    c.set_cap(0.0)
    c.go_to(goal_at((0.0, 0.0, -0.05)))
    for _ in range(300):
        c.step()
    assert c.phase is Phase.MOVING and c.s == 0.0
    c.set_cap(0.01)
    trace = run(c, Phase.REACHED)
    assert max(v for _, v in trace) == pytest.approx(0.01, abs=1e-9)


def test_the_supervisors_limit_under_a_cap_still_rules():
    c = core()
    c.set_cap(0.05)
    c.go_to(goal_at((0.06, 0.0, -0.20)))
    c.set_limits(0.01)
    trace = run(c, Phase.REACHED)
    assert max(v for _, v in trace) == pytest.approx(0.01, abs=1e-9)


# --- specs from fw's mutants (issue 41) ----------------------------------------------


def test_a_core_at_rest_has_no_goal_and_no_stop_point():
    c = core()
    assert c.phase is Phase.IDLE
    assert c.goal is None and c.stop_pose is None and c.stop_s == 0.0


def test_limits_given_as_text_or_whole_numbers_are_taken_as_numbers():
    """A command line gives numbers as text; the limits the core keeps are floats."""
    c = core()
    c.set_limits("0.05", 1)
    assert c.velocity == 0.05 and type(c.velocity) is float
    assert c.acceleration == 1.0 and type(c.acceleration) is float


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf"), 10.0])
def test_a_bad_acceleration_is_refused_and_neither_limit_changes(bad):
    c = core()
    with pytest.raises(LimitError, match="acceleration must be in"):
        c.set_limits(0.05, bad)
    assert (c.velocity, c.acceleration) == (SEEG["velocity"], SEEG["acceleration"])


def test_a_new_acceleration_while_moving_rules_the_very_next_cycle():
    """Lowered from 0.25 to 0.05 m/s^2 at cruise, with a lower speed: the path slows at
    the new acceleration from the next cycle on, not at the old one."""
    c = core()
    c.go_to(goal_at((0.06, 0.0, -0.20)))
    for _ in range(600):
        c.step()
    assert c.speed == pytest.approx(0.075, abs=1e-9)
    c.set_limits(0.05, 0.05)
    speeds = [c.speed]
    for _ in range(100):
        c.step()
        speeds.append(c.speed)
    assert np.allclose(np.diff(speeds) / DT, -0.05, atol=1e-6)


def test_goals_given_as_nested_lists_are_taken_as_poses():
    c = core(velocity=0.05)
    goal = goal_at((0.0, 0.0, -0.02))
    c.go_to(goal.tolist())
    assert np.array_equal(c.goal, goal)
    c.steer(moved(goal, (0.002, 0.0, 0.0)).tolist())
    run(c, Phase.REACHED)
    commanded_speeds(c, 200)
    assert np.allclose(c.pose[:3, 3], moved(goal, (0.002, 0.0, 0.0))[:3, 3], atol=1e-9)


def test_a_bad_goal_while_moving_is_refused_and_the_motion_goes_on():
    c = core()
    goal = goal_at((0.0, 0.0, -0.05))
    c.go_to(goal)
    commanded_speeds(c, 300)
    bad = goal_at((0.05, 0.0, 0.0))
    bad[0, 3] = np.inf
    with pytest.raises(ValueError, match="finite 4x4 pose"):
        c.go_to(bad)
    assert c.phase is Phase.MOVING, "not braking to turn toward a refused goal"
    run(c, Phase.REACHED)
    assert np.allclose(c.pose, goal, atol=1e-9)


def test_turning_to_a_new_goal_never_makes_the_command_jump():
    """Braked on the first path, the second starts where the command stands: the
    commanded TCP never moves faster than the limit across the turn."""
    c = core()
    c.go_to(goal_at((0.0, 0.0, -0.2)))
    commanded_speeds(c, 500)
    second = goal_at((0.1, 0.1, -0.05))
    c.go_to(second)
    speeds = commanded_speeds(c, 6000)
    assert c.phase is Phase.REACHED and np.allclose(c.pose, second, atol=1e-9)
    assert speeds.max() <= 0.075 * (1 + 1e-9)


def test_a_steered_motion_stands_on_a_cap_of_zero_too():
    c = core(velocity=0.05)
    goal = goal_at((0.0, 0.0, -0.15))
    c.go_to(goal)
    commanded_speeds(c, 600)
    c.steer(moved(goal, (0.0005, 0.0, 0.0)))
    commanded_speeds(c, 100)
    c.set_cap(0.0)
    commanded_speeds(c, 300)
    s = c.s
    speeds = commanded_speeds(c, 200)
    assert c.phase is Phase.MOVING and c.s == s and speeds.max() == 0.0


def test_a_motion_resumed_after_a_cap_of_zero_keeps_the_pending_correction_its_share():
    """Stood on a cap of 0 with a correction pending (a cap of 0 leaves it no speed
    either), the motion heads on at half the limit until the correction is made."""
    c = core(velocity=0.05)
    goal = goal_at((0.0, 0.0, -0.15))
    c.go_to(goal)
    commanded_speeds(c, 600)
    c.set_cap(0.0)
    commanded_speeds(c, 300)
    c.steer(moved(goal, (0.01, 0.0, 0.0)))
    x = c.pose[0, 3]
    commanded_speeds(c, 50)
    assert c.pose[0, 3] == x, "no speed for the correction while the cap is 0"
    c.set_cap(float("inf"))
    commanded_speeds(c, 300)
    assert c.speed == pytest.approx(0.025), "the path leaves the correction half the limit"
    commanded_speeds(c, 600)
    assert c.speed == pytest.approx(0.05), "the correction made, the path cruises again"


def test_a_new_goal_while_standing_on_a_cap_of_zero_waits_for_the_cap_to_rise():
    c = core()
    c.go_to(goal_at((0.0, 0.0, -0.15)))
    commanded_speeds(c, 300)
    c.set_cap(0.0)
    commanded_speeds(c, 300)
    assert c.speed == 0.0
    second = goal_at((0.02, 0.0, -0.05))
    c.go_to(second)  # standing: no braking needed, the new path begins at once
    commanded_speeds(c, 500)
    assert c.phase is Phase.MOVING and c.s == 0.0, "not a nanometre while the cap is 0"
    c.set_cap(0.01)
    run(c, Phase.REACHED)
    assert np.allclose(c.pose, second, atol=1e-9)


def test_a_failing_trajectory_generator_raises_and_never_moves_on_silently():
    """Every input ruckig gets is checked first, so a failure is a defect: it must stop
    the cycle (the component's loop brakes on the exception), not pass on garbage."""
    from ruckig import Result

    c = core()
    c.go_to(goal_at((0.0, 0.0, -0.05)))

    class Failing:
        def update(self, *_):
            return Result.ErrorInvalidInput

    c._otg = Failing()
    with pytest.raises(RuntimeError, match="ruckig failed"):
        c.step()


def test_the_ik_time_counts_the_ik_and_nothing_else(monkeypatch):
    """`ik_seconds` (fw bench cost's IK stage) sums the time inside IK steps only: on a
    clock that moves only while the IK runs, it is that time exactly."""
    from components.robot import interpolator

    now = [0.0]
    monkeypatch.setattr(interpolator.time, "perf_counter", lambda: now[0])
    c = core()
    solve = c.ik.step

    def timed(q, pose):
        now[0] += 1e-4
        return solve(q, pose)

    c.ik.step = timed
    c.go_to(goal_at((0.0, 0.0, -0.05)))
    for _ in range(10):
        c.step()
    assert c.ik_seconds == pytest.approx(10e-4, abs=1e-12)


def test_at_rest_the_setpoint_converges_before_it_is_held():
    """Held (the same setpoint, no IK solved) only once one more IK step would not move
    the joints: stopped at speed, the IK still lags the command and keeps converging."""
    c = core(velocity=0.075, brake_acceleration=5.0)
    c.go_to(goal_at((0.06, 0.0, -0.20)))
    commanded_speeds(c, 1500)
    c.stop()
    run(c, Phase.STOPPED)
    for _ in range(200):
        q = c.step()
        if np.array_equal(c.step(), q):
            break
    assert np.max(np.abs(c.ik.step(q, c.pose) - q)) < 1e-10


def test_the_new_path_begins_exactly_where_braking_on_the_old_one_ended():
    """Turning to a new goal, the command first runs out the whole braking distance on
    the old path (v^2 / 2a beyond where the goal came), then leaves from that point."""
    c = core(velocity=0.075, brake_acceleration=2.0)
    start = c.pose[:3, 3].copy()
    down = np.array([0.0, 0.0, -1.0])
    c.go_to(goal_at((0.0, 0.0, -0.2)))
    commanded_speeds(c, 1500)
    at, speed = float((c.pose[:3, 3] - start) @ down), c.speed
    c.go_to(goal_at((0.1, 0.1, -0.05)))
    furthest = at
    for _ in range(200):
        c.step()
        furthest = max(furthest, float((c.pose[:3, 3] - start) @ down))
    assert furthest - at == pytest.approx(speed**2 / (2 * 2.0), abs=1e-9)


def test_a_stop_standing_on_a_cap_of_zero_ends_where_it_stands_with_no_way_back():
    """Stopped while people hold the motion still, the robot is where the stop was
    asserted: it ends STOPPED there, never passing through a return leg, even if the
    cap rises before the stop is finished."""
    c = core()
    c.go_to(goal_at((0.0, 0.0, -0.20)))
    for _ in range(600):
        c.step()
    c.set_cap(0.0)
    for _ in range(800):
        c.step()
    assert c.phase is Phase.MOVING and c.speed == 0.0, "standing"
    c.stop()
    stop_pose = c.pose.copy()
    c.set_cap(float("inf"))
    phases = []
    for _ in range(50):
        c.step()
        phases.append(c.phase)
    assert Phase.RETURNING not in phases and c.phase is Phase.STOPPED
    assert np.allclose(c.pose, stop_pose, atol=1e-12)


def test_a_stop_whose_way_back_a_cap_of_zero_forbids_ends_where_braking_ended():
    """The way back to the stop point is a motion too: with people holding the robot
    still it is not made; the robot ends STOPPED where braking ended."""
    c = core()
    c.go_to(goal_at((0.0, 0.0, -0.25)))
    for _ in range(700):
        c.step()
    c.stop()
    c.set_cap(0.0)
    trace = run(c, Phase.STOPPED, limit=2000)
    assert c.speed == 0.0 and c.s > c.stop_s, "it braked past the stop point"
    assert max(s for s, _ in trace) == pytest.approx(c.s, abs=1e-12), "and stayed there"
