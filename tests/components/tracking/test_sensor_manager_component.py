"""Spec: the Sensor Manager component reads real tracker ports and publishes its choice."""

import pytest

from components.tracking.certus_sim import TrackerSim
from components.tracking.sensor_manager import SensorManager
from components.tracking.synthetic import sensors_config, standard_rigs
from framework.activity import Activity
from framework.container import Container
from framework.messages import EventMessage
from framework.ports import InputPort
from tests.conftest import wait_until


@pytest.fixture
def rig(hub, peer, tmp_path):
    import yaml

    from components.tracking.geometry import matrix_to_quat

    config = sensors_config(standard_rigs(), hysteresis=3)
    sensors = {}

    def as_yaml(t):
        return {"position": t[:3, 3].tolist(), "quaternion": list(matrix_to_quat(t[:3, :3]))}

    for s in config.sensors:
        sensors[s.name] = {
            "priority": s.priority,
            "rate": s.rate,
            "keys": {"cto": f"{s.name}/cto", "rto": f"{s.name}/rto"},
            "limits": s.limits,
            "calibration": {
                "C": as_yaml(s.master_from_sensor),
                "X": as_yaml(s.rto_from_base),
                "Y": as_yaml(s.ee_from_cto),
            },
        }
    path = tmp_path / "sensors.yaml"
    path.write_text(yaml.safe_dump({"master": "certus", "hysteresis": 3, "sensors": sensors}))
    trackers, manager_side = Container("trackers", hub), Container("manager", peer)
    certus = trackers.add(TrackerSim("certus"), Activity.periodic(100), {"rig": "certus"})
    vicra = trackers.add(TrackerSim("vicra"), Activity.periodic(20), {"rig": "vicra", "seed": 1})
    manager = manager_side.add(
        SensorManager("sensor_manager"), Activity.periodic(200), {"sensors_file": str(path)}
    )
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
    assert manager.robot_pose.stats.written > 10


def test_a_sensors_file_that_cannot_be_read_stops_configuration_with_its_location(hub, tmp_path):
    bad = tmp_path / "sensors.yaml"
    bad.write_text("sensors: {a: {priority: 1, rate: 0, keys: {cto: x, rto: y}}}\n")
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
