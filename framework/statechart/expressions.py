"""Guard and value expressions: a small, side-effect-free language.

Expressions use Python syntax restricted to literals, declared variables,
`event.<field>` (the triggering event's payload; `event.name` is its name),
arithmetic, comparisons, `and`/`or`/`not`, `a if c else b` and a few pure
functions (`abs min max len round int float str bool` and `active('State')`).
They are parsed and checked once at load time and compiled into a tree of
closures, so nothing is `eval`-ed at run time and nothing can have a side
effect. The compiler also records what an expression refers to, so the
validator can check names and prove some guards mutually exclusive.
"""

from __future__ import annotations

import ast
import operator
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from framework.errors import FwError


class ExpressionError(FwError):
    """An expression does not parse or uses something the language forbids."""


class EvaluationError(FwError):
    """An expression failed at run time (missing payload field, type error...)."""


class Env:
    """What an expression can see while it runs."""

    __slots__ = ("event", "is_active", "vars")

    def __init__(
        self,
        variables: Mapping[str, Any],
        event: Any = None,
        is_active: Callable[[str], bool] | None = None,
    ):
        self.vars = variables
        self.event = event
        self.is_active = is_active or (lambda name: False)


Compiled = Callable[[Env], Any]

_LITERAL_NAMES = {
    "true": True,
    "false": False,
    "null": None,
    "True": True,
    "False": False,
    "None": None,
}
_FUNCTIONS: dict[str, Callable[..., Any]] = {
    "abs": abs,
    "min": min,
    "max": max,
    "len": len,
    "round": round,
    "int": int,
    "float": float,
    "str": str,
    "bool": bool,
}
_BINOPS = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
    ast.FloorDiv: operator.floordiv,
    ast.Mod: operator.mod,
}
_CMPOPS = {
    ast.Eq: operator.eq,
    ast.NotEq: operator.ne,
    ast.Lt: operator.lt,
    ast.LtE: operator.le,
    ast.Gt: operator.gt,
    ast.GtE: operator.ge,
    ast.In: lambda a, b: a in b,
    ast.NotIn: lambda a, b: a not in b,
}
_CMP_SYMBOL = {
    ast.Eq: "==",
    ast.NotEq: "!=",
    ast.Lt: "<",
    ast.LtE: "<=",
    ast.Gt: ">",
    ast.GtE: ">=",
}
_FLIP = {"<": ">", "<=": ">=", ">": "<", ">=": "<=", "==": "==", "!=": "!="}

Atom = tuple[str, str, Any]
"""A proven fact of a guard: (operand key, operator, constant), e.g. ('var:n', '>', 2)."""


@dataclass
class Expression:
    """A checked, compiled expression and what it refers to."""

    source: str
    fn: Compiled
    variables: set[str] = field(default_factory=set)
    event_fields: set[str] = field(default_factory=set)
    states: set[str] = field(default_factory=set)
    atoms: tuple[Atom, ...] | None = None
    """The guard as a conjunction of atoms, when it has that simple shape."""

    def __call__(self, env: Env) -> Any:
        return self.fn(env)


def _payload_get(event: Any, name: str) -> Any:
    if event is None:
        raise EvaluationError(f"'event.{name}' used but there is no triggering event")
    if name == "name":
        return event.name
    payload = event.payload
    if payload is None or name not in payload:
        raise EvaluationError(f"event {event.name!r} has no payload field {name!r}")
    return payload[name]


class _Compiler:
    def __init__(self, source: str):
        self.source = source
        self.variables: set[str] = set()
        self.event_fields: set[str] = set()
        self.states: set[str] = set()

    def fail(self, node: ast.AST, message: str) -> ExpressionError:
        col = getattr(node, "col_offset", 0)
        return ExpressionError(f"{message} in expression {self.source!r} (at column {col + 1})")

    def compile(self, node: ast.AST) -> Compiled:
        if isinstance(node, ast.Constant):
            if not isinstance(node.value, (int, float, str, bool, type(None))):
                raise self.fail(node, "unsupported literal")
            value = node.value
            return lambda env: value
        if isinstance(node, ast.Name):
            return self._name(node)
        if isinstance(node, ast.Attribute):
            return self._attribute(node)
        if isinstance(node, ast.Subscript):
            base, index = self.compile(node.value), self.compile(node.slice)
            return lambda env: base(env)[index(env)]
        if isinstance(node, ast.BoolOp):
            parts = [self.compile(v) for v in node.values]
            if isinstance(node.op, ast.And):
                return lambda env: all(p(env) for p in parts)
            return lambda env: any(p(env) for p in parts)
        if isinstance(node, ast.UnaryOp):
            operand = self.compile(node.operand)
            if isinstance(node.op, ast.Not):
                return lambda env: not operand(env)
            if isinstance(node.op, ast.USub):
                return lambda env: -operand(env)
            if isinstance(node.op, ast.UAdd):
                return lambda env: +operand(env)
            raise self.fail(node, "unsupported unary operator")
        if isinstance(node, ast.BinOp):
            op = _BINOPS.get(type(node.op))
            if op is None:
                raise self.fail(node, "unsupported operator")
            left, right = self.compile(node.left), self.compile(node.right)
            return lambda env: op(left(env), right(env))
        if isinstance(node, ast.Compare):
            return self._compare(node)
        if isinstance(node, ast.IfExp):
            test, body, orelse = (self.compile(n) for n in (node.test, node.body, node.orelse))
            return lambda env: body(env) if test(env) else orelse(env)
        if isinstance(node, (ast.List, ast.Tuple)):
            items = [self.compile(e) for e in node.elts]
            return lambda env: tuple(i(env) for i in items)
        if isinstance(node, ast.Call):
            return self._call(node)
        raise self.fail(node, f"'{type(node).__name__}' is not allowed")

    def _name(self, node: ast.Name) -> Compiled:
        if node.id in _LITERAL_NAMES:
            value = _LITERAL_NAMES[node.id]
            return lambda env: value
        if node.id == "event":
            return lambda env: env.event
        name = node.id
        self.variables.add(name)

        def variable(env: Env) -> Any:
            try:
                return env.vars[name]
            except KeyError:
                raise EvaluationError(f"unknown variable {name!r}") from None

        return variable

    def _attribute(self, node: ast.Attribute) -> Compiled:
        if node.attr.startswith("_"):
            raise self.fail(node, "private attributes are not allowed")
        if isinstance(node.value, ast.Name) and node.value.id == "event":
            name = node.attr
            if name != "name":
                self.event_fields.add(name)
            return lambda env: _payload_get(env.event, name)
        base, key = self.compile(node.value), node.attr

        def member(env: Env) -> Any:
            value = base(env)
            if isinstance(value, Mapping) and key in value:
                return value[key]
            raise EvaluationError(f"no field {key!r} in {value!r}")

        return member

    def _compare(self, node: ast.Compare) -> Compiled:
        ops = []
        for op in node.ops:
            fn = _CMPOPS.get(type(op))
            if fn is None:
                raise self.fail(node, "unsupported comparison ('is' is not allowed; use ==)")
            ops.append(fn)
        operands = [self.compile(node.left), *(self.compile(c) for c in node.comparators)]
        if len(ops) == 1:
            op, left, right = ops[0], operands[0], operands[1]
            return lambda env: op(left(env), right(env))

        def chain(env: Env) -> bool:
            left = operands[0](env)
            for op, right_fn in zip(ops, operands[1:], strict=True):
                right = right_fn(env)
                if not op(left, right):
                    return False
                left = right
            return True

        return chain

    def _call(self, node: ast.Call) -> Compiled:
        if not isinstance(node.func, ast.Name) or node.keywords:
            raise self.fail(node, "only plain calls of known functions are allowed")
        name = node.func.id
        if name == "active":
            arg = node.args[0] if len(node.args) == 1 else None
            if not (isinstance(arg, ast.Constant) and isinstance(arg.value, str)):
                raise self.fail(node, "active() takes one quoted state name")
            state = arg.value
            self.states.add(state)
            return lambda env: env.is_active(state)
        fn = _FUNCTIONS.get(name)
        if fn is None:
            known = ", ".join(sorted([*_FUNCTIONS, "active"]))
            raise self.fail(node, f"unknown function {name!r} (known: {known})")
        args = [self.compile(a) for a in node.args]
        return lambda env: fn(*(a(env) for a in args))


def _operand_key(node: ast.AST) -> str | None:
    if isinstance(node, ast.Name) and node.id not in _LITERAL_NAMES and node.id != "event":
        return f"var:{node.id}"
    if (
        isinstance(node, ast.Attribute)
        and isinstance(node.value, ast.Name)
        and node.value.id == "event"
    ):
        return f"event:{node.attr}"
    return None


def _constant(node: ast.AST) -> tuple[bool, Any]:
    if isinstance(node, ast.Constant):
        return True, node.value
    if isinstance(node, ast.Name) and node.id in _LITERAL_NAMES:
        return True, _LITERAL_NAMES[node.id]
    if (
        isinstance(node, ast.UnaryOp)
        and isinstance(node.op, ast.USub)
        and isinstance(node.operand, ast.Constant)
        and isinstance(node.operand.value, (int, float))
    ):
        return True, -node.operand.value
    return False, None


def _atoms(node: ast.AST) -> tuple[Atom, ...] | None:
    """The guard as a conjunction of simple facts, or None if it is not that shape."""
    if isinstance(node, ast.BoolOp) and isinstance(node.op, ast.And):
        out: list[Atom] = []
        for value in node.values:
            sub = _atoms(value)
            if sub is None:
                return None
            out.extend(sub)
        return tuple(out)
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not):
        key = _operand_key(node.operand)
        if key:
            return ((key, "truthy", False),)
        inner = _atoms(node.operand)
        if inner and len(inner) == 1 and inner[0][1] in _NEGATE:
            k, op, c = inner[0]
            return ((k, _NEGATE[op], c),)
        return None
    key = _operand_key(node)
    if key:
        return ((key, "truthy", True),)
    if isinstance(node, ast.Compare) and len(node.ops) == 1 and type(node.ops[0]) in _CMP_SYMBOL:
        symbol = _CMP_SYMBOL[type(node.ops[0])]
        left, right = node.left, node.comparators[0]
        key, (is_const, value) = _operand_key(left), _constant(right)
        if key and is_const:
            return ((key, symbol, value),)
        key, (is_const, value) = _operand_key(right), _constant(left)
        if key and is_const:
            return ((key, _FLIP[symbol], value),)
    return None


_NEGATE = {"==": "!=", "!=": "==", "<": ">=", "<=": ">", ">": "<=", ">=": "<", "truthy": "truthy"}


def _contradict(a: Atom, b: Atom) -> bool:
    """True when two facts about the same operand cannot both hold."""
    if a[0] != b[0]:
        return False
    (_, op1, c1), (_, op2, c2) = a, b
    if op1 == "truthy" or op2 == "truthy":
        return op1 == op2 == "truthy" and c1 != c2
    if op1 == "==" and op2 == "==":
        return c1 != c2
    if {op1, op2} == {"==", "!="}:
        return c1 == c2
    if op1 == "==":
        return not _holds(c1, op2, c2)
    if op2 == "==":
        return not _holds(c2, op1, c1)
    if not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in (c1, c2)):
        return False
    lo1, hi1 = _interval(op1, c1)
    lo2, hi2 = _interval(op2, c2)
    low, high = max(lo1, lo2, key=lambda x: x[0]), min(hi1, hi2, key=lambda x: x[0])
    if low[0] > high[0]:
        return True
    return low[0] == high[0] and not (low[1] and high[1])


def _holds(value: Any, op: str, const: Any) -> bool:
    try:
        return bool(
            {
                "!=": operator.ne,
                "<": operator.lt,
                "<=": operator.le,
                ">": operator.gt,
                ">=": operator.ge,
            }[op](value, const)
        )
    except TypeError:
        return True  # cannot decide: assume it may hold


def _interval(op: str, c: float) -> tuple[tuple[float, bool], tuple[float, bool]]:
    inf = float("inf")
    return {
        "<": ((-inf, False), (c, False)),
        "<=": ((-inf, False), (c, True)),
        ">": ((c, False), (inf, False)),
        ">=": ((c, True), (inf, False)),
        "!=": ((-inf, False), (inf, False)),
    }[op]


def provably_exclusive(a: Expression | None, b: Expression | None) -> bool:
    """True only if the two guards can never both be true (a sound, partial proof)."""
    if a is None or b is None or a.atoms is None or b.atoms is None:
        return False
    return any(_contradict(x, y) for x in a.atoms for y in b.atoms)


def compile_expression(source: str) -> Expression:
    """Parse, check and compile an expression; raise `ExpressionError` if it is not allowed."""
    if not isinstance(source, str) or not source.strip():
        raise ExpressionError("an expression must be a non-empty string")
    try:
        tree = ast.parse(source.strip(), mode="eval")
    except SyntaxError as exc:
        raise ExpressionError(
            f"syntax error in expression {source!r}: {exc.msg} (at column {exc.offset or 0})"
        ) from None
    compiler = _Compiler(source)
    fn = compiler.compile(tree.body)
    return Expression(
        source, fn, compiler.variables, compiler.event_fields, compiler.states, _atoms(tree.body)
    )
