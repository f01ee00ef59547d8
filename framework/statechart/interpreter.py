"""Run a statechart: run-to-completion steps with rFSM's outer-first priority.

Semantics (documented in docs/statecharts.md, checked by property tests):

* One event per step. Internal events (raised by the chart) come first, then
  due time events, then external events, each FIFO. Every dequeued event
  either fires a transition, settles an awaited configuration, or is
  reported to listeners as unhandled: nothing is dropped silently.
* Outer-first priority: the active state closest to the root with an
  enabled transition wins; inside one state, higher `priority` first, then
  document order. A parallel state's regions are searched independently, so
  one event may fire one transition per region, in region document order; a
  transition whose source was left by an earlier one in the same step does
  not fire.
* A transition exits innermost-first, runs its effects, enters
  outermost-first. Completion (eventless) transitions fire when their source
  is complete, re-checked after every step until the chart is quiet.
* A state with `configure: tag` asks the host for that configuration on
  entry and is complete only once `config.done` for the tag arrives; a
  timeout raises `config.failed` on the chart's clock.
"""

from __future__ import annotations

import heapq
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any

from framework.clock import Clock, MonotonicClock, SimulatedClock
from framework.errors import FwError
from framework.statechart.events import Event, Listener, Output
from framework.statechart.expressions import Env
from framework.statechart.model import (
    CONFIG_DONE,
    CONFIG_FAILED,
    Action,
    Kind,
    State,
    Statechart,
    Transition,
    Value,
)

_COMPOUND, _PARALLEL, _FINAL = Kind.COMPOUND, Kind.PARALLEL, Kind.FINAL
_JUNCTION = Kind.JUNCTION
_HISTORY = (Kind.SHALLOW_HISTORY, Kind.DEEP_HISTORY)
MAX_MICROSTEPS = 10_000


class StatechartRuntimeError(FwError):
    """The interpreter was used wrongly (not started, bad snapshot...)."""


class _Node:
    """Run-time twin of a `State`: the interpreter's mutable, precomputed view."""

    __slots__ = (
        "active",
        "active_child",
        "by_event",
        "children",
        "completion",
        "epoch",
        "has_history",
        "initial",
        "kind",
        "parent",
        "state",
        "subtree_completion",
        "subtree_events",
        "timed",
    )

    def __init__(self, state: State):
        self.state = state
        self.kind = state.kind
        self.active = False
        self.active_child: _Node | None = None
        self.epoch = 0
        self.parent: _Node | None = None
        self.children: list[_Node] = []
        self.initial: _Node | None = None
        self.by_event: dict[str, tuple[_Arc, ...]] = {}
        self.completion: tuple[_Arc, ...] = ()
        self.timed: tuple[_Arc, ...] = ()
        self.subtree_events: frozenset[str] = frozenset()
        self.subtree_completion = False
        self.has_history: tuple[_Node, ...] = ()


class _Arc:
    """Run-time twin of a `Transition` with its exit domain and entry path precomputed."""

    __slots__ = (
        "chain",
        "domain",
        "effect",
        "guard",
        "is_else",
        "path",
        "resume",
        "source",
        "target",
        "transition",
    )

    def __init__(self, transition: Transition, source: _Node, target: _Node | None):
        self.transition = transition
        self.source = source
        self.target = target
        self.guard = transition.guard
        self.is_else = transition.is_else
        self.effect = transition.effect
        self.chain = (self,)
        self.domain: _Node | None = None
        self.path: tuple[_Node, ...] = ()
        self.resume: _Node | None = None


def _domain_and_path(source: _Node, target: _Node) -> tuple[_Node, tuple[_Node, ...], _Node | None]:
    """Exit domain (never exited), entry path below it, and a history node to resume."""
    resume = None
    if target.kind in _HISTORY:
        resume, target = target, target.parent  # type: ignore[assignment]
    anc = target.parent
    target_ancestors = []
    while anc is not None:
        target_ancestors.append(anc)
        anc = anc.parent
    if source.kind is _COMPOUND and source in target_ancestors and target is not source:
        domain = source
    else:
        domain = source.parent
        while domain is not None and domain not in target_ancestors:
            domain = domain.parent
    assert domain is not None
    while domain.kind is _PARALLEL:
        domain = domain.parent  # type: ignore[assignment]
    path = [target]
    node = target.parent
    while node is not domain:
        path.append(node)  # type: ignore[arg-type]
        node = node.parent  # type: ignore[union-attr]
    path.reverse()
    return domain, tuple(path), resume


class Interpreter:
    """Executes one `Statechart`; see the module docstring for the semantics."""

    def __init__(
        self,
        chart: Statechart,
        clock: Clock | None = None,
        listeners: Iterable[Listener] = (),
        on_output: Callable[[Output], None] | None = None,
    ):
        self.chart = chart
        self.clock: Clock = clock or MonotonicClock()
        self.listeners: list[Listener] = list(listeners)
        self.on_output = on_output
        self.variables: dict[str, Any] = {n: v.initial for n, v in chart.variables.items()}
        self.started = False
        self.finished = False
        self._internal: deque[Event] = deque()
        self._external: deque[Event] = deque()
        self._timers: list[tuple[float, int, _Node, int, _Arc | None]] = []
        self._seq = 0
        self._pending: dict[_Node, tuple[str, float]] = {}
        self._pending_tags: dict[str, int] = {}
        self._shallow: dict[_Node, _Node] = {}
        self._deep: dict[_Node, list[_Node]] = {}
        self._nodes: dict[str, _Node] = {}
        self._root = self._compile(chart)
        self._by_name: dict[str, _Node | None] = {}

    # -- compilation -------------------------------------------------------------
    def _compile(self, chart: Statechart) -> _Node:
        nodes = {path: _Node(state) for path, state in chart.states.items()}
        self._nodes = nodes
        for node in nodes.values():
            state = node.state
            node.parent = nodes[state.parent.path] if state.parent is not None else None
            node.children = [nodes[c.path] for c in state.children]
            node.initial = nodes[state.initial.path] if state.initial is not None else None
            node.has_history = tuple(c for c in node.children if c.kind in _HISTORY)
        for node in nodes.values():
            by_event: dict[str, list[_Arc]] = {}
            completion, timed = [], []
            for t in node.state.transitions:  # already sorted: priority, then document order
                arc = _Arc(t, node, nodes[t.target.path] if t.target is not None else None)
                if arc.target is not None:
                    final = arc.target
                    if final.kind is not _JUNCTION:
                        arc.domain, arc.path, arc.resume = _domain_and_path(node, final)
                if t.events:
                    for name in t.events:
                        by_event.setdefault(name, []).append(arc)
                elif t.after is not None:
                    timed.append(arc)
                else:
                    completion.append(arc)
            node.by_event = {k: tuple(v) for k, v in by_event.items()}
            node.completion, node.timed = tuple(completion), tuple(timed)
        root = nodes[""]
        self._index_subtrees(root)
        return root

    def _index_subtrees(self, node: _Node) -> None:
        events = set(node.by_event)
        completion = bool(node.completion)
        for child in node.children:
            self._index_subtrees(child)
            events |= child.subtree_events
            completion = completion or child.subtree_completion
        node.subtree_events = frozenset(events)
        node.subtree_completion = completion

    # -- public API --------------------------------------------------------------
    def start(self) -> None:
        """Enter the initial configuration and run until quiet."""
        if self.started:
            raise StatechartRuntimeError("the interpreter is already started")
        self.started = True
        root = self._root
        root.active = True
        env = Env(self.variables, None, self.is_active)
        self._enter_children(root, env)
        self._complete(env)
        self.run()

    def queue(self, name: str, payload: dict[str, Any] | None = None) -> None:
        """Add an external event to the queue (processed by `step`/`run`)."""
        self._external.append(Event(name, payload))

    def dispatch(self, name: str, payload: dict[str, Any] | None = None) -> int:
        """Queue one external event and run until quiet; return the steps taken."""
        self._external.append(Event(name, payload))
        return self.run()

    def step(self) -> bool:
        """Process one event (internal, then due timer, then external); False if idle."""
        if not self.started:
            raise StatechartRuntimeError("call start() before processing events")
        if self._internal:
            self._process(self._internal.popleft())
            return True
        timers = self._timers
        if timers:
            now = self.clock.now()
            while timers and timers[0][0] <= now:
                _, _, node, epoch, arc = heapq.heappop(timers)
                if node.active and node.epoch == epoch:
                    self._process_timer(node, arc)
                    return True
        if self._external:
            self._process(self._external.popleft())
            return True
        return False

    def run(self) -> int:
        """Process events until none is ready; return how many steps were taken."""
        steps = 0
        while self.step():
            steps += 1
        return steps

    def next_deadline(self) -> float | None:
        """When the next live time event is due (None if none is scheduled)."""
        timers = self._timers
        while timers:
            _, _, node, epoch, _ = timers[0]
            if node.active and node.epoch == epoch:
                return timers[0][0]
            heapq.heappop(timers)
        return None

    def advance(self, seconds: float) -> int:
        """Simulated clock only: move time forward, firing time events at their deadlines."""
        return self.advance_to(self.clock.now() + seconds)

    def advance_to(self, t: float) -> int:
        """Simulated clock only: move to time `t`, processing everything due on the way."""
        clock = self.clock
        if not isinstance(clock, SimulatedClock):
            raise StatechartRuntimeError("advance() needs a SimulatedClock")
        steps = self.run()
        while True:
            deadline = self.next_deadline()
            if deadline is None or deadline > t:
                break
            clock.set(max(deadline, clock.now()))
            steps += self.run()
        clock.set(max(t, clock.now()))
        return steps + self.run()

    def is_active(self, name: str) -> bool:
        """True if the state with this path or unique name is active."""
        node = self._by_name.get(name)
        if node is None:
            try:
                node = self._nodes[self.chart.state(name).path]
            except KeyError:
                return False
            self._by_name[name] = node
        return node.active

    def accepts(self, name: str) -> bool:
        """True if an active state (or the root) has a transition on event `name` now.
        Guards are not evaluated: an accepted event may still find every guard false.
        This is what a console needs to enable a control."""
        if name in self._root.by_event:
            return True
        return any(name in node.by_event for node in self._active_preorder(self._root))

    @property
    def configuration(self) -> list[str]:
        """Paths of the active states in document order (the root excluded)."""
        return [n.state.path for n in self._active_preorder(self._root)]

    @property
    def leaves(self) -> list[str]:
        """Paths of the active states that have no active child."""
        return [
            n.state.path
            for n in self._active_preorder(self._root)
            if n.kind not in (_COMPOUND, _PARALLEL)
        ]

    @property
    def pending_configurations(self) -> dict[str, str]:
        """Configuration tags awaited, by requesting state path."""
        return {n.state.path: tag for n, (tag, _) in self._pending.items()}

    @property
    def queued(self) -> int:
        """Events waiting: internal plus external."""
        return len(self._internal) + len(self._external)

    # -- steps -------------------------------------------------------------------
    def _process(self, event: Event) -> None:
        listeners = self.listeners
        if listeners:
            for listener in listeners:
                listener.on_event(event)
        if self.finished:
            self._unhandled(event, "the chart has finished")
            return
        name = event.name
        settled = self._settle(event) if name in (CONFIG_DONE, CONFIG_FAILED) else False
        env = Env(self.variables, event, self.is_active)
        chosen: list[tuple[_Arc, ...]] = []
        if name in self._root.subtree_events:
            self._select(self._root, name, env, chosen)
        if chosen:
            self._fire_all(chosen, event, env)
        elif not settled:
            self._unhandled(event, "no enabled transition")
        if self._root.subtree_completion:
            self._complete(Env(self.variables, None, self.is_active))

    def _process_timer(self, node: _Node, arc: _Arc | None) -> None:
        if arc is None:  # a configuration timeout
            pending = self._pending.pop(node, None)
            if pending is not None:
                self._process(
                    Event(
                        CONFIG_FAILED,
                        {
                            "tag": pending[0],
                            "state": node.state.path,
                            "reason": f"no acknowledgement within {node.state.configure.timeout:g} s",
                        },
                        "internal",
                    )
                )
            return
        event = Event("after", {"state": node.state.path, "delay": arc.transition.after}, "timer")
        for listener in self.listeners:
            listener.on_event(event)
        env = Env(self.variables, event, self.is_active)
        chain = self._enabled(arc, env)
        if chain is None:
            self._unhandled(event, "guard of the time event is false")
        else:
            self._fire(chain, event, env)
        if self._root.subtree_completion:
            self._complete(Env(self.variables, None, self.is_active))

    def _unhandled(self, event: Event, reason: str) -> None:
        for listener in self.listeners:
            listener.on_unhandled(event, reason)

    def _settle(self, event: Event) -> bool:
        """Clear awaited configurations acknowledged by this event; True if any was."""
        tag = (event.payload or {}).get("tag")
        settled = False
        if self._pending_tags.get(tag):
            self._pending_tags[tag] -= 1
            settled = True
        waiting = [n for n, (t, _) in self._pending.items() if t == tag]
        for node in waiting:
            del self._pending[node]
            settled = True
            if event.name == CONFIG_DONE and node.state.do:
                self._actions(node.state.do, Env(self.variables, event, self.is_active), node.state)
        return settled

    def _guard(self, arc: _Arc, env: Env) -> bool:
        try:
            return bool(arc.guard(env))  # type: ignore[misc]
        except Exception as exc:  # a guard never crashes the Coordinator
            self._error(
                f"guard {arc.guard.source!r} of {arc.transition.location} failed: "
                f"{exc}; treated as false",
                env.event,
            )
            return False

    def _enabled(self, arc: _Arc, env: Env) -> tuple[_Arc, ...] | None:
        """The arc's full chain through junctions if it is enabled now, else None."""
        if arc.guard is not None and not self._guard(arc, env):
            return None
        target = arc.target
        if target is None or target.kind is not _JUNCTION:
            return arc.chain
        chain = [arc]
        for _ in range(64):
            fallback = None
            for branch in target.completion:
                if branch.is_else:
                    fallback = fallback or branch
                elif branch.guard is None or self._guard(branch, env):
                    break
            else:
                branch = fallback  # type: ignore[assignment]
            if branch is None:
                return None
            chain.append(branch)
            target = branch.target
            if target is None or target.kind is not _JUNCTION:
                return tuple(chain)
        self._error(f"junction chain from {arc.transition.location} is too long", env.event)
        return None

    def _select(self, node: _Node, name: str, env: Env, out: list[tuple[_Arc, ...]]) -> None:
        arcs = node.by_event.get(name)
        if arcs:
            for arc in arcs:
                chain = self._enabled(arc, env)
                if chain is not None:
                    out.append(chain)
                    return
        if node.kind is _PARALLEL:
            for child in node.children:
                if name in child.subtree_events:
                    self._select(child, name, env, out)
        else:
            child = node.active_child
            if child is not None and name in child.subtree_events:
                self._select(child, name, env, out)

    def _is_complete(self, node: _Node) -> bool:
        if node in self._pending:
            return False
        kind = node.kind
        if kind is _COMPOUND:
            child = node.active_child
            return child is not None and child.kind is _FINAL
        if kind is _PARALLEL:
            return all(self._is_complete(c) for c in node.children)
        return True

    def _select_completion(self, node: _Node, env: Env, out: list[tuple[_Arc, ...]]) -> None:
        if node.completion and self._is_complete(node):
            for arc in node.completion:
                chain = self._enabled(arc, env)
                if chain is not None:
                    out.append(chain)
                    return
        if node.kind is _PARALLEL:
            for child in node.children:
                if child.subtree_completion:
                    self._select_completion(child, env, out)
        else:
            child = node.active_child
            if child is not None and child.subtree_completion:
                self._select_completion(child, env, out)

    def _complete(self, env: Env) -> None:
        for _ in range(MAX_MICROSTEPS):
            if self.finished:
                return
            chosen: list[tuple[_Arc, ...]] = []
            self._select_completion(self._root, env, chosen)
            if not chosen:
                return
            self._fire_all(chosen, None, env)
        self._error(
            f"more than {MAX_MICROSTEPS} completion transitions in one step (a livelock); stopped",
            None,
        )

    # -- firing ------------------------------------------------------------------
    def _fire_all(self, chosen: list[tuple[_Arc, ...]], event: Event | None, env: Env) -> None:
        """Fire the transitions selected in one step, in order; one whose source an
        earlier one left in this step does not fire, even if that source was entered
        again (a region's transition to its own parallel state re-enters the others)."""
        epochs = [chain[0].source.epoch for chain in chosen]
        for chain, epoch in zip(chosen, epochs, strict=True):
            source = chain[0].source
            if source.active and source.epoch == epoch:
                self._fire(chain, event, env)

    def _fire(self, chain: tuple[_Arc, ...], event: Event | None, env: Env) -> None:
        first, last = chain[0], chain[-1]
        if last.target is None:  # internal transition: effect only
            for listener in self.listeners:
                listener.on_transition(first.transition, event)
            for arc in chain:
                if arc.effect:
                    self._actions(arc.effect, env, first.source.state)
            return
        if len(chain) == 1:
            domain, path, resume = first.domain, first.path, first.resume
        else:
            domain, path, resume = _domain_and_path(first.source, last.target)
        self._exit_below(domain)  # type: ignore[arg-type]
        for listener in self.listeners:
            listener.on_transition(first.transition, event)
        for arc in chain:
            if arc.effect:
                self._actions(arc.effect, env, first.source.state)
        self._enter_path(path, 0, resume, env)

    def _active_preorder(self, node: _Node) -> list[_Node]:
        """Active descendants of `node`, parents before children, regions in order."""
        out: list[_Node] = []
        while True:
            if node.kind is _PARALLEL:
                for region in node.children:
                    if region.active:
                        out.append(region)
                        out.extend(self._active_preorder(region))
                return out
            child = node.active_child
            if child is None:
                return out
            out.append(child)
            node = child

    def _exit_below(self, domain: _Node) -> None:
        below = self._active_preorder(domain)
        for node in below:
            if node.has_history:
                self._remember(node)
        for node in reversed(below):
            self._exit(node)

    def _remember(self, node: _Node) -> None:
        for history in node.has_history:
            if history.kind is Kind.SHALLOW_HISTORY:
                if node.active_child is not None:
                    self._shallow[node] = node.active_child
            else:
                self._deep[node] = self._active_preorder(node)

    def _exit(self, node: _Node) -> None:
        state = node.state
        if state.exit:
            self._actions(state.exit, Env(self.variables, None, self.is_active), state)
        node.active = False
        node.epoch += 1
        parent = node.parent
        if parent is not None and parent.active_child is node:
            parent.active_child = None
        if self._pending:
            self._pending.pop(node, None)
        for listener in self.listeners:
            listener.on_exit(state)

    def _enter(self, node: _Node, env: Env) -> None:
        node.active = True
        node.epoch += 1
        parent = node.parent
        if parent is not None and parent.kind is not _PARALLEL:
            parent.active_child = node
        state = node.state
        if state.entry:
            self._actions(state.entry, env, state)
        for arc in node.timed:
            self._seq += 1
            heapq.heappush(
                self._timers,
                (self.clock.now() + arc.transition.after, self._seq, node, node.epoch, arc),
            )
        request = state.configure
        if request is not None:
            deadline = self.clock.now() + request.timeout
            self._pending[node] = (request.tag, deadline)
            self._seq += 1
            heapq.heappush(self._timers, (deadline, self._seq, node, node.epoch, None))
            self._output(Output("configure", state.path, tag=request.tag, timeout=request.timeout))
        elif state.do:
            self._actions(state.do, env, state)
        for listener in self.listeners:
            listener.on_entry(state)
        if node.kind is _FINAL and parent is self._root:
            self.finished = True

    def _enter_path(self, path: tuple[_Node, ...], i: int, resume: _Node | None, env: Env) -> None:
        node = path[i]
        self._enter(node, env)
        if i + 1 < len(path):
            following = path[i + 1]
            if node.kind is _PARALLEL:
                for region in node.children:
                    if region is following:
                        self._enter_path(path, i + 1, resume, env)
                    else:
                        self._enter(region, env)
                        self._enter_children(region, env)
            else:
                self._enter_path(path, i + 1, resume, env)
        elif resume is not None:
            self._resume(node, resume, env)
        else:
            self._enter_children(node, env)

    def _enter_children(self, node: _Node, env: Env) -> None:
        kind = node.kind
        if kind is _PARALLEL:
            for region in node.children:
                self._enter(region, env)
                self._enter_children(region, env)
        elif kind is _COMPOUND:
            self._enter_below(node, node.initial, env)  # type: ignore[arg-type]

    def _enter_below(self, node: _Node, target: _Node, env: Env) -> None:
        """Enter from `node` (already active) down to `target`, through junctions/history."""
        if target.kind is _JUNCTION:
            chain = None
            for arc in target.completion:
                chain = self._enabled(arc, env)
                if chain is not None:
                    break
            if chain is None:  # the validator requires an else branch; stay consistent anyway
                self._error(
                    f"no branch of initial junction {target.state.path} is enabled; "
                    "taking its last branch",
                    env.event,
                )
                chain = (target.completion[-1],)
            for arc in chain:
                if arc.effect:
                    self._actions(arc.effect, env, node.state)
            target = chain[-1].target  # type: ignore[assignment]
        if target.kind in _HISTORY:
            if target.parent is node:
                self._resume(node, target, env)
                return
            target = target.parent  # type: ignore[assignment]
        path = [target]
        parent = target.parent
        while parent is not node and parent is not None:
            path.append(parent)
            parent = parent.parent
        path.reverse()
        self._enter_path(tuple(path), 0, None, env)

    def _resume(self, node: _Node, history: _Node, env: Env) -> None:
        if history.kind is Kind.DEEP_HISTORY:
            remembered = self._deep.get(node)
            if remembered:
                for child in remembered:
                    self._enter(child, env)
                return
        else:
            child = self._shallow.get(node)
            if child is not None:
                self._enter(child, env)
                self._enter_children(child, env)
                return
        default = history.state.default
        if default is not None:
            self._enter_below(node, self._nodes[default.path], env)
        else:
            self._enter_children(node, env)

    # -- actions -----------------------------------------------------------------
    def _value(self, value: Value, env: Env) -> Any:
        return value.expression(env) if value.expression is not None else value.literal

    def _values(self, values: dict[str, Value], env: Env) -> dict[str, Any]:
        return {k: self._value(v, env) for k, v in values.items()}

    def _actions(self, actions: tuple[Action, ...], env: Env, state: State) -> None:
        for action in actions:
            try:
                self._action(action, env, state)
            except Exception as exc:  # an action never crashes the Coordinator
                self._error(f"{action.kind} action at {action.location} failed: {exc}", env.event)

    def _action(self, action: Action, env: Env, state: State) -> None:
        kind = action.kind
        if kind == "set":
            for name, value in action.assignments.items():
                self.variables[name] = self._value(value, env)
        elif kind == "raise":
            self._internal.append(
                Event(action.event, self._values(action.payload, env) or None, "internal")
            )
        elif kind == "send":
            self._output(
                Output(
                    "send",
                    state.path,
                    event=action.event,
                    payload=self._values(action.payload, env),
                )
            )
        elif kind == "configure":
            self._pending_tags[action.tag] = self._pending_tags.get(action.tag, 0) + 1
            self._output(
                Output(
                    "configure", state.path, tag=action.tag, timeout=self.chart.configure_timeout
                )
            )
        elif kind == "write":
            self._output(
                Output("write", state.path, port=action.port, value=self._value(action.value, env))
            )  # type: ignore[arg-type]
        elif kind == "call":
            self._output(
                Output(
                    "call",
                    state.path,
                    operation=action.operation,
                    args=self._values(action.args, env),
                )
            )
        else:
            self._output(Output("log", state.path, message=action.message))

    def _output(self, output: Output) -> None:
        for listener in self.listeners:
            listener.on_output(output)
        if self.on_output is not None:
            try:
                self.on_output(output)
            except Exception as exc:  # the host's handler: its failure is the chart's error event
                self._error(f"output handler failed on {output.kind}: {exc}", None)

    def _error(self, message: str, event: Event | None) -> None:
        for listener in self.listeners:
            listener.on_error(message, event)

    # -- snapshot ----------------------------------------------------------------
    def snapshot(self) -> dict[str, Any]:
        """The full run-time state as JSON-ready data (times relative to now)."""
        now = self.clock.now()
        live = sorted(t for t in self._timers if t[2].active and t[2].epoch == t[3])
        return {
            "chart": self.chart.name,
            "started": self.started,
            "finished": self.finished,
            "active": self.configuration,
            "variables": dict(self.variables),
            "shallow": {n.state.path: c.state.path for n, c in self._shallow.items()},
            "deep": {n.state.path: [c.state.path for c in cs] for n, cs in self._deep.items()},
            "pending": {
                n.state.path: [tag, deadline - now] for n, (tag, deadline) in self._pending.items()
            },
            "pending_tags": dict(self._pending_tags),
            "timers": [
                [deadline - now, node.state.path, arc.transition.order if arc is not None else None]
                for deadline, _, node, _, arc in live
            ],
            "internal": [[e.name, e.payload] for e in self._internal],
            "external": [[e.name, e.payload] for e in self._external],
        }

    def restore(self, snapshot: dict[str, Any]) -> None:
        """Load a snapshot into this fresh (not started) interpreter; no actions run."""
        if self.started:
            raise StatechartRuntimeError("restore() needs a fresh, not started interpreter")
        if snapshot.get("chart") != self.chart.name:
            raise StatechartRuntimeError(
                f"snapshot is of chart {snapshot.get('chart')!r}, not {self.chart.name!r}"
            )
        try:
            self._restore(snapshot)
        except KeyError as exc:
            raise StatechartRuntimeError(f"snapshot names unknown state {exc}") from None

    def _arcs_by_order(self) -> dict[int, _Arc]:
        """Every arc by its transition's document order (built once: a snapshot's timers
        name their transition by it)."""
        arcs = getattr(self, "_arcs", None)
        if arcs is None:
            arcs = self._arcs = {
                a.transition.order: a
                for n in self._nodes.values()
                for a in (*n.timed, *n.completion, *(x for v in n.by_event.values() for x in v))
            }
        return arcs

    def load(self, snapshot: dict[str, Any]) -> None:
        """Replace the whole run-time state with `snapshot`, started or not; no actions
        run. The verifier's way back to a state it explored (`framework.verify`): the
        compiled chart is kept, so going back costs no compilation."""
        for node in self._nodes.values():
            node.active = False
            node.active_child = None
        self._internal.clear()
        self._external.clear()
        self._timers = []
        self._pending = {}
        self._pending_tags = {}
        self._shallow = {}
        self._deep = {}
        self.started = False
        self.restore(snapshot)

    def _restore(self, snap: dict[str, Any]) -> None:
        nodes, now = self._nodes, self.clock.now()
        self.started, self.finished = snap["started"], snap["finished"]
        self.variables = dict(snap["variables"])
        self._root.active = self.started
        for path in snap["active"]:
            node = nodes[path]
            node.active = True
            node.epoch += 1
            if node.parent is not None and node.parent.kind is not _PARALLEL:
                node.parent.active_child = node
        self._shallow = {nodes[p]: nodes[c] for p, c in snap["shallow"].items()}
        self._deep = {nodes[p]: [nodes[c] for c in cs] for p, cs in snap["deep"].items()}
        self._pending = {nodes[p]: (tag, now + rest) for p, (tag, rest) in snap["pending"].items()}
        self._pending_tags = dict(snap["pending_tags"])
        arcs = self._arcs_by_order() if snap["timers"] else {}
        for rest, path, order in snap["timers"]:
            node = nodes[path]
            self._seq += 1
            heapq.heappush(
                self._timers,
                (
                    now + rest,
                    self._seq,
                    node,
                    node.epoch,
                    arcs[order] if order is not None else None,
                ),
            )
        self._internal = deque(Event(n, p, "internal") for n, p in snap["internal"])
        self._external = deque(Event(n, p) for n, p in snap["external"])
