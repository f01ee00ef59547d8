"""Fixtures shared by the framework's tests."""

import pytest

from framework.deployer import Deployment


@pytest.fixture
def deployed(toy, tmp_path):
    """The toy topology deployed on real processes (stopped after the test)."""
    deployment = Deployment(toy, tmp_path)
    deployment.start()
    yield deployment
    deployment.stop()
