"""zenoh-ros2-sdk, an rmw_zenoh peer written apart from fw, as the ROS 2 side of the
specs of framework/ros2: its type hashes, and its publishers and subscribers on a
real Zenoh router."""

from __future__ import annotations

import time
from typing import Any

from tests.conftest import REPO

MSGS = REPO / "tests" / "data" / "ros2_msgs"


def sdk_registry() -> Any:
    """The SDK's message registry, reading the .msg files of tests/data/ros2_msgs (the
    SDK would clone them from GitHub otherwise)."""
    from zenoh_ros2_sdk.message_registry import get_registry

    registry = get_registry(str(MSGS))
    assert registry.messages_dir == MSGS, "the SDK's registry was made elsewhere first"
    return registry


def sdk_type_hash(ros_type: str) -> str:
    """The RIHS01 hash the SDK computes from the .msg files."""
    from zenoh_ros2_sdk.utils import get_type_hash, load_dependencies_recursive

    registry = sdk_registry()
    definition = registry.get_msg_file_path(ros_type).read_text()
    return get_type_hash(
        ros_type, definition, load_dependencies_recursive(ros_type, definition, registry)
    )


def ros_time(store: Any, seconds: float) -> Any:
    """A builtin_interfaces/msg/Time of the SDK's type store."""
    sec = int(seconds)
    return store.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=int((seconds - sec) * 1e9))


def pose_stamped(store: Any, position, quaternion_xyzw, stamp: float | None = None, frame="map"):
    """Keyword arguments for the SDK's PoseStamped publisher."""
    header = store.types["std_msgs/msg/Header"](
        stamp=ros_time(store, time.time() if stamp is None else stamp), frame_id=frame
    )
    x, y, z, w = quaternion_xyzw
    pose = store.types["geometry_msgs/msg/Pose"](
        position=store.types["geometry_msgs/msg/Point"](*position),
        orientation=store.types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w),
    )
    return {"header": header, "pose": pose}
