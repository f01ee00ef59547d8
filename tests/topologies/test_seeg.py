"""Spec: `fw deploy topologies/seeg.yaml --scenario F` on real processes, for every
scenario of the procedure: the simulated OR plays it and every expectation holds. These
test the procedure, not the watches: their safety deadlines are stretched for a shared
host (`SHARED_HOST_MARGIN`); test_seeg_faults.py proves the watches at the shipped ones."""

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


@pytest.mark.parametrize("path", SCENARIOS, ids=[p.stem for p in SCENARIOS])
def test_scenario_passes_on_real_processes(path, bus_config, tmp_path):
    history: list = []
    failed = play_seeg_scenario(path, bus_config, tmp_path, history, SHARED_HOST_MARGIN)
    assert not failed, explain(failed)
    for tag, process in LOCAL_SWITCHES.get(path.stem, {}).items():
        made = [o.switched_by for o in history if o.tag == tag and o.ok]
        assert made == [process], f"{tag}: switched by {made}"
