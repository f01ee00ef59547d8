"""Spec: the tracking topology deploys the whole chain on real processes: the simulated
Vicra on a pty read by the NDI driver, a simulated Certus, the Sensor Manager choosing."""

import dataclasses

from framework.deployer import Deployment
from framework.remote import RemoteComponent
from framework.topology import load_topology
from tests.conftest import REPO, wait_until


def test_the_tracking_chain_chooses_the_certus_and_falls_back_to_the_vicra(bus_config, tmp_path):
    topology = load_topology(REPO / "topologies" / "tracking.yaml")
    topology.bus = dataclasses.replace(
        topology.bus, namespace=bus_config.namespace, hub_port=bus_config.hub_port
    )
    link = str(tmp_path / "ttyVICRA")  # a private device node for this test
    topology.components["vicra_sim"].properties["link"] = link
    topology.components["vicra"].properties["device"] = link
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
