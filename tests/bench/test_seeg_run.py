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


class Asked(SeegRun):
    """A run whose deployment answers the Supervisor's report from a script."""

    def __init__(self, bests, health=None, **kw):
        super().__init__(**kw)
        self.bests, self.health, self.asked = list(bests), health or {}, []

    def call(self, ref, **args):
        self.asked.append(ref)
        if ref == "supervisor.report":
            return {"best": self.bests.pop(0) if len(self.bests) > 1 else self.bests[0]}
        assert ref == "sensor_manager.current"
        return {"best": None, "health": self.health}


def test_a_run_starts_only_once_the_supervisor_would_name_a_tracker(tmp_path):
    """START before a tracker is trusted is answered e_NOTRACKER and brakes until
    RELEASE: the run asks until the Supervisor has one, as an operator waits for it."""
    run = Asked([None, None, "certus"], workdir=tmp_path)
    assert run.wait_tracker(5.0) == "certus"
    assert run.asked == ["supervisor.report"] * 3


def test_no_tracker_trusted_in_time_is_an_error_saying_what_each_lacks(tmp_path):
    health = {
        "certus": {"ok": True, "cause": ""},
        "vicra": {"ok": False, "cause": "missing tool"},
    }
    run = Asked([None], health=health, workdir=tmp_path)
    with pytest.raises(BenchError, match=r"certus: healthy, not trusted yet; vicra: missing tool"):
        run.wait_tracker(0.05)
