"""Export a chart and one of its properties to Promela, so SPIN can judge the property
with semantics written a second time.

`fw verify` explores a chart with fw's own interpreter. A second checker must not
share that engine, or a bug in it would agree with itself: this module writes the
chart's run-to-completion semantics out again, as Promela code generated from the
*model* (states, transitions, guards and actions), with no call into
`framework.statechart.interpreter`, and writes the property as a monitor of its own.
The chart-independent half, fw's semantics as a small interpreter in Promela, is
`chart.pml` beside this file, readable on its own; this module writes the other
half: the chart as tables, its guards and actions, the property's monitor and the
environment.
SPIN then searches the model (`framework.verify.spin`).

What the two share on purpose is the *question*: the same environment (the events and
payload values of `framework.verify.explore.Environment`), the same time quantum and
the same bound on unanswered requests, so both explore the same abstraction and must
give the same verdict (and the input numbering maps SPIN's trail back to explorer
inputs, so fw's interpreter can confirm SPIN's counterexample). What is written twice is the *answer*: which transitions are enabled and fire
(outer-first priority, regions in order, junctions, `else`), exit and entry order,
completion of configure states and compound/parallel states, time events and
configuration timeouts in deadline order, the bookkeeping of awaited configurations,
expressions (including an event field that is missing, which makes a guard false),
and the four property patterns.

One step of the model is one step of the explorer, one `atomic` sequence: an input
chosen by the environment, then the chart until it is quiet, in stages (event,
fire, completion, timers) of one `d_step` each, since SPIN bounds a `d_step` to 2048
jumps; then the property is judged (`assert`) and the step's scratch cleared, so equal
chart states are equal model states. The export covers what fw's charts use; `raise`, history states
and arithmetic other than + - * % are refused with a located error
(`PromelaUnsupported`), not approximated.
"""

from __future__ import annotations

import ast
from collections.abc import Iterable
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Any

from framework.errors import FwError
from framework.statechart.model import (
    CONFIG_DONE,
    CONFIG_FAILED,
    Action,
    Kind,
    State,
    Statechart,
    Transition,
)
from framework.verify.explore import DONE, FAILED, SEND, TICK, Explorer, Input
from framework.verify.properties import Matcher, Property

AFTER = "after"
MARKER = "/* == the chart's own variables and code are generated here == */\n"
SEMANTICS = (Path(__file__).parent / "chart.pml").read_text()
"""The chart-independent half of every model: fw's semantics in Promela."""
SYMBOL_BASE = 1000
"""String values are numbered from here, away from the small integers charts count."""


class PromelaUnsupported(FwError):
    """The chart uses something the Promela export does not cover."""


@dataclass
class Inputs:
    """The environment both checkers share: each event with its payloads, the events a
    property watches (sent even when the chart ignores them), the time quantum and the
    bound on unanswered requests."""

    events: dict[str, list[dict[str, Any]]]
    observed: frozenset[str]
    quantum: float | None
    unanswered: int

    @classmethod
    def of(cls, explorer: Explorer) -> Inputs:
        """The question `explorer` answers, for SPIN to answer too."""
        return cls(
            explorer.environment.events, explorer.observed, explorer.quantum, explorer.unanswered
        )


@dataclass
class Model:
    """A generated Promela model and how to read its replayed trail."""

    text: str
    inputs: list[Input | None] = field(default_factory=list)
    """What each input number of the model stands for (0: the start)."""


def export(chart: Statechart, prop: Property, inputs: Inputs) -> Model:
    """The Promela model of `chart` under `inputs`, asserting `prop` after every step."""
    return _Writer(chart, prop, inputs).model()


# -- expressions -----------------------------------------------------------------------


class _Expr:
    """Compiles a chart expression to a Promela pair (defined, value): Python raises on
    a missing event field, and fw treats a guard that raised as false."""

    def __init__(self, w: _Writer, source: str, chart_context: bool):
        self.w = w
        self.source = source
        self.chart_context = chart_context

    def fail(self, what: str) -> PromelaUnsupported:
        return PromelaUnsupported(f"Promela export: {what} in expression {self.source!r}")

    def compile(self) -> tuple[str, str]:
        tree = ast.parse(self.source.strip(), mode="eval").body
        d, v = self.node(tree)
        return _simplify(d), v

    def node(self, n: ast.AST) -> tuple[str, str]:
        if isinstance(n, ast.Constant):
            return "1", self.w.encode(n.value)
        if isinstance(n, ast.Name):
            literal = {"True": 1, "true": 1, "False": 0, "false": 0}
            if n.id in literal:
                return "1", str(literal[n.id])
            if n.id in ("None", "null"):
                return "1", self.w.encode(None)
            if n.id not in self.w.chart.variables:
                raise self.fail(f"unknown variable {n.id!r}")
            return "1", f"v_{n.id}"
        if isinstance(n, ast.Attribute):
            if not (isinstance(n.value, ast.Name) and n.value.id == "event") or n.attr == "name":
                raise self.fail("only event.FIELD may be read from the event")
            self.w.fields.add(n.attr)
            defined = f"h_{n.attr}" if not self.chart_context else f"(!noev && h_{n.attr})"
            return defined, f"f_{n.attr}"
        if isinstance(n, ast.BoolOp):
            parts = [self.node(x) for x in n.values]
            d, v = parts[0]
            for d2, v2 in parts[1:]:
                if isinstance(n.op, ast.And):
                    d = f"({d} && (!({v}) || {d2}))"
                    v = f"({v} && {v2})"
                else:
                    d = f"({d} && (({v}) || {d2}))"
                    v = f"({v} || {v2})"
            return d, v
        if isinstance(n, ast.UnaryOp):
            d, v = self.node(n.operand)
            if isinstance(n.op, ast.Not):
                return d, f"(!{v})"
            if isinstance(n.op, ast.USub):
                return d, f"(-{v})"
            raise self.fail("an unsupported unary operator")
        if isinstance(n, ast.BinOp):
            ops = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Mod: "%"}
            op = ops.get(type(n.op))
            if op is None:
                raise self.fail("an operator other than + - * %")
            (d1, v1), (d2, v2) = self.node(n.left), self.node(n.right)
            return f"({d1} && {d2})", f"({v1} {op} {v2})"
        if isinstance(n, ast.Compare):
            return self.compare(n)
        if isinstance(n, ast.IfExp):
            (dt, vt), (db, vb), (do, vo) = (self.node(x) for x in (n.test, n.body, n.orelse))
            return f"({dt} && ({vt} -> {db} : {do}))", f"({vt} -> {vb} : {vo})"
        if isinstance(n, ast.Call):
            ok = (
                isinstance(n.func, ast.Name)
                and n.func.id == "active"
                and len(n.args) == 1
                and isinstance(n.args[0], ast.Constant)
            )
            if not ok:
                raise self.fail("a call other than active('State')")
            return "1", f"act[{self.w.node_id(self.w.chart.state(n.args[0].value))}]"
        raise self.fail(f"'{type(n).__name__}'")

    def compare(self, n: ast.Compare) -> tuple[str, str]:
        symbols = {ast.Eq: "==", ast.NotEq: "!=", ast.Lt: "<", ast.LtE: "<=", ast.Gt: ">"}
        symbols[ast.GtE] = ">="
        operands = [n.left, *n.comparators]
        ds, vs = [], []
        for left, op, right in zip(operands, n.ops, operands[1:], strict=False):
            dl, vl = self.node(left)
            if isinstance(op, ast.In | ast.NotIn):
                if not isinstance(right, ast.Tuple | ast.List):
                    raise self.fail("'in' other than in a literal list")
                items = [self.node(e) for e in right.elts]
                any_of = " || ".join(f"{vl} == {vi}" for _, vi in items) or "0"
                ds.append(" && ".join([dl, *(di for di, _ in items)]))
                vs.append(f"({any_of})" if isinstance(op, ast.In) else f"!({any_of})")
                continue
            symbol = symbols.get(type(op))
            if symbol is None:
                raise self.fail("an unsupported comparison")
            dr, vr = self.node(right)
            if symbol not in ("==", "!=") and _is_string(left, right):
                raise self.fail("an ordering of strings")
            ds.append(f"{dl} && {dr}")
            vs.append(f"({vl} {symbol} {vr})")
        return f"({' && '.join(ds)})", f"({' && '.join(vs)})"


def _is_string(*nodes: ast.AST) -> bool:
    return any(isinstance(n, ast.Constant) and isinstance(n.value, str) for n in nodes)


def _simplify(d: str) -> str:
    previous = None
    while previous != d:
        previous = d
        for a, b in (("(1 && 1)", "1"), ("1 && ", ""), (" && 1)", ")"), ("(1)", "1")):
            d = d.replace(a, b)
    return d


# -- the writer ------------------------------------------------------------------------

KIND = {
    Kind.ATOMIC: 0,
    Kind.COMPOUND: 1,
    Kind.PARALLEL: 2,
    Kind.FINAL: 3,
    Kind.JUNCTION: 4,
}
COMPOUND, PARALLEL, FINAL, JUNCTION = 1, 2, 3, 4
MAX_CHAIN = 8
"""Transitions in one chain through junctions (fw's interpreter allows 64)."""


class _Writer:
    """Generates the model: the chart as tables (states in document preorder, their
    transitions, timers, configure requests) and a small interpreter in Promela that
    walks them; only guards, actions and the property's monitor are generated per
    chart, each behind one dispatch. Table-driven on purpose: SPIN allows a `d_step`
    at most 2048 jumps, and a chart's run-to-completion step must be one `d_step`."""

    def __init__(self, chart: Statechart, prop: Property, inputs: Inputs):
        self.chart, self.prop, self.inputs = chart, prop, inputs
        self.nodes: list[State] = []
        self._preorder(chart.root)
        for s in self.nodes:
            if s.kind not in KIND:
                raise PromelaUnsupported(f"{s.location}: Promela export: {s.kind.value} states")
        self.ids = {s.path: i for i, s in enumerate(self.nodes)}
        self.end = {i: self._last(s) for i, s in enumerate(self.nodes)}
        self.trans: list[Transition] = [t for s in self.nodes for t in s.transitions]
        self.tid = {id(t): k for k, t in enumerate(self.trans)}
        self.slots: list[tuple[State, Transition | None]] = []
        for s in self.nodes:
            self.slots += [(s, t) for t in s.transitions if t.after is not None]
            if s.configure is not None:
                self.slots.append((s, None))
        self.tags = sorted(
            {s.configure.tag for s in self.nodes if s.configure} | self._action_tags()
        )
        names = {e for t in self.trans for e in t.events} | set(inputs.events)
        self.event_bits = {e: i for i, e in enumerate(sorted(names | {CONFIG_DONE, CONFIG_FAILED}))}
        if len(self.event_bits) > 31:
            raise PromelaUnsupported("Promela export: more than 31 events")
        self.symbols: dict[str, int] = {}
        self.fields: set[str] = {"tag"}
        self.guards: list[str] = []
        self.lists: list[tuple[Action, ...]] = []
        self._check_junctions()

    def _preorder(self, s: State) -> None:
        self.nodes.append(s)
        for c in s.children:
            self._preorder(c)

    def _last(self, s: State) -> int:
        while s.children:
            s = s.children[-1]
        return self.nodes.index(s)

    def _action_tags(self) -> set[str]:
        return {
            a.tag
            for s in self.nodes
            for a in (*s.entry, *s.exit, *s.do, *(x for t in s.transitions for x in t.effect))
            if a.kind == "configure"
        }

    def concurrent(self) -> int:
        """How many transitions one step can choose at most: one per region that can be
        searched on its own, plus one above them all."""
        return 1 + sum(len(s.children) for s in self.nodes if s.kind is Kind.PARALLEL)

    def _check_junctions(self) -> None:
        for s in self.nodes:
            if (
                s.kind is Kind.COMPOUND
                and s.initial is not None
                and s.initial.kind is Kind.JUNCTION
            ):
                for b in s.initial.transitions:
                    if b.target is not None and b.target.kind is Kind.JUNCTION:
                        raise PromelaUnsupported(
                            f"{b.location}: Promela export: an initial junction into a junction"
                        )

    # helpers
    def node_id(self, state: State) -> int:
        return self.ids[state.path]

    def encode(self, value: Any) -> str:
        if isinstance(value, bool):
            return str(int(value))
        if isinstance(value, int):
            return str(value)
        if isinstance(value, float) and value.is_integer():
            return str(int(value))
        if isinstance(value, str) or value is None:
            key = repr(value)
            if key not in self.symbols:
                self.symbols[key] = SYMBOL_BASE + len(self.symbols)
            return str(self.symbols[key])
        raise PromelaUnsupported(f"Promela export: the value {value!r} (only integers and strings)")

    def expr(self, source: str, chart_context: bool = True) -> tuple[str, str]:
        return _Expr(self, source, chart_context).compile()

    def guard_id(self, t: Transition) -> int:
        if t.guard is None:
            return 0
        d, v = self.expr(t.guard.source)
        self.guards.append(f"({d} && {v})")
        return len(self.guards)

    def list_id(self, actions: tuple[Action, ...]) -> int:
        """A number for an action list that changes the chart's state (0: none does)."""
        for a in actions:
            if a.kind == "raise":
                raise PromelaUnsupported(f"{a.location}: Promela export: 'raise' actions")
        if not any(a.kind in ("set", "configure") for a in actions):
            return 0
        self.lists.append(actions)
        return len(self.lists)

    def quanta(self, k: int) -> int:
        state, t = self.slots[k]
        span = t.after if t is not None else state.configure.timeout  # type: ignore[union-attr]
        q = self.inputs.quantum
        assert q is not None and span is not None
        n = Fraction(str(round(span, 6))) / Fraction(str(round(q, 6)))
        if n.denominator != 1:
            raise PromelaUnsupported(f"{state.location}: a delay that is no multiple of {q:g} s")
        return int(n)

    # -- actions and the monitor -----------------------------------------------------
    def actions(self, actions: Iterable[Action], out: list[str]) -> None:
        for a in actions:
            if a.kind == "set":
                self.assignments(list(a.assignments.items()), out)
            elif a.kind == "configure":
                out.append(f"ptag[{self.tags.index(a.tag)}]++;")
                out.append(f"rq = {self.tags.index(a.tag)}; request();")
            # send, call, write, log: outputs that change no state of the chart

    def assignments(self, items: list[tuple[str, Any]], out: list[str]) -> None:
        """A `set` stops at its first assignment that fails (as the interpreter does)."""
        if not items:
            return
        name, value = items[0]
        rest: list[str] = []
        self.assignments(items[1:], rest)
        if value.expression is None:
            out.append(f"v_{name} = {self.encode(value.literal)};")
            out.extend(rest)
            return
        d, v = self.expr(value.expression.source)
        out.append(f"if :: {d} -> v_{name} = {v}; {' '.join(rest) or 'skip'} :: else -> skip fi;")

    def holds(self, m: Matcher) -> str:
        parts = []
        if m.states:
            parts.append("(" + " || ".join(f"act[{self.ids[p]}]" for p in m.states) + ")")
        if m.when is not None:
            d, v = self.expr(m.when.source, chart_context=False)
            parts.append(f"({d} && {v})")
        return " && ".join(parts) or "1"

    def matches(self, m: Matcher | None, kind: str, name: str) -> bool:
        return m is not None and m.kind == kind and name in m.names

    def observe(self, kind: str, name: str) -> list[str]:
        """The monitor's reaction to one observation (`_Observer._observe`'s rules)."""
        p, out = self.prop, []
        if p.pattern == "never":
            if self.matches(p.first, kind, name):
                out.append(f"if :: {self.holds(p.first)} -> viol = 1 :: else -> skip fi;")
        elif p.pattern == "responds":
            assert p.second is not None
            if self.matches(p.first, kind, name):
                out.append(
                    f"if :: mon == -1 && !answered && {self.holds(p.first)} -> mon = {p.within} "
                    ":: else -> skip fi;"
                )
            if self.matches(p.second, kind, name):
                out.append(
                    f"if :: {self.holds(p.second)} -> mon = -1; answered = 1 :: else -> skip fi;"
                )
        elif p.pattern == "precedes":
            assert p.second is not None and p.third is not None
            if self.matches(p.second, kind, name):
                out.append(
                    f"if :: mon == 1 && {self.holds(p.second)} -> viol = 1 :: else -> skip fi;"
                )
            if self.matches(p.third, kind, name):
                out.append(f"if :: {self.holds(p.third)} -> mon = 0 :: else -> skip fi;")
            if self.matches(p.first, kind, name):
                out.append(f"if :: {self.holds(p.first)} -> mon = 1 :: else -> skip fi;")
        return out

    def dispatch(self, kind: str, variable: str, names: Iterable[tuple[str, str]]) -> list[str]:
        """`if :: variable == key -> monitor code ... fi` over the names observed."""
        options = []
        for key, name in names:
            code = self.observe(kind, name)
            if code:
                options.append(f":: {variable} == {key} -> {' '.join(code)}")
        return ["if", *options, ":: else -> skip fi;"] if options else ["skip;"]

    def judge(self) -> list[str]:
        """What the monitor checks once a step is over (`_Observer.end`)."""
        p = self.prop
        if p.pattern in ("never", "always") and not p.first.kind:
            cond = self.holds(p.first)
            bad = cond if p.pattern == "never" else f"!({cond})"
            return [f"if :: {bad} -> viol = 1 :: else -> skip fi;"]
        if p.pattern == "responds":
            assert p.second is not None
            settle = f":: {self.holds(p.second)} -> mon = -1 " if not p.second.kind else ""
            return [
                "if :: mon != -1 ->",
                f"    if {settle}:: else ->",
                "      if :: mon == 0 -> mon = -1; viol = 1 :: else -> mon-- fi",
                "    fi",
                ":: else -> skip fi;",
            ]
        return []

    # -- events ----------------------------------------------------------------------
    def set_event(self, name: str, payload: dict[str, Any]) -> list[str]:
        bit = self.event_bits.get(name)
        out = [
            f"ev = {self.encode('event:' + name)}; evbit = {1 << bit if bit is not None else 0};"
        ]
        for f in sorted(self.fields):
            if f in payload:
                out.append(f"h_{f} = 1; f_{f} = {self.encode(payload[f])};")
            else:
                out.append(f"h_{f} = 0; f_{f} = 0;")
        return out

    def _input_events(self) -> list[tuple[str, dict[str, Any]]]:
        return [(name, p) for name, payloads in self.inputs.events.items() for p in payloads]

    def _accepts(self, event: str) -> str:
        """`Interpreter.accepts`: the root or an active state has a transition on it."""
        holders = [s for s in self.nodes if any(event in t.events for t in s.transitions)]
        if any(s is self.chart.root for s in holders):
            return "1"
        return " || ".join(f"act[{self.node_id(s)}]" for s in holders) or "0"

    # -- the model -------------------------------------------------------------------
    def model(self) -> Model:
        self._generate()  # a first pass finds every event field and symbol
        self.guards, self.lists = [], []
        text = self._generate()
        inputs: list[Input | None] = [None]
        inputs += [Input(SEND, n, tuple(sorted(p.items()))) for n, p in self._input_events()]
        inputs += [Input(DONE), Input(FAILED), Input(TICK)]
        return Model(text, inputs)

    def _generate(self) -> str:
        chart, prop = self.chart, self.prop
        n_nodes, n_trans, n_slots = (
            len(self.nodes),
            max(1, len(self.trans)),
            max(1, len(self.slots)),
        )
        n_tags = max(1, len(self.tags))
        tables: list[str] = []
        for i, s in enumerate(self.nodes):
            first = self.tid[id(s.transitions[0])] if s.transitions else 0
            tables.append(
                f"parent_[{i}] = {self.node_id(s.parent) if s.parent else -1}; kind_[{i}] = {KIND[s.kind]}; "
                f"end_[{i}] = {self.end[i]}; tfirst_[{i}] = {first}; tlast_[{i}] = {first + len(s.transitions)}; "
                f"init_[{i}] = {self.node_id(s.initial) if s.initial is not None else -1}; "
                f"cfg_[{i}] = {self.tags.index(s.configure.tag) if s.configure else -1}; "
                f"entry_[{i}] = {self.list_id(s.entry)}; exit_[{i}] = {self.list_id(s.exit)}; "
                f"do_[{i}] = {self.list_id(s.do)};"
            )
        for k, t in enumerate(self.trans):
            mask = sum(1 << self.event_bits[e] for e in t.events)
            ttype = 0 if t.events else (2 if t.after is not None else 1)
            tables.append(
                f"tsrc_[{k}] = {self.node_id(t.source)}; ttgt_[{k}] = {self.node_id(t.target) if t.target else -1}; "
                f"tev_[{k}] = {mask}; ttype_[{k}] = {ttype}; telse_[{k}] = {int(t.is_else)}; "
                f"tguard_[{k}] = {self.guard_id(t)}; teff_[{k}] = {self.list_id(t.effect)};"
            )
        for k, (s, t) in enumerate(self.slots):
            tables.append(
                f"snode_[{k}] = {self.node_id(s)}; strans_[{k}] = {self.tid[id(t)] if t else -1}; "
                f"slen_[{k}] = {self.quanta(k)};"
            )
        for k, tag in enumerate(self.tags):
            tables.append(f"tagsym_[{k}] = {self.encode(tag)};")

        done_bit = 1 << self.event_bits[CONFIG_DONE]
        failed_bit = 1 << self.event_bits[CONFIG_FAILED]
        semantics, chart_code = SEMANTICS.split(MARKER)
        lines: list[str] = []
        emit = lines.append
        emit(f"/* fw verify --spin: chart {chart.name}, property {prop.name} (generated) */")
        for name, value in (
            ("N", n_nodes),
            ("T", n_trans),
            ("S", n_slots),
            ("TAGS", n_tags),
            ("QMAX", self.inputs.unanswered + 8),
            ("K", self.inputs.unanswered),
            ("MAXC", MAX_CHAIN),
            ("CH", self.concurrent()),
            ("DONE_BIT", done_bit),
            ("FAILED_BIT", failed_bit),
        ):
            emit(f"#define {name} {value}")
        lines.append(semantics.rstrip("\n"))
        emit(MARKER.strip())
        for name, spec in chart.variables.items():
            emit(f"int v_{name} = {self.encode(spec.initial)};")
        for f in sorted(self.fields):
            emit(f"bit h_{f}; int f_{f};")

        def inline(name: str, body: list[str]) -> None:
            emit(f"inline {name}() {{")
            lines.extend("  " + b for b in (body or ["skip;"]))
            emit("}")

        # the property's monitor, by observation
        tag_keys = [(str(k), tag) for k, tag in enumerate(self.tags)]
        inline("observe_request", self.dispatch("request", "rq", tag_keys))
        inline(
            "request",
            [
                "if :: nout < QMAX -> outq[nout] = rq; nout++ :: else -> overflow = 1 fi;",
                "observe_request();",
            ],
        )
        states = [(str(i), s.path) for i, s in enumerate(self.nodes)]
        inline("observe_enter", self.dispatch("enter", "e_n", states))
        inline("observe_exit", self.dispatch("exit", "x_n", states))
        events = [(self.encode("event:" + e), e) for e in sorted(self.event_bits)]
        inline("observe_event", self.dispatch("event", "ev", events))
        inline("judge", self.judge())
        # guards and action lists, each behind one dispatch (numbered in the tables)
        guard_options = [f":: g == {i} -> gok = {g}" for i, g in enumerate(self.guards, start=1)]
        emit("inline eval_guard(g) {")
        emit("  if :: g == 0 -> gok = 1")
        lines.extend("  " + o for o in guard_options)
        emit("  :: else -> gok = 0 fi")
        emit("}")
        emit("inline run_actions(a) {")
        emit("  if")
        for i, acts in enumerate(self.lists, start=1):
            body: list[str] = []
            self.actions(acts, body)
            emit(f"  :: a == {i} -> {' '.join(body)}")
        emit("  :: else -> skip fi")
        emit("}")
        # the events the chart makes itself: a configuration timeout, a time event
        timeouts = []
        for k, (s, t) in enumerate(self.slots):
            if t is None:
                assert s.configure is not None
                payload = {
                    "tag": s.configure.tag,
                    "state": s.path,
                    "reason": f"no acknowledgement within {s.configure.timeout:g} s",
                }
                timeouts.append(
                    f":: best == {k} -> {' '.join(self.set_event(CONFIG_FAILED, payload))}"
                )
        inline("timeout_event", ["if", *timeouts, ":: else -> skip fi"])
        inline("after_event", self.set_event(AFTER, {}))
        inline("clear_fields", [f"h_{f} = 0; f_{f} = 0;" for f in sorted(self.fields)] or ["skip"])
        lines.append(chart_code.strip("\n"))
        _, failed_payload = Input(FAILED).event("")  # the environment's own answer
        failed_payload = {k: v for k, v in (failed_payload or {}).items() if k != "tag"}
        inputs = self._input_events()
        done = len(inputs) + 1
        start_mon = 0 if prop.pattern == "precedes" else -1
        emit("active proctype chart() {")
        emit("end:")
        emit("  do :: !beyond ->")
        emit("    if")
        emit("    :: !started -> inp = 0")
        for n, (name, _) in enumerate(inputs, start=1):
            guard = "1" if name in self.inputs.observed else self._accepts(name)
            emit(f"    :: started && ({guard}) -> inp = {n}")
        emit(f"    :: started && nout > 0 -> inp = {done}")
        emit(f"    :: started && nout > 0 -> inp = {done + 1}")
        if self.inputs.quantum is not None and self.slots:
            timers = " || ".join(f"tm_on[{k}]" for k in range(len(self.slots)))
            emit(f"    :: started && ({timers}) -> inp = {done + 2}")
        emit("    fi;")
        emit("    atomic {")
        emit("     d_step {")
        emit('      printf("STEP %d\\n", inp);')
        emit("      /* what the environment does: the event it sends, or the time it lets pass */")
        emit("      stage = S_EVENT; then = S_DONE;")
        emit("      if")
        emit("      :: inp == 0 ->")
        lines.extend("           " + t for t in tables)
        emit(f"           started = 1; mon = {start_mon}; act[0] = 1; noev = 1;")
        emit("           e_n = 0; dflt[0] = 1; open_below(); dom = 0; enter_sweep(); dflt[0] = 0;")
        emit("           stage = S_COMPLETE")
        for n, (name, payload) in enumerate(inputs, start=1):
            emit(f"      :: inp == {n} -> {' '.join(self.set_event(name, payload))}")
        for k, event in ((done, CONFIG_DONE), (done + 1, CONFIG_FAILED)):
            answer = failed_payload if event == CONFIG_FAILED else {}
            emit(f"      :: inp == {k} -> {' '.join(self.set_event(event, answer))}")
            emit("           h_tag = 1; f_tag = tagsym_[outq[0]];")
            emit(
                "           r_i = 0; do :: r_i + 1 < nout -> outq[r_i] = outq[r_i + 1]; r_i++ :: else -> break od;"
            )
            emit("           nout--; outq[nout] = 0; r_i = 0")
        emit(f"      :: inp == {done + 2} ->")
        emit(
            "           r_i = 0; do :: r_i < S -> if :: tm_on[r_i] && tm_rem[r_i] > 0 -> tm_rem[r_i]-- :: else -> skip fi; r_i++ :: else -> break od;"
        )
        emit("           r_i = 0; stage = S_TIMER")
        emit("      :: else -> skip")
        emit("      fi;")
        emit("     }")
        emit("      run_chart();")
        emit("      d_step { end_step() }")
        emit("    }")
        emit("  od")
        emit("}")
        return "\n".join(lines) + "\n"
