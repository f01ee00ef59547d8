"""Spec: `fw deploy topologies/seeg.yaml --scenario F` on real processes, for every
scenario of the procedure: the simulated OR plays it and every expectation holds. These
test the procedure, not the watches: their safety deadlines are stretched for a shared
host (`SHARED_HOST_MARGIN`); test_seeg_faults.py proves the watches at the shipped ones."""

import itertools

import pytest

from tests.conftest import (
    REPO,
    SHARED_HOST_MARGIN,
    check_scenarios,
    explain,
    play_seeg_scenario,
)

SCENARIOS = sorted((REPO / "procedures" / "seeg" / "scenarios").glob("*.yaml"))


def test_every_scenario_is_checked_against_the_chart_and_topology():
    assert len(SCENARIOS) >= 5
    check_scenarios(REPO / "topologies" / "seeg.yaml", SCENARIOS)


LOCAL_SWITCHES = {"tracker_swap": {"tracker_2_up": "supervision"}}
"""Configurations a scenario makes: switched by the process of the ports it rewires
(framework/local_switch.py), not over a round trip from the Configurator."""


RECORDED = {"nominal"}
"""Scenarios whose flight recording is checked too (one run already in the suite)."""


@pytest.mark.parametrize("path", SCENARIOS, ids=[p.stem for p in SCENARIOS])
def test_scenario_passes_on_real_processes(path, bus_config, tmp_path):
    history: list = []
    record = tmp_path / "run.mcap" if path.stem in RECORDED else None
    failed = play_seeg_scenario(path, bus_config, tmp_path, history, SHARED_HOST_MARGIN, record)
    assert not failed, explain(failed)
    for tag, process in LOCAL_SWITCHES.get(path.stem, {}).items():
        made = [o.switched_by for o in history if o.tag == tag and o.ok]
        assert made == [process], f"{tag}: switched by {made}"
    if record is not None:
        foxglove_shows_the_run(record)


def foxglove_shows_the_run(path):
    """The recording holds, as Foxglove's well-known messages, one message per frame
    recorded of the robot's joints, its tool (TCP), the tools each tracker sees, the
    patient's head and the people; and the TCP's transform is where the recorded joints
    put it by the deployment's own kinematics (issue 48)."""
    import numpy as np
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    from components.domain import lwr4
    from framework.recorder import read_recording

    frames: dict[str, int] = {}
    for topic, _, _ in read_recording(path):
        if topic.startswith("/fw/samples/"):
            frames[topic] = frames.get(topic, 0) + 1
    drawn: dict[str, int] = {}
    joints, tcp, parents = {}, {}, {}
    with path.open("rb") as handle:
        reader = make_reader(handle, decoder_factories=[DecoderFactory()])
        for _, channel, _, message in reader.iter_decoded_messages(
            topics=["/tf", "/joint_states/robot.joints", "/people/people_detector.envelopes"]
        ):
            if channel.topic == "/tf":
                for t in message.transforms:
                    drawn[t.child_frame_id] = drawn.get(t.child_frame_id, 0) + 1
                    parents[t.child_frame_id] = t.parent_frame_id
                    if t.child_frame_id == "robot.tcp":
                        when = (t.timestamp.seconds, t.timestamp.nanos)
                        tcp[when] = (t.translation.x, t.translation.y, t.translation.z)
            else:
                drawn[channel.topic] = drawn.get(channel.topic, 0) + 1
                if channel.topic.startswith("/joint_states/"):
                    when = (message.timestamp.seconds, message.timestamp.nanos)
                    joints[when] = [j.position for j in message.joints]
    expected = {
        "robot.tcp": "base",
        "patient.pose": "base",
        "certus.cto": "certus",
        "certus.rto": "certus",
        "vicra.cto": "vicra",
        "vicra.rto": "vicra",
    }
    arm = ["base", *(f"link{i}" for i in range(1, 8)), "tcp"]
    expected |= {child: parent for parent, child in itertools.pairwise(arm)}
    assert parents == expected
    assert drawn["tcp"] == drawn["/joint_states/robot.joints"], "the arm drawn for every joints"
    recorded = {
        "robot.tcp": "robot/tcp",
        "patient.pose": "sim/patient",
        "certus.cto": "certus/calibration_tool_optical",
        "certus.rto": "certus/reference_tool_optical",
        "vicra.cto": "vicra/calibration_tool_optical",
        "vicra.rto": "vicra/reference_tool_optical",
        "/joint_states/robot.joints": "robot/joints",
        "/people/people_detector.envelopes": "people_detector/envelopes",
    }
    for name, key in recorded.items():
        (count,) = [n for topic, n in frames.items() if topic.startswith(f"/fw/samples/{key}/")]
        assert drawn.get(name) == count > 10, f"{name}: {drawn.get(name)} drawn of {count}"
    paired = sorted(set(joints) & set(tcp))
    # each thinned stream keeps the first sample of its period: many share a cycle
    assert len(paired) >= 20, f"only {len(paired)} TCP transforms with joints of their cycle"
    for when in paired:
        forward = lwr4.dh_forward(np.array(joints[when]))[:3, 3]
        assert forward == pytest.approx(np.array(tcp[when]), abs=1e-9), when
