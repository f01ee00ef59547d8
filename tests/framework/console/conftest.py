"""A deployment with its console served on a free port, for the console's tests."""

import contextlib

from framework.console.model import ConsoleModel
from framework.console.server import ConsoleServer
from framework.deployer import Deployment


@contextlib.contextmanager
def served(topology, workdir, **options):
    """Deploy `topology` and serve its console on 127.0.0.1 (any free port); yields
    (server, deployment) and shuts everything down afterwards."""
    deployment = Deployment(topology, workdir)
    deployment.start()
    model = ConsoleModel(deployment.hub, topology, deployment.coordinator.chart).start()
    server = ConsoleServer(model, "127.0.0.1", 0, **options)
    server.start()
    try:
        yield server, deployment
    finally:
        server.stop()
        model.stop()
        deployment.stop()
