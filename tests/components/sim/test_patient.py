"""Spec: the simulated patient's head moves as scenarios ask (drift, bump, breathing,
composed), publishes the reference tool where the head is, refuses motions that are
not numbers, and referees how far the real TCP is from the target on the head
(components/sim/patient.py)."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from components.domain.geometry import pose_matrix
from components.robot.navigation import Navigator
from components.sim.patient import Bump, HeadMotion, PatientHead
from framework.activity import Activity, SteppedExecutor
from framework.clock import SimulatedClock
from framework.container import Container
from framework.errors import FwError
from framework.messages import Pose
from tests.conftest import REPO, reader_port, writer_port


def test_a_drift_moves_at_its_velocity_and_stops_where_it_got_to():
    motion = HeadMotion()
    motion.drift(1.0, (0.001, 0.0, -0.002))
    assert np.allclose(motion.offset(0.5), 0.0), "nothing before it starts"
    assert np.allclose(motion.offset(3.0), (0.002, 0.0, -0.004))
    motion.drift(3.0, (0.0, 0.0, 0.0))
    assert np.allclose(motion.offset(10.0), (0.002, 0.0, -0.004))


@given(st.floats(0.0, 0.2), st.floats(-0.01, 0.01))
def test_a_bump_ramps_smoothly_and_monotonically_to_its_offset(duration, size):
    bump = Bump(1.0, (size, 0.0, 0.0), duration)
    times = np.linspace(0.9, 1.0 + duration + 0.1, 200)
    xs = np.array([bump.at(t)[0] for t in times])
    assert bump.at(1.0)[0] == 0.0 and bump.at(1.0 + duration + 1e-9)[0] == pytest.approx(size)
    steps = np.diff(xs) * np.sign(size or 1.0)
    assert (steps >= -1e-15).all(), "never back"


def test_breathing_is_a_sinusoid_along_its_axis_and_amplitude_zero_stops_it():
    motion = HeadMotion()
    motion.breathe(0.002, 4.0, (0.0, 0.0, 2.0))  # the axis is normalised
    assert np.allclose(motion.offset(1.0), (0.0, 0.0, 0.002))
    assert np.allclose(motion.offset(3.0), (0.0, 0.0, -0.002))
    motion.breathe(0.0, 4.0, (0, 0, 1))
    assert np.allclose(motion.offset(1.0), 0.0)
    with pytest.raises(ValueError, match="non-zero axis"):
        motion.breathe(0.001, 4.0, (0, 0, 0))
    with pytest.raises(ValueError, match="positive period"):
        motion.breathe(0.001, 0.0, (0, 0, 1))


def test_motions_compose():
    motion = HeadMotion()
    motion.drift(0.0, (0.001, 0.0, 0.0))
    motion.bump(1.0, (0.0, 0.005, 0.0), 0.05)
    motion.breathe(0.001, 2.0, (0, 0, 1))
    assert np.allclose(motion.offset(2.5), (0.0025, 0.005, math.sin(2 * math.pi * 2.5 / 2) * 1e-3))


@pytest.fixture
def head(hub):
    container = Container("c", hub, SteppedExecutor(clock := SimulatedClock()))
    head = container.add(PatientHead("head"), Activity())
    head.set_property("procedure_file", str(REPO / "procedures" / "seeg.yaml"))
    tcp = writer_port(hub, "test/tcp", Pose)
    container.connect("head", "tcp", "test/tcp")
    poses = reader_port(hub, "head/pose", Pose)
    assert head.configure() and head.start()
    yield head, clock, tcp, poses
    container.shutdown()


def test_the_reference_tool_is_published_where_the_head_is(head):
    component, clock, _, poses = head
    rest = component.base_from_rto()[:3, 3].copy()
    component.call("bump", dy=5.0, duration_ms=0.0)
    clock.advance(0.01)
    component.update_hook()
    _, pose = poses.read()
    assert pose.frame == "base" and pose.tool == "rto" and pose.valid
    assert np.allclose(np.array(pose.position) - rest, (0.0, 0.005, 0.0), atol=1e-9)
    assert component.call("report")["offset_mm"] == [0.0, 5.0, 0.0]


def test_the_referee_measures_the_real_tcp_against_the_target_on_the_moved_head(head):
    component, clock, tcp, _ = head
    assert component.call("report")["target_error_mm"] is None, "no TCP yet"
    target = component.base_from_rto() @ component.target
    on = Pose(tuple(target[:3, 3]), (1.0, 0.0, 0.0, 0.0), 0.0, 0.0, 1, True, "base", "tcp")
    tcp.write(on)
    assert component.call("report")["target_error_mm"] == 0.0
    component.call("bump", dx=3.0, dz=4.0, duration_ms=0.0)
    clock.advance(0.01)
    assert component.call("report")["target_error_mm"] == pytest.approx(5.0, abs=1e-3)


@pytest.mark.parametrize(
    ("operation", "arguments", "message"),
    [
        ("drift", {"vx": math.nan}, "drift needs 3 finite numbers"),
        ("bump", {"dx": math.inf}, "bump needs 3 finite numbers"),
        ("bump", {"dx": 1.0, "duration_ms": -5.0}, "duration_ms must be >= 0"),
        ("breathe", {"axis": [0, 0]}, "axis needs 3 finite numbers"),
        ("breathe", {"axis": [0, 0, 0]}, "non-zero axis"),
    ],
)
def test_a_motion_that_is_not_numbers_is_refused(head, operation, arguments, message):
    component = head[0]
    with pytest.raises(FwError, match=message):
        component.call(operation, **arguments)
    assert component.call("report")["offset_mm"] == [0.0, 0.0, 0.0]


def test_the_referee_scores_against_the_target_defined_last(hub):
    """After e_DEFINE_TARGET (the navigator's define_target), the referee measures the
    real TCP against the new target on the moving head, as the navigator's goals say it
    was defined, not against the procedure file's."""
    container = Container("c", hub, SteppedExecutor(clock := SimulatedClock()))
    head = container.add(PatientHead("head"), Activity())
    navigator = container.add(Navigator("navigator"), Activity())
    head.set_property("procedure_file", str(REPO / "procedures" / "seeg.yaml"))
    navigator.set_property("procedure_file", str(REPO / "procedures" / "seeg.yaml"))
    navigator.set_property("sensors_file", str(REPO / "procedures" / "seeg" / "sensors.yaml"))
    tcp = writer_port(hub, "test/tcp", Pose)
    container.connect("head", "tcp", "test/tcp")
    container.connect("head", "goals", "navigator/goals")
    try:
        assert head.configure() and head.start() and navigator.configure() and navigator.start()
        navigator.call("define_target", x=0.01, y=0.02, z=0.03, roll=0, pitch=180, yaw=0)
        navigator.update_hook()  # publishes its goals
        new_target = head.base_from_rto() @ pose_matrix(
            Pose((0.01, 0.02, 0.03), (1.0, 0.0, 0.0, 0.0))
        )
        tcp.write(Pose(tuple(new_target[:3, 3]), (1.0, 0.0, 0.0, 0.0), 0.0, 0.0, 1, True))
        assert head.call("report")["target_error_mm"] == pytest.approx(0.0, abs=1e-3)
        head.call("bump", dy=4.0, duration_ms=0.0)
        clock.advance(0.01)
        assert head.call("report")["target_error_mm"] == pytest.approx(4.0, abs=1e-3)
        navigator.call("define_target", x=0.5, y=0.0, z=0.3, roll=0, pitch=180, yaw=0, frame="base")
        navigator.update_hook()
        tcp.write(Pose((0.5, 0.0, 0.33), (1.0, 0.0, 0.0, 0.0), 0.0, 0.0, 1, True))
        assert head.call("report")["target_error_mm"] == pytest.approx(30.0, abs=1e-3)
    finally:
        container.shutdown()
