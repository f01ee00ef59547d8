"""Spec: `fw bench chaos` runs a case again on a fresh deployment when its setup never
began the approach (no fault was injected: no result of the case), says why each time,
and gives up after `SETUP_TRIES` with the reason."""

import pytest

from fw_bench import chaos
from fw_bench.chaos import SETUP_TRIES, Case, SetupFailed


def test_a_case_whose_approach_never_began_is_run_again_and_counted_apart(monkeypatch):
    calls = []

    def run_case(process, signal_name, hold, link=None):
        calls.append(process)
        if len(calls) == 1:
            raise SetupFailed("state Moving_Fast not reached in 30 s; e_NOTRACKER: {}")
        return Case(process, signal_name, hold)

    monkeypatch.setattr(chaos, "run_case", run_case)
    cases, setups = chaos.chaos(1)
    planned = len(chaos.PROCESSES) * len(chaos.FAULTS) + len(chaos.LINK_FAULTS)
    assert len(cases) == planned and len(calls) == planned + 1
    assert cases[0].process == chaos.PROCESSES[0]
    assert setups == [
        f"{chaos.PROCESSES[0]} KILL: state Moving_Fast not reached in 30 s; e_NOTRACKER: {{}}"
    ]


def test_a_case_that_never_sets_up_ends_the_run_with_its_reason(monkeypatch):
    calls = []

    def run_case(process, signal_name, hold, link=None):
        calls.append(process)
        raise SetupFailed("Setup_Aborted: vicra: no answer in 2 s")

    monkeypatch.setattr(chaos, "run_case", run_case)
    with pytest.raises(SetupFailed, match="no answer in 2 s"):
        chaos.chaos(1)
    assert len(calls) == SETUP_TRIES


def test_a_failed_setup_says_what_each_tracker_lacked_when_the_chart_had_none():
    class Run:
        def __init__(self, payload):
            self.payload = payload

        def last_payload(self, event):
            assert event == "e_NOTRACKER"
            return self.payload

    why = chaos.BenchError("state Moving_Fast not reached in 30 s")
    assert str(chaos.setup_failed(Run(None), why)) == "state Moving_Fast not reached in 30 s"
    said = chaos.setup_failed(Run({"why": "certus: healthy, not trusted again yet"}), why)
    assert isinstance(said, SetupFailed)
    assert str(said).endswith("; e_NOTRACKER: {'why': 'certus: healthy, not trusted again yet'}")
