"""fw's own mutation operators: the mistakes a developer makes that cosmic-ray's
operators never make.

cosmic-ray changes one token of an expression (a comparison, an operator, a
constant). A reviewer's mutants are coarser and closer to real slips:

* **DeleteStatement**: a statement of a function replaced by `pass` (a forgotten
  update, a call that never happens, a refusal never raised);
* **SwapVariable**: a name read where another of the same type in scope was meant
  (`now` for `age`, `self.best` for `self.in_use`); "same type" is inferred from
  annotations, literals, the calls that made the value and, for attributes, every
  `self.x = ...` of the class and its declared properties;
* **SwapMinMax**: `min` for `max` (and numpy's `minimum`/`maximum`, `argmin`/`argmax`,
  `.min()`/`.max()`);
* **DropNoneCheck**: `x is not None` written as a truthiness test `x` (and `x is None`
  as `not x`): a zero, an empty list or an empty string then counts as missing;
* **MoveLine**: a statement swapped with the next one of its block (an update done
  after its use instead of before).

Each mutant keeps the module's line count, so its line and the line's text before
and after name it as cosmic-ray's do (and `tools/mutation_equivalents.yaml` can
list it). Only code inside functions is mutated.
"""

from __future__ import annotations

import ast
import itertools
from collections.abc import Iterator
from dataclasses import dataclass

DELETE = "fw/DeleteStatement"
SWAP_VARIABLE = "fw/SwapVariable"
SWAP_MIN_MAX = "fw/SwapMinMax"
DROP_NONE_CHECK = "fw/DropNoneCheck"
MOVE_LINE = "fw/MoveLine"
OPERATORS = (DELETE, SWAP_VARIABLE, SWAP_MIN_MAX, DROP_NONE_CHECK, MOVE_LINE)

_MIN_MAX = {
    "min": "max",
    "max": "min",
    "minimum": "maximum",
    "maximum": "minimum",
    "argmin": "argmax",
    "argmax": "argmin",
    "nanmin": "nanmax",
    "nanmax": "nanmin",
    "fmin": "fmax",
    "fmax": "fmin",
}
_NUMBER_CALLS = {"float", "int", "len", "abs", "round", "sum", "min", "max", "hypot", "sqrt"}
_NUMBER_CALLS |= {"perf_counter", "monotonic", "time", "now", "radians", "degrees", "exp", "log"}
_ARRAY_CALLS = {"array", "asarray", "zeros", "ones", "full", "eye", "copy", "concatenate"}
_ANNOTATION_KINDS = {"float": "number", "int": "number", "str": "str", "bool": "bool"}
_ANNOTATION_KINDS |= {"np.ndarray": "array", "ndarray": "array"}


@dataclass(frozen=True)
class Change:
    """One mutant as an edit of the module's lines: `lines` replaced from row `first`
    (0-based; as many as were there), reported on 1-based `line`."""

    operator: str
    line: int
    first: int
    lines: tuple[str, ...]


def fw_changes(code: str, lines: tuple[int, int] | None = None) -> list[Change]:
    """Every mutant fw's operators make of `code` (only `lines`, 1-based, if given)."""
    tree = ast.parse(code)
    source = code.splitlines()
    found: list[Change] = []
    classes = {id(f): c for c in ast.walk(tree) if isinstance(c, ast.ClassDef) for f in c.body}
    for function in ast.walk(tree):
        if not isinstance(function, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        cls = classes.get(id(function))
        attributes = _attribute_kinds(cls) if cls is not None else {}
        found += _deletions(function, source)
        found += _variable_swaps(function, source, attributes)
        found += _min_max_swaps(function, source)
        found += _none_checks(function, source)
        found += _moves(function, source)
    unique: dict[tuple[str, int, tuple[str, ...]], Change] = {}
    for change in found:
        if lines and not lines[0] <= change.line <= lines[1]:
            continue
        unique.setdefault((change.operator, change.first, change.lines), change)
    return sorted(unique.values(), key=lambda c: (c.line, c.operator))


def apply(code: str, change: Change) -> str:
    """The module's text with `change` made."""
    rows = code.splitlines()
    rows[change.first : change.first + len(change.lines)] = change.lines
    return "\n".join(rows) + "\n"


# -- helpers -------------------------------------------------------------------------


def _own_nodes(function: ast.AST) -> Iterator[ast.AST]:
    """The nodes of a function's body, not of functions or classes nested in it."""
    stack = list(ast.iter_child_nodes(function))
    while stack:
        node = stack.pop()
        yield node
        if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef | ast.Lambda):
            stack.extend(ast.iter_child_nodes(node))


def _replace(source: list[str], node: ast.AST, text: str, operator: str) -> Change | None:
    """Replace the (one-line) source of `node` by `text`; None for a node written over
    several lines (the line count must stay)."""
    if node.lineno != node.end_lineno or node.end_col_offset is None:
        return None
    row = node.lineno - 1
    raw = source[row].encode("utf-8")  # ast's columns count UTF-8 bytes
    new = raw[: node.col_offset] + text.encode("utf-8") + raw[node.end_col_offset :]
    return Change(operator, node.lineno, row, (new.decode("utf-8"),))


def _segment(source: list[str], node: ast.AST) -> str:
    row = source[node.lineno - 1].encode("utf-8")
    return row[node.col_offset : node.end_col_offset].decode("utf-8")


def _is_docstring(node: ast.stmt) -> bool:
    return isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant)


# -- DeleteStatement -----------------------------------------------------------------


def _deletions(function: ast.AST, source: list[str]) -> list[Change]:
    """Each statement of the function replaced by `pass` (docstrings, `pass` and `...`
    are left alone; a statement sharing its line with another is too)."""
    kinds = (ast.Expr, ast.Assign, ast.AugAssign, ast.AnnAssign, ast.Raise, ast.Return)
    out = []
    for node in _own_nodes(function):
        if not isinstance(node, kinds) or _is_docstring(node):  # type: ignore[arg-type]
            continue
        if isinstance(node, ast.AnnAssign) and node.value is None:
            continue
        first, last = node.lineno, node.end_lineno or node.lineno
        text = source[first - 1]
        if text[: node.col_offset].strip():  # shares its line (`if x: y = 1`)
            continue
        new = [" " * node.col_offset + "pass"] + [""] * (last - first)
        out.append(Change(DELETE, first, first - 1, tuple(new)))
    return out


# -- SwapVariable --------------------------------------------------------------------


def _kind(expr: ast.AST | None, known: dict[str, str], attributes: dict[str, str]) -> str:
    """What kind of value `expr` makes ('number', 'str', 'bool', 'array', a class
    name from an annotation) or '' when it cannot be told."""
    if expr is None:
        return ""
    if isinstance(expr, ast.Constant):
        if isinstance(expr.value, bool):
            return "bool"
        if isinstance(expr.value, int | float):
            return "number"
        if isinstance(expr.value, str):
            return "str"
        return ""
    if isinstance(expr, ast.JoinedStr):
        return "str"
    if isinstance(expr, ast.Compare) or (
        isinstance(expr, ast.UnaryOp) and isinstance(expr.op, ast.Not)
    ):
        return "bool"
    if isinstance(expr, ast.UnaryOp):
        return _kind(expr.operand, known, attributes)
    if isinstance(expr, ast.BinOp):
        left, right = _kind(expr.left, known, attributes), _kind(expr.right, known, attributes)
        if "array" in (left, right):
            return "array"
        return "number" if "number" in (left, right) else ""
    if isinstance(expr, ast.IfExp):
        return _kind(expr.body, known, attributes) or _kind(expr.orelse, known, attributes)
    if isinstance(expr, ast.Name):
        return known.get(expr.id, "")
    if isinstance(expr, ast.Attribute):
        if isinstance(expr.value, ast.Name) and expr.value.id == "self":
            return attributes.get(expr.attr, "")
        return ""
    if isinstance(expr, ast.Call):
        func = expr.func
        name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
        if name in ("str", "repr", "format", "join", "strip"):
            return "str"
        if name == "bool":
            return "bool"
        if name in _ARRAY_CALLS and isinstance(func, ast.Attribute):
            return "array"
        if isinstance(func, ast.Attribute) and getattr(func.value, "id", "") == "np":
            return "number" if name in ("dot", "hypot") else "array"
        if name in _NUMBER_CALLS:
            return "number"
        if name == "prop" and expr.args:  # a declared property: prop(float, ...)
            return _annotation_kind(expr.args[0])
    return ""


def _annotation_kind(annotation: ast.AST | None) -> str:
    if annotation is None:
        return ""
    text = ast.unparse(annotation).strip("'\"")
    return _ANNOTATION_KINDS.get(text, text if text[:1].isupper() and "|" not in text else "")


def _attribute_kinds(cls: ast.ClassDef) -> dict[str, str]:
    """Each `self.x` attribute of a class with one kind (from its assignments and its
    declared properties); attributes assigned values of different kinds are left out."""
    seen: dict[str, set[str]] = {}
    for node in cls.body:  # declared properties: rate = prop(float, ...)
        if isinstance(node, ast.Assign) and len(node.targets) == 1:
            target = node.targets[0]
            if isinstance(target, ast.Name):
                kind = _kind(node.value, {}, {})
                if kind and isinstance(node.value, ast.Call):
                    seen.setdefault(target.id, set()).add(kind)
    for node in ast.walk(cls):
        if isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                if (
                    isinstance(target, ast.Attribute)
                    and isinstance(target.value, ast.Name)
                    and target.value.id == "self"
                ):
                    kind = _kind(node.value, {}, {})
                    if isinstance(node, ast.AnnAssign):
                        kind = _annotation_kind(node.annotation) or kind
                    seen.setdefault(target.attr, set()).add(kind)
    return {
        name: kinds.pop() for name, kinds in seen.items() if len(kinds) == 1 and "" not in kinds
    }


def _variable_swaps(
    function: ast.FunctionDef | ast.AsyncFunctionDef, source: list[str], attributes: dict[str, str]
) -> list[Change]:
    """Each read of a name (or `self.x`) of a known kind replaced by the nearest other
    one of that kind defined before it in the function (parameters first)."""
    defined: list[tuple[int, str, str]] = []  # (line, name, kind)
    known: dict[str, str] = {}
    args = function.args
    for arg in [*args.posonlyargs, *args.args, *args.kwonlyargs]:
        if arg.arg in ("self", "cls"):
            continue
        kind = _annotation_kind(arg.annotation)
        if kind:
            known[arg.arg] = kind
            defined.append((function.lineno - 1, arg.arg, kind))
    assignments = sorted(
        (n for n in _own_nodes(function) if isinstance(n, ast.Assign | ast.AnnAssign)),
        key=lambda n: (n.lineno, n.col_offset),
    )
    conflicted: set[str] = set()
    for node in assignments:
        targets = node.targets if isinstance(node, ast.Assign) else [node.target]
        for target in targets:
            if not isinstance(target, ast.Name):
                continue
            kind = _kind(node.value, known, attributes)
            if isinstance(node, ast.AnnAssign):
                kind = _annotation_kind(node.annotation) or kind
            if target.id in known and known[target.id] != kind:
                conflicted.add(target.id)
            elif kind and target.id not in known:
                known[target.id] = kind
                defined.append((node.lineno, target.id, kind))
    for name in conflicted:
        known.pop(name, None)
    defined = [d for d in defined if d[1] not in conflicted]
    calls = {id(n.func) for n in _own_nodes(function) if isinstance(n, ast.Call)}
    used_here = {
        n.attr
        for n in _own_nodes(function)
        if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name) and n.value.id == "self"
    }
    out = []
    for node in _own_nodes(function):
        if id(node) in calls:
            continue
        if isinstance(node, ast.Name) and isinstance(node.ctx, ast.Load):
            kind = known.get(node.id, "")
            before = [
                n for line, n, k in defined if k == kind and n != node.id and line < node.lineno
            ]
            if kind and before:
                change = _replace(source, node, before[-1], SWAP_VARIABLE)
                if change is not None:
                    out.append(change)
        elif (
            isinstance(node, ast.Attribute)
            and isinstance(node.ctx, ast.Load)
            and isinstance(node.value, ast.Name)
            and node.value.id == "self"
        ):
            kind = attributes.get(node.attr, "")
            order = list(attributes)
            others = sorted(
                (a for a, k in attributes.items() if k == kind and a != node.attr),
                key=lambda a: (
                    a not in used_here,  # the function reads both: the likelier slip
                    abs(order.index(a) - order.index(node.attr)),
                ),
            )
            if kind and others:
                change = _replace(source, node, f"self.{others[0]}", SWAP_VARIABLE)
                if change is not None:
                    out.append(change)
    return out


# -- SwapMinMax ----------------------------------------------------------------------


def _min_max_swaps(function: ast.AST, source: list[str]) -> list[Change]:
    out = []
    for node in _own_nodes(function):
        if not isinstance(node, ast.Call):
            continue
        func = node.func
        if isinstance(func, ast.Name) and func.id in _MIN_MAX:
            change = _replace(source, func, _MIN_MAX[func.id], SWAP_MIN_MAX)
        elif isinstance(func, ast.Attribute) and func.attr in _MIN_MAX:
            text = _segment(source, func) if func.lineno == func.end_lineno else ""
            if not text.endswith(func.attr):
                continue
            change = _replace(
                source, func, text[: -len(func.attr)] + _MIN_MAX[func.attr], SWAP_MIN_MAX
            )
        else:
            continue
        if change is not None:
            out.append(change)
    return out


# -- DropNoneCheck -------------------------------------------------------------------


def _none_checks(function: ast.AST, source: list[str]) -> list[Change]:
    out = []
    for node in _own_nodes(function):
        if not (
            isinstance(node, ast.Compare)
            and len(node.ops) == 1
            and isinstance(node.ops[0], ast.Is | ast.IsNot)
            and isinstance(node.comparators[0], ast.Constant)
            and node.comparators[0].value is None
            and node.left.lineno == node.left.end_lineno
        ):
            continue
        left = _segment(source, node.left)
        text = left if isinstance(node.ops[0], ast.IsNot) else f"not {left}"
        change = _replace(source, node, text, DROP_NONE_CHECK)
        if change is not None:
            out.append(change)
    return out


# -- MoveLine ------------------------------------------------------------------------


def _moves(function: ast.AST, source: list[str]) -> list[Change]:
    """Each statement swapped with the next of its block (with what lies between them,
    comments or blank lines, kept in place)."""
    out = []
    for node in [function, *_own_nodes(function)]:
        for field in ("body", "orelse", "finalbody"):
            block = getattr(node, field, None)
            if not isinstance(block, list):
                continue
            statements = [s for s in block if isinstance(s, ast.stmt) and not _is_docstring(s)]
            for a, b in itertools.pairwise(statements):
                if isinstance(a, ast.FunctionDef | ast.ClassDef) or isinstance(
                    b, ast.FunctionDef | ast.ClassDef
                ):
                    continue
                a_end, b_end = (a.end_lineno or a.lineno), (b.end_lineno or b.lineno)
                if a_end >= b.lineno:  # on one line (`a; b`)
                    continue
                first_a = source[a.lineno - 1 : a_end]
                between = source[a_end : b.lineno - 1]
                first_b = source[b.lineno - 1 : b_end]
                if first_a == first_b or _commute(a, b):
                    continue
                moved = (*first_b, *between, *first_a)
                out.append(Change(MOVE_LINE, a.lineno, a.lineno - 1, moved))
    return out


_PURE_CALLS = {"deque", "dict", "list", "set", "tuple", "float", "int", "str", "bool", "len"}
_PURE_CALLS |= {"zeros", "ones", "eye", "full", "array", "asarray", "field", "inf", "copy"}
_PURE_CALLS |= {"Lock", "RLock", "Event", "Condition", "now", "monotonic", "perf_counter"}
_PURE_CALLS |= {"time", "sorted", "min", "max", "abs", "round", "enumerate", "zip", "range"}
"""Calls that build a value and touch nothing else (a clock read counts: two reads of it
beside unrelated statements do not depend on their order). A call of a capitalised name
builds an object too."""


def _commute(a: ast.stmt, b: ast.stmt) -> bool:
    """True when swapping `a` and `b` cannot change anything, so the mutant would be
    equivalent by construction and is not made: two assignments, neither of which reads
    or writes what the other writes, whose values call nothing but pure constructors
    (`self._sent = deque(maxlen=2)` beside `self._commanding = False`)."""
    if not (_is_plain_assignment(a) and _is_plain_assignment(b)):
        return False
    written_a, written_b = _targets(a), _targets(b)  # type: ignore[arg-type]
    if None in written_a or None in written_b:
        return False
    reads_a, reads_b = _reads(a), _reads(b)
    return not (_overlap(written_a, reads_b | written_b) or _overlap(written_b, reads_a))


def _overlap(written: set, touched: set) -> bool:
    """Whether a written chain is, contains or is inside a touched one (self.x and
    self.x.y overlap; self.x and self.xy do not)."""
    return any(
        w == t or t.startswith(w + ".") or w.startswith(t + ".") for w in written for t in touched
    )


def _is_plain_assignment(node: ast.stmt) -> bool:
    if not isinstance(node, ast.Assign | ast.AnnAssign | ast.AugAssign):
        return False
    if getattr(node, "value", None) is None:
        return False
    for sub in ast.walk(node.value):  # type: ignore[arg-type]
        if isinstance(sub, ast.Call):
            func = sub.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            if name not in _PURE_CALLS and not name[:1].isupper():
                return False
        elif isinstance(sub, ast.Await | ast.Yield | ast.YieldFrom | ast.NamedExpr | ast.Lambda):
            return False
    return True


def _chain(node: ast.AST) -> str:
    """`self.a.b` as "self.a.b", a name as itself; "" for anything else."""
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        inner = _chain(node.value)
        return f"{inner}.{node.attr}" if inner else ""
    return ""


def _reads(node: ast.stmt) -> set[str]:
    """What an assignment reads: its value's chains, and for `x += v` or `x[i] = v` the
    target itself (its old value, or the container written into)."""
    out = _chains(node.value)  # type: ignore[attr-defined]
    targets = node.targets if isinstance(node, ast.Assign) else [node.target]  # type: ignore[attr-defined]
    for target in targets:
        for element in target.elts if isinstance(target, ast.Tuple) else [target]:
            if isinstance(node, ast.AugAssign) or isinstance(element, ast.Subscript):
                out |= _chains(element)
    return out


def _chains(node: ast.AST) -> set[str]:
    """The longest name and attribute chains read anywhere in `node`."""
    out: set[str] = set()
    stack = [node]
    while stack:
        sub = stack.pop()
        chain = _chain(sub)
        if chain:
            out.add(chain)
            continue  # not its inner parts: self.x.y reads self.x.y, not all of self
        stack.extend(ast.iter_child_nodes(sub))
    return out


def _targets(node: ast.Assign | ast.AnnAssign | ast.AugAssign) -> set[str | None]:
    """What an assignment writes, as chains; None for what cannot be told apart."""
    targets = node.targets if isinstance(node, ast.Assign) else [node.target]
    out: set[str | None] = set()
    for target in targets:
        for element in target.elts if isinstance(target, ast.Tuple) else [target]:
            if isinstance(element, ast.Subscript):
                element = element.value  # self.x[i] = ... writes (into) self.x
            out.add(_chain(element) or None)
    return out
