"""Spec: the house plan's boundaries (ARCHITECTURE.md), read from the code's imports:
the framework knows no procedure's components, no module needs itself through a
circle of imports when it runs (imports for type annotations only are not run), and
components share code through `components.domain`, not by importing one another."""

from __future__ import annotations

import ast
from pathlib import Path

from tests.conftest import REPO

PACKAGES = ("framework", "components")


def _module(path: Path) -> str:
    parts = path.relative_to(REPO).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def run_time_imports(tree: ast.AST) -> set[str]:
    """Modules a file imports when it runs (anywhere but under `if TYPE_CHECKING:`)."""
    out: set[str] = set()

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _type_checking(node):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            out.add(node.module)
            out.update(f"{node.module}.{alias.name}" for alias in node.names)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return out


def every_import(tree: ast.AST) -> set[str]:
    """Modules a file names in an import, for type annotations included."""
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            out.add(node.module)
            out.update(f"{node.module}.{alias.name}" for alias in node.names)
    return out


def import_graph(type_only: bool = False) -> dict[str, set[str]]:
    """Module -> the modules of this repository's packages it imports at run time (with
    `type_only`, also those it imports for type annotations only)."""
    files = [p for pkg in PACKAGES for p in (REPO / pkg).rglob("*.py")]
    modules = {_module(p): p for p in files}
    reader = every_import if type_only else run_time_imports
    graph = {}
    for name, path in modules.items():
        found = reader(ast.parse(path.read_text(encoding="utf-8")))
        graph[name] = {m for m in found if m in modules and m != name}
    return graph


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected groups of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def connect(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    for v in graph:
        if v not in index:
            connect(v)
    return out


def test_no_module_imports_itself_through_a_circle():
    assert circles(import_graph()) == []


def test_no_two_modules_know_each_other_even_for_types():
    """A circle of type-only imports is one side knowing too much of the other: each
    side names a narrow Protocol of what it uses instead (`PanelHost`, `PortLookup`,
    `Watched`)."""
    assert circles(import_graph(type_only=True)) == []


def test_the_circle_finder_finds_a_circle_and_skips_type_only_imports():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert circles(graph) == [["a", "b", "c"]]
    code = "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import x\nimport y\n"
    assert run_time_imports(ast.parse(code)) == {"typing", "typing.TYPE_CHECKING", "y"}


def test_the_framework_imports_no_procedure_component_at_run_time():
    graph = import_graph()
    framework = {m: deps for m, deps in graph.items() if m.startswith("framework")}
    leaks = {
        m: sorted(d for d in deps if d.startswith("components")) for m, deps in framework.items()
    }
    assert {m: d for m, d in leaks.items() if d} == {}


DOMAIN = "components.domain"
"""What components share (geometry, the LWR 4+ model and its IK, capsule distances, the
procedure and sensors files, calibration solvers, the skeleton model, the simulated
rigs' layout, speed and separation monitoring): every component package may import it;
it imports none of them."""


def _cross_component_imports() -> set[tuple[str, str]]:
    out = set()
    for module, deps in import_graph().items():
        if not module.startswith("components."):
            continue
        package = module.split(".")[1]
        for dep in deps:
            parts = dep.split(".")
            if (
                dep.startswith("components.")
                and len(parts) > 2
                and parts[1] not in (package, "domain")
            ):
                out.add((module, dep))
    return out


def test_the_domain_package_imports_no_component():
    graph = import_graph()
    leaks = {
        (m, d)
        for m, deps in graph.items()
        if m.startswith(DOMAIN)
        for d in deps
        if d.startswith("components.") and not d.startswith(DOMAIN)
    }
    assert leaks == set()


def test_no_component_package_imports_another():
    assert sorted(_cross_component_imports()) == []


LOCK_RELEASING = "np.linalg.norm without axis (BLAS dot), ndarray.dot / np.dot"
"""numpy calls that release the interpreter lock even for a 3-vector: beside another
busy Python thread of the process, each then waits up to a switch interval (5 ms) to
take it back (components/domain/geometry.py: `norm`)."""


def lock_releasing_calls(tree: ast.AST) -> list[int]:
    """Lines calling `np.linalg.norm(x)` without `axis`, `np.dot(...)` or `x.dot(...)`."""
    lines = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call) or not isinstance(node.func, ast.Attribute):
            continue
        name, owner = node.func.attr, ast.unparse(node.func.value)
        whole_norm = name == "norm" and owner.endswith("linalg") and len(node.args) < 3
        whole_norm = whole_norm and not any(k.arg == "axis" for k in node.keywords)
        if whole_norm or name == "dot":
            lines.append(node.lineno)
    return lines


def test_the_lock_releasing_finder_finds_them():
    found = lock_releasing_calls(
        ast.parse("np.linalg.norm(v)\nnp.linalg.norm(m, axis=1)\na.dot(b)\nnp.dot(a, b)\na @ b")
    )
    assert found == [1, 3, 4]


def test_components_and_the_framework_never_release_the_lock_for_small_numpy_work():
    """Their processes run several Python threads (components, bus callbacks): a call
    that releases the lock costs up to 5 ms there (measured: the Navigator's and the
    Sensor Manager's updates waited milliseconds in `np.linalg.norm`). The bench
    (fw-bench, tools/bench), a harness in a process of its own, may."""
    files = [p for pkg in PACKAGES for p in (REPO / pkg).rglob("*.py")]
    found = {
        f"{p.relative_to(REPO)}:{line}"
        for p in files
        for line in lock_releasing_calls(ast.parse(p.read_text(encoding="utf-8")))
    }
    assert sorted(found) == [], LOCK_RELEASING


def test_every_component_hook_says_when_it_runs_in_which_thread_and_what_a_failure_does():
    """The component contract as OROCOS RTT writes it (TaskCore.hpp): an author of a
    component reads, on each hook, when it is called, by which thread, and what an
    exception or a refusal in it leads to."""
    import inspect

    from framework.component import Component

    hooks = [n for n in vars(Component) if n.endswith("_hook") and not n.startswith("_")]
    assert len(hooks) == 11, hooks
    vague = []
    for name in hooks:
        doc = " ".join((inspect.getdoc(getattr(Component, name)) or "").split())
        says = ("thread" in doc, "lifecycle lock" in doc or "outside the" in doc)
        failure = "Exception" in doc or "FatalError" in doc or "refuse" in doc.lower()
        if not (all(says) and failure):
            vague.append(name)
    assert vague == []


def test_every_broad_except_in_the_framework_says_why_and_where_the_error_goes():
    """`except Exception` only with a comment on the line saying why everything must
    be caught there and what becomes of the error (never silently)."""
    silent = []
    for path in sorted((REPO / "framework").rglob("*.py")):
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            stripped = line.strip()
            if stripped.startswith("except Exception") and "#" not in stripped:
                silent.append(f"{path.relative_to(REPO)}:{number}")
    assert silent == []


def test_fws_wheel_holds_no_test_code_and_no_harness():
    """What fw ships (framework/, components/) never imports the specs' scaffolding
    (tests/) or the experiment harness (fw-bench, a distribution of its own), and its
    wheel takes only those two packages."""
    import tomllib

    reached = {
        f"{module} -> {dep}"
        for path in (p for pkg in PACKAGES for p in (REPO / pkg).rglob("*.py"))
        for module in [_module(path)]
        for dep in run_time_imports(ast.parse(path.read_text(encoding="utf-8")))
        if dep.split(".")[0] in ("tests", "fw_bench")
    }
    assert sorted(reached) == []
    project = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))
    assert project["tool"]["setuptools"]["packages"]["find"]["include"] == [
        "framework*",
        "components*",
    ]


def undocumented(module_name: str) -> list[str]:
    """Public classes and functions of a module (and public methods of its classes)
    without a docstring of their own or one they inherit from the method they override
    (`inspect.getdoc`: a Listener's `on_entry` says what it does once, in Listener)."""
    import importlib
    import inspect

    module = importlib.import_module(module_name)
    out = []
    for name, value in vars(module).items():
        if name.startswith("_") or getattr(value, "__module__", None) != module_name:
            continue
        if not (inspect.isclass(value) or inspect.isfunction(value)):
            continue
        if not inspect.getdoc(value):
            out.append(f"{module_name}.{name}")
        if inspect.isclass(value):
            for attr, member in vars(value).items():
                if attr.startswith("_") or not callable(getattr(member, "fget", member)):
                    continue
                if not inspect.getdoc(getattr(value, attr)):
                    out.append(f"{module_name}.{name}.{attr}")
    return out


def test_every_public_definition_of_the_framework_says_what_it_is():
    """What a newcomer reads first: every public class and function of framework/ has
    a docstring (its own, or the one of the hook or listener method it overrides)."""
    modules = sorted(m for m in import_graph() if m.startswith("framework"))
    missing = [name for m in modules for name in undocumented(m)]
    assert missing == []
