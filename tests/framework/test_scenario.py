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
