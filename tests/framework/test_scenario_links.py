"""Spec: network faults as scenario verbs (issue 46): `fault: {link: HOST, partition:
2s}` or `{link: HOST, loss/delay/jitter, for: 5s}`, checked against the topology's hosts
with located errors; the deployer refuses them clearly where the hosts are not network
namespaces of this machine."""

import pytest

from framework.deployer import DeployError, Deployment
from framework.errors import FindingsError
from framework.scenario import load_scenario

HEAD = "scenario: s\nsteps:\n"


def scenario(write, step: str):
    return write(HEAD + f"  - {{at: 1s, fault: {step}}}\n", "s.yaml")


def test_a_partition_and_an_impairment_are_read_as_link_faults(write):
    cut = load_scenario(scenario(write, "{link: cameras, partition: 2s}"), hosts={"cameras"})
    fault = cut.steps[0].fault
    assert (fault.link, fault.partition, fault.hold) == ("cameras", True, 2.0)
    assert fault.describe() == "fault link cameras partition 2s"
    slow = load_scenario(
        scenario(write, "{link: tracking, loss: 30%, delay: 80ms, jitter: 20ms, for: 5s}"),
        hosts={"tracking"},
    )
    fault = slow.steps[0].fault
    assert (fault.loss, fault.delay, fault.jitter, fault.hold) == (0.3, 0.08, 0.02, 5.0)
    assert fault.describe() == "fault link tracking loss 30% delay 80ms jitter 20ms for 5s"


@pytest.mark.parametrize(
    ("step", "said"),
    [
        ("{link: camera, partition: 2s}", "the topology has no host 'camera'"),
        ("{link: cameras}", "either a `partition` or `loss`/`delay`/`jitter`"),
        ("{link: cameras, partition: 2s, delay: 1s, for: 1s}", "either a `partition`"),
        ("{link: cameras, delay: 80ms}", "need `for`"),
        ("{link: cameras, partition: 2s, for: 1s}", "says its own length"),
    ],
)
def test_a_link_fault_that_cannot_be_made_is_a_located_error(write, step, said):
    with pytest.raises(FindingsError) as caught:
        load_scenario(scenario(write, step), hosts={"cameras", "control"})
    findings = caught.value.findings
    assert any(said in f.message for f in findings), [f.message for f in findings]
    assert all(f.location.line == 3 for f in findings), "on the step's line"


def test_a_link_fault_where_the_hosts_are_not_namespaces_is_refused_clearly(
    toy, tmp_path, write, monkeypatch
):
    monkeypatch.setenv("FW_NETNS_PREFIX", "fw-none-such-")
    fault = load_scenario(scenario(write, "{link: cameras, partition: 2s}")).steps[0].fault
    with pytest.raises(
        DeployError, match=r"no network namespace 'fw-none-such-cameras'.*framework.netns up"
    ):
        Deployment(toy, tmp_path).inject_fault(fault)
