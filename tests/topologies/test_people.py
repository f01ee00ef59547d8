"""Spec: the people topology deploys two simulated Kinects and the detector on real
processes; a person placed in the room becomes one confirmed person, leaving removes them."""

from framework.deployer import Deployment
from framework.remote import RemoteComponent
from tests.conftest import REPO, private_topology, wait_until


def test_a_person_in_the_room_is_one_person_and_leaving_clears_it(bus_config, tmp_path):
    topology = private_topology(REPO / "topologies" / "people.yaml", bus_config)
    deployment = Deployment(topology, tmp_path)
    deployment.start()
    try:
        hub = deployment.hub
        detector = RemoteComponent(hub, "people_detector", 5.0)
        assert wait_until(lambda: detector.state() == "Running", timeout=15)
        for camera in ("kinect_0", "kinect_1"):  # the same person, seen by both cameras
            RemoteComponent(hub, camera, 5.0).call("place", person=1, x=0.5, y=0.0)

        def people():
            return detector.call("current")["people"]

        assert wait_until(lambda: len(people()) == 1, timeout=10), detector.call("current")
        person = people()[0]
        assert person["cameras"] == ["kinect_0", "kinect_1"], (
            "named as in procedures/people_demo/cameras.yaml"
        )
        assert abs(person["torso"][0] - 0.5) < 0.15 and abs(person["torso"][1]) < 0.15
        assert wait_until(lambda: detector.call("current")["users_near"] == 1, timeout=5)
        for camera in ("kinect_0", "kinect_1"):
            RemoteComponent(hub, camera, 5.0).call("remove", person=1)
        assert wait_until(lambda: people() == [], timeout=10)
    finally:
        deployment.stop()
