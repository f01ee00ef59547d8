"""Spec: the Sensor Manager component reads real tracker ports and publishes its choice."""

import dataclasses

import numpy as np
import pytest
import yaml

from components.domain.geometry import matrix_to_quat, quat_to_matrix, rigid
from components.domain.rigs import ee_path, sensors_config, standard_rigs
from components.tracking.certus_sim import TrackerSim
from components.tracking.sensor_manager import SensorManager
from framework.activity import Activity, SteppedExecutor
from framework.clock import SimulatedClock
from framework.container import Container
from framework.messages import EventMessage, Pose
from framework.ports import InputPort
from tests.conftest import drained, reader_port, wait_until, writer_port
from tests.support.peer_clock import from_host_apart


def as_yaml(t):
    """A transform as sensors.yaml writes it."""
    return {"position": t[:3, 3].tolist(), "quaternion": list(matrix_to_quat(t[:3, :3]))}


def write_sensors(tmp_path, hysteresis=3):
    """sensors.yaml for the thesis' two trackers (exact calibration)."""
    config = sensors_config(standard_rigs(), hysteresis=hysteresis)
    sensors = {}
    for s in config.sensors:
        sensors[s.name] = {
            "priority": s.priority,
            "rate": s.rate,
            "limits": s.limits,
            "calibration": {
                "C": as_yaml(s.master_from_sensor),
                "X": as_yaml(s.rto_from_base),
                "Y": as_yaml(s.ee_from_cto),
            },
        }
    path = tmp_path / "sensors.yaml"
    path.write_text(
        yaml.safe_dump({"master": "certus", "hysteresis": hysteresis, "sensors": sensors})
    )
    return path


TRACKER_PORTS = ("certus_cto", "certus_rto", "vicra_cto", "vicra_rto")


@pytest.fixture(
    params=[Activity.periodic(200), Activity.event(*TRACKER_PORTS, idle=0.1)],
    ids=["periodic", "event-driven"],
)
def rig(hub, peer, tmp_path, request):
    """Two trackers and the Sensor Manager, polling at 200 Hz or woken by the ports its
    sensors file declares (and by its own staleness deadlines)."""
    path = write_sensors(tmp_path)
    trackers, manager_side = Container("trackers", hub), Container("manager", peer)
    certus = trackers.add(TrackerSim("certus"), Activity.periodic(100), {"rig": "certus"})
    vicra = trackers.add(TrackerSim("vicra"), Activity.periodic(20), {"rig": "vicra", "seed": 1})
    manager = manager_side.add(
        SensorManager("sensor_manager"), request.param, {"sensors_file": str(path)}
    )
    for tracker in ("certus", "vicra"):  # as the topology's connections wire them
        for tool in ("cto", "rto"):
            manager_side.connect("sensor_manager", f"{tracker}_{tool}", f"{tracker}/{tool}")
    status = InputPort("status", EventMessage)
    status.bus = hub
    status.connect("sensor_manager/status")
    for c in (certus, vicra, manager):
        c.configure()
        assert c.start(), c.last_error
    trackers.start()
    manager_side.start()
    yield certus, vicra, manager
    status.close()
    manager_side.shutdown()
    trackers.shutdown()


def best(manager):
    return manager.call("current")["best"]


def test_the_component_chooses_the_master_then_swaps_on_a_fault(rig):
    certus, vicra, manager = rig
    assert wait_until(lambda: best(manager) == "certus", timeout=10)
    certus.call("occlude", tool="cto")
    assert wait_until(lambda: best(manager) == "vicra", timeout=5)
    health = manager.call("current")["health"]
    assert health["certus"]["cause"] == "cto_missing"
    certus.call("occlude", tool="cto", hidden=False)
    assert wait_until(lambda: best(manager) == "certus", timeout=5)
    certus.call("crash")
    assert wait_until(
        lambda: manager.call("current")["health"]["certus"]["cause"] == "stale", timeout=5
    )
    vicra.call("corrupt_data")
    assert wait_until(lambda: best(manager) is None, timeout=5)
    assert manager.robot_pose.stats.written > 0, "the best sensor's view was published"


def test_a_sensors_file_that_cannot_be_read_stops_configuration_with_its_location(hub, tmp_path):
    bad = tmp_path / "sensors.yaml"
    bad.write_text("sensors: {a: {priority: 1, rate: 0}}\n")
    side = Container("manager", hub)
    try:
        manager = side.add(SensorManager("sm"), Activity.periodic(200), {"sensors_file": str(bad)})
        assert manager.call("current") == {
            "best": None,
            "limits": {},
            "calibration": None,
            "health": {},
        }
        assert not manager.configure()
        assert manager.last_error.startswith(f"{bad}:1:")
        nameless = side.add(SensorManager("nameless"), Activity.periodic(200))
        assert not nameless.configure() and "sensors_file" in nameless.last_error
    finally:
        side.shutdown()


TICK = 1 / 256  # s: the stepped manager's cycle, exact in binary


class Stepped:
    """The Sensor Manager in a stepped container on the hub session; the test plays both
    trackers (their tools' ports) and the robot (its end-effector pose from joints) on
    the same session, so every sample has arrived when `tick` returns."""

    def __init__(self, hub, tmp_path, activity=None):
        self.clock = SimulatedClock()
        self.container = Container("c", hub, SteppedExecutor(self.clock))
        self.manager = self.container.add(
            SensorManager("sensor_manager"),
            activity or Activity.periodic(1 / TICK),
            {"sensors_file": str(write_sensors(tmp_path))},
        )
        self.rigs = standard_rigs()
        self.trackers = {
            f"{rig.name}/{tool}": writer_port(hub, f"{rig.name}/{tool}", Pose)
            for rig in self.rigs
            for tool in ("cto", "rto")
        }
        for key in self.trackers:
            self.container.connect("sensor_manager", key.replace("/", "_"), key)
        self.ee = writer_port(hub, "test/ee_pose", Pose)
        self.container.connect("sensor_manager", "ee_pose", "test/ee_pose")
        self.status = reader_port(hub, "sensor_manager/status", EventMessage)
        self.robot_pose = reader_port(hub, "sensor_manager/robot_pose", Pose)
        assert self.manager.configure() and self.manager.start(), self.manager.last_error
        self.rng = np.random.default_rng(3)
        self.hidden: set[str] = set()  # tracker/tool not seen
        self.ticks = 0
        self.statuses: list[tuple[int, dict]] = []  # (tick, payload)
        self.poses: list[Pose] = []

    def tick(self, n=1, kinematics=None):
        """`n` cycles with both trackers seeing the robot at rest at `ee_path(0)`;
        `kinematics`: the end-effector pose the robot's joints give, sent every cycle."""
        truth = ee_path(0.0)
        for _ in range(n):
            self.ticks += 1
            stamp = self.ticks * TICK
            for rig in self.rigs:
                samples = rig.observe(truth, self.rng, stamp)
                for tool, pose in zip(("cto", "rto"), samples, strict=True):
                    valid = f"{rig.name}/{tool}" not in self.hidden
                    self.trackers[f"{rig.name}/{tool}"].write(
                        dataclasses.replace(pose, valid=valid)
                    )
            if kinematics is not None:
                rotation = matrix_to_quat(kinematics[:3, :3])
                self.ee.write(Pose(tuple(kinematics[:3, 3]), rotation, stamp))
            self.container.executor.advance(TICK)
            self.statuses += [(self.ticks, m.payload) for m in drained(self.status)]
            self.poses += drained(self.robot_pose)

    def best(self):
        return self.statuses[-1][1]["best"]


@pytest.fixture
def stepped(hub, tmp_path):
    rig = Stepped(hub, tmp_path)
    yield rig
    rig.container.shutdown()


def test_the_tracking_status_is_said_at_once_on_every_change_and_every_half_second(stepped):
    stepped.tick()
    assert stepped.statuses == [(1, stepped.statuses[0][1])]  # before any sensor is chosen
    assert stepped.best() is None
    stepped.tick(2 * round(0.5 / TICK) + 10)
    period, chosen = round(0.5 / TICK), 3  # every half second; certus after 3 fresh frames
    assert [t for t, _ in stepped.statuses] == [1, chosen, chosen + period, chosen + 2 * period]
    assert [p["best"] for _, p in stepped.statuses] == [None, "certus", "certus", "certus"]
    stepped.hidden.add("certus/cto")
    before = stepped.ticks
    stepped.tick(3)
    assert stepped.statuses[-1] == (before + 1, stepped.statuses[-1][1])
    assert stepped.best() == "vicra"
    assert stepped.statuses[-1][1]["health"]["certus"]["cause"] == "cto_missing"


def test_the_best_sensors_end_effector_is_published_in_the_master_frame(stepped):
    stepped.tick(10)
    assert stepped.best() == "certus"
    pose = stepped.poses[-1]
    truth = stepped.rigs[0].rto_from_base @ ee_path(0.0)  # the master's reference frame
    assert np.linalg.norm(np.array(pose.position) - truth[:3, 3]) < 1e-3
    assert np.allclose(quat_to_matrix(np.array(pose.orientation)), truth[:3, :3], atol=1e-6)
    assert (pose.rms, pose.frame_number, pose.valid, pose.frame, pose.tool) == (
        0.0,
        0,
        True,
        "certus",
        "ee",
    )


def test_the_robots_own_kinematics_overrule_trackers_that_agree_with_each_other(stepped):
    truth = ee_path(0.0)
    stepped.tick(10, kinematics=truth)
    assert stepped.best() == "certus"
    off = rigid((0.02, 0.0, 0.0), (0.0, 0.0, 0.0)) @ truth  # 20 mm away from both trackers
    stepped.tick(3, kinematics=off)
    assert stepped.best() is None
    health = stepped.statuses[-1][1]["health"]
    assert {health[n]["cause"] for n in ("certus", "vicra")} == {"calibration"}
    assert "away from the robot's kinematics" in health["certus"]["detail"]
    stepped.tick(10, kinematics=truth)
    assert stepped.best() == "certus"


def test_the_ports_the_sensors_file_declares_stay_wired_through_cleanup_like_any_port(stepped):
    """The topology wires them, not configure: a manager cleaned up and configured again
    tracks again without anyone reconnecting it."""
    stepped.tick(5)
    manager = stepped.manager
    assert stepped.best() == "certus"
    assert manager.stop() and manager.cleanup()
    assert manager.inputs["certus_cto"].connected
    assert manager.configure() and manager.start(), manager.last_error
    stepped.tick(5)
    assert stepped.best() == "certus"
    assert manager.call("current")["health"]["vicra"]["ok"]


def test_trusting_again_is_refused_for_an_unknown_sensor_or_one_not_distrusted(stepped):
    from framework.errors import FwError

    stepped.tick(5)
    with pytest.raises(FwError, match=r"no sensor 'polaris': one of certus, vicra"):
        stepped.manager.call("trust", sensor="polaris")
    with pytest.raises(FwError, match="certus is not distrusted for a moved reference tool"):
        stepped.manager.call("trust", sensor="certus")


def test_the_manager_decides_once_per_tracker_frame_not_once_per_sample(stepped):
    stepped.tick(10)
    assert stepped.best() == "certus"
    certus = next(rig for rig in stepped.rigs if rig.name == "certus")
    cto, rto = certus.observe(ee_path(0.0), stepped.rng, stepped.ticks * TICK)

    def cycle(*samples):
        for tool, pose, frame in samples:
            stepped.trackers[f"certus/{tool}"].write(dataclasses.replace(pose, frame_number=frame))
        before = len(stepped.poses)
        stepped.container.executor.advance(TICK)
        stepped.poses += drained(stepped.robot_pose)
        return len(stepped.poses) - before  # decisions (each publishes the robot's pose)

    assert cycle(("cto", cto, 99)) == 0, "half of frame 99: its reference is on its way"
    assert cycle(("rto", rto, 99)) == 1, "the whole frame: one decision"
    assert cycle(("cto", cto, 100), ("rto", rto, 100)) == 1
    assert cycle(("cto", cto, 101)) == 0
    assert cycle() == 1, "a half frame waits once: the next wake decides with what came"


def test_trackers_that_all_fall_silent_are_said_stale_by_the_idle_wake(hub, tmp_path):
    """Woken by samples, the Sensor Manager must still wake by itself when none come: with
    both trackers silent, nothing else would ever say they are stale."""
    rig = Stepped(hub, tmp_path, Activity.event(*TRACKER_PORTS, idle=0.1))
    try:
        rig.tick(round(0.3 / TICK))
        assert rig.best() == "certus"
        rig.container.executor.advance(0.3)  # nobody sends
        rig.statuses += [(rig.ticks, m.payload) for m in drained(rig.status)]
        last = rig.statuses[-1][1]
        assert last["best"] is None, last
        assert {h["cause"] for h in last["health"].values()} == {"stale"}, last
    finally:
        rig.container.shutdown()


# --- trackers on a host whose clock runs apart (issue 46, docs/hosts.md) ------------------


def on_tracking_host(stepped: Stepped, offset: float | None) -> None:
    """Both trackers' samples come from another host (`tracking`) whose clock is
    `offset` s ahead of this one, as measured by a 1 ms round trip (None: not yet)."""
    from_host_apart(stepped.container, "tracking", "trackers", offset, tuple(stepped.trackers))


def approach(
    stepped: Stepped,
    skew: float,
    seconds: float,
    speed: float = 0.075,
    robot_skew: float = 0.0,
    robot_shift: float = 0.0,
) -> None:
    """The robot moves at `speed` (m/s) for `seconds`; both trackers see it at each
    tick's moment and stamp it on their host's clock, `skew` s ahead of this one, and
    the robot stamps its end-effector pose on its own, `robot_skew` s ahead (and says
    it `robot_shift` m further along x than it is)."""
    for _ in range(round(seconds / TICK)):
        stepped.ticks += 1
        t = stepped.ticks * TICK
        truth = rigid((speed * t, 0.0, 0.0), (0.0, 0.0, 0.0)) @ ee_path(0.0)
        for rig in stepped.rigs:
            seen = rig.observe(truth, stepped.rng, t + skew)
            for tool, pose in zip(("cto", "rto"), seen, strict=True):
                stepped.trackers[f"{rig.name}/{tool}"].write(pose)
        stamp = t + robot_skew
        said = truth[:3, 3] + (robot_shift, 0.0, 0.0)
        stepped.ee.write(Pose(tuple(said), matrix_to_quat(truth[:3, :3]), stamp))
        stepped.container.executor.advance(TICK)
        stepped.statuses += [(stepped.ticks, m.payload) for m in drained(stepped.status)]


def agrees_with_the_kinematics_throughout(stepped: Stepped) -> None:
    """The Certus chosen, and no tracker ever faulted for its calibration."""
    assert stepped.best() == "certus"
    causes = {p["health"][n]["cause"] for _, p in stepped.statuses for n in ("certus", "vicra")}
    assert "calibration" not in causes


@pytest.mark.parametrize("skew", [0.1, -0.1])
def test_samples_stamped_on_a_clock_apart_are_checked_against_the_robot_of_their_moment(
    stepped, skew
):
    """The tracking PC's clock runs 100 ms ahead (or behind) of the robot's while the
    robot approaches at 7.5 cm/s. Compared by their stamps as written, every sample
    would meet the robot 7.5 mm from where it saw it, beyond the 5 mm tolerance: a
    calibration fault on fresh, correct data. On the robot's clock, by the measured
    offset, both trackers agree with the kinematics throughout."""
    on_tracking_host(stepped, skew)
    approach(stepped, skew, 1.0)
    agrees_with_the_kinematics_throughout(stepped)


def test_samples_from_a_host_whose_clock_is_not_measured_yet_are_refused_and_said(stepped):
    refusals = []
    stepped.manager.add_refusal_listener(refusals.append)
    on_tracking_host(stepped, None)
    approach(stepped, 0.0, 0.1)
    assert stepped.best() is None
    assert "clock offset is not measured yet" in refusals[0].reason
    on_tracking_host(stepped, 0.0)
    approach(stepped, 0.0, 0.2)
    assert stepped.best() == "certus"


def on_robot_host(stepped: Stepped, offset: float | None) -> None:
    """The end-effector poses come from another host (`robot`) whose clock is `offset` s
    ahead of this one (None: not measured yet); the trackers are this host's."""
    from_host_apart(stepped.container, "robot", "robot", offset, ("test/ee_pose",))


@pytest.mark.parametrize("skew", [0.1, -0.1])
def test_robot_poses_stamped_on_a_clock_apart_are_paired_on_this_hosts_clock(stepped, skew):
    """The robot's host runs 100 ms apart from the Sensor Manager's, the trackers' is
    its own: the robot's poses move onto this clock before a sample meets them, so the
    trackers agree with the kinematics through the approach."""
    on_robot_host(stepped, skew)
    approach(stepped, 0.0, 1.0, robot_skew=skew)
    agrees_with_the_kinematics_throughout(stepped)


def test_robot_poses_from_a_host_whose_clock_is_not_measured_yet_are_refused_and_said(stepped):
    refusals = []
    stepped.manager.add_refusal_listener(refusals.append)
    on_robot_host(stepped, None)
    approach(stepped, 0.0, 0.2)
    assert any(r.port == "ee_pose" and "not measured yet" in r.reason for r in refusals)


def test_robot_poses_that_cannot_be_placed_in_time_judge_no_tracker(stepped):
    """A refused pose is not used in any way: while the robot's host is not measured,
    the robot saying it stands 2 cm from where both trackers see it faults neither
    (used as "the pose for every moment", it would fault both for their calibration)."""
    on_robot_host(stepped, None)
    approach(stepped, 0.0, 0.5, robot_shift=0.02)
    agrees_with_the_kinematics_throughout(stepped)
