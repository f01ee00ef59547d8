"""Spec: the tracking topology deploys the whole chain on real processes: the simulated
Vicra on a pty read by the NDI driver, a simulated Certus, the Sensor Manager choosing."""

from framework.deployer import Deployment
from framework.remote import RemoteComponent
from tests.conftest import REPO, private_topology, wait_until


def test_the_tracking_chain_chooses_the_certus_and_falls_back_to_the_vicra(bus_config, tmp_path):
    topology = private_topology(REPO / "topologies" / "tracking.yaml", bus_config, tmp_path)
    deployment = Deployment(topology, tmp_path / "logs")
    deployment.start()
    try:
        manager = RemoteComponent(deployment.hub, "sensor_manager")

        def current():
            return manager.call("current")

        assert wait_until(
            lambda: current()["best"] == "certus" and current()["health"]["vicra"]["ok"], timeout=15
        ), current()
        assert RemoteComponent(deployment.hub, "vicra").call("status")["frames"] > 0
        RemoteComponent(deployment.hub, "certus").call("occlude", tool="cto")
        assert wait_until(lambda: current()["best"] == "vicra", timeout=5)
        assert current()["health"]["certus"]["cause"] == "cto_missing"
        RemoteComponent(deployment.hub, "vicra_sim").call("occlude", tool="rto")
        assert wait_until(lambda: current()["best"] is None, timeout=5), "no tracker left"
    finally:
        deployment.stop()
