"""Spec: the interpolator as a component, cycle by cycle. The test plays the robot
interface (measured joints in, setpoints out), the Supervisor (limits, the halt reflex),
the navigator (where the goals are now) and the Configurator (operations): limits beyond
the procedure are refused, any halt brakes, an arm that does not follow stops the
motion, a goal re-sent while moving there does not interrupt it, the motion steers to
where the navigator says its goal is now, and a refusal of the patient's motion stops it."""

import json

import numpy as np
import pytest

from components.domain.geometry import pose_list, quat_to_matrix
from components.domain.lwr4 import HOME
from components.domain.procedure import pose_from
from components.robot.interpolator import CartesianInterpolator
from framework.activity import Activity, SteppedExecutor
from framework.clock import SimulatedClock
from framework.container import Container
from framework.errors import FwError
from framework.messages import EventMessage, JointState, Pose, Scalar
from tests.conftest import REPO, drained, reader_port, writer_port

PROCEDURE = REPO / "procedures" / "seeg.yaml"
TARGET = pose_from((0.60, 0.0, 0.12), (0, 180, 0))  # where the navigator says it is
HOME_GOAL = pose_from((0.54, 0.0, 0.37), (0, 180, 0))  # seeg.yaml's home (base frame)


class Robot:
    """The interpolator in a stepped container on the hub session, the test's ports on
    the same session (delivery is done when `cycle` returns); the arm follows every
    setpoint exactly unless told to lag."""

    def __init__(self, hub, procedure=PROCEDURE, navigator=True, paced=True):
        self.paced = paced  # as in the robot's loop: its after-cycle work after each cycle
        self.container = Container("c", hub, SteppedExecutor(SimulatedClock()))
        self.interp = self.container.add(
            CartesianInterpolator("interpolator"), Activity("after", master="robot")
        )
        self.interp.set_property("procedure_file", str(procedure))
        self.writers = {}
        for name, kind in [
            ("joints", JointState),
            ("limits", EventMessage),
            ("halt", EventMessage),
            ("goals", EventMessage),
            ("speed_cap", Scalar),
        ]:
            self.writers[name] = writer_port(hub, f"test/{name}", kind)
            self.container.connect("interpolator", name, f"test/{name}")
        self.readers = {
            name: reader_port(hub, f"interpolator/{name}", kind, size=100000)
            for name, kind in [
                ("setpoint", JointState),
                ("command", Pose),
                ("status", EventMessage),
            ]
        }
        self.container.start()
        self.configured = self.interp.configure() and self.interp.start()
        self.q = np.array(HOME, dtype=float)
        self.lag = np.zeros(7)
        if navigator:
            self.navigate(target=TARGET)

    def navigate(self, refused="", revisions=None, **goals):
        """The navigator says where the goals are now (base frame), as it does each sample."""
        payload = {
            "goals": {name: pose_list(pose) for name, pose in {"home": HOME_GOAL, **goals}.items()},
            "revisions": revisions or {},
            "tracker": "certus",
            "refused": refused,
        }
        self.writers["goals"].write(EventMessage(0.0, "goals", "navigator", payload))

    def cycle(self, n=1):
        for _ in range(n):
            self.writers["joints"].write(JointState(0.0, tuple(self.q + self.lag)))
            self.interp.update_hook()
            if self.paced:
                self.interp.after_cycle()
            setpoints = self.drain("setpoint")
            if setpoints:
                self.q = np.array(setpoints[-1].position)

    def drain(self, name):
        return drained(self.readers[name])

    def until(self, phase, limit=20000):
        for _ in range(limit):
            self.cycle()
            if self.report()["phase"] == phase:
                return
        raise AssertionError(f"never {phase}: {self.report()}")

    def report(self):
        return self.interp.call("report")

    def limits(self, **payload):
        self.writers["limits"].write(EventMessage(0.0, "limits", "supervisor", payload))
        self.cycle()

    def close(self):
        self.container.shutdown()


@pytest.fixture(params=[True, False], ids=["paced loop", "other activity"])
def robot(hub, request):
    """The interpolator as the robot's loop runs it (the goals taken after each cycle's
    setpoint), and as any other activity runs it (taken within the cycle): the same
    behaviour either way, a cycle later at most."""
    robot = Robot(hub, paced=request.param)
    assert robot.configured, robot.interp.last_error
    yield robot
    robot.close()


def test_it_waits_for_the_arms_joints_then_holds_them(robot):
    assert robot.report() == {"phase": "waiting for joints"}
    with pytest.raises(FwError, match="no joint state received yet"):
        robot.interp.call("go_to", goal="target")
    robot.cycle(5)
    assert np.allclose(robot.q, HOME, atol=1e-9), "at rest where the arm stands"
    assert [s.name for s in robot.drain("status")] == ["idle"]
    assert len(robot.drain("command")) == 1, "idle: the pose once, not every cycle"


def test_until_the_supervisor_sets_limits_it_moves_at_the_procedures_slowest_speed(robot):
    robot.cycle()
    assert robot.interp.call("go_to", goal="target")["velocity"] == 0.010  # seeg.yaml
    robot.cycle(1000)
    assert robot.report()["speed"] == pytest.approx(0.010, abs=1e-12)
    robot.limits(velocity=0.075)
    robot.cycle(1000)
    assert robot.report()["speed"] == pytest.approx(0.075, abs=1e-12)


def test_it_moves_to_a_named_goal_and_says_when_it_is_there(robot):
    robot.cycle()
    robot.limits(velocity=0.075)
    report = robot.interp.call("go_to", goal="target")
    assert report["phase"] == "moving" and report["goal"] == "target"
    robot.until("reached")
    assert [s.name for s in robot.drain("status")] == ["idle", "moving", "reached"]
    report = robot.report()
    assert report["tcp"] == pytest.approx([0.6, 0.0, 0.12], abs=1e-6)
    assert report["s"] == report["length"] > 0.1 and report["speed"] == 0.0
    command = robot.drain("command")[-1]  # the commanded TCP, for whoever records it
    assert command.position == pytest.approx((0.6, 0.0, 0.12), abs=1e-6)
    assert np.allclose(quat_to_matrix(np.array(command.orientation)), TARGET[:3, :3])
    assert (command.rms, command.frame_number, command.valid, command.frame, command.tool) == (
        0.0,
        0,
        True,
        "base",
        "tcp",
    )


def test_the_same_goal_sent_again_while_moving_there_is_not_a_new_motion(robot):
    robot.cycle()
    robot.interp.call("go_to", goal="target")
    robot.cycle(300)
    travelled = robot.report()["s"]
    again = json.loads('"target"')  # as decoded from the bus: equal, not the same object
    robot.interp.call("go_to", goal=again)  # a tracker swap re-applies the goto
    robot.cycle()
    assert robot.report()["s"] > travelled and robot.report()["phase"] == "moving"


def test_another_goal_while_moving_brakes_then_heads_for_it(robot):
    robot.cycle()
    robot.interp.call("go_to", goal="target")
    robot.cycle(300)
    assert robot.interp.call("go_to", goal="home")["phase"] == "stopping"
    robot.until("reached")
    assert robot.report()["goal"] == "home"
    assert robot.report()["tcp"] == pytest.approx([0.54, 0.0, 0.37], abs=1e-6)


def test_unknown_goals_and_bad_poses_are_refused(robot):
    robot.cycle()
    with pytest.raises(FwError, match="unknown goal 'moon': one of target, home"):
        robot.interp.call("go_to", goal="moon")
    with pytest.raises(FwError):
        robot.interp.call("go_to_pose", position=[0.5, 0.0], rpy_deg=[0, 180, 0])


def test_a_pose_and_a_new_target_are_reached_as_given(robot):
    with pytest.raises(FwError, match="no joint state received yet"):
        robot.interp.call("go_to_pose", position=[0.55, 0.05, 0.3], rpy_deg=[0, 180, 0])
    robot.cycle()
    assert robot.report()["goal"] == "", "a refused goal is no goal"
    report = robot.interp.call("go_to_pose", position=[0.55, 0.05, 0.3], rpy_deg=[0, 180, 0])
    assert report["phase"] == "moving" and report["goal"] == "pose"
    robot.until("reached")
    assert robot.report()["goal"] == "pose"
    assert robot.report()["tcp"] == pytest.approx([0.55, 0.05, 0.3], abs=1e-6)
    robot.navigate(target=pose_from((0.58, -0.02, 0.2), (0, 180, 0)), revisions={"target": 1})
    robot.cycle()
    robot.interp.call("go_to", goal="target")
    robot.until("reached")
    assert robot.report()["tcp"] == pytest.approx([0.58, -0.02, 0.2], abs=1e-6)


def test_limits_from_the_supervisor_apply_at_once(robot):
    robot.cycle()
    robot.limits(velocity=0.01, acceleration=0.1)
    report = robot.report()
    assert (report["velocity"], report["acceleration"]) == (0.01, 0.1)
    robot.limits(velocity=0.075)
    assert robot.report()["velocity"] == 0.075, "the procedure's fastest speed is allowed"
    assert robot.report()["acceleration"] == 0.1, "no acceleration: it stays"
    robot.limits(velocity=0.05, acceleration=0.25)
    assert robot.report()["acceleration"] == 0.25


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        ({"velocity": 0.0751}, "velocity 0.0751 m/s is over the procedure's 0.075"),
        ({"velocity": 0.08}, "velocity 0.08 m/s is over the procedure's 0.075"),
        ({"velocity": 0.05, "acceleration": 0.26}, "acceleration 0.26 m/s^2 is over"),
        ({"velocity": 0.0}, "velocity must be in (0, 0.25], got 0.0"),
        ({"velocity": 0.05, "acceleration": 0}, "acceleration must be in (0, 5], got 0.0"),
        ({"speed": 0.05}, "malformed limits: KeyError('velocity')"),
        ({"velocity": "fast"}, "malformed limits: ValueError"),
    ],
)
def test_limits_beyond_the_procedure_or_malformed_are_refused_and_the_old_ones_stay(
    robot, payload, reason
):
    refusals = []
    robot.interp.add_refusal_listener(refusals.append)
    robot.cycle()
    robot.limits(velocity=0.02, acceleration=0.2)
    robot.limits(**payload)
    assert (robot.report()["velocity"], robot.report()["acceleration"]) == (0.02, 0.2)
    assert robot.interp.last_error.startswith(f"limits refused: {reason}")
    assert [(r.port, r.reason) for r in refusals] == [("limits", robot.interp.last_error[16:])]


def test_limits_given_as_text_on_the_port_are_numbers(robot):
    robot.cycle()
    robot.limits(velocity="0.02", acceleration="0.2")
    assert (robot.report()["velocity"], robot.report()["acceleration"]) == (0.02, 0.2)


def test_the_set_limits_operation_holds_to_the_procedure_too(robot):
    robot.cycle()
    with pytest.raises(FwError, match="over the procedure"):
        robot.interp.call("set_limits", velocity=0.2)
    assert robot.interp.call("set_limits", velocity=0.03)["velocity"] == 0.03


def test_any_halt_brakes_the_motion_and_says_why(robot):
    robot.cycle()
    robot.interp.call("go_to", goal="target")
    robot.cycle(500)
    robot.writers["halt"].write(EventMessage(0.0, "halt", "supervisor", {"reason": "e_STOP"}))
    robot.cycle()
    report = robot.report()
    assert report["phase"] == "stopping" and report["halted"] == "e_STOP"
    assert report["goal"] == "", "the goal is dropped: a re-sent goto starts anew"
    robot.until("stopped")


def test_an_arm_that_stops_following_stops_the_motion(robot):
    robot.cycle()
    robot.interp.call("go_to", goal="target")
    robot.cycle(300)
    robot.lag = np.zeros(7)
    robot.lag[1] = 0.049  # within the allowed gap, either way
    robot.cycle()
    assert robot.report()["phase"] == "moving"
    robot.lag[1] = -0.049
    robot.cycle()
    assert robot.report()["phase"] == "moving"
    robot.lag[1] = 0.051
    stands = robot.q + robot.lag
    robot.cycle()
    assert robot.report()["phase"] == "stopped", "stopped where the arm stands: no braking"
    assert np.allclose(robot.q, stands, atol=1e-9), "the setpoint is where the arm stands"
    assert robot.interp.last_error.startswith("the arm lags the command by 2.9 deg")


def test_stop_motion_then_a_plain_sync_while_moving_keeps_the_motion(robot):
    robot.cycle()
    robot.interp.call("go_to", goal="target")
    robot.cycle(300)
    before = robot.report()["s"]
    robot.interp.call("sync")
    assert robot.report()["s"] == before, "a swap's sync must not cut the approach"
    report = robot.interp.call("stop_motion")
    assert report["phase"] == "stopping" and report["goal"] == ""
    robot.until("stopped")


def test_a_forced_sync_restarts_from_where_the_arm_stands(robot):
    robot.cycle()
    robot.interp.call("go_to", goal="target")
    robot.cycle(300)
    robot.lag = np.full(7, 0.01)  # the arm was stopped a little away
    stands = robot.q + robot.lag  # what the next measured state says
    robot.cycle()
    report = robot.interp.call("sync", force=True)
    assert report["phase"] == "idle" and report["goal"] == "" and report["s"] == 0.0
    said = robot.drain("setpoint")
    assert said and np.allclose(said[-1].position, stands, atol=1e-9), (
        "where it stands goes out at once: the release may reach the arm before the next update"
    )
    robot.cycle()
    assert np.allclose(robot.q, stands, atol=1e-6), "the next setpoint is where it stands"


def test_a_procedure_that_cannot_be_read_stops_configuration(hub, tmp_path):
    bad = tmp_path / "seeg.yaml"
    bad.write_text("procedure: x\n", encoding="utf-8")
    robot = Robot(hub, bad)
    try:
        assert not robot.configured and "seeg.yaml" in robot.interp.last_error
    finally:
        robot.close()


# --- the navigator's goals --------------------------------------------------------------


def moved(pose, dx=0.0, dy=0.0, dz=0.0):
    out = pose.copy()
    out[:3, 3] += (dx, dy, dz)
    return out


def test_the_motion_ends_where_the_navigator_says_its_goal_is_now(robot):
    refusals = []
    robot.interp.add_refusal_listener(lambda refusal: refusals.append(refusal))
    robot.limits(velocity=0.075)
    robot.interp.call("go_to", goal="target")
    robot.cycle(500)
    robot.navigate(target=moved(TARGET, dy=0.004))  # the head moved 4 mm
    robot.until("reached")
    robot.cycle(1000)
    assert robot.report()["tcp"] == pytest.approx([0.60, 0.004, 0.12], abs=1e-6)
    robot.navigate(target=moved(TARGET, dy=0.001))  # while holding: followed too
    robot.cycle(1000)
    assert robot.report()["tcp"] == pytest.approx([0.60, 0.001, 0.12], abs=1e-6)
    assert not refusals, "within what the patient and the arm explain: nothing refused"


def test_a_target_defined_anew_is_not_followed_until_the_next_go_to(robot):
    robot.limits(velocity=0.075)
    robot.interp.call("go_to", goal="target")
    robot.until("reached")
    robot.navigate(target=moved(TARGET, dx=-0.02), revisions={"target": 1})
    robot.cycle(2000)
    assert robot.report()["tcp"] == pytest.approx([0.60, 0.0, 0.12], abs=1e-6)
    robot.interp.call("go_to", goal="home")
    robot.until("reached")
    robot.interp.call("go_to", goal="target")
    robot.until("reached")
    assert robot.report()["tcp"] == pytest.approx([0.58, 0.0, 0.12], abs=1e-6)


def test_a_target_defined_anew_many_times_is_followed_like_the_first(robot):
    """Revisions are counters that grow over a long procedure: compared by value."""
    robot.limits(velocity=0.075)
    robot.navigate(target=TARGET, revisions={"target": 100000})
    robot.cycle()
    robot.interp.call("go_to", goal="target")
    robot.cycle(300)
    robot.navigate(target=moved(TARGET, dy=0.0041234), revisions=json.loads('{"target": 100000}'))
    robot.until("reached")
    robot.cycle(1000)
    tcp = robot.report()["tcp"]
    assert tcp[1] == 0.004123, "the report gives the TCP to the micrometre"
    assert robot.report()["speed"] == 0.0


def test_the_report_gives_the_speed_to_the_micrometre_per_second(robot):
    robot.limits(velocity=0.0123456)
    robot.interp.call("go_to", goal="target")
    robot.cycle(1500)  # cruising
    assert robot.report()["speed"] == 0.012346


def test_a_goal_whose_revision_went_back_does_not_steer_the_motion(robot):
    """A restarted navigator counts from 0 again: its target is the procedure's, not the
    one defined anew that the motion heads for."""
    robot.limits(velocity=0.075)
    robot.navigate(target=moved(TARGET, dx=-0.02), revisions={"target": 1})
    robot.cycle()
    robot.interp.call("go_to", goal="target")
    robot.until("reached")
    robot.navigate(target=moved(TARGET, dy=0.004), revisions={"target": 0})
    robot.cycle(2000)
    assert robot.report()["tcp"] == pytest.approx([0.58, 0.0, 0.12], abs=1e-6)


def test_a_goal_farther_than_the_patient_and_the_arm_can_explain_is_followed_only_so_far(robot):
    """A navigator gone wrong cannot pull the arm far: the correction stops at the
    procedure's max_patient_motion plus max_model_error (15 mm), and the refusal is said."""
    refusals = []
    robot.interp.add_refusal_listener(lambda refusal: refusals.append(refusal))
    robot.limits(velocity=0.075)
    robot.interp.call("go_to", goal="target")
    robot.cycle(300)
    robot.navigate(target=moved(TARGET, dy=0.06))
    robot.until("reached")
    robot.cycle(2000)
    assert robot.report()["tcp"] == pytest.approx([0.60, 0.015, 0.12], abs=1e-6)
    assert refusals[0].port == "goals" and "60.0 mm from where the motion" in refusals[0].reason
    assert "corrected 15 mm at most" in refusals[0].reason


def test_a_refusal_of_the_patients_motion_stops_the_motion_and_a_go_to(robot):
    robot.limits(velocity=0.075)
    robot.interp.call("go_to", goal="target")
    robot.cycle(300)
    robot.navigate(target=moved(TARGET, dz=0.02), refused="the patient moved 20.0 mm")
    robot.cycle()
    assert robot.report()["phase"] == "stopping"
    assert robot.report()["halted"] == "the patient moved 20.0 mm"
    assert robot.report()["goal"] == "", "the goal is dropped, as by a halt"
    with pytest.raises(FwError, match=r"navigation refuses: the patient moved 20\.0 mm"):
        robot.interp.call("go_to", goal="target")
    robot.until("stopped")
    robot.navigate(target=TARGET)  # registered again: go
    robot.cycle()
    assert robot.interp.call("go_to", goal="target")["phase"] == "moving"


@pytest.mark.parametrize(
    "payload",
    [{"goals": {"target": [0.6, 0.0]}}, {"goals": {"target": [0.6, 0, 0.1, 2.0, 0, 0, 0]}}, {}],
    ids=["short pose", "not a rotation", "no goals"],
)
def test_goals_that_are_not_poses_are_refused_and_change_nothing(robot, payload):
    refusals = []
    robot.interp.add_refusal_listener(lambda refusal: refusals.append(refusal))
    robot.limits(velocity=0.075)
    robot.interp.call("go_to", goal="target")
    robot.writers["goals"].write(EventMessage(0.0, "goals", "navigator", payload))
    robot.until("reached")
    assert robot.report()["tcp"] == pytest.approx([0.60, 0.0, 0.12], abs=1e-6)
    assert refusals and refusals[0].port == "goals"


def test_a_goal_on_the_patient_needs_a_navigator(hub):
    robot = Robot(hub)
    try:
        robot.writers["goals"].write(EventMessage(0.0, "goals", "navigator", {"goals": {}}))
        robot.cycle()
        with pytest.raises(FwError, match="'target' is on the patient and no navigator said"):
            robot.interp.call("go_to", goal="target")
        robot.cycle(10)
        assert robot.report()["phase"] == "idle", "refused: nothing moved"
        assert robot.interp.call("go_to", goal="home")["phase"] == "moving"  # in the base
    finally:
        robot.close()


def test_a_cycle_before_the_arms_first_joints_writes_nothing(robot):
    robot.interp.update_hook()
    assert robot.drain("setpoint") == [] and robot.drain("status") == []
    assert robot.report() == {"phase": "waiting for joints"}


def test_before_any_navigator_sample_a_base_frame_goal_is_taken(hub):
    robot = Robot(hub, navigator=False)
    try:
        robot.cycle()
        with pytest.raises(FwError, match="'target' is on the patient and no navigator said"):
            robot.interp.call("go_to", goal="target")
        assert robot.interp.call("go_to", goal="home")["phase"] == "moving"
    finally:
        robot.close()


def test_a_speed_cap_from_the_port_slows_the_motion_and_a_cap_of_zero_stands_it(robot):
    robot.cycle()
    robot.limits(velocity=0.075)
    robot.interp.call("go_to", goal="target")
    robot.cycle(1000)
    robot.writers["speed_cap"].write(Scalar(0.0, 0.02))
    robot.cycle(1000)
    assert robot.report()["speed"] == pytest.approx(0.02, abs=1e-12)
    robot.writers["speed_cap"].write(Scalar(0.0, 0.0))
    robot.cycle(1000)
    assert robot.report()["phase"] == "moving" and robot.report()["speed"] == 0.0


def test_configured_again_it_starts_afresh_from_the_arms_joints(robot):
    robot.cycle()
    robot.interp.call("go_to", goal="target")
    robot.cycle(500)
    assert robot.interp.stop() and robot.interp.configure() and robot.interp.start()
    assert robot.report() == {"phase": "waiting for joints"}
    robot.cycle()
    assert robot.report()["phase"] == "idle" and robot.report()["goal"] == ""


def test_a_report_before_configure_says_it_waits_for_joints():
    """The console may ask any component for its report before it is configured."""
    assert CartesianInterpolator("fresh").call("report") == {"phase": "waiting for joints"}


def test_a_cycle_says_its_ik_time_and_the_rest_of_the_interpolation_as_stages(robot, monkeypatch):
    """`fw bench cost`'s per-stage figures: IK is the time inside the IK, interpolation
    the rest of the cycle's steps (on a clock that moves only inside the two)."""
    from components.robot import interpolator

    now = [100.0]  # a clock's reading, not a duration
    monkeypatch.setattr(interpolator.time, "perf_counter", lambda: now[0])
    robot.cycle()
    core = robot.interp.core
    solve, plan = core.ik.step, core._otg

    def timed_ik(q, pose):
        now[0] += 1e-4
        return solve(q, pose)

    class TimedRuckig:
        def update(self, *args):
            now[0] += 5e-5
            return plan.update(*args)

    core.ik.step, core._otg = timed_ik, TimedRuckig()
    robot.interp.call("go_to", goal="target")
    stages = []
    monkeypatch.setattr(robot.interp, "stage", lambda *said: stages.append(said))
    robot.cycle()
    assert stages == [("IK", pytest.approx(1e-4)), ("interpolation", pytest.approx(5e-5))]


def test_setpoints_commands_and_status_are_stamped_with_the_cycles_time(robot):
    import time

    robot.cycle()
    robot.interp.call("go_to", goal="target")
    for name in ("setpoint", "command", "status"):
        robot.drain(name)
    robot.writers["joints"].write(JointState(0.0, tuple(robot.q)))
    before = time.time()
    robot.interp.update_hook()
    after = time.time()
    said = robot.drain("setpoint") + robot.drain("command") + robot.drain("status")
    assert len(said) == 3
    assert all(before <= m.stamp <= after for m in said)


def test_one_arm_state_is_caught_up_on_at_most_forty_steps(robot):
    """A step per cycle the arm says passed (its monitor mode reports every few), but a
    gap of more than 40 cycles is a stall, not time to catch up on: the command never
    leaps ahead of an arm that was away."""
    robot.cycle()
    robot.limits(velocity=0.075)
    robot.interp.call("go_to", goal="target")
    robot.cycle(1000)
    core = robot.interp.core
    assert core.speed == pytest.approx(0.075, abs=1e-12), "at cruise speed"
    for cycles, steps in ((10, 10), (40, 40), (41, 40), (100, 40)):
        s = core.s
        robot.writers["joints"].write(JointState(0.0, tuple(robot.q), cycles=cycles))
        robot.interp.update_hook()
        robot.drain("setpoint")
        assert core.s - s == pytest.approx(steps * 0.001 * 0.075, rel=1e-9), cycles
