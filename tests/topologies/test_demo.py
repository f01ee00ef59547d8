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


def test_the_live_screen_says_not_responding_only_after_two_silent_screens(bus_config, tmp_path):
    """A component that misses one state query (a busy first second) keeps its last
    state, marked slow; only a second silent screen in a row says NOT RESPONDING (or
    LOST, once its bus lease has run out)."""
    import os
    import signal

    deployment = Deployment(private_topology(DEMO, bus_config), tmp_path)
    deployment.start()
    trackers = next(p for p in deployment.processes if p.name == "trackers")
    try:
        assert wait_until(
            lambda: deployment.coordinator.active()["active"] == ["Working.Use_T1"], timeout=10
        )
        seen: dict = {}

        def row(name):
            screen = live_screen(deployment, 0.0, seen=seen)
            return next(line for line in screen.splitlines() if line.startswith(name + " "))

        assert row("tracker_1").endswith(" Running")
        os.kill(trackers.popen.pid, signal.SIGSTOP)  # it hangs: no answers at all
        try:
            assert row("tracker_1").endswith(" Running (slow to answer)")
            second = row("tracker_1")
            assert second.endswith(" NOT RESPONDING") or " LOST (" in second, second
        finally:
            os.kill(trackers.popen.pid, signal.SIGCONT)
    finally:
        deployment.stop()


def test_the_live_screen_says_the_robot_sides_stop_and_why_as_the_console_does(hub):
    """Not only 'Stopped': the brakes, the latch, its reason and whether a RELEASE would
    be taken, asked of the component that hosts the safety monitor."""
    from types import SimpleNamespace

    from framework.activity import Activity, SteppedExecutor
    from framework.clock import SimulatedClock
    from framework.component import Component, operation
    from framework.container import Container

    class Robot(Component):
        @operation(readonly=True)
        def report(self) -> dict:
            return {
                "braked": True,
                "latched": "arm.measured: no data for 52 ms (deadline 50 ms)",
                "reason": "arm.measured: no data for 52 ms (deadline 50 ms)",
                "problems": [],
            }

    container = Container("c", hub, SteppedExecutor(SimulatedClock()))
    container.add(Robot("robot"), Activity.periodic(10))
    container.start()
    topology = SimpleNamespace(
        name="t", external_events=[], components={}, safety=SimpleNamespace(monitor="robot")
    )
    deployment = SimpleNamespace(
        topology=topology, coordinator=None, configurator=None, watch=None, hub=hub
    )
    try:
        screen = live_screen(deployment, 0.0)
        topology.safety = SimpleNamespace(monitor="nobody")
        silent = live_screen(deployment, 0.0)
    finally:
        container.shutdown()
    assert (
        "robot      SAFETY STOP: arm.measured: no data for 52 ms (deadline 50 ms) "
        "(RELEASE possible)" in screen
    )
    assert "robot      (nobody does not answer)" in silent
