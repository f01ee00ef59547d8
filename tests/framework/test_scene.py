"""Specs of Foxglove's well-known messages in flight recordings (framework/scene.py,
issue 48): decoded as Foxglove decodes them (protobuf, by the schema the file
carries), they say what fw's own messages said."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from framework import scene
from framework.messages import Envelopes, JointState, Pose
from tests.conftest import wait_until


def decoded(converted: scene.Converted):
    """The message as a reader of the recording gets it (protobuf, its own schema)."""
    from mcap.records import Schema
    from mcap_protobuf.decoder import DecoderFactory

    schema = Schema(id=1, name=converted.schema_name, encoding="protobuf", data=converted.schema)
    return DecoderFactory().decoder_for("protobuf", schema)(converted.data)


def test_a_pose_is_the_transform_from_its_frame_to_the_recorded_key():
    """fw's quaternions are (w, x, y, z): 90 deg about z must reach Foxglove as w=0.707,
    z=0.707, not with w read as x."""
    half = math.sqrt(0.5)
    pose = Pose((0.1, -0.2, 0.3), (half, 0.0, 0.0, half), stamp=12.25, frame="certus")
    message = decoded(scene.frame_transforms(pose, "certus/cto"))
    (transform,) = message.transforms
    assert (transform.parent_frame_id, transform.child_frame_id) == ("certus", "certus/cto")
    assert (transform.translation.x, transform.translation.y, transform.translation.z) == (
        0.1,
        -0.2,
        0.3,
    )
    r = transform.rotation
    assert (r.w, r.x, r.y, r.z) == pytest.approx((half, 0.0, 0.0, half))
    assert (transform.timestamp.seconds, transform.timestamp.nanos) == (12, 250_000_000)


def test_a_pose_without_a_frame_hangs_from_the_world():
    message = decoded(scene.frame_transforms(Pose((0.0, 0.0, 1.0)), "patient/pose"))
    assert message.transforms[0].parent_frame_id == "world"


def test_the_arms_joints_keep_their_order_and_units():
    sample = JointState(3.5, tuple(0.1 * i for i in range(7)), (0.5,) * 7, (2.0,) * 7)
    message = decoded(scene.joint_states(sample, "robot/joints"))
    assert [j.name for j in message.joints] == [f"a{i}" for i in range(1, 8)]
    assert [j.position for j in message.joints] == pytest.approx(sample.position)
    assert [j.velocity for j in message.joints] == pytest.approx(sample.velocity)
    assert [j.effort for j in message.joints] == pytest.approx(sample.effort)


def rotate(q, v):
    """`v` rotated by the unit quaternion `q` (a Foxglove Quaternion)."""
    w, u = q.w, np.array([q.x, q.y, q.z])
    v = np.asarray(v, float)
    return v + 2 * np.cross(u, np.cross(u, v) + w * v)


directions = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 3).filter(
    lambda v: math.dist(v, (0, 0, 0)) > 1e-3
)


@settings(max_examples=60, deadline=None)
@given(a=st.tuples(*[st.floats(-2, 2, allow_nan=False)] * 3), axis=directions)
def test_a_persons_capsule_is_a_cylinder_from_one_end_to_the_other(a, axis):
    """Whatever its direction (straight down included), the cylinder stands between
    the capsule's ends, as long as the segment, with a sphere on each end."""
    b = tuple(p + d for p, d in zip(a, axis, strict=True))
    message = decoded(scene.people(Envelopes(1.0, a, b, (0.2,)), "people/envelopes"))
    (entity,) = message.entities
    (cylinder,) = entity.cylinders
    length = math.dist(a, b)
    assert cylinder.size.z == pytest.approx(length)
    middle = cylinder.pose.position
    z = rotate(cylinder.pose.orientation, (0.0, 0.0, length / 2))
    top = np.array([middle.x, middle.y, middle.z]) + z
    assert top == pytest.approx(np.array(b), abs=1e-9)
    ends = [(s.pose.position.x, s.pose.position.y, s.pose.position.z) for s in entity.spheres]
    assert ends == [pytest.approx(a), pytest.approx(b)]
    assert (entity.frame_id, entity.id) == (scene.BASE_FRAME, "people/envelopes")


def test_refusals_and_faults_are_warnings_steps_are_information():
    from foxglove.messages import LogLevel

    def level(line):
        return decoded(scene.log(1.0, line)).level

    assert level("REFUSED    robot.envelopes: NaN") == LogLevel.Warning.value
    assert level("event      component.lost {}") == LogLevel.Warning.value
    assert level("transition A -> B") == LogLevel.Info.value


def test_a_recording_holds_the_foxglove_messages_beside_fws_own(hub, tmp_path):
    """Through a real bus: the chart's records become /fw/log lines worded as `fw log`
    words them, a recorded pose becomes /tf; `read_recording` (fw log, fw replay) still
    reads only fw's JSON channels."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    from framework.ports import OutputPort
    from framework.recorder import FlightRecorder, read_recording
    from framework.timeline import line

    path = tmp_path / "run.mcap"
    recorder = FlightRecorder(path, hub, {"test/tool": "Pose"})
    record = {"component": "vicra", "old": "Stopped", "new": "Running", "reason": ""}
    recorder.write("/fw/components", "fw.ComponentState", record, stamp=5.0)
    out: OutputPort[Pose] = OutputPort("tool", Pose)
    out.bus = hub
    out.connect("test/tool")
    poses = [Pose((0.01 * i, 0.0, 0.5), stamp=10.0 + i, frame="certus") for i in range(5)]
    for pose in poses:
        out.write(pose)
    # each pose: its fw.Sample record and its transform; the state record: itself and its line
    assert wait_until(lambda: recorder.count >= 2 + 2 * len(poses))
    recorder.close()

    with path.open("rb") as handle:
        found = [
            (channel.topic, message)
            for _, channel, _, message in make_reader(
                handle, decoder_factories=[DecoderFactory()]
            ).iter_decoded_messages(topics=["/fw/log", "/tf"])
        ]
    logs = [m.message for topic, m in found if topic == "/fw/log"]
    assert line("/fw/components", record) in logs
    tf = [m.transforms[0] for topic, m in found if topic == "/tf"]
    assert [t.translation.x for t in tf] == pytest.approx([p.position[0] for p in poses])
    assert {t.child_frame_id for t in tf} == {"test/tool"}
    topics = {topic for topic, _, _ in read_recording(path)}
    assert "/fw/log" not in topics and "/tf" not in topics and "/fw/components" in topics


def test_the_arms_links_are_drawn_from_its_joints_by_its_own_kinematics():
    """Each link in the one before it, base to TCP: composed, they put the TCP where the
    robot's kinematics do (the hook a topology's `record:` names)."""
    from components.domain import lwr4
    from components.domain.geometry import quat_to_matrix

    q = (0.3, -0.5, 0.2, 1.1, -0.4, 0.7, 0.1)
    message = decoded(scene.link_transforms(JointState(1.0, q), lwr4.link_poses))
    chain = [(t.parent_frame_id, t.child_frame_id) for t in message.transforms]
    names = ["base", *(f"link{i}" for i in range(1, 8)), "tcp"]
    assert chain == list(itertools.pairwise(names))
    composed = np.eye(4)
    for t in message.transforms:
        step = np.eye(4)
        step[:3, :3] = quat_to_matrix(
            np.array([t.rotation.w, t.rotation.x, t.rotation.y, t.rotation.z])
        )
        step[:3, 3] = (t.translation.x, t.translation.y, t.translation.z)
        composed = composed @ step
    assert composed == pytest.approx(lwr4.dh_forward(np.array(q)), abs=1e-9)


def broken_links(q):
    """A kinematics hook with a bug (for the spec below)."""
    raise ValueError(f"{len(q)} joints, expected 9")


def test_joints_a_hook_cannot_draw_are_said_once_and_the_recording_goes_on(hub, tmp_path):
    """A bug in the topology's kinematics hook costs the drawing, never the recording:
    fw's own samples are all kept, and the refusal is in the timeline once."""
    from framework.ports import OutputPort
    from framework.recorder import FlightRecorder, read_recording

    path = tmp_path / "run.mcap"
    recorder = FlightRecorder(
        path, hub, {"test/joints": "JointState"}, links={"test/joints": f"{__name__}:broken_links"}
    )
    out: OutputPort[JointState] = OutputPort("joints", JointState)
    out.bus = hub
    out.connect("test/joints")
    for i in range(5):
        out.write(JointState(1.0 + i, (0.0,) * 7))
    assert wait_until(lambda: recorder.count >= 7)  # 5 samples, 1 refusal and its line
    recorder.close()
    records = list(read_recording(path))
    assert sum(topic == "/fw/samples/test/joints" for topic, _, _ in records) == 5
    refusals = [data for topic, _, data in records if topic == "/fw/refused"]
    assert len(refusals) == 1 and "7 joints, expected 9" in refusals[0]["reason"]


def test_shapes_become_transforms_and_one_scene_entity_per_recorded_output():
    """A drawing function's frames go to `/tf`, its capsules (a cylinder and two end
    balls each) and spheres to `/scene/<key>`, in the frame it says."""
    drawn = scene.Shapes(
        frames=(("base", "goal/target", (0.1, 0.2, 0.3), (1.0, 0.0, 0.0, 0.0)),),
        capsules=(((0.0, 0.0, 0.0), (0.0, 0.0, 0.5), 0.05),),
        spheres=(((0.1, 0.2, 0.3), 0.04),),
        frame="base",
    )
    out = dict(scene.shapes(2.5, "navigator.goals", drawn))
    assert set(out) == {"/tf", "/scene/navigator.goals"}
    (t,) = decoded(out["/tf"]).transforms
    assert (t.parent_frame_id, t.child_frame_id) == ("base", "goal/target")
    assert (t.translation.x, t.translation.y, t.translation.z) == pytest.approx((0.1, 0.2, 0.3))
    (entity,) = decoded(out["/scene/navigator.goals"]).entities
    assert entity.frame_id == "base" and entity.id == "navigator.goals"
    (cylinder,) = entity.cylinders
    assert cylinder.size.z == pytest.approx(0.5) and cylinder.size.x == pytest.approx(0.1)
    centres = [(b.pose.position.x, b.pose.position.y, b.pose.position.z) for b in entity.spheres]
    assert np.array(centres) == pytest.approx(np.array([(0.1, 0.2, 0.3), (0, 0, 0), (0, 0, 0.5)]))
    assert [b.size.x for b in entity.spheres] == pytest.approx([0.08, 0.1, 0.1])
    assert scene.shapes(2.5, "nothing", scene.Shapes()) == [], "nothing to draw: no message"


def drawn_goals(sample):
    """A drawing function for the spec below: a sphere where the payload says."""
    return scene.Shapes(spheres=((tuple(sample.payload["at"]), 0.05),))


def test_a_drawn_output_of_any_kind_is_in_the_recording_beside_its_samples(hub, tmp_path):
    """`draw:` works on outputs Foxglove has no message for (an EventMessage): each
    sample recorded as fw's, and drawn on `/scene/<its name>`."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    from framework.messages import EventMessage
    from framework.ports import OutputPort
    from framework.recorder import FlightRecorder

    path = tmp_path / "run.mcap"
    recorder = FlightRecorder(
        path,
        hub,
        {"test/goals": "EventMessage"},
        names={"test/goals": "navigator.goals"},
        draws={"test/goals": f"{__name__}:drawn_goals"},
    )
    out: OutputPort[EventMessage] = OutputPort("goals", EventMessage)
    out.bus = hub
    out.connect("test/goals")
    for i in range(3):
        out.write(EventMessage(1.0 + i, "goals", "navigator", {"at": [0.1 * i, 0.0, 0.0]}))
    assert wait_until(lambda: recorder.count >= 6)  # 3 samples, 3 drawings
    recorder.close()
    with path.open("rb") as handle:
        reader = make_reader(handle, decoder_factories=[DecoderFactory()])
        drawn = [
            m.entities[0].spheres[0].pose.position.x
            for _, _, _, m in reader.iter_decoded_messages(topics=["/scene/navigator.goals"])
        ]
    assert drawn == pytest.approx([0.0, 0.1, 0.2])
