"""Spec: fw writes rmw_zenoh's keys, liveliness tokens and attachments as its design
says (../shared/FACTS.md), and as zenoh-ros2-sdk, written apart from fw, writes them."""

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from framework.ros2.rmw import (
    ATTACHMENT_SIZE,
    DEFAULT_QOS,
    Attachment,
    EntityKind,
    Node,
    RmwError,
    check_topic,
    dds_type,
    mangle,
    topic_key,
)

HASH = "RIHS01_" + "ab" * 32


def test_a_topic_key_is_domain_topic_dds_type_and_hash():
    key = topic_key(3, "/robot/joint_states", "sensor_msgs/msg/JointState", HASH)
    assert key == f"3/robot/joint_states/sensor_msgs::msg::dds_::JointState_/{HASH}"


@pytest.mark.parametrize(
    "bad", ["joint_states", "/", "/a//b", "/a/", "/1abc", "/a b", "/a-b", "/a/%b"]
)
def test_a_topic_name_ros_would_not_take_is_refused_with_the_reason(bad):
    with pytest.raises(RmwError, match="ROS topic"):
        check_topic(bad)


def test_types_must_be_package_msg_name():
    assert dds_type("std_msgs/msg/Float64") == "std_msgs::msg::dds_::Float64_"
    for bad in ("Float64", "std_msgs/Float64", "std_msgs/srv/Float64", "std_msgs/msg/float64"):
        with pytest.raises(RmwError):
            dds_type(bad)


def test_tokens_write_every_slash_inside_a_part_as_percent():
    node = Node(0, "a1b2", "fw_seeg")
    assert node.token() == "@ros2_lv/0/a1b2/0/0/NN/%/%/fw_seeg"
    token = node.endpoint_token(
        EntityKind.PUBLISHER, 4, "/robot/joints", "sensor_msgs/msg/JointState", HASH
    )
    assert token == (
        "@ros2_lv/0/a1b2/0/4/MP/%/%/fw_seeg/%robot%joints/"
        f"sensor_msgs::msg::dds_::JointState_/{HASH}/{DEFAULT_QOS}"
    )
    assert mangle("/ns/sub") == "%ns%sub" and mangle("") == "%"


def test_tokens_equal_the_ones_zenoh_ros2_sdk_declares():
    from zenoh_ros2_sdk.entity import EndpointEntity, NodeEntity
    from zenoh_ros2_sdk.entity import EntityKind as SdkKind
    from zenoh_ros2_sdk.keyexpr import endpoint_liveliness_keyexpr, node_liveliness_keyexpr

    sdk_node = NodeEntity(domain_id=7, session_id="zid9", node_id=2, node_name="fw")
    ours = Node(7, "zid9", "fw", node_id=2)
    assert ours.token() == node_liveliness_keyexpr(sdk_node)
    for kind in (EntityKind.PUBLISHER, EntityKind.SUBSCRIPTION):
        sdk = EndpointEntity(
            node=sdk_node,
            entity_id=5,
            kind=SdkKind(kind.value),
            name="/tracker/pose",
            dds_type_name=dds_type("geometry_msgs/msg/PoseStamped"),
            type_hash=HASH,
            qos=DEFAULT_QOS,
        )
        assert ours.endpoint_token(
            kind, 5, "/tracker/pose", "geometry_msgs/msg/PoseStamped", HASH
        ) == endpoint_liveliness_keyexpr(sdk)


def test_the_attachment_is_sequence_source_time_gid_length_and_gid():
    data = Attachment(1, 1_700_000_000_123_456_789, bytes(range(16))).encode()
    assert len(data) == ATTACHMENT_SIZE == 33
    assert struct.unpack_from("<qqB", data) == (1, 1_700_000_000_123_456_789, 16)
    assert data[17:] == bytes(range(16))


@given(st.integers(0, 2**63 - 1), st.integers(0, 2**63 - 1), st.binary(min_size=16, max_size=16))
def test_an_attachment_decodes_to_what_was_encoded(sequence, source_ns, gid):
    assert Attachment.decode(Attachment(sequence, source_ns, gid).encode()) == Attachment(
        sequence, source_ns, gid
    )


@given(st.binary(max_size=40))
def test_any_bytes_decode_to_an_attachment_or_a_clear_error(data):
    try:
        found = Attachment.decode(data)
    except RmwError as exc:
        assert "attachment" in str(exc)
    else:
        assert len(found.gid) == data[16]


def test_the_sdk_reads_our_attachment():
    from zenoh_ros2_sdk.attachment import Attachment as SdkAttachment

    ours = Attachment(42, 123, b"\x01" * 16)
    theirs = SdkAttachment.from_bytes(ours.encode())
    assert (theirs.sequence_id, theirs.timestamp_ns, theirs.gid) == (42, 123, b"\x01" * 16)


def test_a_gid_of_another_size_is_not_sent():
    with pytest.raises(RmwError, match="a GID is 16 bytes, not 8"):
        Attachment(1, 2, bytes(8)).encode()
