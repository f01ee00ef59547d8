"""Export a chart and one of its properties to Promela, so SPIN can judge the property
with semantics written a second time.

`fw verify` explores a chart with fw's own interpreter. A second checker must not
share that engine, or a bug in it would agree with itself: this module writes the
chart's run-to-completion semantics out again, as Promela code generated from the
*model* (states, transitions, guards and actions), with no call into
`framework.statechart.interpreter`, and writes the property as a monitor of its own.
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
from framework.verify.explore import DONE, FAILED, SEND, TICK, Input
from framework.verify.properties import Matcher, Property

AFTER = "after"
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
        self.lists: list[tuple[tuple[Action, ...], bool]] = []
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

    def list_id(self, actions: tuple[Action, ...], exit_context: bool = False) -> int:
        """A number for an action list that changes the chart's state (0: none does)."""
        for a in actions:
            if a.kind == "raise":
                raise PromelaUnsupported(f"{a.location}: Promela export: 'raise' actions")
        if not any(a.kind in ("set", "configure") for a in actions):
            return 0
        self.lists.append((actions, exit_context))
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
                f"entry_[{i}] = {self.list_id(s.entry)}; exit_[{i}] = {self.list_id(s.exit, True)}; "
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

        lines: list[str] = []
        emit = lines.append
        emit(f"/* fw verify --spin: chart {chart.name}, property {prop.name} (generated) */")
        emit(f"#define N {n_nodes}")
        emit(f"#define T {n_trans}")
        emit(f"#define S {n_slots}")
        emit(f"#define TAGS {n_tags}")
        emit(f"#define QMAX {self.inputs.unanswered + 8}")
        emit(f"#define K {self.inputs.unanswered}")
        emit(f"#define MAXC {MAX_CHAIN}")
        emit(f"#define CH {self.concurrent()}")
        emit(f"#define COMPOUND {COMPOUND}")
        emit(f"#define PARALLEL {PARALLEL}")
        emit(f"#define FINAL {FINAL}")
        emit(f"#define JUNCTION {JUNCTION}")
        emit(
            "#define S_EVENT 1\n#define S_FIRE 2\n#define S_COMPLETE 3\n#define S_TIMER 4\n#define S_DONE 5"
        )
        emit("/* the chart's tables: constant, so hidden from the state vector */")
        emit("hidden short parent_[N]; hidden byte kind_[N]; hidden short end_[N];")
        emit(
            "hidden short tfirst_[N]; hidden short tlast_[N]; hidden short init_[N]; hidden short cfg_[N];"
        )
        emit("hidden short entry_[N]; hidden short exit_[N]; hidden short do_[N];")
        emit(
            "hidden short tsrc_[T]; hidden short ttgt_[T]; hidden int tev_[T]; hidden byte ttype_[T];"
        )
        emit("hidden byte telse_[T]; hidden short tguard_[T]; hidden short teff_[T];")
        emit(
            "hidden short snode_[S]; hidden short strans_[S]; hidden short slen_[S]; hidden int tagsym_[TAGS];"
        )
        emit("/* the chart's state */")
        emit("bit act[N]; bit pend[N]; bit tm_on[S]; short tm_rem[S]; short tm_seq[S]; short seqc;")
        emit(
            "byte ptag[TAGS]; byte outq[QMAX]; byte nout; bit overflow; bit finished; bit beyond; short mon;"
        )
        for name, spec in chart.variables.items():
            emit(f"int v_{name} = {self.encode(spec.initial)};")
        emit("/* one step's scratch: cleared at the end of every step */")
        emit("bit exited[N]; bit want[N]; bit dflt[N]; bit cmp[N]; bit blk[N]; short rank[S];")
        emit("short chn[CH * MAXC]; byte chl[CH]; byte nch; short tmpc[MAXC]; byte tmplen;")
        emit("int ev; int evbit; bit noev; bit noev_x; bit viol; bit answered; bit gok; bit found;")
        emit("byte stage; byte then; bit started;")
        emit(
            "short inp; short rq; short tg; short src; short tgt; short dom; short d_; short lc; short best; short bseq;"
        )
        emit(
            "short s_n; short s_t; short j_node; short j_b; short j_pick; short fb; short f_i; short f_m; short f_last;"
        )
        emit(
            "short x_n; short x_k; short e_n; short e_k; short e_m; short i_tg; short i_b; short i_pick; short r_i; short r_j; short r_k;"
        )
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
        # guards and action lists, each behind one dispatch (compiled above via tables)
        guard_options = [f":: g == {i} -> gok = {g}" for i, g in enumerate(self.guards, start=1)]
        emit("inline eval_guard(g) {")
        emit("  if :: g == 0 -> gok = 1")
        lines.extend("  " + o for o in guard_options)
        emit("  :: else -> gok = 0 fi")
        emit("}")
        emit("inline run_actions(a) {")
        emit("  if")
        for i, (acts, _) in enumerate(self.lists, start=1):
            body: list[str] = []
            self.actions(acts, body)
            emit(f"  :: a == {i} -> {' '.join(body)}")
        emit("  :: else -> skip fi")
        emit("}")
        inline(
            "try_enable",
            [
                "/* t in s_t: its guard, then through junctions: branches in order, `else` as",
                "   the fallback; tmplen 0: not enabled */",
                "eval_guard(tguard_[s_t]);",
                "if :: gok ->",
                "  tmplen = 1; tmpc[0] = s_t; j_node = ttgt_[s_t];",
                "  do :: j_node != -1 && kind_[j_node] == JUNCTION && tmplen > 0 ->",
                "       fb = -1; j_pick = -1; j_b = tfirst_[j_node];",
                "       do :: j_b < tlast_[j_node] ->",
                "            if :: telse_[j_b] -> if :: fb == -1 -> fb = j_b :: else -> skip fi",
                "               :: else -> eval_guard(tguard_[j_b]); if :: gok -> j_pick = j_b; break :: else -> skip fi",
                "            fi; j_b++",
                "       :: else -> break od;",
                "       if :: j_pick == -1 -> j_pick = fb :: else -> skip fi;",
                "       if :: j_pick == -1 || tmplen >= MAXC -> tmplen = 0",
                "          :: else -> tmpc[tmplen] = j_pick; tmplen++; j_node = ttgt_[j_pick] fi",
                "  :: else -> break od",
                ":: else -> tmplen = 0 fi",
            ],
        )
        inline(
            "push_chain",
            [
                "chl[nch] = tmplen; f_m = 0;",
                "do :: f_m < tmplen -> chn[nch * MAXC + f_m] = tmpc[f_m]; f_m++ :: else -> break od;",
                "nch++; f_m = 0",
            ],
        )
        inline(
            "select_event",
            [
                "/* outer-first: a state's own transitions (priority, document order), else its",
                "   active children's; regions of a parallel state each in document order */",
                "nch = 0; s_n = 0;",
                "do :: s_n < N ->",
                "     if :: act[s_n] && (s_n == 0 || !blk[parent_[s_n]]) ->",
                "          found = 0; s_t = tfirst_[s_n];",
                "          do :: s_t < tlast_[s_n] && !found ->",
                "               if :: ttype_[s_t] == 0 && (tev_[s_t] & evbit) != 0 ->",
                "                    try_enable(); if :: tmplen > 0 -> found = 1; push_chain() :: else -> skip fi",
                "               :: else -> skip fi; s_t++",
                "          :: else -> break od;",
                "          blk[s_n] = found",
                "     :: else -> blk[s_n] = 1 fi; s_n++",
                ":: else -> break od;",
                "s_n = 0; do :: s_n < N -> blk[s_n] = 0; s_n++ :: else -> break od; s_n = 0; s_t = 0",
            ],
        )
        inline(
            "completeness",
            [
                "/* complete: no awaited configuration, and a final child (compound) or",
                "   every region complete (parallel); children first, in reverse preorder */",
                "s_n = N - 1;",
                "do :: s_n >= 0 -> cmp[s_n] = (kind_[s_n] != COMPOUND); s_n-- :: else -> break od;",
                "s_n = N - 1;",
                "do :: s_n >= 0 ->",
                "     cmp[s_n] = cmp[s_n] && !pend[s_n];",
                "     if :: s_n > 0 && kind_[parent_[s_n]] == PARALLEL && kind_[s_n] != JUNCTION && !cmp[s_n] -> cmp[parent_[s_n]] = 0",
                "        :: s_n > 0 && kind_[parent_[s_n]] == COMPOUND && kind_[s_n] == FINAL && act[s_n] -> cmp[parent_[s_n]] = 1",
                "        :: else -> skip fi;",
                "     s_n--",
                ":: else -> break od; s_n = 0",
            ],
        )
        inline(
            "select_completion",
            [
                "completeness();",
                "nch = 0; s_n = 0;",
                "do :: s_n < N ->",
                "     if :: act[s_n] && (s_n == 0 || !blk[parent_[s_n]]) ->",
                "          found = 0; s_t = tfirst_[s_n];",
                "          do :: s_t < tlast_[s_n] && !found && cmp[s_n] ->",
                "               if :: ttype_[s_t] == 1 ->",
                "                    try_enable(); if :: tmplen > 0 -> found = 1; push_chain() :: else -> skip fi",
                "               :: else -> skip fi; s_t++",
                "          :: else -> break od;",
                "          blk[s_n] = found",
                "     :: else -> blk[s_n] = 1 fi; s_n++",
                ":: else -> break od;",
                "s_n = 0; do :: s_n < N -> blk[s_n] = 0; cmp[s_n] = 0; s_n++ :: else -> break od; s_n = 0; s_t = 0",
            ],
        )
        inline(
            "exit_one",
            [
                "if :: exit_[x_n] != 0 -> noev_x = noev; noev = 1; run_actions(exit_[x_n]); noev = noev_x :: else -> skip fi;",
                "act[x_n] = 0; exited[x_n] = 1; pend[x_n] = 0;",
                "x_k = 0; do :: x_k < S -> if :: snode_[x_k] == x_n -> tm_on[x_k] = 0; tm_rem[x_k] = 0; tm_seq[x_k] = 0 :: else -> skip fi; x_k++ :: else -> break od;",
                "observe_exit()",
            ],
        )
        inline(
            "exit_below",
            [
                "/* every active state below dom, innermost first (reverse document preorder) */",
                "x_n = end_[dom]; do :: x_n > dom -> if :: act[x_n] -> exit_one() :: else -> skip fi; x_n-- :: else -> break od; x_n = 0",
            ],
        )
        inline(
            "enter_one",
            [
                "act[e_n] = 1;",
                "run_actions(entry_[e_n]);",
                "e_k = 0; do :: e_k < S -> if :: snode_[e_k] == e_n && strans_[e_k] != -1 -> tm_on[e_k] = 1; tm_rem[e_k] = slen_[e_k]; seqc++; tm_seq[e_k] = seqc :: else -> skip fi; e_k++ :: else -> break od;",
                "if :: cfg_[e_n] != -1 ->",
                "     pend[e_n] = 1;",
                "     e_k = 0; do :: e_k < S -> if :: snode_[e_k] == e_n && strans_[e_k] == -1 -> tm_on[e_k] = 1; tm_rem[e_k] = slen_[e_k]; seqc++; tm_seq[e_k] = seqc :: else -> skip fi; e_k++ :: else -> break od;",
                "     rq = cfg_[e_n]; request()",
                ":: else -> run_actions(do_[e_n]) fi;",
                "observe_enter();",
                "if :: kind_[e_n] == FINAL && parent_[e_n] == 0 -> finished = 1 :: else -> skip fi; e_k = 0",
            ],
        )
        inline(
            "resolve_initial",
            [
                "/* e_n's initial state, through its initial junction: the first branch in order",
                "   whose guard is true or absent (`else` where it stands), else its last */",
                "i_tg = init_[e_n];",
                "if :: kind_[i_tg] == JUNCTION ->",
                "     i_pick = -1; i_b = tfirst_[i_tg];",
                "     do :: i_b < tlast_[i_tg] -> eval_guard(tguard_[i_b]); if :: gok -> i_pick = i_b; break :: else -> skip fi; i_b++",
                "     :: else -> break od;",
                "     if :: i_pick == -1 -> i_pick = tlast_[i_tg] - 1 :: else -> skip fi;",
                "     run_actions(teff_[i_pick]); i_tg = ttgt_[i_pick]",
                ":: else -> skip fi;",
                "d_ = i_tg; do :: d_ != e_n -> want[d_] = 1; d_ = parent_[d_] :: else -> break od; dflt[i_tg] = 1;",
                "i_tg = 0; i_b = 0; i_pick = 0",
            ],
        )
        inline(
            "open_below",
            [
                "/* what entering e_n means for its children: every region of a parallel state,",
                "   the initial state of a compound one entered by default */",
                "if :: kind_[e_n] == PARALLEL ->",
                "     e_m = e_n + 1;",
                "     do :: e_m <= end_[e_n] -> if :: parent_[e_m] == e_n && !want[e_m] -> want[e_m] = 1; dflt[e_m] = 1 :: else -> skip fi; e_m++",
                "     :: else -> break od; e_m = 0",
                ":: kind_[e_n] == COMPOUND && dflt[e_n] && init_[e_n] != -1 -> resolve_initial()",
                ":: else -> skip fi",
            ],
        )
        inline(
            "enter_sweep",
            [
                "/* enter the marked states below dom, outermost first, in document order */",
                "e_n = dom + 1;",
                "do :: e_n <= end_[dom] ->",
                "     if :: want[e_n] -> enter_one(); open_below() :: else -> skip fi;",
                "     want[e_n] = 0; dflt[e_n] = 0; e_n++",
                ":: else -> break od; e_n = 0",
            ],
        )
        inline(
            "fire_chain",
            [
                "/* chain f_i: exit below its domain, run every effect, enter the target */",
                "f_last = chn[f_i * MAXC + chl[f_i] - 1]; tgt = ttgt_[f_last];",
                "if :: tgt != -1 ->",
                "     if :: kind_[src] == COMPOUND && src < tgt && tgt <= end_[src] -> dom = src",
                "        :: else -> dom = parent_[src];",
                "           do :: !(dom < tgt && tgt <= end_[dom]) -> dom = parent_[dom] :: else -> break od",
                "     fi;",
                "     do :: kind_[dom] == PARALLEL -> dom = parent_[dom] :: else -> break od;",
                "     exit_below()",
                ":: else -> skip fi;",
                "f_m = 0; do :: f_m < chl[f_i] -> run_actions(teff_[chn[f_i * MAXC + f_m]]); f_m++ :: else -> break od;",
                "if :: tgt != -1 ->",
                "     d_ = tgt; do :: d_ != dom -> want[d_] = 1; d_ = parent_[d_] :: else -> break od; dflt[tgt] = 1;",
                "     enter_sweep()",
                ":: else -> skip fi; f_m = 0",
            ],
        )
        inline(
            "fire_all",
            [
                "/* fire the chosen chains in order; one whose source was left in this step does not */",
                "f_i = 0;",
                "do :: f_i < nch ->",
                "     src = tsrc_[chn[f_i * MAXC]];",
                "     if :: act[src] && !exited[src] -> fire_chain() :: else -> skip fi; f_i++",
                ":: else -> break od;",
                "f_i = 0; do :: f_i < N -> exited[f_i] = 0; f_i++ :: else -> break od;",
                "f_i = 0; do :: f_i < CH -> chl[f_i] = 0; f_i++ :: else -> break od;",
                "f_i = 0; do :: f_i < CH * MAXC -> chn[f_i] = 0; f_i++ :: else -> break od;",
                "f_i = 0; nch = 0; src = 0; tgt = 0; dom = 0; f_last = 0; d_ = 0",
            ],
        )
        done_bit = 1 << self.event_bits[CONFIG_DONE]
        failed_bit = 1 << self.event_bits[CONFIG_FAILED]
        inline(
            "settle",
            [
                "/* a configuration answer clears the requests awaiting its tag */",
                "tg = -1; s_n = 0;",
                "do :: s_n < TAGS -> if :: h_tag && tagsym_[s_n] == f_tag -> tg = s_n :: else -> skip fi; s_n++ :: else -> break od;",
                "if :: tg != -1 && ptag[tg] > 0 -> ptag[tg]-- :: else -> skip fi;",
                "s_n = 0;",
                "do :: s_n < N ->",
                "     if :: tg != -1 && pend[s_n] && cfg_[s_n] == tg -> pend[s_n] = 0;",
                f"          if :: evbit == {done_bit} -> run_actions(do_[s_n]) :: else -> skip fi",
                "     :: else -> skip fi; s_n++",
                ":: else -> break od; s_n = 0; tg = 0",
            ],
        )
        timeout_events = []
        for k, (s, t) in enumerate(self.slots):
            if t is None:
                assert s.configure is not None
                payload = {
                    "tag": s.configure.tag,
                    "state": s.path,
                    "reason": f"no acknowledgement within {s.configure.timeout:g} s",
                }
                timeout_events.append(
                    f"     :: best == {k} -> {' '.join(self.set_event(CONFIG_FAILED, payload))}"
                )
        inline(
            "next_timer",
            [
                "/* the next due timer, in deadline then creation order; none: the tick is over */",
                "best = -1; bseq = 32000; r_i = 0;",
                "do :: r_i < S -> if :: tm_on[r_i] && tm_rem[r_i] == 0 && tm_seq[r_i] < bseq -> best = r_i; bseq = tm_seq[r_i] :: else -> skip fi; r_i++ :: else -> break od;",
                "r_i = 0;",
                "if :: best == -1 -> stage = S_DONE",
                ":: else ->",
                "   tm_on[best] = 0; tm_seq[best] = 0; then = S_TIMER; lc = 0;",
                "   if :: strans_[best] == -1 ->",
                "        if :: pend[snode_[best]] -> pend[snode_[best]] = 0;",
                "             if",
                *timeout_events,
                "             :: else -> skip fi;",
                "             stage = S_EVENT",
                "        :: else -> skip fi",
                "   :: else ->",
                "        " + " ".join(self.set_event(AFTER, {})),
                "        s_t = strans_[best]; try_enable(); s_t = 0; nch = 0;",
                "        if :: tmplen > 0 -> push_chain() :: else -> skip fi;",
                "        stage = S_FIRE",
                "   fi",
                "fi",
            ],
        )
        _, failed_payload = Input(FAILED).event("")  # the environment's own answer
        failed_payload = {k: v for k, v in (failed_payload or {}).items() if k != "tag"}
        scratch = [
            "ev = 0; evbit = 0; noev = 0; noev_x = 0; answered = 0; gok = 0; found = 0;",
            "inp = 0; rq = 0; best = 0; bseq = 0; tmplen = 0; j_node = 0; j_b = 0; j_pick = 0; fb = 0;",
            "stage = 0; then = 0; lc = 0;",
            "r_i = 0; do :: r_i < MAXC -> tmpc[r_i] = 0; r_i++ :: else -> break od;",
        ]
        scratch += [f"h_{f} = 0; f_{f} = 0;" for f in sorted(self.fields)]
        inline(
            "end_step",
            [
                "/* the bound on unanswered requests, then the property, then a canonical state */",
                "if :: nout > K || overflow -> beyond = 1",
                ":: else ->",
                *("     " + j for j in self.judge()),
                "     assert(!viol)",
                "fi;",
                *scratch,
                "r_i = 0; seqc = 0;",
                "do :: r_i < S ->",
                "     if :: tm_on[r_i] -> r_k = 1; r_j = 0;",
                "          do :: r_j < S -> if :: tm_on[r_j] && tm_seq[r_j] < tm_seq[r_i] -> r_k++ :: else -> skip fi; r_j++ :: else -> break od;",
                "          rank[r_i] = r_k; seqc++",
                "     :: else -> rank[r_i] = 0 fi; r_i++",
                ":: else -> break od;",
                "r_i = 0; do :: r_i < S -> tm_seq[r_i] = rank[r_i]; rank[r_i] = 0; r_i++ :: else -> break od;",
                "r_i = 0; r_j = 0; r_k = 0",
            ],
        )
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
        emit(
            "      /* the chart until quiet (Interpreter._process, _process_timer, _complete), one"
        )
        emit("         stage per d_step (SPIN bounds a d_step's size); the whole step is atomic */")
        emit("      do")
        emit("      :: stage == S_EVENT -> d_step {")
        emit("           noev = 0; lc = 0; observe_event();")
        emit("           if :: finished -> stage = then")
        emit(
            f"              :: else -> if :: evbit == {done_bit} || evbit == {failed_bit} -> settle() :: else -> skip fi;"
        )
        emit("                 select_event(); stage = S_FIRE")
        emit("           fi }")
        emit("      :: stage == S_FIRE -> d_step { fire_all(); stage = S_COMPLETE }")
        emit("      :: stage == S_COMPLETE -> d_step {")
        emit("           noev = 1;")
        emit("           if :: finished || lc >= 10000 -> noev = 0; stage = then")
        emit("              :: else -> select_completion();")
        emit("                 if :: nch == 0 -> noev = 0; stage = then")
        emit("                    :: else -> lc++; stage = S_FIRE fi")
        emit("           fi }")
        emit("      :: stage == S_TIMER -> d_step { noev = 0; next_timer() }")
        emit("      :: stage == S_DONE -> break")
        emit("      od;")
        emit("      d_step { end_step() }")
        emit("    }")
        emit("  od")
        emit("}")
        return "\n".join(lines) + "\n"
