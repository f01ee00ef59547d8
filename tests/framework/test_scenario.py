"""Spec: a scenario's invariants judge the robot, not the referee's line to it. A
sample whose call times out is counted and asked again; three in a row fail it."""

import itertools
import textwrap

from framework.remote import RemoteError
from framework.scenario import UNANSWERED_LIMIT, ScenarioRunner, load_scenario


def _played(tmp_path, answers):
    """Play a 1 s scenario whose one invariant (peak_step at most 1, always) is asked of
    `answers`: an iterator of results, or of exceptions to raise."""
    path = tmp_path / "referee.yaml"
    path.write_text(
        textwrap.dedent(
            """
            scenario: referee
            steps:
              - {at: 1s, send: e_NOTHING}
            invariants:
              - {check: robot.report, max: {peak_step: 1}}
            """
        )
    )

    def call(_operation, _args):
        answer = next(answers)
        if isinstance(answer, Exception):
            raise answer
        return answer

    runner = ScenarioRunner(load_scenario(path), send=lambda *_: None, call=call)
    runner.start()
    assert runner.finished.wait(10)
    runner.stop()
    return runner.report()[-1]


def _unanswered():
    return RemoteError("no answer from component 'robot' to operation 'report'", "Timeout")


def test_a_sample_the_busy_robot_did_not_answer_is_asked_again_not_judged(tmp_path):
    fine = {"peak_step": 0.2}
    answers = itertools.chain([fine, _unanswered(), _unanswered(), fine], itertools.repeat(fine))
    outcome = _played(tmp_path, answers)
    assert outcome.ok, outcome.detail
    assert "2 more asked but not answered in time" in outcome.detail


def test_a_robot_that_answers_none_of_three_samples_fails_the_invariant(tmp_path):
    answers = itertools.chain(
        [{"peak_step": 0.2}], [_unanswered()] * UNANSWERED_LIMIT, itertools.repeat({})
    )
    outcome = _played(tmp_path, answers)
    assert not outcome.ok and "call failed: no answer from component 'robot'" in outcome.detail


def test_a_call_refused_for_another_reason_is_a_violation_at_once(tmp_path):
    answers = itertools.chain(
        [RemoteError("robot: no operation 'report'", "OperationError")],
        itertools.repeat({"peak_step": 0.2}),
    )
    outcome = _played(tmp_path, answers)
    assert not outcome.ok and "call failed: robot: no operation" in outcome.detail


def test_an_answer_over_the_limit_is_a_violation_whatever_came_before(tmp_path):
    answers = itertools.chain([_unanswered(), {"peak_step": 1.5}], itertools.repeat({}))
    outcome = _played(tmp_path, answers)
    assert not outcome.ok and "peak_step" in outcome.detail


def test_a_configurator_answer_in_a_scenario_is_not_sent_to_a_deployment(tmp_path):
    """A counterexample of `fw verify` gives the Configurator's answers as steps (the
    chart alone needs them); on a deployment the Configurator answers by itself, so the
    runner plays the operator's events only and says why it skipped the others."""
    path = tmp_path / "cx.yaml"
    path.write_text(
        textwrap.dedent(
            """
            scenario: cx
            steps:
              - {at: 0s, send: config.done, payload: {tag: setup}}
              - {at: 0.1s, send: e_START}
              - {at: 0.2s, send: config.failed, payload: {tag: auto_up, reason: x}}
            """
        )
    )
    sent, said = [], []
    runner = ScenarioRunner(
        load_scenario(path),
        send=lambda event, payload: sent.append(event),
        call=lambda *_: None,
        report=said.append,
    )
    runner.start()
    assert runner.finished.wait(10)
    runner.stop()
    assert sent == ["e_START"]
    assert sum("not sent" in line for line in said) == 2


def test_a_run_that_can_no_longer_pass_ends_at_once_and_says_why(tmp_path):
    """A `never_event` that came (the robot stopped by a fault) fails the run whatever
    follows: the run ends then, naming the event and its payload, instead of waiting out
    its timeout for a target the stopped robot never reaches (the multi-host run waited
    166 s)."""
    from framework.statechart.events import Event

    path = tmp_path / "doomed.yaml"
    path.write_text(
        textwrap.dedent(
            """
            scenario: doomed
            timeout: 600s
            steps:
              - {at: 0s, send: e_START}
              - {when: Target_Reached, check: robot.report, expect: {braked: false}}
            expect:
              - {never_event: e_STOP}
            """
        )
    )
    runner = ScenarioRunner(
        load_scenario(path),
        send=lambda event, payload: runner.on_event(Event("e_STOP", {"reason": "FRI"})),
        call=lambda *_: {"braked": False},
    )
    runner.start()
    assert runner.finished.wait(60), "still waiting for Target_Reached"
    runner.stop()
    failed = {v.what: v.detail for v in runner.report() if not v.ok}
    assert failed["on Target_Reached: check robot.report"].startswith(
        "not played: event e_STOP came at"
    )
    assert "FRI" in failed["never event e_STOP"]


def test_a_start_state_never_entered_says_where_the_chart_stood(tmp_path):
    """A deployment whose chart never reached the scenario's start state (a CI run: a
    setup that never finished) is reported with the chart's innermost active states and
    the last event it took, so the log says which configuration it waited for."""
    from types import SimpleNamespace

    from framework.statechart.events import Event

    path = tmp_path / "stuck.yaml"
    path.write_text(
        textwrap.dedent(
            """
            scenario: stuck
            start: System_OK
            timeout: 0.3s
            steps:
              - {at: 0s, send: e_START}
            """
        )
    )
    runner = ScenarioRunner(load_scenario(path), send=lambda *_: None, call=lambda *_: None)
    for state in ("System_Setup", "System_Setup.Start_Components"):
        runner.on_entry(SimpleNamespace(path=state))
    runner.on_event(Event("config.done", {"tag": "setup_tracking"}))
    runner.start()
    assert runner.finished.wait(10)
    runner.stop()
    failed = {v.what: v.detail for v in runner.report() if not v.ok}
    assert failed["start state System_OK never entered"] == (
        "the chart was in System_Setup.Start_Components; its last event: config.done"
    )
