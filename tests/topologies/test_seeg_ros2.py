"""Spec: SEEG with its ROS 2 bridge (topologies/seeg_ros2.yaml) is clean, and the
bridge's process fails safe like any other: killed while the arm approaches the target,
with a ROS router linked, the robot ends braked and latched, the bridge comes back, and
nothing moves before the surgeon's RELEASE (procedures/seeg/scenarios/ros2/; the hang
scenario beside it is run by hand)."""

from framework.bus import free_port
from framework.ros2.router import open_router
from framework.topology import check_topology
from tests.conftest import REPO, check_scenarios, explain, play_scenario

SEEG_ROS2 = REPO / "topologies" / "seeg_ros2.yaml"
SCENARIOS = REPO / "procedures" / "seeg" / "scenarios" / "ros2"


def test_seeg_ros2_and_its_scenarios_are_clean():
    assert [f.one_line() for f in check_topology(SEEG_ROS2)[1]] == []
    check_scenarios(SEEG_ROS2, sorted(SCENARIOS.glob("*.yaml")))


def test_a_killed_bridge_brakes_the_robot_until_release(bus_config, tmp_path):
    port = free_port()
    overlay = tmp_path / "seeg_ros2_here.yaml"
    overlay.write_text(
        f"extends: {SEEG_ROS2}\ntopology: seeg_ros2_here\nros2:\n  router: tcp/127.0.0.1:{port}\n"
    )
    router = open_router(f"tcp/127.0.0.1:{port}")
    try:
        failed = play_scenario(overlay, SCENARIOS / "bridge_kill.yaml", bus_config, tmp_path)
    finally:
        router.close()
    assert not failed, explain(failed)
