"""Spec: the demo topology of the README validates and really runs: it swaps trackers
on its own, stops on e_STOP and resumes on e_RELEASE."""

from framework.cli_deploy import live_screen
from framework.deployer import Deployment
from framework.remote import RemoteComponent
from framework.statechart.files import validate_file
from framework.topology import check_topology
from tests.conftest import REPO, private_topology, wait_until

DEMO = REPO / "topologies" / "demo.yaml"


def test_the_demo_topology_and_chart_are_clean():
    assert [f for f in check_topology(DEMO)[1]] == []
    assert validate_file(REPO / "statecharts" / "demo.yaml") == []


def test_the_demo_runs_swaps_stops_and_resumes(bus_config, tmp_path):
    topology = private_topology(DEMO, bus_config)
    deployment = Deployment(topology, tmp_path)
    deployment.start()
    try:

        def leaf():
            return deployment.coordinator.active()["active"]

        assert wait_until(lambda: leaf() == ["Working.Use_T1"], timeout=10)
        assert wait_until(lambda: leaf() == ["Working.Use_T2"], timeout=10), "swapped by itself"
        deployment.send("e_STOP")
        assert wait_until(
            lambda: leaf() == ["Stopped"] and not deployment.coordinator.active()["pending"],
            timeout=10,
        )
        state = RemoteComponent(deployment.hub, "supervisor").state()
        assert state == "Stopped", "all_stop stopped the robot side"
        screen = live_screen(deployment, 0.0)
        assert "chart      Stopped" in screen and "supervisor" in screen
        deployment.send("e_RELEASE")
        assert wait_until(lambda: leaf() == ["Working.Use_T1"], timeout=10)
    finally:
        deployment.stop()
