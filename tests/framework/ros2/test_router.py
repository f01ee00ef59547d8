"""Spec: `fw ros2 router` says in one line why it cannot listen."""

import pytest

from framework.bus import free_port
from framework.ros2.link import RosLinkError
from framework.ros2.router import open_router


def test_a_taken_port_or_a_bad_address_is_one_clear_line():
    port = free_port()
    router = open_router(f"tcp/127.0.0.1:{port}")
    try:
        with pytest.raises(RosLinkError, match=r"Address already in use.*router already there"):
            open_router(f"tcp/127.0.0.1:{port}")
    finally:
        router.close()
    with pytest.raises(RosLinkError) as bad:
        open_router("tcp/256.0.0.1:7447")
    assert "cannot listen on tcp/256.0.0.1:7447" in str(bad.value)
    assert ".rs:" not in str(bad.value), "no Rust source paths in what fw says"
