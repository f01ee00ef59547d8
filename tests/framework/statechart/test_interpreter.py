"""Spec: the interpreter's run-to-completion semantics (docs/statecharts.md, "Semantics")."""

import pytest

from framework.statechart.interpreter import Interpreter, StatechartRuntimeError

NESTED = """
statechart: nested
events: {e: null, f: null}
initial: P
states:
  - name: P
    initial: C
    entry: [{log: enter P}]
    exit: [{log: exit P}]
    states:
      - name: C
        initial: L
        entry: [{log: enter C}]
        exit: [{log: exit C}]
        states:
          - name: L
            entry: [{log: enter L}]
            exit: [{log: exit L}]
            transitions:
              - {event: e, target: Q, effect: [{log: inner effect}]}
              - {event: f, target: Q, effect: [{log: inner f}]}
    transitions:
      - {event: e, target: Q, effect: [{log: outer effect}]}
  - name: Q
    entry: [{log: enter Q}]
    transitions: [{event: f, target: P}]
"""


def logs(run):
    return [o.message for o in run.outputs if o.kind == "log"]


def test_outer_first_priority_the_transition_closest_to_the_root_wins(run):
    r = run(NESTED, validate=False)
    r.send("e")
    assert "outer effect" in logs(r) and "inner effect" not in logs(r)


def test_exit_innermost_first_then_effect_then_entry_outermost_first(run):
    r = run(NESTED, validate=False)
    r.outputs.clear()
    r.send("e")
    assert logs(r) == ["exit L", "exit C", "exit P", "outer effect", "enter Q"]
    r.outputs.clear()
    r.send("f")
    assert logs(r) == ["enter P", "enter C", "enter L"]


def test_inner_transition_fires_when_no_outer_one_is_enabled(run):
    r = run(NESTED, validate=False)
    r.send("f")
    assert "inner f" in logs(r) and r.leaves == ["Q"]


def test_priority_then_document_order_inside_one_state(run):
    r = run(
        """
        statechart: p
        events: {e: null}
        initial: A
        states:
          - name: A
            transitions:
              - {event: e, target: B}
              - {event: e, target: C, priority: 5}
          - {name: B, transitions: [{event: e, target: A}]}
          - {name: C, transitions: [{event: e, target: A}]}
        """,
        validate=False,
    )
    r.send("e")
    assert r.leaves == ["C"]


def test_every_event_gets_its_own_step_and_unhandled_ones_are_reported(run):
    r = run("""
        statechart: q
        events: {a: null, b: null}
        initial: S
        states:
          - {name: S, transitions: [{event: a, target: T}]}
          - {name: T, transitions: [{event: a, target: S}]}
        """)
    for name in ["a", "b", "a", "a", "b"]:
        r.interpreter.queue(name)
    assert r.interpreter.run() == 5
    assert [x[1] for x in r.kinds("event")] == ["a", "b", "a", "a", "b"]
    assert [x[1] for x in r.kinds("unhandled")] == ["b", "b"]
    assert r.leaves == ["T"]


def test_internal_events_are_processed_before_external_ones(run):
    r = run("""
        statechart: i
        events: {go: null, ping: null, other: null}
        initial: A
        states:
          - name: A
            transitions: [{event: go, target: B, effect: [{raise: ping}]}]
          - name: B
            transitions:
              - {event: ping, target: C}
              - {event: other, target: A}
          - name: C
            transitions: [{event: other, target: A}]
        """)
    r.interpreter.queue("go")
    r.interpreter.queue("other")
    r.interpreter.run()
    names = [x[1] for x in r.kinds("event")]
    assert names == ["go", "ping", "other"] and r.leaves == ["A"]


PARALLEL = """
statechart: par
events: {e: null, leave: null}
initial: P
states:
  - name: P
    type: parallel
    states:
      - name: R1
        initial: A1
        states:
          - {name: A1, transitions: [{event: e, target: B1}]}
          - {name: B1, transitions: [{event: leave, target: Out}]}
      - name: R2
        initial: A2
        states:
          - {name: A2, transitions: [{event: e, target: B2}]}
          - {name: B2, transitions: [{event: leave, target: A2}]}
  - name: Out
    transitions: [{event: e, target: P}]
"""


def test_parallel_regions_all_active_and_each_handles_the_event(run):
    r = run(PARALLEL, validate=False)
    assert r.leaves == ["P.R1.A1", "P.R2.A2"]
    r.send("e")
    assert r.leaves == ["P.R1.B1", "P.R2.B2"]
    transitions = [x[1] for x in r.kinds("transition")]
    assert transitions == ["P.R1.A1", "P.R2.A2"], "region document order"


def test_a_region_leaving_the_parallel_state_preempts_later_regions(run):
    r = run(PARALLEL, validate=False)
    r.send("e", "leave")
    assert r.leaves == ["Out"]
    assert ("transition", "P.R2.B2", "P.R2.A2", "leave") not in r.trace.records


def test_entering_a_parallel_state_through_one_region_enters_the_others(run):
    r = run(
        """
        statechart: pe
        events: {go: null}
        initial: X
        states:
          - {name: X, transitions: [{event: go, target: B2}]}
          - name: P
            type: parallel
            states:
              - {name: R1, initial: A1, states: [{name: A1}]}
              - {name: R2, initial: A2, states: [{name: A2}, {name: B2}]}
        """,
        validate=False,
    )
    r.send("go")
    assert r.leaves == ["P.R1.A1", "P.R2.B2"]


HISTORY = """
statechart: h
events: {next: null, out: null, back: null, deep: null}
initial: M
states:
  - name: M
    initial: A
    states:
      - {name: H, type: shallow_history}
      - {name: D, type: deep_history}
      - {name: A, transitions: [{event: next, target: B}]}
      - name: B
        initial: B1
        states:
          - {name: B1, transitions: [{event: next, target: B2}]}
          - {name: B2}
    transitions: [{event: out, target: Away}]
  - name: Away
    transitions:
      - {event: back, target: M.H}
      - {event: deep, target: M.D}
"""


def test_shallow_history_resumes_the_last_child_with_its_default_entry(run):
    r = run(HISTORY, validate=False)
    r.send("next", "next", "out", "back")
    assert r.leaves == ["M.B.B1"]


def test_deep_history_resumes_the_whole_configuration(run):
    r = run(HISTORY, validate=False)
    r.send("next", "next", "out", "deep")
    assert r.leaves == ["M.B.B2"]


def test_history_without_memory_uses_the_default_entry(run):
    r = run(HISTORY.replace("initial: M", "initial: Away"), validate=False)
    r.send("deep")
    assert r.leaves == ["M.A"]


JUNCTION = """
statechart: j
events: {go: {payload: {n: integer}}}
initial: A
states:
  - name: A
    transitions: [{event: go, target: J, effect: [{log: t1}]}]
  - name: J
    type: junction
    transitions:
      - {guard: event.n > 10, target: Big, effect: [{log: big}]}
      - {guard: event.n > 0, target: Small, effect: [{log: small}]}
  - {name: Big}
  - {name: Small}
"""


def test_junction_branches_are_chosen_before_anything_runs(run):
    r = run(JUNCTION, validate=False)
    r.send(("go", {"n": 20}))
    assert r.leaves == ["Big"] and logs(r) == ["t1", "big"]


def test_a_blocked_junction_means_the_transition_is_not_enabled(run):
    r = run(JUNCTION, validate=False)
    r.send(("go", {"n": -1}))
    assert r.leaves == ["A"] and logs(r) == []
    assert r.kinds("unhandled")


TIMED = """
statechart: t
events: {reset: null}
initial: A
states:
  - name: A
    transitions: [{after: 2s, target: B}, {event: reset, target: A}]
  - name: B
    transitions: [{after: 500ms, target: A}]
"""


def test_time_events_fire_at_their_deadline_on_the_simulated_clock(run):
    r = run(TIMED)
    r.interpreter.advance(1.999)
    assert r.leaves == ["A"]
    r.interpreter.advance(0.001)
    assert r.leaves == ["B"]
    r.interpreter.advance(0.5)
    assert r.leaves == ["A"] and r.clock.now() == pytest.approx(2.5)


def test_time_events_restart_when_the_state_is_reentered(run):
    r = run(TIMED)
    r.interpreter.advance(1.5)
    r.send("reset")
    r.interpreter.advance(1.5)
    assert r.leaves == ["A"], "the 2 s count restarted at t=1.5"
    r.interpreter.advance(0.5)
    assert r.leaves == ["B"]


def test_advancing_far_fires_chained_time_events_in_order(run):
    r = run(TIMED)
    r.interpreter.advance(9.9)
    # A->B at 2, B->A at 2.5, A->B at 4.5, B->A at 5, A->B at 7, B->A at 7.5, A->B at 9.5
    assert r.leaves == ["B"]
    assert len(r.kinds("transition")) == 7
    r.interpreter.advance(0.1)  # a deadline equal to the target time fires
    assert r.leaves == ["A"]


def test_configure_requests_the_tag_and_completes_only_on_its_ack(run):
    r = run(CONFIG_OK)
    assert [o.tag for o in r.outputs if o.kind == "configure"] == ["setup"]
    assert r.leaves == ["Top.A"] and r.interpreter.variables["done"] == 0
    r.send(("config.done", {"tag": "other"}))
    assert r.leaves == ["Top.A"]
    r.send(("config.done", {"tag": "setup"}))
    assert r.leaves == ["Top.B"] and r.interpreter.variables["done"] == 1


def test_a_configuration_timeout_raises_config_failed(run):
    r = run(CONFIG_OK)
    r.interpreter.advance(3.0)
    assert r.leaves == ["Failed"]
    failed = [x for x in r.kinds("event") if x[1] == "config.failed"]
    assert failed and failed[0][2]["tag"] == "setup" and "3 s" in failed[0][2]["reason"]


def test_a_late_ack_after_leaving_is_reported_not_lost(run):
    r = run(CONFIG_OK)
    r.interpreter.advance(3.0)
    r.send(("config.done", {"tag": "setup"}))
    assert r.kinds("unhandled")[-1][1] == "config.done"


CONFIG_OK = """
statechart: c
events: {go: null}
variables: {done: 0}
initial: Top
states:
  - name: Top
    initial: A
    states:
      - name: A
        configure: {tag: setup, timeout: 3s}
        do: [{set: {done: "= done + 1"}}]
        transitions: [{target: B}]
      - {name: B, transitions: [{event: go, target: A}]}
    transitions: [{event: config.failed, target: Failed}]
  - name: Failed
    transitions: [{event: go, target: Top}]
"""


def test_completion_of_a_composite_when_its_final_child_is_reached(run):
    r = run("""
        statechart: f
        events: {go: null}
        initial: C
        states:
          - name: C
            initial: X
            states:
              - {name: X, transitions: [{event: go, target: End}]}
              - {name: End, type: final}
            transitions: [{target: After}]
          - {name: After, type: final}
        """)
    assert not r.interpreter.finished
    r.send("go")
    assert r.leaves == ["After"] and r.interpreter.finished
    r.send("go")
    assert r.kinds("unhandled")[-1] == ("unhandled", "go", "the chart has finished")


def test_internal_transitions_do_not_exit_or_enter(run):
    r = run(
        """
        statechart: it
        events: {tick: null}
        variables: {n: 0}
        initial: A
        states:
          - name: A
            exit: [{log: exit}]
            transitions:
              - {event: tick, effect: [{set: {n: "= n + 1"}}]}
        """,
        validate=False,
    )
    r.send("tick", "tick")
    assert r.interpreter.variables["n"] == 2 and logs(r) == []


def test_local_transition_to_a_descendant_keeps_the_composite_self_transition_does_not(run):
    r = run(
        """
        statechart: lo
        events: {down: null, self: null}
        initial: C
        states:
          - name: C
            initial: X
            exit: [{log: exit C}]
            states: [{name: X}, {name: Y}]
            transitions:
              - {event: down, target: Y}
              - {event: self, target: C}
        """,
        validate=False,
    )
    r.send("down")
    assert r.leaves == ["C.Y"] and "exit C" not in logs(r)
    r.send("self")
    assert r.leaves == ["C.X"] and "exit C" in logs(r)


def test_a_failing_guard_is_reported_and_treated_as_false(run):
    r = run(
        """
        statechart: g
        events: {e: {payload: {x: number}}}
        initial: A
        states:
          - {name: A, transitions: [{event: e, guard: event.x > 1, target: B}]}
          - {name: B}
        """,
        validate=False,
    )
    r.send("e")
    assert r.leaves == ["A"] and r.kinds("error") and r.kinds("unhandled")


def test_actions_reach_the_host_as_outputs(run):
    r = run(
        """
        statechart: o
        events: {e: {payload: {v: number}}, out: null}
        variables: {k: 2}
        initial: A
        states:
          - name: A
            transitions:
              - event: e
                effect:
                  - send: {event: out, payload: {v: "= event.v * k"}}
                  - write: {port: speed, value: "= event.v"}
                  - call: {operation: robot.brake, args: {hard: true}}
                  - configure: extra
        """,
        validate=False,
    )
    r.send(("e", {"v": 1.5}))
    kinds = {o.kind: o for o in r.outputs}
    assert kinds["send"].payload == {"v": 3.0}
    assert kinds["write"].port == "speed" and kinds["write"].value == 1.5
    assert kinds["call"].operation == "robot.brake" and kinds["call"].args == {"hard": True}
    assert kinds["configure"].tag == "extra"
    r.send(("config.done", {"tag": "extra"}))
    assert not r.kinds("unhandled"), "the ack of an action-level configure is consumed"


def test_snapshot_restore_continues_identically(chart):
    from framework.clock import SimulatedClock
    from framework.statechart.events import Trace

    c = chart(HISTORY, validate=False)
    a = Interpreter(c, SimulatedClock())
    a.start()
    for e in ["next", "out"]:
        a.dispatch(e)
    snap = a.snapshot()
    b = Interpreter(c, SimulatedClock())
    b.restore(snap)
    ta, tb = Trace(), Trace()
    a.listeners.append(ta)
    b.listeners.append(tb)
    for e in ["deep", "out", "back", "next"]:
        a.dispatch(e)
        b.dispatch(e)
    assert ta.records == tb.records and a.configuration == b.configuration


def test_misuse_is_a_clear_error(chart):
    c = chart(TIMED)
    i = Interpreter(c)
    with pytest.raises(StatechartRuntimeError, match="start"):
        i.step()
    i.start()
    with pytest.raises(StatechartRuntimeError, match="already started"):
        i.start()
    with pytest.raises(StatechartRuntimeError, match="SimulatedClock"):
        i.advance(1)
    with pytest.raises(StatechartRuntimeError, match="fresh"):
        i.restore(i.snapshot())


def test_a_do_action_does_not_run_when_the_configuration_fails(run):
    r = run(CONFIG_OK)
    r.send(("config.failed", {"tag": "setup", "step": "call x.y", "reason": "no"}))
    assert r.leaves == ["Failed"] and r.interpreter.variables["done"] == 0


def test_a_duplicate_ack_is_reported_as_unhandled(run):
    r = run(CONFIG_OK)
    r.send(("config.done", {"tag": "setup"}))
    assert r.leaves == ["Top.B"] and r.interpreter.variables["done"] == 1
    r.send(("config.done", {"tag": "setup"}))
    assert r.kinds("unhandled")[-1][1] == "config.done"
    assert r.leaves == ["Top.B"] and r.interpreter.variables["done"] == 1, "do ran once"


@pytest.mark.parametrize("other", ["other", "wrap_up"])
def test_an_ack_for_another_tag_settles_nothing_and_is_reported(run, other):
    r = run(CONFIG_OK)
    r.send(("config.done", {"tag": other}))
    assert r.kinds("unhandled")[-1][1] == "config.done"
    assert r.interpreter.pending_configurations, "still waiting for its own ack"


# --- time events on a running clock (the Coordinator calls run() when it wakes up) ------

RACE = """
statechart: race
events: {leave: null, back: null, poke: null}
initial: A
states:
  - name: A
    transitions:
      - {after: 1s, target: B}
      - {after: 5s, target: C}
      - {event: leave, target: D}
  - {name: B, transitions: [{event: poke, target: C}]}
  - {name: C, type: final}
  - name: D
    transitions: [{event: back, target: A}]
"""


def test_a_time_event_already_past_fires_when_the_chart_next_runs(run):
    r = run(RACE)
    r.clock.set(2.0)  # woke up late: the 1 s deadline is behind us
    assert r.interpreter.run() == 1 and r.leaves == ["B"]


def test_a_running_chart_fires_the_earliest_due_time_event_and_then_its_queue(run):
    r = run(RACE)
    r.interpreter.queue("poke")
    r.clock.set(1.0)
    assert r.interpreter.run() == 2, "the time event, then the queued event, in one run"
    assert r.leaves == ["C"]


def test_the_time_event_of_a_state_left_and_reentered_restarts(run):
    r = run(RACE)
    r.clock.set(0.5)
    r.send("leave")
    r.clock.set(0.6)
    r.send("back")  # A again: its 1 s count starts at 0.6
    r.clock.set(1.2)
    assert r.interpreter.run() == 0 and r.leaves == ["A"], "the old deadline is dead"
    assert r.interpreter.next_deadline() == pytest.approx(1.6)
    r.clock.set(1.6)
    r.interpreter.run()
    assert r.leaves == ["B"]


def test_a_state_reentered_hundreds_of_times_still_keeps_time(run):
    r = run(RACE)
    for _ in range(300):
        r.send("leave")
        r.send("back")
    r.interpreter.advance(1.0)
    assert r.leaves == ["B"]


def test_states_never_entered_are_not_active(run):
    r = run(RACE)
    assert r.interpreter.is_active("A")
    assert not any(r.interpreter.is_active(s) for s in ("B", "C", "D", "nowhere"))


def test_advancing_returns_how_many_steps_it_took(run):
    r = run(TIMED)
    assert r.interpreter.advance(9.9) == 7
    r.interpreter.queue("reset")
    assert r.interpreter.advance(0.05) == 1


def test_a_time_event_is_reported_and_its_target_completes_at_once(run):
    r = run("""
        statechart: chained
        events: {}
        initial: A
        states:
          - {name: A, transitions: [{after: 1s, target: B}]}
          - {name: B, transitions: [{target: C}]}
          - {name: C, type: final}
    """)
    r.interpreter.advance(1.0)
    assert r.leaves == ["C"] and r.interpreter.finished
    assert ("event", "after", {"state": "A", "delay": 1.0}, "timer") in r.kinds("event")


FIRE_AND_FORGET = """
statechart: f
events: {go: null}
initial: A
states:
  - name: A
    entry: [{configure: lamp_on}, {configure: lamp_on}]
    transitions: [{event: go, target: B}]
  - {name: B, type: final}
"""


def test_acks_of_configurations_not_waited_for_are_consumed_one_each(run):
    r = run(FIRE_AND_FORGET)
    assert r.interpreter.pending_configurations == {}, "nothing waits for them"
    r.send(("config.done", {"tag": "lamp_on"}), ("config.failed", {"tag": "lamp_on"}))
    assert not r.kinds("unhandled"), "both consumed silently"
    r.send(("config.done", {"tag": "lamp_on"}))
    assert r.kinds("unhandled")[-1][1] == "config.done", "a third one was never asked for"


def test_the_awaited_configurations_and_the_queue_are_visible(run):
    r = run(CONFIG_OK)
    assert r.interpreter.pending_configurations == {"Top.A": "setup"}
    r.interpreter.queue("go")
    r.interpreter.queue("go")
    assert r.interpreter.queued == 2
    r.interpreter.run()
    assert r.interpreter.queued == 0


# --- what listeners see, parallel completion, junction paths, history kinds --------------


def test_listeners_see_exit_then_the_transition_then_entry(run):
    r = run(NESTED, validate=False)
    r.trace.records.clear()
    r.send("e")
    seen = [rec for rec in r.trace.records if rec[0] in ("exit", "transition", "entry")]
    assert seen == [
        ("exit", "P.C.L"),
        ("exit", "P.C"),
        ("exit", "P"),
        ("transition", "P", "Q", "e"),
        ("entry", "Q"),
    ]


def test_entering_a_nested_state_directly_enters_its_parents_first(run):
    r = run(
        """
        statechart: direct
        events: {go: null}
        initial: A
        states:
          - {name: A, transitions: [{event: go, target: P.C}]}
          - name: P
            initial: B
            states: [{name: B}, {name: C}]
        """,
        validate=False,
    )
    r.trace.records.clear()
    r.send("go")
    assert r.leaves == ["P.C"]
    assert [rec for rec in r.trace.records if rec[0] == "entry"] == [
        ("entry", "P"),
        ("entry", "P.C"),
    ]


PARALLEL_DONE = """
statechart: pd
events: {a: null, b: null}
initial: P
states:
  - name: P
    type: parallel
    states:
      - name: R1
        initial: A1
        states:
          - {name: A1, transitions: [{event: a, target: F1}]}
          - {name: F1, type: final}
      - name: R2
        initial: A2
        states:
          - {name: A2, transitions: [{event: b, target: F2}]}
          - {name: F2, type: final}
    transitions: [{target: Done}]
  - {name: Done, type: final}
"""


def test_a_parallel_state_completes_only_when_every_region_is_final(run):
    r = run(PARALLEL_DONE, validate=False)
    r.send("a")
    assert r.leaves == ["P.R1.F1", "P.R2.A2"], "one region done is not enough"
    r.send("b")
    assert r.leaves == ["Done"] and r.interpreter.finished


def test_time_events_due_together_in_two_regions_both_fire(run):
    r = run(
        """
        statechart: twin
        events: {}
        initial: P
        states:
          - name: P
            type: parallel
            states:
              - name: R1
                initial: A1
                states:
                  - {name: A1, transitions: [{after: 1s, target: B1}]}
                  - {name: B1}
              - name: R2
                initial: A2
                states:
                  - {name: A2, configure: {tag: x, timeout: 1s}, transitions: [{after: 1s, target: B2}]}
                  - {name: B2}
          - name: Q
            initial: Q1
            states:
              - {name: Q1, configure: {tag: y, timeout: 1s}}
        """,
        validate=False,
    )
    r.interpreter.advance(1.0)
    assert r.leaves == ["P.R1.B1", "P.R2.B2"]


CHAIN = """
statechart: chain
events: {go: {payload: {n: integer}}}
initial: P
states:
  - name: P
    initial: A
    states:
      - {name: A, transitions: [{event: go, target: J1, effect: [{log: leave A}]}]}
      - name: J1
        type: junction
        transitions:
          - {guard: event.n > 10, target: J2, effect: [{log: big}]}
          - {guard: else, target: Small, effect: [{log: else}]}
      - name: J2
        type: junction
        transitions:
          - {guard: event.n > 100, target: Huge}
          - {guard: else, target: Big}
      - {name: Small}
      - {name: Big}
      - {name: Huge}
"""


def test_a_chain_of_junctions_is_one_transition_from_the_state_that_took_the_event(run):
    r = run(CHAIN, validate=False)
    r.trace.records.clear()
    r.send(("go", {"n": 50}))
    assert r.leaves == ["P.Big"]
    assert [rec for rec in r.trace.records if rec[0] == "transition"] == [
        ("transition", "P.A", "P.J1", "go")
    ]
    assert [(o.state, o.message) for o in r.outputs if o.kind == "log"] == [
        ("P.A", "leave A"),
        ("P.A", "big"),
    ]


def test_an_else_branch_is_taken_when_no_guard_holds(run):
    r = run(CHAIN, validate=False)
    r.send(("go", {"n": 3}))
    assert r.leaves == ["P.Small"] and logs(r) == ["leave A", "else"]
    r = run(CHAIN, validate=False)
    r.send(("go", {"n": 500}))
    assert r.leaves == ["P.Huge"]


def test_a_completion_transition_may_go_through_a_junction(run):
    r = run(
        """
        statechart: cj
        events: {}
        variables: {n: 3}
        initial: A
        states:
          - {name: A, transitions: [{target: J}]}
          - name: J
            type: junction
            transitions:
              - {guard: n > 2, target: B}
              - {guard: else, target: C}
          - {name: B}
          - {name: C}
        """,
        validate=False,
    )
    assert r.leaves == ["B"]


ONE_HISTORY = """
statechart: oh
events: {next: null, out: null, back: null}
initial: M
states:
  - name: M
    initial: A
    states:
      - {name: H, type: HISTORY_KIND}
      - {name: A, transitions: [{event: next, target: B}]}
      - name: B
        initial: B1
        states:
          - {name: B1, transitions: [{event: next, target: B2}]}
          - {name: B2}
    transitions: [{event: out, target: Away}]
  - name: Away
    transitions: [{event: back, target: M.H}]
"""


@pytest.mark.parametrize(
    ("kind", "resumed"), [("shallow_history", "M.B.B1"), ("deep_history", "M.B.B2")]
)
def test_a_composite_with_one_history_resumes_as_its_kind_says(run, kind, resumed):
    r = run(ONE_HISTORY.replace("HISTORY_KIND", kind), validate=False)
    r.send("next", "next", "out", "back")
    assert r.leaves == [resumed]


def test_leaving_a_state_before_its_ack_drops_the_wait(run):
    r = run(
        """
        statechart: leave
        events: {go: null}
        initial: A
        states:
          - name: A
            configure: {tag: setup, timeout: 3s}
            transitions: [{event: go, target: B}, {event: config.failed, target: Failed}]
          - {name: B}
          - {name: Failed}
        """,
        validate=False,
    )
    r.send("go")
    assert r.leaves == ["B"] and r.interpreter.pending_configurations == {}
    r.interpreter.advance(5.0)
    assert r.leaves == ["B"], "no timeout for a state that was left"
    r.send(("config.done", {"tag": "setup"}))
    assert r.kinds("unhandled")[-1][1] == "config.done", "a late ack is reported"


def test_a_successful_ack_is_handled_not_reported_unhandled(run):
    r = run(CONFIG_OK)
    r.send(("config.done", {"tag": "setup"}))
    assert not r.kinds("unhandled")


def test_accepts_says_whether_an_active_state_would_take_the_event(run):
    r = run(CONFIG_OK)
    assert not r.interpreter.accepts("go"), "Top.A waits for its ack"
    assert r.interpreter.accepts("config.failed"), "Top takes it from any child"
    r.send(("config.done", {"tag": "setup"}))
    assert r.interpreter.accepts("go") and not r.interpreter.accepts("nothing")


def test_a_livelock_of_completion_transitions_is_stopped_and_reported(run):
    r = run(
        """
        statechart: loop
        events: {}
        initial: A
        states:
          - {name: A, transitions: [{target: B}]}
          - {name: B, transitions: [{target: A}]}
        """,
        validate=False,
    )
    errors = [rec for rec in r.trace.records if rec[0] == "error"]
    assert errors and "more than 10000 completion transitions" in errors[0][1]
    assert len(r.kinds("transition")) == 10_000


# --- robustness: initial junctions, failing actions and hosts, snapshots with time -------

INITIAL_BRANCH = """
statechart: ij
events: {go: null}
variables: {mode: 2}
initial: P
states:
  - name: P
    initial: J
    states:
      - name: J
        type: junction
        transitions:
          - {guard: mode == 1, target: One, effect: [{log: chose one}]}
          - {guard: mode == 2, target: Two, effect: [{log: chose two}]}
      - {name: One}
      - {name: Two}
"""


def test_an_initial_junction_chooses_the_first_entered_child(run):
    r = run(INITIAL_BRANCH, validate=False)
    assert r.leaves == ["P.Two"] and logs(r) == ["chose two"]


def test_an_initial_junction_takes_its_first_enabled_branch_quietly(run):
    r = run(INITIAL_BRANCH.replace("mode: 2", "mode: 1"), validate=False)
    assert r.leaves == ["P.One"] and logs(r) == ["chose one"]
    assert not [rec for rec in r.trace.records if rec[0] == "error"]


def test_the_configuration_names_a_parallel_states_regions_and_their_states(run):
    r = run(
        """
        statechart: pr
        events: {e: null}
        initial: P
        states:
          - name: P
            type: parallel
            states:
              - {name: R1, initial: A, states: [{name: A}]}
              - {name: R2, initial: B, states: [{name: B}]}
        """,
        validate=False,
    )
    assert r.interpreter.configuration == ["P", "P.R1", "P.R1.A", "P.R2", "P.R2.B"]
    assert r.leaves == ["P.R1.A", "P.R2.B"]


def test_an_initial_junction_with_no_branch_enabled_takes_its_last_and_says_so(run):
    r = run(INITIAL_BRANCH.replace("mode: 2", "mode: 3"), validate=False)
    assert r.leaves == ["P.Two"]
    errors = [rec for rec in r.trace.records if rec[0] == "error"]
    assert errors and "no branch of initial junction P.J is enabled" in errors[0][1]


def test_a_failing_action_is_reported_and_the_chart_goes_on(run):
    r = run(
        """
        statechart: fa
        events: {go: null}
        variables: {x: 0}
        initial: A
        states:
          - {name: A, transitions: [{event: go, target: B, effect: [{set: {x: "= 1 // x"}}, {log: after}]}]}
          - {name: B}
        """,
        validate=False,
    )
    r.send("go")
    assert r.leaves == ["B"] and logs(r) == ["after"]
    errors = [rec for rec in r.trace.records if rec[0] == "error"]
    assert errors and "set action at" in errors[0][1] and "failed" in errors[0][1]


def test_a_host_that_fails_on_an_output_does_not_stop_the_chart(chart):
    from framework.clock import SimulatedClock
    from framework.statechart.events import Trace

    def broken(output):
        raise RuntimeError("host down")

    trace = Trace()
    i = Interpreter(chart(CONFIG_OK), SimulatedClock(), [trace], on_output=broken)
    i.start()
    assert i.leaves == ["Top.A"]
    errors = [rec for rec in trace.records if rec[0] == "error"]
    assert errors and "output handler failed on configure: host down" in errors[0][1]


def test_a_snapshot_keeps_the_time_left_on_running_timers(chart):
    from framework.clock import SimulatedClock

    c = chart(TIMED)
    a = Interpreter(c, SimulatedClock())
    a.start()
    a.advance(1.5)
    b = Interpreter(c, SimulatedClock(100.0))
    b.restore(a.snapshot())
    b.advance(0.49)
    assert b.leaves == ["A"], "0.5 s were left of the 2 s"
    b.advance(0.01)
    assert b.leaves == ["B"]


def test_a_snapshot_of_another_chart_or_an_unknown_state_is_refused(chart):
    from framework.clock import SimulatedClock

    c = chart(TIMED)
    a = Interpreter(c, SimulatedClock())
    a.start()
    snap = a.snapshot()
    with pytest.raises(StatechartRuntimeError, match="not started"):
        a.restore(snap)
    with pytest.raises(StatechartRuntimeError, match="snapshot is of chart 'other'"):
        Interpreter(c, SimulatedClock()).restore({**snap, "chart": "other"})
    with pytest.raises(StatechartRuntimeError, match="unknown state"):
        Interpreter(c, SimulatedClock()).restore({**snap, "active": ["Nowhere"]})


def test_time_events_due_at_different_times_fire_at_their_own_time(run):
    r = run(
        """
        statechart: two_timers
        events: {}
        initial: A
        states:
          - {name: A, transitions: [{after: 1s, target: B}, {after: 5s, target: D}]}
          - {name: B, transitions: [{after: 1s, target: C}]}
          - {name: C}
          - {name: D}
        """,
        validate=False,
    )
    r.interpreter.advance(3.0)
    assert r.leaves == ["C"], "B at 1 s, C at 2 s"


def test_a_snapshot_keeps_the_history_and_the_events_still_queued(chart):
    """A restored Coordinator resumes where it was: the shallow history it recorded and
    the external events queued but not yet processed."""
    from framework.clock import SimulatedClock

    c = chart(HISTORY, validate=False)
    a = Interpreter(c, SimulatedClock())
    a.start()
    a.dispatch("next")
    a.dispatch("out")  # M left from B: its shallow history is B
    a.queue("back")
    a.queue("next")
    b = Interpreter(c, SimulatedClock())
    b.restore(a.snapshot())
    assert b.leaves == ["Away"]
    b.run()
    a.run()
    assert b.leaves == a.leaves == ["M.B.B2"], "back to B (history), then on to B2"


def test_a_snapshot_keeps_the_variables_and_the_configuration_still_awaited(chart):
    from framework.clock import SimulatedClock

    c = chart(CONFIG_OK)
    a = Interpreter(c, SimulatedClock())
    a.start()
    a.dispatch("config.done", {"tag": "setup"})
    a.dispatch("go")  # A again: `setup` requested anew, its ack awaited
    assert a.variables["done"] == 1 and a.leaves == ["Top.A"]
    b = Interpreter(c, SimulatedClock())
    b.restore(a.snapshot())
    assert b.variables == {"done": 1}
    b.dispatch("config.done", {"tag": "setup"})
    assert b.variables == {"done": 2} and b.leaves == ["Top.B"], "the awaited ack is taken"


def test_listeners_hear_internal_transitions_and_outputs(run):
    from framework.statechart.events import Trace

    r = run(
        """
        statechart: l
        events: {e: null}
        initial: A
        states:
          - name: A
            transitions:
              - event: e
                effect: [{call: {operation: robot.brake}}]
        """,
        validate=False,
    )
    trace = Trace()
    r.interpreter.listeners.append(trace)
    r.send("e")
    assert ("transition", "A", None, "e") in trace.records, "an internal transition is heard"
    assert ("output", "call", "robot.brake") in trace.records


def test_a_snapshot_keeps_an_effects_configuration_still_awaited(chart):
    """A configuration an effect asked for is awaited across a restore: its ack is
    taken, not reported as unhandled."""
    from framework.clock import SimulatedClock
    from framework.statechart.events import Trace

    c = chart(
        """
        statechart: a
        events: {e: null}
        initial: A
        states:
          - name: A
            transitions: [{event: e, effect: [{configure: extra}]}]
        """,
        validate=False,
    )
    a = Interpreter(c, SimulatedClock())
    a.start()
    a.dispatch("e")
    trace = Trace()
    b = Interpreter(c, SimulatedClock(), [trace])
    b.restore(a.snapshot())
    b.dispatch("config.done", {"tag": "extra"})
    assert not [r for r in trace.records if r[0] == "unhandled"]
    b.dispatch("config.done", {"tag": "extra"})
    assert [r[1] for r in trace.records if r[0] == "unhandled"] == ["config.done"], "once only"


def test_a_time_event_of_zero_seconds_comes_after_the_events_raised_on_entry(run):
    """`after: 0s` is a time event due at once, not a completion: the events the state
    raised on entry are processed first (internal before time events), and the one that
    leaves the state cancels it."""
    r = run(
        """
        statechart: zero
        events: {}
        initial: A
        states:
          - name: A
            entry: [{raise: x}]
            transitions: [{after: 0s, target: B}, {event: x, target: C}]
          - {name: B}
          - {name: C}
        """,
        validate=False,
    )
    assert r.leaves == ["C"]


def test_a_transition_across_regions_leaves_and_enters_the_whole_parallel_state(run):
    """From a state of one region to a state of another: no region can be left alone, so
    the parallel state is left (its regions in reverse document order, as SCXML, its own
    exit last) and entered again,
    the source's region at its initial state and the target's at the target."""
    r = run(
        """
        statechart: across
        events: {e: null}
        initial: P
        states:
          - name: P
            type: parallel
            entry: [{log: enter P}]
            exit: [{log: exit P}]
            states:
              - name: R1
                initial: A
                states:
                  - {name: A, transitions: [{event: e, target: C}], exit: [{log: exit A}]}
                  - {name: A2}
              - name: R2
                initial: B
                states: [{name: B, exit: [{log: exit B}]}, {name: C, entry: [{log: enter C}]}]
        """,
        validate=False,
    )
    r.send("e")
    assert r.leaves == ["P.R1.A", "P.R2.C"]
    assert logs(r)[-5:] == ["exit B", "exit A", "exit P", "enter P", "enter C"], logs(r)


def test_a_regions_transition_whose_source_was_left_in_the_same_step_does_not_fire(run):
    """R1's transition on e re-enters the parallel state P: R2's source was left in this
    step (and entered anew), so R2's own transition on e does not fire (issue 20)."""
    r = run(
        """
        statechart: reenter
        events: {e: null}
        initial: P
        states:
          - name: P
            type: parallel
            states:
              - name: R1
                initial: A
                states: [{name: A, transitions: [{event: e, target: P}]}]
              - name: R2
                initial: B
                states:
                  - {name: B, transitions: [{event: e, target: C, effect: [{log: R2 fired}]}]}
                  - {name: C}
        """,
        validate=False,
    )
    r.send("e")
    assert r.leaves == ["P.R1.A", "P.R2.B"]
    assert logs(r) == []


def test_a_state_left_is_no_longer_active_for_a_guard_in_another_region(run):
    """`active('A')` reads the configuration now: once R1 left A, a guard on it in R2 is
    false (a left state must not keep answering as active)."""
    r = run(
        """
        statechart: g
        events: {leave: null, check: null}
        initial: P
        states:
          - name: P
            type: parallel
            states:
              - name: R1
                initial: A
                states: [{name: A, transitions: [{event: leave, target: A2}]}, {name: A2}]
              - name: R2
                initial: B
                states:
                  - name: B
                    transitions:
                      - {event: check, guard: "active('A')", target: C}
                  - {name: C}
        """,
        validate=False,
    )
    assert r.interpreter.is_active("A")
    r.send("leave", "check")
    assert not r.interpreter.is_active("A")
    assert r.leaves == ["P.R1.A2", "P.R2.B"], "the guard saw A left"


def test_a_snapshot_keeps_the_time_left_for_an_awaited_configuration(chart):
    """The configuration's timeout counts on after a restore, from where it was."""
    from framework.clock import SimulatedClock
    from framework.statechart.events import Trace

    c = chart(CONFIG_OK)
    a = Interpreter(c, SimulatedClock(50.0))
    a.start()
    a.advance(1.0)  # 2 s left of setup's 3 s
    trace = Trace()
    b = Interpreter(c, SimulatedClock(200.0), [trace])
    b.restore(a.snapshot())
    assert b.snapshot()["pending"] == {"Top.A": ["setup", pytest.approx(2.0)]}
    b.advance(1.99)
    assert b.leaves == ["Top.A"], "not timed out yet"
    b.advance(0.02)
    assert b.leaves == ["Failed"], "timed out 2 s after the restore"


# --- what a first run of fw's own mutants found unspecified (2026-11-28) ----------------
def restored_after(chart, seconds):
    """An interpreter started on a simulated clock and run `seconds`, restored from its
    snapshot into a new one whose clock reads otherwise (times travel as time left)."""
    from framework.clock import SimulatedClock

    a = Interpreter(chart, SimulatedClock())
    a.start()
    a.advance(seconds)
    b = Interpreter(chart, SimulatedClock(100.0))
    b.restore(a.snapshot())
    return b


def test_a_time_event_whose_guard_is_false_is_reported_unhandled(run):
    r = run(
        """
        statechart: g
        events: {}
        initial: A
        states:
          - {name: A, transitions: [{after: 1s, guard: "False", target: B}]}
          - {name: B}
        """,
        validate=False,
    )
    r.interpreter.advance(1.0)
    assert r.leaves == ["A"]
    assert ("unhandled", "after", "guard of the time event is false") in r.trace.records


def test_a_junction_chain_that_loops_is_an_error_and_nothing_fires(run):
    r = run(
        """
        statechart: loop
        events: {go: null}
        initial: A
        states:
          - {name: A, transitions: [{event: go, target: J1}]}
          - {name: J1, type: junction, transitions: [{target: J2}]}
          - {name: J2, type: junction, transitions: [{target: J1}]}
        """,
        validate=False,
    )
    r.send("go")
    assert r.leaves == ["A"]
    errors = [e[1] for e in r.kinds("error")]
    assert len(errors) == 1 and "junction chain from" in errors[0] and "too long" in errors[0]


def test_a_junction_chain_that_ends_reports_no_error(run):
    r = run(JUNCTION, validate=False)
    r.send(("go", {"n": 5}))
    assert r.leaves == ["Small"] and r.kinds("error") == []


def test_a_finished_chart_still_lets_listeners_hear_an_event_then_reports_it_unhandled(run):
    r = run(
        """
        statechart: done
        events: {e: null}
        initial: F
        states: [{name: F, type: final}]
        """,
        validate=False,
    )
    assert r.interpreter.finished
    r.send("e")
    assert ("event", "e", None, "external") in r.trace.records
    assert ("unhandled", "e", "the chart has finished") in r.trace.records


def test_an_outer_internal_transition_takes_the_event_from_the_inner_state(run):
    """Outer first: the outer state's transition on e, internal (no target, nothing
    exited), is the one taken; the inner state's own transition on e does not fire."""
    r = run(
        """
        statechart: outer
        events: {e: null}
        initial: M
        states:
          - name: M
            initial: A
            transitions: [{event: e, effect: [{log: outer}]}]
            states:
              - {name: A, transitions: [{event: e, target: B, effect: [{log: inner}]}]}
              - {name: B}
        """,
        validate=False,
    )
    r.send("e")
    assert r.leaves == ["M.A"] and logs(r) == ["outer"]


def test_a_history_with_a_default_enters_the_default_when_it_has_no_memory(run):
    chart = HISTORY.replace(
        "{name: D, type: deep_history}", "{name: D, type: deep_history, default: B.B2}"
    ).replace("initial: M", "initial: Away")
    r = run(chart, validate=False)
    r.send("deep")
    assert r.leaves == ["M.B.B2"]


def test_a_transition_to_its_own_ancestors_history_leaves_and_resumes_that_ancestor(run):
    """From M.B.B2 to M's shallow history: M is left (its exit runs) and entered again
    at the child it was in, B, with B's default entry."""
    chart = HISTORY.replace(
        "          - {name: B2}",
        "          - {name: B2, transitions: [{event: back, target: M.H}]}",
    )
    r = run(chart, validate=False)
    r.send("next", "next")
    assert r.leaves == ["M.B.B2"]
    r.send("back")
    assert r.leaves == ["M.B.B1"]
    assert ("exit", "M") in r.trace.records and r.trace.records.count(("entry", "M")) == 2


def test_a_restored_time_event_of_a_parent_state_outlives_its_childs_transitions(chart):

    c = chart(
        """
        statechart: parent_timer
        events: {next: null}
        initial: M
        states:
          - name: M
            initial: A
            transitions: [{after: 2s, target: Out}]
            states:
              - {name: A, transitions: [{event: next, target: B}]}
              - {name: B}
          - {name: Out}
        """,
        validate=False,
    )
    b = restored_after(c, 1.0)
    b.dispatch("next")
    assert b.leaves == ["M.B"]
    b.advance(1.0)
    assert b.leaves == ["Out"], "M's time event, 1 s left at the snapshot"


def test_an_initial_state_nested_deeper_is_entered_through_every_state_above_it(run):
    r = run(
        """
        statechart: deep_initial
        events: {}
        initial: M
        states:
          - name: M
            initial: B.B2
            states:
              - {name: A}
              - name: B
                initial: B1
                entry: [{log: enter B}]
                states: [{name: B1}, {name: B2, entry: [{log: enter B2}]}]
        """,
        validate=False,
    )
    assert r.leaves == ["M.B.B2"]
    assert logs(r) == ["enter B", "enter B2"]


def test_a_state_whose_initial_is_its_own_history_resumes_it(run):
    """M's initial is its shallow history: the first time, its default; after M was
    left from B, B again."""
    r = run(
        """
        statechart: ih
        events: {next: null, out: null, back: null}
        initial: M
        states:
          - name: M
            initial: H
            transitions: [{event: out, target: Away}]
            states:
              - {name: H, type: shallow_history, default: A}
              - {name: A, transitions: [{event: next, target: B}]}
              - {name: B}
          - {name: Away, transitions: [{event: back, target: M}]}
        """,
        validate=False,
    )
    assert r.leaves == ["M.A"]
    r.send("next", "out", "back")
    assert r.leaves == ["M.B"]


def test_a_states_do_actions_run_on_entry_when_it_asks_no_configuration(run):
    r = run(
        """
        statechart: do
        events: {}
        variables: {done: 0}
        initial: A
        states: [{name: A, do: [{set: {done: "= done + 1"}}, {log: did it}]}]
        """,
        validate=False,
    )
    assert r.interpreter.variables["done"] == 1 and logs(r) == ["did it"]


def test_an_eventless_transition_inside_a_region_of_a_parallel_state_fires(run):
    r = run(
        """
        statechart: pc
        events: {}
        initial: P
        states:
          - name: P
            type: parallel
            states:
              - {name: R1, initial: A, states: [{name: A, transitions: [{target: A2}]}, {name: A2}]}
              - {name: R2, initial: B, states: [{name: B}]}
        """,
        validate=False,
    )
    assert r.leaves == ["P.R1.A2", "P.R2.B"]


@pytest.mark.parametrize("internal", [False, True], ids=["external", "internal"])
def test_a_transition_is_heard_before_its_effect_runs(run, internal):
    """What a trace or recording shows: the transition, then what its effect did."""
    target = "" if internal else ", target: B"
    r = run(
        f"""
        statechart: heard
        events: {{e: null}}
        initial: A
        states:
          - {{name: A, transitions: [{{event: e{target}, effect: [{{log: effect}}]}}]}}
          - {{name: B}}
        """,
        validate=False,
    )
    r.send("e")
    kinds = [rec[0] for rec in r.trace.records if rec[0] in ("transition", "output")]
    assert kinds == ["transition", "output"]


def test_a_parallel_state_enters_each_region_before_the_regions_states(run):
    """Entry order is parent before child in every region, whichever way the parallel
    state is entered (its initial entry, or through one region's state)."""
    chart = """
        statechart: order
        events: {e: null}
        initial: START
        states:
          - {name: START, transitions: [{event: e, target: TARGET}]}
          - name: P
            type: parallel
            states:
              - name: R1
                initial: A
                entry: [{log: R1}]
                states: [{name: A, entry: [{log: A}]}, {name: A2, entry: [{log: A2}]}]
              - name: R2
                initial: B
                entry: [{log: R2}]
                states: [{name: B, entry: [{log: B}]}]
        """
    plain = run(chart.replace("TARGET", "P"), validate=False).send("e")
    assert logs(plain) == ["R1", "A", "R2", "B"]
    through = run(chart.replace("TARGET", "P.R1.A2"), validate=False).send("e")
    assert logs(through) == ["R1", "A2", "R2", "B"]


def test_a_shallow_history_enters_the_remembered_state_before_its_children(run):
    chart = HISTORY.replace(
        "        initial: B1\n", "        initial: B1\n        entry: [{log: B}]\n"
    ).replace("{name: B1, ", "{name: B1, entry: [{log: B1}], ")
    r = run(chart, validate=False)
    r.send("next", "out", "back")
    assert r.leaves == ["M.B.B1"] and logs(r)[-2:] == ["B", "B1"]


def test_two_time_events_due_at_the_same_instant_survive_a_restore(chart):

    c = chart(
        """
        statechart: twins
        events: {}
        initial: M
        states:
          - name: M
            initial: A
            transitions: [{after: 2s, target: Out, effect: [{log: M's}]}]
            states: [{name: A, transitions: [{after: 2s, target: A2}]}, {name: A2}]
          - {name: Out}
        """,
        validate=False,
    )
    b = restored_after(c, 0.5)
    b.advance(1.5)
    assert b.leaves == ["Out"], "outer first, at the same instant"
