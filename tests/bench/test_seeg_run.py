"""Spec: the bench's wait for a state of SEEG's chart (tools/bench/fw_bench/seeg_run.py):
it returns when the state is entered; a setup that aborted is an error at once that
says the chart's reason, never a wait to the timeout; a state not reached in time is an
error naming the states the chart entered last."""

from types import SimpleNamespace

import pytest

from fw_bench.seeg_run import BenchError, SeegRun


def chart_went(run, *states, event=None, payload=None):
    if event is not None:
        run._states.on_event(SimpleNamespace(name=event, payload=payload))
    for state in states:
        run._states.on_entry(SimpleNamespace(name=state))


def test_the_wait_returns_when_the_state_is_entered(tmp_path):
    run = SeegRun(workdir=tmp_path)
    chart_went(run, "System_Setup", "Wait_Start")
    assert run.wait_state("Wait_Start", 0.1) > 0


def test_an_aborted_setup_is_an_error_at_once_with_the_charts_reason(tmp_path):
    run = SeegRun(workdir=tmp_path)
    chart_went(
        run,
        "System_Setup",
        "Setup_Tracking",
        "Setup_Aborted",
        event="config.failed",
        payload={"tag": "setup_tracking", "reason": "vicra: no answer in 2 s"},
    )
    # a wait to the timeout would end in "not reached in 30 s", without the reason
    with pytest.raises(BenchError, match=r"never reached: .*setup_tracking.*no answer in 2 s"):
        run.wait_state("Wait_Start", 30.0)


def test_a_state_not_reached_in_time_names_the_last_states(tmp_path):
    run = SeegRun(workdir=tmp_path)
    chart_went(run, "System_Setup", "Setup_Tracking")
    with pytest.raises(BenchError, match="Setup_Tracking"):
        run.wait_state("Wait_Start", 0.05)


def test_a_start_that_fails_shuts_down_what_it_had_started(tmp_path):
    stopped = []

    class NeverReady(SeegRun):
        def _start(self):
            self.deployment = SimpleNamespace(stop=lambda: stopped.append(True))
            raise BenchError("state Wait_Start not reached in 60 s")

    run = NeverReady(workdir=tmp_path)
    with pytest.raises(BenchError, match="Wait_Start"):
        run.start()
    # `with SeegRun() as run` never calls stop when start raised: start must
    assert stopped == [True] and run.deployment is None
