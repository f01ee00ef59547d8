"""Spec: a topology's `ros2:` section becomes bridge components and connections that
the loader checks like any other, each finding located at the entry that wrote it."""

import shutil

from framework.topology import check_topology, load_topology
from framework.topology.model import StepKind
from tests.conftest import REPO

TOY = REPO / "tests" / "data" / "toy"


def toy_with(tmp_path, section: str):
    """The toy topology with `section` appended, next to a copy of its chart."""
    shutil.copy(TOY / "toy_chart.yaml", tmp_path / "toy_chart.yaml")
    path = tmp_path / "toy.yaml"
    path.write_text((TOY / "toy.yaml").read_text() + section)
    return path


SECTION = """ros2:
  router: tcp/127.0.0.1:7999
  domain: 4
  publish:
    - {from: t1.out, topic: /fw/count, type: std_msgs/msg/Float64, rate: 10}
  subscribe:
    - {topic: /ros/pose, type: geometry_msgs/msg/PoseStamped, to: supervisor.pose, frame: map}
"""


def errors(path):
    return [f for f in check_topology(path)[1] if f.severity == "error"]


def test_each_topic_becomes_a_bridge_component_in_the_bridge_process(tmp_path):
    path = toy_with(tmp_path, SECTION)
    assert errors(path) == []
    topo = load_topology(path)
    out, into = topo.components["ros2_out_fw_count"], topo.components["ros2_in_ros_pose"]
    assert out.class_path == "framework.ros2.bridge:ScalarToRos"
    assert into.class_path == "framework.ros2.bridge:PoseFromRos"
    assert out.process == into.process == "ros2" and "ros2" in topo.processes
    assert out.properties["router"] == "tcp/127.0.0.1:7999" and out.properties["domain"] == 4
    assert out.properties["node"] == "fw_toy" and into.properties["frame"] == "map"
    assert into.output_key("sample") == "ros2/ros/pose"
    wiring = {(s.component, s.target, s.key) for s in topo.connections}
    assert ("ros2_out_fw_count", "sample", "t1/out/at_10hz") in wiring
    assert ("supervisor", "pose", "ros2/ros/pose") in wiring
    assert all(s.kind is StepKind.CONNECT for s in topo.connections)


def test_without_a_section_nothing_is_added(tmp_path):
    topo = load_topology(toy_with(tmp_path, ""))
    assert not [c for c in topo.components if c.startswith("ros2_")]
    assert "ros2" not in topo.processes


def test_a_wrong_output_or_type_is_found_at_the_entry_that_says_it(tmp_path):
    path = toy_with(
        tmp_path,
        "ros2:\n"
        "  publish:\n"
        "    - {from: t1.nope, topic: /a, type: std_msgs/msg/Float64}\n"
        "    - {from: t1.out, topic: /b, type: sensor_msgs/msg/JointState}\n"
        "  subscribe:\n"
        "    - {topic: /c, type: std_msgs/msg/Float64, to: supervisor.pose}\n",
    )
    base = len((TOY / "toy.yaml").read_text().splitlines())
    found = {(f.code, f.location.line - base) for f in errors(path)}
    assert ("unknown-port", 3) in found, found
    assert ("type-mismatch", 4) in found, "a Scalar output is not a JointState"
    assert ("type-mismatch", 6) in found, "a Float64 topic cannot feed a Pose input"
    assert all(f.location.file == str(path) for f in errors(path))
    said = {f.code: f.location.path for f in errors(path) if f.location.line - base == 6}
    assert said == {"type-mismatch": "ros2.subscribe[0]"}, "the path the user wrote"


def test_a_bad_topic_or_an_unbridged_type_is_a_schema_error_with_its_line(tmp_path):
    path = toy_with(
        tmp_path,
        "ros2:\n  publish:\n    - {from: t1.out, topic: joint_states, type: std_msgs/msg/Float64}\n"
        "    - {from: t1.out, topic: /x, type: nav_msgs/msg/Odometry}\n",
    )
    found = errors(path)
    base = len((TOY / "toy.yaml").read_text().splitlines())
    assert {f.location.line - base for f in found} == {3, 4}, [f.one_line() for f in found]


def test_two_entries_that_would_share_a_component_name_are_told_apart(tmp_path):
    path = toy_with(
        tmp_path,
        "ros2:\n  publish:\n"
        "    - {from: t1.out, topic: /a/b, type: std_msgs/msg/Float64}\n"
        "    - {from: t2.out, topic: /a_b, type: std_msgs/msg/Float64}\n",
    )
    (finding,) = [f for f in errors(path) if f.code == "ros2-name"]
    assert "ros2_out_a_b" in finding.message and "name:" in finding.hint
    assert finding.location.line == len((TOY / "toy.yaml").read_text().splitlines()) + 4


def test_loading_a_bridged_topology_maps_no_rosbags():
    """Every process loads the whole topology, the bridge classes with it; only the
    bridge's process may map rosbags (each library mapped lengthens crash detection)."""
    import subprocess
    import sys

    code = (
        "import sys; from framework.topology import load_topology; "
        "load_topology('topologies/seeg_ros2.yaml'); "
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('rosbags', 'ruamel')))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "[]", out.stdout


def test_the_bridge_may_publish_on_fws_bus_only_what_it_reads_from_ros(tmp_path):
    """The access rules every session enforces (framework/access.py) let the bridge's
    process put data only on its subscribed topics' keys: whatever a ROS node sends,
    it cannot pose as the robot, a tracker or the chart."""
    from framework.access import process_keys

    seeg = load_topology(REPO / "topologies" / "seeg_ros2.yaml")
    assert [k for k in process_keys(seeg, "ros2")["put"] if not k.startswith("fw/")] == []
    toy = load_topology(toy_with(tmp_path, SECTION))
    assert [k for k in process_keys(toy, "ros2")["put"] if not k.startswith("fw/")] == [
        "ros2/ros/pose"
    ]
