"""Spec: the SEEG deployment on the machines of an operating room (issue 46), built as
network namespaces of this machine joined by a bridge, the KRC on a link of its own
(framework/netns.py): real interfaces between the hosts, every host's part started by
its own `fw deploy --host`, nothing copied beyond what `fw keys` wrote. The procedure
runs across them."""

import subprocess
import sys

import pytest

from framework import netns
from tests.conftest import REPO, SHARED_HOST_MARGIN, check_scenarios
from tests.support import clock_apart
from tests.support.hosts import run_on_hosts, stretched

WHY = netns.available()
pytestmark = pytest.mark.skipif(bool(WHY), reason=f"no hosts as namespaces here: {WHY}")
TOPOLOGY = REPO / "topologies" / "seeg_hosts.yaml"
SCENARIOS = REPO / "procedures" / "seeg" / "scenarios"


@pytest.fixture(scope="module")
def hosts():
    built = netns.Hosts(prefix="fwt-", bridge="fwtbr0").up()
    yield built
    built.down()


@pytest.fixture(scope="module")
def procedure(tmp_path_factory):
    """seeg_hosts.yaml with its safety deadlines stretched for a shared 2-core host
    (`stretched`): these runs test the procedure across the hosts, not the watches."""
    return stretched(TOPOLOGY, SHARED_HOST_MARGIN, tmp_path_factory.mktemp("topology"))


@pytest.fixture(scope="module")
def keys(tmp_path_factory):
    folder = tmp_path_factory.mktemp("keys") / "seeg_hosts"
    made = subprocess.run(
        [sys.executable, "-m", "framework.cli", "keys", str(TOPOLOGY), "-o", str(folder)],
        capture_output=True, text=True, cwd=REPO,
    )  # fmt: skip
    assert made.returncode == 0, made.stderr
    return folder


def test_every_scenario_for_several_hosts_is_checked_against_the_chart_and_topology():
    check_scenarios(TOPOLOGY, sorted((SCENARIOS / "hosts").glob("*.yaml")))


def test_the_hosts_are_namespaces_on_real_links(hosts):
    assert hosts.address("tracking") == "10.77.0.2" and hosts.address(netns.KRC) == "10.78.0.2"
    links = subprocess.run(
        hosts.command("robot", "ip", "-brief", "addr"), capture_output=True, text=True
    ).stdout
    assert "eth0" in links and "10.77.0.4/24" in links, "on the bridge"
    assert "fri0" in links and "10.78.0.1/30" in links, "and on the KRC's own link"


# The other hosts' partitions and lossy links are shipped beside them and run by hand
# (docs/hosts.md). The robot's and the tracking host's cuts joined the suite once fw
# mended the routes Zenoh leaves unmade (framework/routes.py): by hand on 2026-12-07,
# tracking 15 of 24 passed before, 8 of 8 after; robot 2 of 3 before, 6 of 6 after;
# control 3 of 3 after. They left the suite again the same day: in the full suite a
# reopen of the supervision process while the arm moved left its heartbeat 151 ms
# silent at the robot, which braked (the overlap that fixes it is not landed yet)
LOSS_WHY = WHY or netns.loss_available()


@pytest.mark.parametrize(
    "scenario",
    [
        "hosts/cameras_partition_release.yaml",
        "hosts/krc_partition.yaml",
        pytest.param(
            "hosts/krc_loss.yaml",
            marks=pytest.mark.skipif(bool(LOSS_WHY), reason=f"no lossy links here: {LOSS_WHY}"),
        ),
    ],
)
def test_a_host_cut_off_stops_the_robot_latched_until_release(
    hosts, keys, procedure, scenario, monkeypatch
):
    """The camera PC cut off for 2 s, the KRC's FRI link cut for 2 s or losing 30% of
    its datagrams for 5 s, while the arm approaches: the robot side stops by itself (the
    KRC by its answers' absence or quality) and latches, the link heals, nothing moves
    until RELEASE, then the approach resumes (each scenario says how). The nominal
    approach across the hosts is the clock tests' first half."""
    monkeypatch.setenv("FW_NETNS_PREFIX", hosts.prefix)
    run = run_on_hosts(hosts, procedure, keys, SCENARIOS / scenario, REPO)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    assert "PASSED" in run.stdout


@pytest.mark.skipif(clock_apart.library() is None, reason=clock_apart.MISSING)
@pytest.mark.parametrize("offset", [0.1, -0.1], ids=["ahead", "behind"])
def test_a_tracking_host_whose_clock_runs_apart_neither_stops_on_fresh_data_nor_hides_stale(
    hosts, keys, procedure, offset, monkeypatch
):
    """The tracking PC's part runs with its clock 100 ms ahead, then behind, of every
    other host's (tests/support/clock_apart.py):
    procedures/seeg/scenarios/hosts/tracking_clock.yaml. 100 ms, not the 50 ms a
    modest drift gives: at 50 ms a sample paired by its stamp as written meets the
    robot 3.75 mm from where it saw it, inside the 5 mm calibration tolerance, so
    the run could not tell; at 100 ms such pairing fails it (the Vicra "6.0 mm away
    from the robot's kinematics", no tracker), paired on the robot's clock it passes."""
    monkeypatch.setenv("FW_NETNS_PREFIX", hosts.prefix)
    scenario = SCENARIOS / "hosts" / "tracking_clock.yaml"
    apart = {"tracking": clock_apart.environment(offset)}
    run = run_on_hosts(hosts, procedure, keys, scenario, REPO, environment=apart)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    assert "PASSED" in run.stdout


def test_a_host_that_never_comes_up_is_a_clear_error_naming_it_not_a_hang(hosts, keys):
    from tests.support.hosts import FW

    run = subprocess.run(
        hosts.command(
            "control", *FW, "deploy", str(TOPOLOGY), "--keys", str(keys), "--headless",
            "--no-console", "--start-timeout", "5",
        ),
        capture_output=True, text=True, cwd=REPO, timeout=120,
    )  # fmt: skip
    assert run.returncode != 0
    assert "Traceback" not in run.stderr
    for host in ("tracking", "cameras", "robot", "krc"):
        assert f"on host {host!r}: is its part running there?" in run.stderr, run.stderr
    assert "components not alive after 5 s" in run.stderr
