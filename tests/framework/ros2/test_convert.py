"""Spec: fw samples cross to ROS 2 and back unchanged, in the bytes and type hashes ROS
nodes use; what a ROS node sends is checked like any sample fw reads, and a clock
running ahead on a ROS host never makes its data look fresher than they are."""

import json
import math
import time

import pytest
from hypothesis import given
from hypothesis import strategies as st

from framework.messages import JointState, Pose, Scalar
from framework.ros2.convert import (
    CONVERSIONS,
    Options,
    Refused,
    conversion,
    deserialize,
    serialize,
    type_hash,
)
from tests.conftest import REPO
from tests.support.ros2 import sdk_type_hash

finite = st.floats(-1e6, 1e6, allow_nan=False)
stamps = st.floats(1e9, 2e9, allow_nan=False)


NO_OPTIONS = Options()
POSE = "geometry_msgs/msg/PoseStamped"


def across(sample, ros_type, options=NO_OPTIONS, arrival=None):
    """`sample` to ROS, to CDR bytes, back, and to fw again."""
    c = conversion(ros_type)
    data = serialize(c.to_ros(sample, sample.stamp, options), ros_type)
    message = deserialize(data, ros_type)
    return c.from_ros(message, sample.stamp if arrival is None else arrival, options)


@pytest.mark.parametrize("ros_type", sorted(CONVERSIONS))
def test_type_hashes_agree_with_the_ones_zenoh_ros2_sdk_computes(ros_type):
    assert type_hash(ros_type) == sdk_type_hash(ros_type)


def test_the_schema_offers_exactly_the_types_fw_converts():
    schema = json.loads((REPO / "framework/schema/topology.schema.json").read_text())
    assert set(schema["$defs"]["rosType"]["enum"]) == set(CONVERSIONS)


def test_cdr_bytes_start_with_the_little_endian_encapsulation_header():
    c = conversion("std_msgs/msg/Float64")
    data = serialize(c.to_ros(Scalar(1.0, 2.5), 1.0, Options()), "std_msgs/msg/Float64")
    assert data[:4] == b"\x00\x01\x00\x00" and len(data) == 12


@given(st.lists(finite, min_size=1, max_size=9), stamps)
def test_joints_come_back_as_they_went(positions, stamp):
    n = len(positions)
    sample = JointState(stamp, tuple(positions), tuple(positions[::-1]), (0.5,) * n)
    back = across(sample, "sensor_msgs/msg/JointState")
    assert back.position == sample.position and back.velocity == sample.velocity
    assert back.effort == sample.effort
    assert abs(back.stamp - stamp) < 1e-6  # ROS time has nanoseconds


def test_received_joints_are_put_in_fws_order_by_name():
    c = conversion("sensor_msgs/msg/JointState")
    message = c.to_ros(JointState(5.0, (3.0, 1.0, 2.0)), 5.0, Options(names=("c", "a", "b")))
    back = c.from_ros(message, 6.0, Options(names=("a", "b", "c")))
    assert back.position == (1.0, 2.0, 3.0) and back.stamp == 5.0


def test_joints_missing_a_named_one_or_not_finite_are_refused():
    c = conversion("sensor_msgs/msg/JointState")
    message = c.to_ros(JointState(5.0, (1.0, 2.0)), 5.0, Options(names=("a", "b")))
    with pytest.raises(Refused, match=r"\['c'\] missing"):
        c.from_ros(message, 6.0, Options(names=("a", "b", "c")))
    message.position[1] = math.nan
    with pytest.raises(Refused, match="not finite"):
        c.from_ros(message, 6.0, Options())
    with pytest.raises(Refused, match="2 joints, and the topology names 1"):
        c.to_ros(JointState(5.0, (1.0, 2.0)), 5.0, Options(names=("a",)))


unit = st.tuples(finite, finite, finite, finite).filter(lambda q: math.hypot(*q) > 1e-3)


@given(st.tuples(finite, finite, finite), unit, stamps)
def test_poses_come_back_as_they_went(position, q, stamp):
    norm = math.hypot(*q)
    orientation = tuple(v / norm for v in q)
    sample = Pose(position, orientation, stamp, valid=True, frame="certus")
    back = across(sample, "geometry_msgs/msg/PoseStamped")
    assert back.position == position and back.frame == "certus" and back.valid
    assert back.orientation == pytest.approx(orientation, abs=1e-12)


def test_an_unseen_tool_is_not_sent_and_a_received_pose_must_be_a_rotation():
    c = conversion("geometry_msgs/msg/PoseStamped")
    with pytest.raises(Refused, match="not valid"):
        c.to_ros(Pose(valid=False), 1.0, Options())
    message = c.to_ros(Pose((0, 0, 0), (1, 0, 0, 0), 1.0, valid=True), 1.0, Options())
    message.pose.orientation.w = 0.5
    with pytest.raises(Refused, match=r"not a rotation \(\|q\| = 0.5\)"):
        c.from_ros(message, 2.0, Options())
    message.pose.orientation.w = 1.0
    message.pose.position.x = math.inf
    with pytest.raises(Refused, match="position is not finite"):
        c.from_ros(message, 2.0, Options())


@given(stamps, st.floats(-5.0, 5.0))
def test_a_received_stamp_is_never_later_than_the_arrival(sent, ahead):
    """A ROS host whose clock runs `ahead` seconds stamps `sent + ahead`: fw takes it as
    at most the arrival's time, so its age can only err on the old side."""
    c = conversion("geometry_msgs/msg/PoseStamped")
    message = c.to_ros(
        Pose((0, 0, 0), (1, 0, 0, 0), sent + ahead, valid=True), sent + ahead, Options()
    )
    arrival = sent + 0.002
    back = c.from_ros(message, arrival, Options())
    assert back.stamp <= arrival
    if ahead <= 0:
        assert back.stamp == pytest.approx(sent + ahead, abs=1e-6), "an older stamp is kept"


def test_an_unstamped_message_is_refused_unless_stamped_on_arrival():
    c = conversion("geometry_msgs/msg/PoseStamped")
    message = c.to_ros(Pose((0, 0, 0), (1, 0, 0, 0), 0.0, valid=True), 0.0, Options())
    with pytest.raises(Refused, match="not stamped"):
        c.from_ros(message, 10.0, Options())
    assert c.from_ros(message, 10.0, Options(stamp="arrival")).stamp == 10.0


@given(st.binary(max_size=64))
def test_any_bytes_are_a_message_or_refused(data):
    for ros_type in CONVERSIONS:
        try:
            deserialize(data, ros_type)
        except Refused as exc:
            assert str(exc)


def test_a_type_fw_does_not_bridge_is_named_with_the_ones_it_does():
    with pytest.raises(
        Exception, match=r"'nav_msgs/msg/Odometry'.*bridges: sensor_msgs/msg/JointState"
    ):
        conversion("nav_msgs/msg/Odometry")


def test_a_float64_is_stamped_on_arrival():
    c = conversion("std_msgs/msg/Float64")
    now = time.time()
    assert c.from_ros(c.to_ros(Scalar(1.0, 4.0), 1.0, Options()), now, Options()) == Scalar(
        now, 4.0
    )
    message = c.to_ros(Scalar(1.0, 4.0), 1.0, Options())
    message.data = math.nan
    with pytest.raises(Refused):
        c.from_ros(message, now, Options())


@pytest.mark.parametrize(
    "data",
    [
        b"",
        b"\x00\x01",
        b"\x01\x00\x00\x00" + bytes(8),
        b"\x00\x01\x00\x00",
        b"\x00\x01\x00\x00\x01",
    ],
)
def test_bytes_that_are_not_cdr_of_the_type_are_refused(data):
    with pytest.raises(Refused, match="not"):
        deserialize(data, "geometry_msgs/msg/PoseStamped")


def test_joints_whose_columns_disagree_in_length_are_refused():
    c = conversion("sensor_msgs/msg/JointState")
    message = c.to_ros(JointState(5.0, (1.0, 2.0), (0.1, 0.2)), 5.0, Options())
    message.velocity = message.velocity[:1]
    with pytest.raises(Refused, match="1 velocity values for 2 positions"):
        c.from_ros(message, 6.0, Options())
    message = c.to_ros(JointState(5.0, (1.0, 2.0)), 5.0, Options())
    message.name = ["only_one"]
    with pytest.raises(Refused, match="1 names for 2 positions"):
        c.from_ros(message, 6.0, Options())
