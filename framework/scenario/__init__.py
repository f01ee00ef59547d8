"""Scenarios: what happens when during a deployment, and what must come of it.

`fw deploy TOPOLOGY --scenario FILE` plays the steps in order while the chart
runs, then reports PASS or FAIL for every expectation (exit code 1 on FAIL).

    scenario: all_trackers_occluded
    start: System_OK            # time zero: this state's first entry (default: chart start)
    timeout: 60s                # give up (FAIL) after this long
    steps:
      - {at: 0.5s, send: e_START}                       # as an operator would
      - {when: Moving_Fast, after: 2s, call: certus.occlude, args: {tool: cto}}
      - {when: No_Tracker, after: 1s, check: robot.report, expect: {braked: true}}
      - {at: 20s, send: e_RELEASE}
      - {when: Moving_Fast, after: 1s, fault: {process: supervision, signal: KILL}}
      - {when: Moving_Fast, after: 1s, fault: {process: robot, signal: STOP, for: 2s}}
    expect:
      - {state: Target_Reached, within: 45s}   # entered at least once (in time)
      - {event: e_NOTRACKER}                   # seen at least once
      - {never_state: Fault}
      - {never_event: e_STOP}
    invariants:                                # sampled at 10 Hz during the whole run
      - {while: No_Tracker, grace: 3s, check: robot.report, expect: {braked: true}}
      - {while: Moving, check: interpolator.report, max: {speed: 0.0751}}
    end: Target_Reached                        # stop early once this state is active

Steps run one after the other: `at` waits until that time after time zero,
`when` waits for the named state's first entry since the previous step was
triggered (consecutive steps with the same `when` share one entry), and `after`
adds a delay to either. A state is named by its full path or by any dotted
suffix of it (`Stopped`, `Task.Stopped`). `check` calls an operation and
compares the given fields of its result, equal to `expect` and no greater than
`max` (a failed check is a FAIL, the scenario goes on); with `wait: 30s` it asks
again until they match or the wait is over,
for outcomes whose timing depends on the host (a simulated arm slows down, it
does not skip, when the machine is busy). `fault` injects a fault into one of the
deployment's processes: `KILL` (a crash), `STOP` (a hang: SIGSTOP, then SIGCONT
after `for`), `TERM` or `INT`; every procedure can so prove how it fails safe.
"""

from framework.scenario.loader import load_scenario
from framework.scenario.model import Expectation, Fault, Invariant, Scenario, ScenarioStep
from framework.scenario.runner import UNANSWERED_LIMIT, ScenarioRunner, Verdict

__all__ = [
    "UNANSWERED_LIMIT",
    "Expectation",
    "Fault",
    "Invariant",
    "Scenario",
    "ScenarioRunner",
    "ScenarioStep",
    "Verdict",
    "load_scenario",
]
