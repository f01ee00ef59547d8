"""Spec: how `fw bench chaos --hosts` judges a case (tools/bench/fw_bench/hosts_chaos.py)
from what the robot interface and the simulated KRC report once the links are back:
the first braking cycle is the first of the robot's stop and the KRC's brakes; a stop
before the fault is counted, not timed; how far past the deadline that tripped the
first braking cycle came is read from the robot's reason; a release after the fault, an arm left
released, or motion after the brakes engaged is a motion without RELEASE; a control host's
run whose deployment never began its approach is a failed setup, run again as `chaos`
runs one."""

import json
import sys
from dataclasses import dataclass

import pytest

from framework.messages import ArmState
from fw_bench.chaos import Case, SetupFailed
from fw_bench.hosts_chaos import SETUP_FAILED, _judge, beyond_deadline, main, run_case

FAULT = 1000.0
STILL_Q = (0.0,) * 7


@dataclass
class Seen:
    message: ArmState


class Watched:
    """The arm states the control host received (a run's `since`)."""

    def __init__(self, states: list[ArmState]):
        self.states = states

    def since(self, t: float, key: str) -> list[Seen]:
        assert key == "arm/measured"
        return [Seen(m) for m in self.states if m.stamp >= t]


def state(stamp: float, braked: bool, speed: float = 0.0) -> ArmState:
    velocity = (speed,) + (0.0,) * 6
    return ArmState(stamp, 0, 0, STILL_Q, velocity, STILL_Q, (), braked, braked, "")


def judged(arm: dict, robot: dict, states=(), releases_before: int = 0) -> Case:
    case = Case("robot", "LINK", 2.0, link="partition 2s")
    _judge(case, Watched(list(states)), FAULT, {"releases": releases_before}, arm, robot)
    return case


def test_braking_begins_with_the_first_of_the_robots_stop_and_the_krcs_brakes():
    case = judged(
        {"braked": True, "braked_at": FAULT + 0.120, "releases": 1},
        {"latched_at": FAULT + 0.080},
    )
    assert case.to_braking_ms == pytest.approx(80.0)
    assert case.to_standstill_ms == pytest.approx(120.0)
    assert case.ok and not case.moved_without_release


def test_a_stop_before_the_fault_is_said_and_not_timed_but_still_judged():
    case = judged(
        {"braked": True, "braked_at": FAULT - 0.369, "releases": 1},
        {"latched_at": FAULT - 0.370},
    )
    assert case.to_braking_ms is None and case.detail.startswith("tripped 370 ms before")
    assert case.ok, "braked and still: safe, only not a measurement"


def test_a_release_after_the_fault_is_a_motion_without_release():
    case = judged(
        {"braked": True, "braked_at": FAULT + 0.1, "releases": 2},
        {"latched_at": FAULT + 0.1},
    )
    assert case.moved_without_release and not case.ok
    assert "released after the fault" in case.detail


def test_an_arm_left_released_is_not_ok():
    case = judged({"braked": False, "braked_at": None, "releases": 1}, {"latched_at": None})
    assert not case.ended_braked and case.moved_without_release and not case.ok


def test_motion_seen_after_the_brakes_engaged_is_a_motion_without_release():
    states = [
        state(FAULT + 0.05, False, 0.1),
        state(FAULT + 0.2, True),
        state(FAULT + 0.3, True, 0.01),
    ]
    case = judged({"braked": True, "braked_at": FAULT + 0.15, "releases": 1}, {}, states)
    assert case.moved_without_release and "moving 300 ms after the fault" in case.detail


def test_an_unknown_host_or_fault_is_refused_with_the_choices(capsys):
    with pytest.raises(SystemExit):
        main(["--case", "moon", "partition 2s", "--topology", "t", "--keys", "k"])
    assert "control, tracking, cameras, robot, krc" in capsys.readouterr().err


def timed(to_braking_ms, reason):
    case = Case("control", "LINK", 2.0, link="partition 2s", to_braking_ms=to_braking_ms)
    case.notes = [reason, "the fault took 8.2 ms to make"] if reason else []
    return case


@pytest.mark.parametrize(
    ("to_braking", "reason", "beyond"),
    [
        (404.8, "robot: process control: no data for 401 ms (deadline 400 ms)", 4.8),
        (92.3, "robot: process trackers: no data for 101 ms (deadline 100 ms)", -7.7),
        (9.6, "robot: the KRC is silent: no measurement for 62 ms (timeout 50 ms)", -40.4),
        (70.0, "robot: ", None),  # a robot that said no deadline
        (None, "robot: process control: no data for 401 ms (deadline 400 ms)", None),
    ],
)
def test_a_stop_is_judged_against_the_deadline_of_the_input_that_tripped(
    to_braking, reason, beyond
):
    got = beyond_deadline(timed(to_braking, reason))
    assert got == (None if beyond is None else pytest.approx(beyond))


class Hosts:
    """Namespaces whose control host's run only prints `said` (a real child process)."""

    prefix = "fwt-"

    def __init__(self, said: dict):
        self.said, self.ended = said, []

    def deploy_others(self, topology, keys, home):
        return ["the other hosts' parts"]

    def command(self, host, *argv):
        return [sys.executable, "-c", f"print({json.dumps(json.dumps(self.said))})"]

    def end(self, parts):
        self.ended.append(parts)


def test_a_control_run_that_never_began_its_approach_is_a_failed_setup(tmp_path):
    why = "state Moving_Fast not reached in 30 s; e_NOTRACKER: {'why': 'vicra: stale'}"
    hosts = Hosts({SETUP_FAILED: why})
    with pytest.raises(SetupFailed, match="e_NOTRACKER"):
        run_case(hosts, tmp_path / "t.yaml", tmp_path / "k", "robot", "partition 2s", {"hold": 2})
    assert hosts.ended == [["the other hosts' parts"]]  # their parts stopped all the same


def test_a_control_runs_case_is_read_from_its_last_line(tmp_path):
    hosts = Hosts(Case("robot", "LINK", 2.0, link="partition 2s", to_braking_ms=41.0).__dict__)
    case = run_case(
        hosts, tmp_path / "t.yaml", tmp_path / "k", "robot", "partition 2s", {"hold": 2}
    )
    assert case.process == "robot" and case.to_braking_ms == 41.0
