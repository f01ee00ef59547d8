"""Spec: a topology is checked completely before anything starts; errors are located."""

import os
import subprocess
import sys

import pytest

from framework.errors import FindingsError
from framework.topology import check_topology, load_topology
from framework.topology.model import Recorded
from tests.conftest import REPO

TOY = (REPO / "tests" / "data" / "toy" / "toy.yaml").read_text()


def findings(write, text, name="topo.yaml"):
    chart = (REPO / "tests" / "data" / "toy" / "toy_chart.yaml").read_text()
    write(chart, "toy_chart.yaml")
    _, found = check_topology(write(text, name))
    return found


def codes(write, text):
    return {f.code for f in findings(write, text) if f.severity == "error"}


def test_the_toy_topology_is_clean():
    topology = load_topology(REPO / "tests" / "data" / "toy" / "toy.yaml")
    assert list(topology.configurations) == ["setup", "tracker_1_up", "tracker_2_up", "broken"]
    steps = [s.describe() for s in topology.configurations["tracker_1_up"].steps]
    assert steps == [
        "state supervisor -> stopped",
        "disconnect supervisor.inp",
        "connect supervisor.inp -> t1/out",
        "state supervisor -> running",
    ]


@pytest.mark.parametrize(
    ("old", "new", "code"),
    [
        ("components.demo:Sink", "components.demo:Sinc", "class"),
        ("components.demo:Sink", "components.nowhere:Sink", "class"),
        ("{step: 1.0}", "{step: fast}", "property-value"),
        ("{step: 1.0}", "{stride: 1.0}", "unknown-property"),
        (
            "disconnect: supervisor.inp\n      - connect: {port: supervisor.inp, from: t1.out",
            "disconnect: supervisor.inpt\n      - connect: {port: supervisor.inp, from: t1.out",
            "unknown-port",
        ),
        ("call: supervisor.fail", "call: supervisor.explode", "unknown-operation"),
        (
            "call: supervisor.fail",
            "call: {operation: supervisor.slow, args: {minutes: 1}}",
            "operation-args",
        ),
        (
            "pre: {supervisor: stopped}\n    do:\n      - disconnect: supervisor.inp\n      - "
            "connect: {port: supervisor.inp, key: t2/out",
            "pre: {supervisr: stopped}\n    do:\n      - disconnect: supervisor.inp\n      - "
            "connect: {port: supervisor.inp, key: t2/out",
            "unknown-component",
        ),
        (
            "connect: {port: supervisor.inp, key: t2/out",
            "connect: {port: supervisor.pose, key: t2/out",
            "type-mismatch",
        ),
        (
            "connect: {port: supervisor.inp, key: t2/out",
            "connect: {port: supervisor.inp, key: t2/out, rate: 10",
            "rate",
        ),
        ("  broken:\n", "  brokn:\n", "unknown-tag"),
        ("external_events: [e_SWAP, e_BREAK]", "external_events: [e_SWAP]", "no-producer"),
        ("activity: {event: inp}", "activity: {event: input}", "activity"),
        ("activity: {event: inp}", "activity: {after: t1}", "activity"),  # another process
        ("activity: {event: inp}", "activity: {after: t9}", "activity"),  # no such component
        ("activity: {event: inp}", "activity: {after: supervisor}", "activity"),  # itself
        ("process: trackers", "process: tracker", "process"),
        (
            "  trackers: {}\n  control_side: {shutdown: first}\n",
            "  trackers: {host: cart}\n  control_side: {shutdown: first}\n"
            "hosts:\n  tower: {address: 10.0.0.7}\n",
            "host",
        ),
    ],
)
def test_every_cross_check_is_located(write, old, new, code):
    assert old in TOY, old
    found = findings(write, TOY.replace(old, new, 1))
    errors = [f for f in found if f.code == code]
    assert errors, [f.one_line() for f in found]
    assert errors[0].location.line > 0 and errors[0].message


def test_a_rate_thins_the_writers_stream_for_that_reader_and_the_writer_may_publish_it(write):
    from framework.access import process_keys
    from framework.deployer import container_spec

    write((REPO / "tests" / "data" / "toy" / "toy_chart.yaml").read_text(), "toy_chart.yaml")
    old = "connect: {port: supervisor.inp, from: t1.out, policy"
    assert old in TOY
    topology = load_topology(
        write(TOY.replace(old, "connect: {port: supervisor.inp, from: t1.out, rate: 10, policy"))
    )
    steps = topology.configurations["tracker_1_up"].steps
    assert [s.key for s in steps if s.kind == "connect"] == ["t1/out/at_10hz"]
    assert topology.thinned == {"t1": {"out": {"t1/out/at_10hz": 10.0}}}
    hosted = {c["name"]: c["thinned"] for c in container_spec(topology, "trackers")["components"]}
    assert hosted == {"t1": {"out": {"t1/out/at_10hz": 10.0}}, "t2": {}}
    assert "t1/out/at_10hz" in process_keys(topology, "trackers")["put"]
    assert "t1/out/at_10hz" not in process_keys(topology, "control_side")["put"]


def test_a_recorded_output_is_thinned_at_its_writer_and_named_for_a_viewer(write):
    """`record:` keeps an output in flight recordings: thinned where a rate is given
    (the writer publishes that stream, as for a connection's rate), with its message
    type, the frame its poses are in and its `component.port` name."""
    from framework.access import process_keys

    write((REPO / "tests" / "data" / "toy" / "toy_chart.yaml").read_text(), "toy_chart.yaml")
    recorded = "record:\n  - {from: t1.out, rate: 10, frame: camera}\n  - {from: t2.out}\nprepare:"
    topology = load_topology(write(TOY.replace("prepare:", recorded, 1)))
    assert topology.records == {
        "t1/out/at_10hz": Recorded("Scalar", "t1.out", frame="camera"),
        "t2/out": Recorded("Scalar", "t2.out"),
    }
    assert "t1/out/at_10hz" in process_keys(topology, "trackers")["put"]


def test_a_recorded_output_that_does_not_exist_is_located(write):
    write((REPO / "tests" / "data" / "toy" / "toy_chart.yaml").read_text(), "toy_chart.yaml")
    found = findings(write, TOY.replace("prepare:", "record:\n  - {from: t1.outt}\nprepare:", 1))
    (error,) = [f for f in found if f.code == "unknown-port"]
    assert "no output port 'outt'" in error.message and error.location.line > 0


@pytest.mark.parametrize(
    "entry, says",
    [
        ("{from: t1.out, links: components.domain.lwr4:link_poses}", "links are drawn from joints"),
        ("{from: t1.out, links: nowhere.at_all:f}", "cannot import 'nowhere.at_all'"),
        ("{from: t1.out, draw: nowhere.at_all:f}", "cannot import 'nowhere.at_all'"),
    ],
)
def test_links_drawn_from_what_is_not_joints_or_not_a_function_are_located(write, entry, says):
    write((REPO / "tests" / "data" / "toy" / "toy_chart.yaml").read_text(), "toy_chart.yaml")
    found = findings(write, TOY.replace("prepare:", f"record:\n  - {entry}\nprepare:", 1))
    code = "record-draw" if "draw:" in entry else "record-links"
    errors = [f for f in found if f.code == code and says in f.message]
    assert errors and errors[0].location.line > 0, [f.one_line() for f in found]


def test_schema_errors_are_located_with_hints(write):
    found = findings(
        write,
        TOY.replace(
            "    do:\n      - call: supervisor.fail", "    does:\n      - call: supervisor.fail"
        ),
    )
    assert found[0].code == "schema" and "did you mean 'do'" in found[0].hint


def test_load_raises_with_every_error(write):
    bad = TOY.replace("{step: 1.0}", "{step: fast}").replace(
        "call: supervisor.fail", "call: supervisor.explode"
    )
    write((REPO / "tests" / "data" / "toy" / "toy_chart.yaml").read_text(), "toy_chart.yaml")
    with pytest.raises(FindingsError) as err:
        load_topology(write(bad, "bad.yaml"))
    assert {f.code for f in err.value.findings} >= {"property-value", "unknown-operation"}


def test_a_required_property_left_out_is_named_before_anything_starts(tmp_path):
    text = (REPO / "topologies" / "seeg.yaml").read_text()
    text = text.replace("../statecharts/seeg.yaml", str(REPO / "statecharts" / "seeg.yaml"))
    supervisor = (
        "    properties: {procedure_file: procedures/seeg.yaml}\n    outputs: {events: fw/events}"
    )
    assert supervisor in text
    text = text.replace(supervisor, "    outputs: {events: fw/events}")
    path = tmp_path / "seeg.yaml"
    path.write_text(text)
    with pytest.raises(FindingsError) as err:
        load_topology(path)
    missing = [f for f in err.value.findings if f.code == "missing-property"]
    assert [f.message for f in missing] == [
        "'supervisor' needs property 'procedure_file' (procedure YAML (target, areas, speeds))"
    ]
    assert missing[0].location.line > 0


SAFE = TOY.replace(
    "prepare:",
    "safety:\n  monitor: supervisor\n  watch: {t1: 100ms, t2.out: 50ms}\nprepare:",
)


def test_a_safety_section_names_a_monitor_that_can_host_one(write):
    found = [f for f in findings(write, SAFE) if f.code == "safety-monitor"]
    assert found and "cannot host the safety monitor" in found[0].message
    assert found[0].location.line == TOY.split("\n").index("prepare:") + 2


def test_safety_watches_must_exist_beat_and_keep_their_deadline(write):
    text = SAFE.replace("{t1: 100ms, t2.out: 50ms}", "{t1: 30ms, t2.nope: 50ms, supervisor: 1s}")
    found = {f.code: f.message for f in findings(write, text)}
    assert "unknown-port" in found and "'nope'" in found["unknown-port"]
    watches = [f.message for f in findings(write, text) if f.code == "safety-watch"]
    assert any("shorter than two of its periods" in m for m in watches), "t1 runs at 50 Hz"
    text = SAFE.replace("activity: {event: inp}", "activity: passive").replace(
        "{t1: 100ms, t2.out: 50ms}", "{supervisor: 100ms}"
    )
    watches = [f.message for f in findings(write, text) if f.code == "safety-watch"]
    assert watches and "only a periodic, event-driven or paced component beats" in watches[0]


def test_the_safety_spec_watches_heartbeats_ports_processes_and_every_component(write):
    from framework.safety import heartbeat_period

    robot = (
        "  robot:\n    class: components.robot.interface:RobotInterface\n"
        "    process: control_side\n    activity: {paced: 20ms}\n"
    )
    text = SAFE.replace("monitor: supervisor", "monitor: robot").replace(
        "safety:", robot + "safety:"
    )
    found = findings(write, text)
    assert not [f for f in found if f.severity == "error"], found
    topology, _ = check_topology(write(text, "topo.yaml"))
    spec = topology.safety
    names = {w.name: (w.key, w.deadline, w.producer) for w in spec.watches}
    assert names["t1"] == ("fw/heartbeat/t1", 0.1, "t1")
    assert names["t2.out"] == ("t2/out", 0.05, "t2")
    assert names["process trackers"][0] == "fw/process/trackers/heartbeat"
    assert names["process control"][1] == 4 * spec.process_deadline, "the chart is slower"
    assert set(spec.components) == {
        "t1",
        "t2",
        "supervisor",
        "robot",
        "configurator",
        "coordinator",
    }
    assert topology.heartbeats() == {"t1": heartbeat_period(0.1)}


def test_hosts_give_the_addresses_processes_listen_on_and_certificates_name(write):
    text = TOY.replace("  trackers: {}\n", "  trackers: {host: cart}\n").replace(
        "processes:", "bus: {address: 10.0.0.1}\nhosts:\n  cart: {address: 10.0.0.7}\nprocesses:"
    )
    chart = (REPO / "tests" / "data" / "toy" / "toy_chart.yaml").read_text()
    write(chart, "toy_chart.yaml")
    topology = load_topology(write(text, "topo.yaml"))
    assert topology.bus.hub_endpoint.endswith("/10.0.0.1:7447")
    assert topology.listen_address("cart") == "10.0.0.7"
    assert topology.listen_address("local") == ""
    assert topology.addresses() == ["127.0.0.1", "10.0.0.1", "10.0.0.7"]


def seeg_with(tmp_path, sensors_text=None, cameras_text=None, rewire=None):
    """The SEEG topology, its sensors or cameras file replaced by the given text; with
    `rewire` (old, new), one of its connection lines replaced."""
    text = (REPO / "topologies" / "seeg.yaml").read_text(encoding="utf-8")
    if rewire is not None:
        assert rewire[0] in text, rewire[0]
        text = text.replace(*rewire)
    text = text.replace("../statecharts/", f"{REPO}/statecharts/")
    text = text.replace("procedure: ../procedures", f"procedure: {REPO}/procedures")
    for name, replaced in (("sensors", sensors_text), ("cameras", cameras_text)):
        if replaced is not None:
            (tmp_path / f"{name}.yaml").write_text(replaced, encoding="utf-8")
            text = text.replace(f"procedures/seeg/{name}.yaml", str(tmp_path / f"{name}.yaml"))
    (tmp_path / "seeg.yaml").write_text(text, encoding="utf-8")
    return tmp_path / "seeg.yaml"


def test_ports_declared_by_configuration_files_are_wired_by_the_topology(tmp_path):
    """The Sensor Manager has two ports per sensor of its sensors file, the detector one
    per camera of its cameras file: the topology's connections wire them like any other
    port, so validate sees who feeds them."""
    topo = load_topology(seeg_with(tmp_path))
    declared = {(name, link.port): link for name, link in topo.file_links}
    assert set(declared) == {
        ("sensor_manager", "certus_cto"),
        ("sensor_manager", "certus_rto"),
        ("sensor_manager", "vicra_cto"),
        ("sensor_manager", "vicra_rto"),
        ("people_detector", "camera_kinect_0"),
        ("people_detector", "camera_kinect_1"),
    }
    wired = {(s.component, s.target): s.key for s in topo.connections}
    assert wired[("sensor_manager", "vicra_rto")] == "vicra/reference_tool_optical"
    assert wired[("people_detector", "camera_kinect_1")] == "kinect/1/users"


def test_a_sensor_added_to_the_file_but_not_wired_is_an_error_that_says_what_to_add(tmp_path):
    sensors = (REPO / "procedures" / "seeg" / "sensors.yaml").read_text(encoding="utf-8")
    third = sensors + "  polaris: {priority: 3, rate: 60.0}\n"
    _, found = check_topology(seeg_with(tmp_path, third))
    wrong = [f for f in found if f.code == "file-links"]
    assert [f.severity for f in wrong] == ["error", "error"], wrong
    assert wrong[0].message.startswith("sensor_manager.polaris_cto (Pose, declared by")
    assert "is not connected: its data never comes" in wrong[0].message
    assert "{port: sensor_manager.polaris_cto, from: " in wrong[0].hint


@pytest.mark.parametrize(
    ("typo", "said"),
    [
        ("NDITracker", "did you mean 'components.tracking.ndi_driver:NdiTracker'?"),
        ("Zebra", "components.tracking.ndi_driver defines NdiTracker"),
    ],
)
def test_a_misspelt_class_is_one_error_with_the_class_meant(tmp_path, typo, said):
    """The class named wrongly is said with the one meant, and nothing built on the
    wrong guess follows: the wiring from it is there, only not checkable (before, two
    errors proposed to feed the Sensor Manager's Vicra ports from the Certus)."""
    rewire = ("ndi_driver:NdiTracker", f"ndi_driver:{typo}")
    _, found = check_topology(seeg_with(tmp_path, rewire=rewire))
    assert [f.code for f in found if f.severity == "error"] == ["class"], found
    assert found[0].message.endswith(said)


def test_a_file_port_fed_by_another_device_than_the_file_names_is_a_warning(tmp_path):
    rewired = (
        "{port: sensor_manager.certus_rto, from: certus.rto}",
        "{port: sensor_manager.certus_rto, from: vicra.rto}",
    )
    _, found = check_topology(seeg_with(tmp_path, rewire=rewired))
    wrong = [f for f in found if f.code == "file-links"]
    assert [f.severity for f in wrong] == ["warning"]
    assert "sensor_manager.certus_rto" in wrong[0].message and "reads vicra.rto" in wrong[0].message


def test_a_file_port_wired_to_the_wrong_message_type_is_an_error(tmp_path):
    rewired = (
        "{port: people_detector.camera_kinect_1, from: kinect_1.users}",
        "{port: people_detector.camera_kinect_1, from: certus.cto}",
    )
    _, found = check_topology(seeg_with(tmp_path, rewire=rewired))
    wrong = [f for f in found if f.code == "type-mismatch"]
    assert len(wrong) == 1
    assert wrong[0].message.startswith("people_detector.camera_kinect_1 (Skeletons)")


def test_a_file_that_still_names_bus_keys_is_refused_with_what_to_do(tmp_path):
    sensors = (REPO / "procedures" / "seeg" / "sensors.yaml").read_text(encoding="utf-8")
    old = sensors.replace("    rate: 20.0\n", "    rate: 20.0\n    keys: {cto: a, rto: b}\n")
    _, found = check_topology(seeg_with(tmp_path, old))
    wrong = [f for f in found if f.code == "file-links"]
    assert len(wrong) == 1 and "'keys' are no longer read" in wrong[0].message
    assert "vicra_cto and vicra_rto" in wrong[0].message


def test_a_projects_own_components_are_found_next_to_its_topology_without_pythonpath(tmp_path):
    component = (
        "from framework.component import Component\n\nclass {0}(Component):\n    '''A {0}.'''\n"
    )
    (tmp_path / "mycomps.py").write_text(component.format("Thing"))
    (tmp_path / "lib").mkdir()
    (tmp_path / "lib" / "othercomps.py").write_text(component.format("Other"))
    topology = tmp_path / "mine.yaml"
    topology.write_text(
        "topology: mine\nimport_paths: [lib]\ncomponents:\n"
        "  a: {class: mycomps:Thing}\n  b: {class: othercomps:Other}\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    fw = [sys.executable, "-m", "framework.cli", "validate", str(topology)]
    found = subprocess.run(fw, capture_output=True, text=True, cwd="/", env=env, timeout=60)
    assert found.returncode == 0, found.stderr
    topology.write_text(topology.read_text().replace("[lib]", "[lib, nowhere]"))
    missing = subprocess.run(fw, capture_output=True, text=True, cwd="/", env=env, timeout=60)
    assert missing.returncode == 1
    said = missing.stdout + missing.stderr
    assert f"{topology}:2:" in said and "import path 'nowhere' is not a folder" in said
