"""Mutation testing of the safety core: would its tests notice if the code were wrong?

    python tools/mutation.py framework/configurator.py            its own tests (the map below)
    python tools/mutation.py components/robot/interface.py --tests tests/components/robot
    python tools/mutation.py --core                               every safety module
    python tools/mutation.py framework/configurator.py --lines 150-200 --jobs 2
    python tools/mutation.py framework/safety.py --operators fw   only fw's own operators
    python tools/mutation.py --core --unused                      equivalents that match nothing now
    python tools/mutation.py framework/coordinator.py --survivors    the last run's survivors again

Two families of mutants, scored apart:

* **cosmic-ray's** (its operators find where and how to change the code: a comparison
  flipped, an operator swapped, a constant changed, `True` for `False`, a `not` added,
  a decorator or an exception handler removed, a loop run zero times);
* **fw's own** (`tools/mutation_operators.py`): the slips a reviewer writes by hand
  and cosmic-ray never makes: a statement deleted, a variable read where another of
  its type was meant, `min` for `max`, `x is not None` as a truthiness test, a line
  moved below the next.

This driver runs each mutant against the module's own fast tests, in a private copy
of the repository per worker (so mutants never touch the working tree and run in
parallel), and says which survived, as file:line before -> after. A mutant meets
first the tests seen running its line (from a coverage run with per-test contexts),
then, if they all pass, every test of the module: a kill is quick, and a survivor is
one the whole set lets through.

* **killed**: a test failed (or the mutant could not even be imported);
* **timeout**: the tests ran over 3x their normal time plus 10 s (counted as killed:
  the mutant made them hang);
* **survived**: every test passed: a behaviour no test pins down;
* **not run**: no longer made: a line the coverage run never saw is still tested
  against the whole set, since coverage cannot see code run by threads Python did not
  start (Zenoh's callbacks: 13 of the Configurator's mutants were reported "not run"
  on lines every local switch runs); older reports may still show the column;
* **equivalent**: listed in `tools/mutation_equivalents.yaml` with the reason it cannot
  change behaviour (matched by module, operator and the line's text before and after,
  so it survives edits elsewhere); left out of the score.

Score = (killed + timeout) / (all - equivalent), per family. Mutants inside
annotations are not made at all: with `from __future__ import annotations` they are
never evaluated. The exit status is 1 when a family scores under its target (90% for
cosmic-ray's, 95% for fw's), so the tool says what the report says.

The tables go to the terminal and, per module and family, into
`docs/results/mutation.md` (its section is replaced; the others stay). A run that is
stopped goes on where it stopped when started again on the same code: what it caught
is kept in `.mutation-cache/` (`Caught`; `--fresh` tests everything). Needs the
`mutation` extra for cosmic-ray's family: `pip install -e '.[mutation]'` (cosmic-ray,
coverage); fw's family needs coverage only.
"""

from __future__ import annotations

import argparse
import ast
import functools
import hashlib
import json
import os
import queue
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tools"))
from mutation_operators import OPERATORS as FW_OPERATORS  # noqa: E402
from mutation_operators import apply, fw_changes  # noqa: E402

REPORT = REPO / "docs" / "results" / "mutation.md"
EQUIVALENTS = REPO / "tools" / "mutation_equivalents.yaml"

REFERENCE = "tests/framework/test_reference.py"
"""docs/reference.md against the classes: a component's declared contract (defaults,
ranges, operation access) is behaviour its users rely on."""

SAFETY_CORE: dict[str, list[str]] = {
    "framework/statechart/interpreter.py": ["tests/framework/statechart/test_interpreter.py"],
    "framework/configurator.py": ["tests/framework/test_configurator.py", REFERENCE],
    "framework/coordinator.py": ["tests/framework/test_coordinator.py", REFERENCE],
    "framework/safety.py": ["tests/framework/test_safety.py"],
    "components/tracking/sensor_manager.py": [
        "tests/components/tracking/test_sensor_manager.py",
        "tests/components/tracking/test_sensor_history.py",
        "tests/components/tracking/test_sensor_manager_component.py",
        REFERENCE,
    ],
    "components/supervisor/supervisor.py": [
        "tests/components/supervisor/test_supervisor.py",
        "tests/components/supervisor/test_supervisor_component.py",
        REFERENCE,
    ],
    "components/robot/interface.py": [
        "tests/components/robot/test_interface.py",
        "tests/components/robot/test_robot_components.py",
        REFERENCE,
    ],
    "components/domain/separation.py": [
        "tests/components/domain/test_separation.py",
        "tests/components/domain/test_separation_walking.py",
    ],
    "components/robot/interpolator.py": [
        "tests/components/robot/test_interpolator.py",
        "tests/components/robot/test_interpolator_component.py",
        # holds the compiled kernel's path pose to the module's numpy fallback
        "tests/components/domain/test_kernel.py",
        REFERENCE,
    ],
    "components/tracking/frame_clock.py": ["tests/components/tracking/test_frame_clock.py"],
    "components/domain/fri.py": [
        "tests/components/domain/test_fri.py",
        # holds the compiled kernel's datagrams to the module's struct references
        "tests/components/domain/test_kernel.py",
    ],
}
"""The modules that keep the robot safe, each with its own fast tests."""

FAMILIES = {"cosmic-ray": 0.90, "fw": 0.95}
"""The two families of mutants and the score each must reach in every module."""

SKIPPED_OPERATORS = ("core/VariableReplacer", "core/VariableInserter")
"""Random variable swaps (they need arguments and are not reproducible)."""


@dataclass
class Mutant:
    """One change to one module."""

    module: str
    operator: str
    occurrence: int
    line: int
    before: str
    after: str
    code: str = field(repr=False)
    status: str = ""
    detail: str = ""

    @property
    def short(self) -> str:
        """The operator without cosmic-ray's (or this tool's) prefix."""
        return self.operator.removeprefix("core/").removeprefix("fw/")


def annotation_lines(code: str) -> set[tuple[int, int, int, int]]:
    """Spans (line, col, end line, end col) of every annotation in `code`."""
    spans = set()
    for node in ast.walk(ast.parse(code)):
        found = []
        if isinstance(node, ast.arg) and node.annotation is not None:
            found.append(node.annotation)
        elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and node.returns:
            found.append(node.returns)
        elif isinstance(node, ast.AnnAssign):
            found.append(node.annotation)
        for item in found:
            spans.add((item.lineno, item.col_offset, item.end_lineno, item.end_col_offset))
    return spans


def _inside(position: tuple[int, int], spans: set[tuple[int, int, int, int]]) -> bool:
    line, col = position
    return any((l0, c0) <= (line, col) < (l1, c1) for l0, c0, l1, c1 in spans)


def make_mutants(module: str, lines: tuple[int, int] | None = None) -> list[Mutant]:
    """Every mutant cosmic-ray's operators make of `module` (outside annotations)."""
    from cosmic_ray.ast import ast_nodes, get_ast
    from cosmic_ray.mutating import mutate_code
    from cosmic_ray.plugins import get_operator, operator_names

    code = (REPO / module).read_text(encoding="utf-8")
    original = code.splitlines()
    tree = get_ast(code)
    skip = annotation_lines(code)
    mutants: list[Mutant] = []
    for name in operator_names():
        if name in SKIPPED_OPERATORS:
            continue
        operator = get_operator(name)()
        positions = [
            start for node in ast_nodes(tree) for start, _ in operator.mutation_positions(node)
        ]
        for occurrence, start in enumerate(positions):
            if _inside(start, skip) or (lines and not lines[0] <= start[0] <= lines[1]):
                continue
            try:
                mutated = mutate_code(code, operator, occurrence)
            except Exception as exc:  # cosmic-ray cannot make this one (a dotted name
                # in an `except (A, b.C)` tuple trips its ExceptionReplacer): say so
                print(f"  {module}:{start[0]} {name}: not made ({exc})", file=sys.stderr)
                continue
            if mutated is None or mutated == code:
                continue
            changed = mutated.splitlines()
            row = start[0] - 1
            before = original[row].strip() if row < len(original) else ""
            after = changed[row].strip() if row < len(changed) else ""
            if len(changed) != len(original):  # a removed line (decorator, handler)
                after = "(removed) " + after
            mutants.append(Mutant(module, name, occurrence, start[0], before, after, mutated))
    return sorted(mutants, key=lambda m: (m.line, m.operator, m.occurrence))


def fw_mutants(module: str, lines: tuple[int, int] | None = None) -> list[Mutant]:
    """Every mutant fw's own operators make of `module` (tools/mutation_operators.py);
    each keeps the line count, so line numbers match the original."""
    code = (REPO / module).read_text(encoding="utf-8")
    original = code.splitlines()
    mutants = []
    for n, change in enumerate(fw_changes(code, lines)):
        before = original[change.first].strip()
        after = change.lines[0].strip()
        mutants.append(
            Mutant(module, change.operator, n, change.line, before, after, apply(code, change))
        )
    return mutants


def load_equivalents() -> list[dict[str, str]]:
    """The mutants known to change nothing, with why (tools/mutation_equivalents.yaml)."""
    if not EQUIVALENTS.exists():
        return []
    from framework.yamlio import YamlError, load_yaml

    try:
        entries = load_yaml(EQUIVALENTS).data
    except YamlError as exc:  # a hand-edited list: say where, not a traceback
        raise SystemExit(f"fw mutation: {exc}") from None
    return list(entries or [])


@functools.lru_cache(maxsize=64)
def _functions(module: str) -> tuple[tuple[int, int, str], ...]:
    """(first line, last line, name) of every function of `module` as it is now."""
    try:
        tree = ast.parse((REPO / module).read_text(encoding="utf-8"))
    except (OSError, SyntaxError):
        return ()
    return tuple(
        (node.lineno, node.end_lineno or node.lineno, node.name)
        for node in ast.walk(tree)
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
    )


def enclosing_function(module: str, line: int) -> str:
    """The name of the innermost function of `module` around `line` ("" at module or
    class level): the same text means different things in configure_hook and in a
    cycle, and an equivalents entry may say which it means."""
    around = [(first, name) for first, last, name in _functions(module) if first <= line <= last]
    return max(around)[1] if around else ""


def listed(mutant: Mutant, item: dict[str, str]) -> bool:
    """Whether the equivalents entry `item` names `mutant` (see `equivalent_reason`)."""
    if item.get("module") != mutant.module:
        return False
    if "function" in item and enclosing_function(mutant.module, mutant.line) != item["function"]:
        return False
    if "changed" in item or "where" in item:
        changed = re.compile(str(item.get("changed", "")))
        where = re.compile(str(item.get("where", "")))
        return bool(
            mutant.short in item.get("operators", ())
            and where.search(mutant.before)
            and changed.search(mutant.after)
            and ("changed" not in item or not changed.search(mutant.before))
        )
    return (
        item.get("operator") == mutant.short
        and item.get("before", "").strip() == mutant.before
        and item.get("after", "").strip() == mutant.after
    )


def cosmic_ray_installed() -> bool:
    """Whether cosmic-ray (the `mutation` extra) can be imported: only its family of
    mutants needs it; fw's own operators need nothing beyond the standard library."""
    import importlib.util

    return importlib.util.find_spec("cosmic_ray") is not None


def family_of(item: dict[str, str]) -> str:
    """The family whose operators an equivalents entry names ("fw" or "cosmic-ray")."""
    names = [item.get("operator", ""), *item.get("operators", ())]
    fw = {name.split("/")[-1] for name in FW_OPERATORS}
    return "fw" if all(name in fw for name in names if name) else "cosmic-ray"


def unused_equivalents(
    modules: list[str], families: list[str] | None = None
) -> list[dict[str, str]]:
    """The equivalents entries of `modules` (of the named families, default both) that
    no mutant of their code as it is now matches: the line they name was changed or
    removed, so the entry hides nothing and should go (or be written for the new line)."""
    families = families or list(FAMILIES)
    known = [
        item
        for item in load_equivalents()
        if item.get("module") in modules and family_of(item) in families
    ]
    unused = []
    for module in modules:
        entries = [item for item in known if item.get("module") == module]
        if not entries or not (REPO / module).is_file():
            unused += entries
            continue
        mutants = fw_mutants(module) if "fw" in families else []
        if "cosmic-ray" in families:
            mutants += make_mutants(module)
        unused += [item for item in entries if not any(listed(m, item) for m in mutants)]
    return unused


def equivalent_reason(mutant: Mutant, known: list[dict[str, str]]) -> str:
    """Why `mutant` is equivalent, or "" if it is not listed. An entry names one mutant
    (operator, before, after), or a kind of them: `operators` with `changed`, a pattern
    the mutated line matches and the original does not (`== Kind.X` where `is Kind.X`
    was: an Enum member compared by value instead of identity), and/or `where`, a
    pattern of the original line (every such mutant of a placeholder's value). Either
    may add `function`: only mutants inside the function of that name."""
    for item in known:
        if listed(mutant, item):
            return str(item.get("reason", "listed as equivalent"))
    return ""


FORK_SERVER = r"""
import atexit, json, os, signal, sys, time
import hypothesis, jsonschema, numpy, pytest, yaml  # the slow imports, once
os.makedirs(os.environ["FW_KEYS"], exist_ok=True)
print("ready", flush=True)
for line in sys.stdin:
    tests, timeout = json.loads(line)
    pid = os.fork()
    if pid == 0:
        os.setsid()
        quiet = os.open(os.devnull, os.O_WRONLY)
        os.dup2(quiet, 1)
        os.dup2(quiet, 2)
        try:
            code = pytest.main(
                ["-x", "-q", "-p", "no:cacheprovider", "-p", "no:randomly", *tests]
            )
            atexit._run_exitfuncs()
        except BaseException:
            code = 99
        os._exit(int(code))
    end = last = time.monotonic()
    end += timeout
    outcome = "timeout"
    while (now := time.monotonic()) < end:
        if now - last > 1.0:  # the run was paused (SIGSTOP): the pause is no test time
            end += now - last
        last = now
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            outcome = "passed" if os.waitstatus_to_exitcode(status) == 0 else "failed"
            break
        time.sleep(0.005)
    else:
        try:
            os.killpg(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        os.waitpid(pid, 0)
    print(outcome, flush=True)
"""
"""The test server of a workspace (see `Workspace.pytest`). A run paused with SIGSTOP
(to measure something else on a quiet host) and continued is not a timeout: time
the server did not run is not counted."""


class Workspace:
    """A private copy of the repository's tracked files and of the compiled extensions
    the package's build put beside them (untracked: without them the copy would run
    numpy's fallbacks, and mutants of the lines that call the compiled kernel would
    never run), where one mutant at a time is written and tested."""

    def __init__(self, root: Path):
        self.root = root
        self._server: subprocess.Popen[str] | None = None
        listed = ["git", "ls-files", "-z"]
        built = [*listed, "--others", "--ignored", "--exclude-standard", "--", "*.so"]
        files = [
            name
            for command in (listed, built)
            for name in subprocess.run(
                command, cwd=REPO, capture_output=True, check=True
            ).stdout.split(b"\0")
        ]
        for name in filter(None, files):
            source = REPO / name.decode()
            if source.is_file():
                target = root / name.decode()
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(source, target)

    def env(self) -> dict[str, str]:
        env = dict(os.environ, PYTHONPATH=str(self.root), PYTHONDONTWRITEBYTECODE="1")
        env.pop("CI", None)
        return env

    def pytest(self, tests: list[str], timeout: float) -> str:
        """Run the tests here: 'passed', 'failed' or 'timeout'. Each run is a fork of a
        server that imported the slow third-party packages once (pytest, hypothesis,
        numpy...), so a mutant costs its tests, not an interpreter start; the project's
        own modules are imported afresh by every run."""
        if self._server is None or self._server.poll() is not None:
            self._server = subprocess.Popen(
                [sys.executable, "-c", FORK_SERVER],
                cwd=self.root,
                env=dict(self.env(), FW_KEYS=str(self.root / ".keys")),
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL,
                text=True,
            )
            assert self._server.stdout is not None
            if self._server.stdout.readline().strip() != "ready":
                raise SystemExit("the mutation test server did not start")
        assert self._server.stdin is not None and self._server.stdout is not None
        self._server.stdin.write(json.dumps([tests, timeout]) + "\n")
        self._server.stdin.flush()
        return self._server.stdout.readline().strip() or "failed"

    def close(self) -> None:
        """Stop the test server."""
        if self._server is not None and self._server.poll() is None:
            self._server.kill()
            self._server.wait()

    def test(self, mutant: Mutant, rounds: list[list[str]], timeout: float) -> str:
        """Test one mutant (its module is restored afterwards): each round of tests in
        turn, until one fails or times out. The first round is the tests seen running
        the mutated line (quick to fail), the last all of them (so a survivor is one
        the whole set lets through)."""
        path = self.root / mutant.module
        original = path.read_text(encoding="utf-8")
        try:
            path.write_text(mutant.code, encoding="utf-8")
            outcome = "passed"
            for tests in rounds:
                outcome = self.pytest(tests, timeout)
                if outcome != "passed":
                    break
            return outcome
        finally:
            path.write_text(original, encoding="utf-8")


def statement_starts(code: str) -> dict[int, int]:
    """For every line of `code`, the first line of the innermost statement spanning it:
    coverage counts a statement written over several lines on its first line only."""
    spans = sorted(
        (
            (node.end_lineno - node.lineno, node.lineno, node.end_lineno)
            for node in ast.walk(ast.parse(code))
            if isinstance(node, ast.stmt) and node.end_lineno is not None
        ),
        reverse=True,
    )
    starts: dict[int, int] = {}
    for _, first, last in spans:  # widest first: inner statements overwrite outer ones
        for line in range(first, last + 1):
            starts[line] = first
    return starts


def covering_tests(space: Workspace, module: str, tests: list[str]) -> dict[int, list[str]] | None:
    """For every line of `module` the unmutated tests execute (in the test process or in
    any process it starts), the test functions seen running it, as pytest node ids (an
    empty list when only code outside a test function ran it: a fixture, a thread, a
    subprocess). None if coverage cannot say."""
    rc = space.root / ".coveragerc.mutation"
    rc.write_text(
        f"[run]\nparallel = true\npatch = subprocess\ndynamic_context = test_function\n"
        f"include = {module}\ndata_file = {space.root / '.coverage.mutation'}\n"
    )
    env = dict(space.env(), COVERAGE_RCFILE=str(rc))
    quiet = {
        "cwd": space.root,
        "env": env,
        "stdout": subprocess.DEVNULL,
        "stderr": subprocess.DEVNULL,
    }
    coverage = [sys.executable, "-m", "coverage"]
    subprocess.run(
        [*coverage, "run", "-m", "pytest", "-q", "-p", "no:cacheprovider", *tests], **quiet
    )
    subprocess.run([*coverage, "combine"], **quiet)
    report = space.root / "coverage.json"
    subprocess.run([*coverage, "json", "--show-contexts", "-o", str(report)], **quiet)
    if not report.exists():
        return None
    starts = statement_starts((space.root / module).read_text(encoding="utf-8"))
    for name, info in json.loads(report.read_text())["files"].items():
        if name.endswith(module):
            contexts = info.get("contexts", {})
            executed = {
                line: sorted(
                    {node for c in contexts.get(str(line), []) if (node := _node_id(space, c))}
                )
                for line in info["executed_lines"]
            }
            # a line inside a multi-line statement ran if the statement did
            return {
                line: executed[first] for line, first in starts.items() if first in executed
            } | executed
    return None


def _node_id(space: Workspace, context: str) -> str:
    """The pytest node id of a coverage test-function context
    ('tests.a.test_b.TestC.test_d' -> 'tests/a/test_b.py::TestC::test_d'), or ''."""
    parts = context.split(".") if context else []
    for cut in range(len(parts) - 1, 0, -1):
        path = "/".join(parts[:cut]) + ".py"
        if (space.root / path).is_file():
            return path + "::" + "::".join(parts[cut:])
    return ""


CACHE = REPO / ".mutation-cache"
"""Mutants caught by runs that did not finish, per module and family (not tracked)."""


class Caught:
    """The mutants of one module's exact code that a run already caught (killed or
    timed out), kept as the run goes so a long run that is stopped (a sitting ends, the
    host is needed) goes on where it stopped: run again on the same code, it tests only
    the rest. Keyed by the module's code: any edit of the module starts afresh. Tests
    only grow between sittings, so a mutant they caught stays caught; survivors are
    always tested again. `--fresh` ignores what is kept."""

    def __init__(self, module: str, family: str, fresh: bool = False):
        code = (REPO / module).read_text(encoding="utf-8")
        self.digest = hashlib.sha256(code.encode()).hexdigest()
        self.path = CACHE / f"{module.replace('/', '__')}.{family}.json"
        self.statuses: dict[str, str] = {}
        if not fresh and self.path.exists():
            try:
                kept = json.loads(self.path.read_text(encoding="utf-8"))
            except (OSError, ValueError):
                kept = {}
            if kept.get("code") == self.digest:
                self.statuses = dict(kept.get("caught", {}))

    @staticmethod
    def key(mutant: Mutant) -> str:
        """A mutant's name within its module's code: operator, occurrence and line."""
        return f"{mutant.operator}#{mutant.occurrence}@{mutant.line}"

    def get(self, mutant: Mutant) -> str:
        """ "killed" or "timeout" if a run of this code caught it, else ""."""
        return self.statuses.get(self.key(mutant), "")

    def add(self, mutant: Mutant) -> None:
        """Keep `mutant`'s status if it was caught (written at once: a stop loses none)."""
        if mutant.status not in ("killed", "timeout"):
            return
        self.statuses[self.key(mutant)] = mutant.status
        self.path.parent.mkdir(parents=True, exist_ok=True)
        partial = self.path.with_suffix(".tmp")
        partial.write_text(json.dumps({"code": self.digest, "caught": self.statuses}))
        partial.replace(self.path)


def run_module(
    module: str,
    tests: list[str],
    jobs: int,
    lines: tuple[int, int] | None,
    coverage: bool,
    family: str = "cosmic-ray",
    mutants: list[Mutant] | None = None,
    fresh: bool = False,
) -> list[Mutant]:
    """Make and test every mutant of `module` of one family (`FAMILIES`), or only
    `mutants`; returns them with their status. Mutants an earlier run of the same code
    caught are not tested again unless `fresh` (`Caught`)."""
    known = load_equivalents()
    if mutants is None:
        mutants = fw_mutants(module, lines) if family == "fw" else make_mutants(module, lines)
    print(f"{module}: {len(mutants)} {family} mutants; tests: {' '.join(tests)}", flush=True)
    caught = Caught(module, family, fresh)
    base = Path(tempfile.mkdtemp(prefix="fw-mutation-"))
    spaces: list[Workspace] = []
    try:
        spaces += [Workspace(base / f"w{i}") for i in range(max(1, jobs))]
        started = time.monotonic()
        if spaces[0].pytest(tests, timeout=1800) != "passed":
            raise SystemExit(f"{module}: its tests fail without any mutant: fix them first")
        normal = time.monotonic() - started
        timeout = 3 * normal + 10
        covering = covering_tests(spaces[0], module, tests) if coverage else None
        print(f"  the tests take {normal:.1f} s; a mutant gets {timeout:.0f} s", flush=True)
        todo: queue.Queue[Mutant] = queue.Queue()
        earlier = 0
        for mutant in mutants:
            reason = equivalent_reason(mutant, known)
            if reason:
                mutant.status, mutant.detail = "equivalent", reason
            elif caught.get(mutant):
                mutant.status = caught.get(mutant)
                earlier += 1
            else:
                todo.put(mutant)
        if earlier:
            print(
                f"  {earlier} caught by an earlier run of this code, not run again "
                f"(kept in {caught.path.relative_to(REPO)}; --fresh runs them)",
                flush=True,
            )
        total, done = todo.qsize(), [0]
        lock = threading.Lock()

        def work(space: Workspace) -> None:
            while True:
                try:
                    mutant = todo.get_nowait()
                except queue.Empty:
                    return
                first = (covering or {}).get(mutant.line, [])
                outcome = space.test(mutant, [first, tests] if first else [tests], timeout)
                mutant.status = {"failed": "killed", "passed": "survived"}.get(outcome, outcome)
                with lock:
                    caught.add(mutant)
                    done[0] += 1
                    if mutant.status != "killed" or done[0] % 25 == 0 or done[0] == total:
                        print(
                            f"  [{done[0]}/{total}] {mutant.status:<8} {module}:{mutant.line} "
                            f"{mutant.short}: {mutant.before} -> {mutant.after}",
                            flush=True,
                        )

        threads = [threading.Thread(target=work, args=(s,)) for s in spaces]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
    finally:
        for space in spaces:
            space.close()
        shutil.rmtree(base, ignore_errors=True)
    return mutants


def score(mutants: list[Mutant]) -> dict[str, float]:
    """Counts per status and the score (see the module docstring)."""
    counts = Counter(m.status for m in mutants)
    counted = len(mutants) - counts["equivalent"]
    caught = counts["killed"] + counts["timeout"]
    return {
        "mutants": len(mutants),
        "killed": counts["killed"],
        "timeout": counts["timeout"],
        "survived": counts["survived"],
        "not run": counts["not run"],
        "equivalent": counts["equivalent"],
        "score": caught / counted if counted else 1.0,
    }


def _marker(module: str, family: str) -> str:
    """The name of a module's section of one family in the report."""
    return f"mutation:{module}" if family == "cosmic-ray" else f"mutation-fw:{module}"


def section(
    module: str,
    tests: list[str],
    mutants: list[Mutant],
    rescored: bool = False,
    family: str = "cosmic-ray",
    again: bool = False,
) -> str:
    """The report's markdown section of one module and family."""
    s = score(mutants)
    how = " (rescored: the run's survivors against today's equivalents list)" if rescored else ""
    if again:
        how = " (the last full run's survivors tested again against today's tests and equivalents)"
    title = "cosmic-ray's operators" if family == "cosmic-ray" else "fw's own operators"
    counts = Counter(m.short for m in mutants)
    per_operator = ", ".join(f"{name} {n}" for name, n in sorted(counts.items()))
    lines = [
        f"<!-- {_marker(module, family)} -->",
        f"### `{module}`: {title}",
        "",
        f"{time.strftime('%Y-%m-%d')}{how}, tests: {', '.join(f'`{t}`' for t in tests)}",
        "",
        "| mutants | killed | timeout | survived | not run | equivalent | score |",
        "|---|---|---|---|---|---|---|",
        f"| {s['mutants']} | {s['killed']} | {s['timeout']} | {s['survived']} | {s['not run']} "
        f"| {s['equivalent']} | {s['score']:.1%} |",
        "",
    ]
    if family == "fw" and per_operator and not rescored:
        lines += [f"Mutants per operator: {per_operator}.", ""]
    left = [m for m in mutants if m.status in ("survived", "not run")]
    if left:
        lines += ["Survivors:", ""]
        lines += [
            f"- {m.module}:{m.line} {m.short}{' (not run)' if m.status == 'not run' else ''}: "
            f"`{m.before}` -> `{m.after}`"
            for m in left
        ]
        lines.append("")
    same = [m for m in mutants if m.status == "equivalent"]
    if same:
        lines += ["Equivalent:", ""]
        lines += [f"- {m.module}:{m.line} {m.short}: {m.detail}" for m in same]
        lines.append("")
    lines.append(f"<!-- /{_marker(module, family)} -->")
    return "\n".join(lines)


HEAD = (
    "# Mutation scores of the safety core\n\n"
    "Regenerated by `python tools/mutation.py MODULE...` (see its docstring): each "
    "module's mutants against its own fast tests, in two families scored apart: "
    "cosmic-ray's operators (target 90%) and fw's own (`tools/mutation_operators.py`: "
    "statement deletion, a variable swapped for another of its type, `min`/`max` "
    "swapped, a `None` check made a truthiness test, a line moved; target 95%).\n"
)


def write_report(module: str, text: str, family: str = "cosmic-ray") -> None:
    """Replace (or add) this module's section of one family in docs/results/mutation.md."""
    current = REPORT.read_text(encoding="utf-8") if REPORT.exists() else HEAD
    marker = re.escape(_marker(module, family))
    pattern = re.compile(rf"<!-- {marker} -->.*?<!-- /{marker} -->", re.S)
    if pattern.search(current):
        current = pattern.sub(lambda _: text, current)
    else:
        current = current.rstrip("\n") + "\n\n" + text + "\n"
    table = summary(current)
    marked = re.compile(r"<!-- summary -->.*?<!-- /summary -->", re.S)
    if marked.search(current):
        current = marked.sub(lambda _: table, current)
    else:
        first = current.find("<!-- mutation")
        current = current[:first] + table + "\n\n" + current[first:]
    REPORT.parent.mkdir(parents=True, exist_ok=True)
    REPORT.write_text(current, encoding="utf-8")


def _sections(report: str) -> dict[tuple[str, str], tuple[str, ...]]:
    """(module, family) -> (mutants, survived + not run, equivalent, score, run) of
    every section of the report."""
    found = {}
    for match in re.finditer(
        r"<!-- mutation(?P<fw>(?:-fw)?):(?P<module>\S+) -->(?P<body>.*?)"
        r"<!-- /mutation(?P=fw):(?P=module) -->",
        report,
        re.S,
    ):
        body = match.group("body")
        counts = re.search(
            r"^\| (\d+) \| (\d+) \| (\d+) \| (\d+) \| (\d+) \| (\d+) \| (.+?) \|$", body, re.M
        )
        when = re.search(r"^(\d{4}-\d\d-\d\d)( \(rescored)?", body, re.M)
        if counts is None:
            continue
        mutants, _, _, survived, not_run, equivalent, score_text = counts.groups()
        run = (when.group(1) + (", rescored" if when.group(2) else "")) if when else ""
        family = "fw" if match.group("fw") else "cosmic-ray"
        found[(match.group("module"), family)] = (
            mutants,
            str(int(survived) + int(not_run)),
            equivalent,
            score_text,
            run,
        )
    return found


def summary(report: str) -> str:
    """One row per reported module: each family's mutants, survivors, equivalents,
    score and run date."""
    found = _sections(report)
    rows = [
        "<!-- summary -->",
        "| module | cosmic-ray: mutants | survived | equivalent | score | run "
        "| fw's: mutants | survived | equivalent | score | run |",
        "|---|---:|---:|---:|---:|---|---:|---:|---:|---:|---|",
    ]
    for module in dict.fromkeys(m for m, _ in found):
        cells = []
        for family in FAMILIES:
            cells += found.get((module, family), ("", "", "", "not run yet", ""))
        rows.append(f"| `{module}` | " + " | ".join(cells) + " |")
    rows.append("<!-- /summary -->")
    return "\n".join(rows)


_SURVIVOR = re.compile(
    r"^- (?P<module>[^:]+):(?P<line>\d+) (?P<op>\w+)(?P<nr> \(not run\))?: `(?P<before>.*)` -> `(?P<after>.*)`$"
)
_EQUIVALENT = re.compile(r"^- (?P<module>[^:]+):(?P<line>\d+) (?P<op>\w+): (?P<reason>.*)$")


def rescored(module: str, family: str = "cosmic-ray") -> tuple[list[Mutant], list[str]]:
    """The module's last reported run of a family with the current equivalents list
    applied: its survivors that the list now explains are set aside (an equivalence is
    a judgement about the code, not a test outcome). Also the tests that run used."""
    current = REPORT.read_text(encoding="utf-8") if REPORT.exists() else ""
    marker = re.escape(_marker(module, family))
    match = re.search(rf"<!-- {marker} -->(.*?)<!-- /{marker} -->", current, re.S)
    if match is None:
        raise SystemExit(f"{module}: no reported {family} run to rescore (run it once in full)")
    text = match.group(1)
    tests = re.findall(r"`(tests/[^`]+)`", text.split("|", 1)[0])
    row = re.search(r"^\| (\d+) \| (\d+) \| (\d+) \| (\d+) \| (\d+) \| (\d+) \|", text, re.M)
    assert row is not None, f"{module}: no table in the report"
    _, killed, timeout, _, _, _ = (int(v) for v in row.groups())
    known = load_equivalents()
    prefix = "fw/" if family == "fw" else "core/"
    mutants = [Mutant(module, "", 0, 0, "", "", "", "killed") for _ in range(killed)]
    mutants += [Mutant(module, "", 0, 0, "", "", "", "timeout") for _ in range(timeout)]
    part = "survivors"
    for line in text.splitlines():
        if line.startswith("Equivalent:"):
            part = "equivalent"
        found = (_SURVIVOR if part == "survivors" else _EQUIVALENT).match(line)
        if found is None:
            continue
        op = prefix + found["op"]
        if part == "equivalent":
            mutants.append(
                Mutant(module, op, 0, int(found["line"]), "", "", "", "equivalent", found["reason"])
            )
            continue
        mutant = Mutant(module, op, 0, int(found["line"]), found["before"], found["after"], "")
        mutant.status = "not run" if found["nr"] else "survived"
        reason = equivalent_reason(mutant, known)
        if reason:
            mutant.status, mutant.detail = "equivalent", reason
        mutants.append(mutant)
    return mutants, tests


def survivors_again(
    module: str, family: str, jobs: int, coverage: bool, tests: list[str]
) -> tuple[list[Mutant], list[str], int]:
    """The module's last reported run of a family, its survivors tested again against
    today's tests (specs written since kill some): the same mutants, made afresh from
    the code as it is and matched by operator and line text; a survivor whose line was
    edited since has no such mutant any more and stays a survivor. Also the tests and
    how many survivors were found again. `tests` are today's (the map may have grown)."""
    reported, _ = rescored(module, family)
    fresh = fw_mutants(module) if family == "fw" else make_mutants(module)
    pool: dict[tuple[str, str, str], list[Mutant]] = {}
    for mutant in fresh:
        pool.setdefault((mutant.short, mutant.before, mutant.after), []).append(mutant)
    again: list[tuple[Mutant, Mutant]] = []
    for old in reported:
        if old.status not in ("survived", "not run"):
            continue
        candidates = pool.get((old.short, old.before, old.after), [])
        if candidates:
            nearest = min(candidates, key=lambda m: abs(m.line - old.line))
            candidates.remove(nearest)
            again.append((old, nearest))
    if again:
        run_module(module, tests, jobs, None, coverage, family, [new for _, new in again])
    for old, new in again:
        old.status, old.line = new.status, new.line
    return reported, tests, len(again)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog=__doc__.split("\n\n", 2)[1],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("modules", nargs="*", metavar="MODULE", help="e.g. framework/safety.py")
    parser.add_argument("--core", action="store_true", help="every module of the safety core")
    parser.add_argument("--tests", nargs="+", metavar="PATH", help="tests to run (default: map)")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1, metavar="N")
    parser.add_argument("--lines", metavar="A-B", help="only mutants on these lines")
    parser.add_argument(
        "--no-coverage", action="store_true", help="no coverage run: every mutant meets all tests"
    )
    parser.add_argument("--no-report", action="store_true", help="do not update the report")
    parser.add_argument(
        "--operators",
        choices=["cosmic-ray", "fw", "both"],
        default="both",
        help="which family of mutants (default: both, each scored apart)",
    )
    parser.add_argument(
        "--unused",
        action="store_true",
        help="no run: list the equivalents entries no mutant of the code as it is matches",
    )
    parser.add_argument(
        "--survivors",
        action="store_true",
        help="test only the reported run's survivors again, against today's tests",
    )
    parser.add_argument(
        "--fresh",
        action="store_true",
        help="test every mutant, also those an unfinished run of the same code caught",
    )
    parser.add_argument(
        "--rescore",
        action="store_true",
        help="no run: apply the current equivalents list to the module's reported run",
    )
    args = parser.parse_args(argv)
    modules = list(SAFETY_CORE) if args.core else args.modules
    if not modules:
        parser.error("name a MODULE (or --core)")
    families = list(FAMILIES) if args.operators == "both" else [args.operators]
    if "cosmic-ray" in families and not cosmic_ray_installed():
        parser.error(
            "cosmic-ray is missing: pip install -e '.[mutation]' (or --operators fw, "
            "fw's own operators, which need nothing more)"
        )
    if args.unused:
        stale = unused_equivalents(modules, families)
        for item in stale:
            what = item.get("operator") or "/".join(item.get("operators", ()))
            text = item.get("before") or item.get("where") or item.get("changed")
            print(f"{item['module']}: {what}: {text}: matches no mutant of the code as it is")
        print(f"{len(stale)} unused equivalents entries")
        return 1 if stale else 0
    lines = None
    if args.lines:
        first, _, last = args.lines.partition("-")
        lines = (int(first), int(last or first))
    failed = False
    for module in modules:
        if not (REPO / module).is_file():
            parser.error(f"no such module: {module}")
        tests = args.tests or SAFETY_CORE.get(module)
        if not tests:
            parser.error(f"{module} has no tests in the map: give --tests")
        missing = [t for t in tests if not (REPO / t).exists()]
        if missing:
            parser.error(f"no such tests: {', '.join(missing)}")
        for family in families:
            if args.survivors:
                mutants, tests, found = survivors_again(
                    module, family, args.jobs, not args.no_coverage, tests
                )
                print(f"{module}: {found} survivors of the reported run tested again")
            elif args.rescore:
                mutants, tests = rescored(module, family)
            else:
                mutants = run_module(
                    module, tests, args.jobs, lines, not args.no_coverage, family, None, args.fresh
                )
            text = section(
                module, tests, mutants, args.rescore or args.survivors, family, args.survivors
            )
            print(text)
            if not args.no_report and lines is None:
                write_report(module, text, family)
            result = score(mutants)["score"]
            if result < FAMILIES[family]:
                print(f"{module}: {family} {result:.1%} is under {FAMILIES[family]:.0%}")
                failed = True
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
