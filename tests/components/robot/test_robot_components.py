"""Spec: the robot interface and the interpolator as components, on a stepped clock: one
millisecond of physics per update, setpoints through real ports, deterministic runs."""

import numpy as np
import pytest

from components.robot.interface import RobotInterface
from components.robot.interpolator import CartesianInterpolator
from components.supervisor.procedure import load_procedure
from framework.activity import Activity, SteppedExecutor
from framework.clock import SimulatedClock
from framework.container import Container
from framework.errors import FwError
from tests.conftest import REPO

PROCEDURE = REPO / "procedures" / "seeg.yaml"


class Cell:
    """Robot interface and interpolator in one container, stepped 1 ms at a time."""

    def __init__(self, bus):
        self.clock = SimulatedClock()
        self.executor = SteppedExecutor(self.clock)
        self.container = Container("cell", bus, self.executor)
        self.robot = self.container.add(RobotInterface("robot"), Activity.periodic(1000))
        self.interp = self.container.add(
            CartesianInterpolator("interpolator"), Activity.event("joints")
        )
        self.container.connect("interpolator", "joints", "robot/joints")
        self.container.connect("robot", "setpoint", "interpolator/setpoint")
        self.interp.set_property("procedure_file", str(PROCEDURE))
        self.container.start()
        for component in (self.robot, self.interp):
            assert component.configure() and component.start(), component.last_error
        self.run(0.01)  # the interpolator learns the joints

    def run(self, seconds: float) -> None:
        self.executor.advance(seconds)

    def tcp(self) -> np.ndarray:
        return self.robot.arm.tcp()[:3, 3]

    def close(self) -> None:
        self.container.shutdown()


@pytest.fixture
def cell(hub):
    c = Cell(hub)
    yield c
    c.close()


def test_the_arm_powers_up_braked_and_a_goal_needs_the_brakes_released(cell):
    cell.interp.call("go_to", goal="target")
    cell.run(1.0)
    assert cell.robot.call("report")["braked"], "setpoints are refused while braked"
    assert np.allclose(cell.tcp(), load_procedure(PROCEDURE).goals["home"][:3, 3], atol=0.01)


def test_released_the_arm_reaches_the_target_through_the_ports(cell):
    target = load_procedure(PROCEDURE).target[:3, 3]
    cell.robot.call("release")
    cell.interp.call("sync")
    cell.interp.call("go_to", goal="target")
    cell.run(6.0)
    assert cell.interp.call("report")["phase"] == "reached"
    assert np.linalg.norm(cell.tcp() - target) < 0.5e-3
    assert not cell.robot.call("report")["braked"]


def test_stop_brakes_along_the_path_returns_and_the_brakes_engage_when_still(cell):
    cell.robot.call("release")
    cell.interp.call("sync")
    cell.interp.call("go_to", goal="target")
    cell.run(2.0)
    asserted = np.array(cell.interp.call("report")["tcp"])
    cell.interp.call("stop_motion")
    cell.robot.call("brake", reason="stop", when_still=True)
    cell.run(3.0)
    report = cell.robot.call("report")
    assert report["braked"] and report["reason"] == "stop"
    assert cell.interp.call("report")["phase"] == "stopped"
    assert np.linalg.norm(cell.tcp() - asserted) < 0.5e-3, "back where STOP was asserted"


def test_the_supervisors_halt_brakes_the_motion_without_the_chart(hub):
    """The safety reflex: a possible collision reaches the interpolator on the
    Supervisor's `halt` port, before (and without) any stop configuration."""
    from components.supervisor.supervisor import Supervisor
    from framework.messages import Scalar
    from framework.ports import OutputPort

    cell = Cell(hub)
    try:
        supervisor = cell.container.add(Supervisor("supervisor"), Activity.event("min_distance"))
        supervisor.set_property("procedure_file", str(PROCEDURE))
        cell.container.connect("supervisor", "min_distance", "test/min_distance")
        cell.container.connect("interpolator", "halt", "supervisor/halt")
        assert supervisor.configure() and supervisor.start(), supervisor.last_error
        distance = OutputPort("distance", Scalar)
        distance.owner, distance.bus = "test", hub
        distance.connect("test/min_distance")

        cell.robot.call("release")
        cell.interp.call("sync")
        cell.interp.call("go_to", goal="target")
        cell.run(1.0)
        assert cell.interp.call("report")["phase"] == "moving"
        distance.write(Scalar(0.0, 0.05))  # 5 cm: under the collision distance
        cell.run(0.002)
        report = cell.interp.call("report")
        assert report["phase"] == "stopping"
        assert report["halted"].startswith("possible collision")
    finally:
        cell.close()


def test_a_dead_interpolator_makes_the_watchdog_brake(cell):
    cell.robot.call("release")
    cell.interp.call("sync")
    cell.interp.call("go_to", goal="target")
    cell.run(1.0)
    cell.interp.stop()  # the interpolator dies: no more setpoints
    cell.run(0.05)
    report = cell.robot.call("report")
    assert report["braked"] and report["reason"].startswith("watchdog")


def test_unknown_goals_and_bad_limits_are_refused_with_reasons(cell):
    with pytest.raises(FwError, match="unknown goal 'moon'"):
        cell.interp.call("go_to", goal="moon")
    with pytest.raises(FwError, match="velocity must be in"):
        cell.interp.call("set_limits", velocity=-1.0)


def test_stepped_runs_are_repeatable(bus_config):
    from framework.bus import Bus

    def trajectory():
        bus = Bus(bus_config, hub=True)
        cell = Cell(bus)
        try:
            cell.robot.call("release")
            cell.interp.call("sync")
            cell.interp.call("go_to", goal="target")
            points = []
            for _ in range(20):
                cell.run(0.1)
                points.append(cell.tcp().copy())
            return np.array(points)
        finally:
            cell.close()
            bus.close()

    assert np.array_equal(trajectory(), trajectory())


def test_an_arm_that_stops_following_stops_the_commanded_motion(cell):
    cell.robot.call("release")
    cell.interp.call("sync")
    cell.interp.call("go_to", goal="target")
    cell.run(1.0)
    cell.robot.call("brake", reason="operator")  # the arm stops; nobody told the interpolator
    cell.run(1.0)
    report = cell.interp.call("report")
    assert report["phase"] == "stopped", report
    assert "lags the command" in cell.interp.last_error
    assert np.allclose(report["tcp"], cell.tcp(), atol=1e-3), "the command is back at the arm"
