"""Spec: the SEEG deployment fails safe on real processes. A crash (SIGKILL) or a hang
(SIGSTOP, then SIGCONT) of the robot, supervision, cameras or arm process while the arm
approaches the target ends braked with the fault latched; nothing moves before the
surgeon's RELEASE (the arm's controller counts its releases), and then the approach
resumes where the process can come back. The same holds when the FRI link between the
robot interface and the KRC fails (answers lost or late, a silent KRC, garbage and a
foreign sender: `arm.impair`, a fault at the physical edge). One scenario per process
and fault kind, and per link fault, lives in procedures/seeg/scenarios/faults/; the ones
in `IN_SUITE` run here (the arm's since its loop runs SCHED_DEADLINE), every one of them
in `fw bench chaos`."""

import pytest

from framework.scenario import load_scenario
from framework.statechart.loader import load_statechart
from framework.statechart.model import BUILTIN_EVENTS
from framework.topology import load_topology
from tests.conftest import REPO, explain, play_seeg_scenario

FAULTS = REPO / "procedures" / "seeg" / "scenarios" / "faults"
IN_SUITE = [
    *(
        f"{p}_{kind}"
        for p in ("robot", "supervision", "cameras", "arm")
        for kind in ("kill", "hang")
    ),
    "fri_answers_lost",
]
LINK_FAULTS = {"fri_answers_lost", "fri_answers_late", "fri_krc_silent", "fri_garbage"}
"""The FRI link's faults that must each have a scenario (`fri_loss_tolerated` shows
what the link tolerates)."""


def test_there_is_a_scenario_per_process_and_fault_kind_and_each_checks():
    topology = load_topology(REPO / "topologies" / "seeg.yaml")
    chart = load_statechart(topology.statechart)
    processes = {c.process for c in topology.components.values()}
    names = {p.stem for p in FAULTS.glob("*.yaml")}
    assert {f"{p}_{k}" for p in processes for k in ("kill", "hang")} <= names
    assert names >= LINK_FAULTS
    operations = {f"{n}.{op}" for n, c in topology.components.items() for op in c.info.operations}
    for path in sorted(FAULTS.glob("*.yaml")):
        scenario = load_scenario(
            path,
            set(chart.events) | set(BUILTIN_EVENTS),
            operations,
            {s.path for s in chart.states.values()},
            processes,
        )
        injects = [s for s in scenario.steps if s.fault is not None or s.call == "arm.impair"]
        assert injects, f"{path.name} injects no fault"


@pytest.mark.parametrize("name", IN_SUITE)
def test_a_fault_ends_braked_latched_and_nothing_moves_before_release(name, bus_config, tmp_path):
    failed = play_seeg_scenario(FAULTS / f"{name}.yaml", bus_config, tmp_path)
    assert not failed, explain(failed)
