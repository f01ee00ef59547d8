"""Spec: the mutation tool's bookkeeping: which mutants a reviewer listed as equivalent,
and the summary table of docs/results/mutation.md."""

import sys

import pytest

from tests.conftest import REPO

sys.path.insert(0, str(REPO / "tools"))
import mutation


def mutant(operator, before, after, module="framework/x.py"):
    return mutation.Mutant(module, f"core/{operator}", 0, 1, before, after, "")


KNOWN = [
    {
        "module": "framework/x.py",
        "operator": "NumberReplacer",
        "before": "x = 0",
        "after": "x = 1",
        "reason": "overwritten",
    },
    {
        "module": "framework/x.py",
        "operators": ["ReplaceComparisonOperator_Is_Eq"],
        "changed": r"== Kind\.\w+",
        "reason": "an Enum",
    },
    {
        "module": "framework/x.py",
        "operators": ["NumberReplacer"],
        "where": r"^_NEVER = ",
        "reason": "a placeholder",
    },
]


def test_a_listed_mutant_is_equivalent_only_in_its_module_and_exactly_as_listed():
    assert mutation.equivalent_reason(mutant("NumberReplacer", "x = 0", "x = 1"), KNOWN)
    assert not mutation.equivalent_reason(mutant("NumberReplacer", "x = 0", "x = -1"), KNOWN)
    other = mutant("NumberReplacer", "x = 0", "x = 1", module="framework/y.py")
    assert not mutation.equivalent_reason(other, KNOWN)


def test_a_kind_of_mutant_is_matched_by_what_the_mutation_introduced():
    enum = mutant("ReplaceComparisonOperator_Is_Eq", "if k is Kind.A:", "if k == Kind.A:")
    assert mutation.equivalent_reason(enum, KNOWN) == "an Enum"
    already = mutant(
        "ReplaceComparisonOperator_Is_Eq", "a == Kind.A and b is c", "a == Kind.A and b == c"
    )
    assert not mutation.equivalent_reason(already, KNOWN), "the pattern was there before"
    placeholder = mutant("NumberReplacer", "_NEVER = (0.0, 1.0)", "_NEVER = (1.0, 1.0)")
    assert mutation.equivalent_reason(placeholder, KNOWN) == "a placeholder"
    elsewhere = mutant("NumberReplacer", "limit = 1.0", "limit = 2.0")
    assert not mutation.equivalent_reason(elsewhere, KNOWN)


def test_an_entry_may_name_the_function_its_mutants_are_in(tmp_path, monkeypatch):
    """The same line means different things in a setup and in a cycle: an entry that
    names its function lists only the mutants inside it."""
    (tmp_path / "framework").mkdir()
    (tmp_path / "framework" / "z.py").write_text(
        "def setup():\n    n = 0\n\n\nclass C:\n    def count(self):\n        n = 0\n"
    )
    monkeypatch.setattr(mutation, "REPO", tmp_path)
    mutation._functions.cache_clear()
    known = [
        {
            "module": "framework/z.py",
            "operators": ["DeleteStatement"],
            "where": "^n = 0$",
            "function": "setup",
            "reason": "set again before it is read",
        }
    ]

    def deleted(line):
        return mutation.Mutant("framework/z.py", "fw/DeleteStatement", 0, line, "n = 0", "pass", "")

    assert mutation.equivalent_reason(deleted(2), known)
    assert not mutation.equivalent_reason(deleted(7), known)
    assert mutation.enclosing_function("framework/z.py", 7) == "count"
    assert mutation.enclosing_function("framework/z.py", 5) == ""
    mutation._functions.cache_clear()


SECTION = """<!-- mutation{fw}:framework/x.py -->
### `framework/x.py`

2026-11-23 (rescored: ...), tests: `tests/x.py`

| mutants | killed | timeout | survived | not run | equivalent | score |
|---|---|---|---|---|---|---|
| {n} | 80 | 2 | 8 | 1 | 9 | 90.1% |
<!-- /mutation{fw}:framework/x.py -->"""


def test_the_summary_has_a_row_per_reported_module_with_each_family_apart():
    cosmic = SECTION.format(fw="", n=100)
    table = mutation.summary("# head\n\n" + cosmic)
    row = table.splitlines()[3]
    assert row.startswith("| `framework/x.py` | 100 | 9 | 9 | 90.1% | 2026-11-23, rescored |")
    assert "not run yet" in row, "fw's family has no run yet: the row says so"
    both = mutation.summary("# head\n\n" + cosmic + "\n\n" + SECTION.format(fw="-fw", n=55))
    assert both.splitlines()[3].endswith("| 55 | 9 | 9 | 90.1% | 2026-11-23, rescored |")
    assert table.startswith("<!-- summary -->") and table.endswith("<!-- /summary -->")


def make(tmp_path, monkeypatch, source):
    (tmp_path / "m.py").write_text(source)
    monkeypatch.setattr(mutation, "REPO", tmp_path)
    mutants = mutation.fw_mutants("m.py")
    for m in mutants:
        compile(m.code, "m.py", "exec")
        assert len(m.code.splitlines()) == len(source.splitlines()), (m.short, m.after)
    return mutants


def test_statement_deletions_keep_the_module_valid_and_its_line_numbers(tmp_path, monkeypatch):
    source = '''"""A module."""


def f(x):
    """Docstring stays."""
    y = x + 1
    if y:
        print(
            y,
        )
    return y
'''
    mutants = make(tmp_path, monkeypatch, source)
    deleted = [(m.line, m.before, m.after) for m in mutants if m.short == "DeleteStatement"]
    assert deleted == [(6, "y = x + 1", "pass"), (8, "print(", "pass"), (11, "return y", "pass")]


def test_a_variable_is_swapped_only_for_another_of_its_type(tmp_path, monkeypatch):
    source = """class Monitor:
    def __init__(self):
        self.best = ""
        self.in_use = ""
        self.count = 0

    def limits(self, now: float, name: str) -> float:
        age = now - 1.0
        label = f"{name}!"
        return age + len(self.in_use) + len(label)
"""
    swaps = {
        (m.line, m.after) for m in make(tmp_path, monkeypatch, source) if m.short == "SwapVariable"
    }
    assert (10, "return now + len(self.in_use) + len(label)") in swaps  # a number for a number
    assert (10, "return age + len(self.best) + len(label)") in swaps  # an attribute of its kind
    assert (10, "return age + len(self.in_use) + len(name)") in swaps  # a str for a str
    assert not any("len(self.count)" in after or "len(age)" in after for _, after in swaps)


def test_min_max_none_checks_and_moved_lines(tmp_path, monkeypatch):
    source = """def f(x, items):
    low = min(items)
    high = low + items.max()
    if x is not None and low:
        return high
    return None
"""
    mutants = make(tmp_path, monkeypatch, source)
    made = {(m.short, m.line, m.after) for m in mutants}
    assert ("SwapMinMax", 2, "low = max(items)") in made
    assert ("SwapMinMax", 3, "high = low + items.min()") in made
    assert ("DropNoneCheck", 4, "if x and low:") in made
    assert ("MoveLine", 2, "high = low + items.max()") in made  # moved above what it reads
    moved = next(m for m in mutants if m.short == "MoveLine" and m.line == 2)
    assert moved.code.splitlines()[1:3] == ["    high = low + items.max()", "    low = min(items)"]


def test_every_listed_equivalent_names_its_module_its_mutants_and_a_reason():
    import re

    for entry in mutation.load_equivalents():
        assert (REPO / entry["module"]).is_file(), entry
        assert len(str(entry.get("reason", ""))) > 10, entry
        if "operators" in entry:
            assert entry["operators"] and ("where" in entry or "changed" in entry), entry
            for key in ("where", "changed"):
                re.compile(str(entry.get(key, "")))
        else:
            assert {"operator", "before", "after"} <= set(entry), entry


def test_two_assignments_that_cannot_affect_each_other_are_not_swapped(tmp_path, monkeypatch):
    """A move that is equivalent by construction is not made (it would only cost a full
    test run and a line in the equivalents list): two assignments, neither touching
    what the other writes, with nothing but pure constructors on the right."""
    source = """class C:
    def reset(self, n):
        self.a = deque(maxlen=2)
        self.b = False
        self.c = self.b
        self.d = n + 1
        self.e = compute()
"""
    moves = [
        (m.line, m.after) for m in make(tmp_path, monkeypatch, source) if m.short == "MoveLine"
    ]
    assert (3, "self.b = False") not in moves, "independent: equivalent by construction"
    assert (4, "self.c = self.b") in moves, "c reads b"
    assert (5, "self.d = n + 1") not in moves
    assert (6, "self.e = compute()") in moves, "a call may do anything"


def test_an_equivalents_entry_whose_line_was_edited_is_reported_unused(tmp_path, monkeypatch):
    """An entry names a mutant by its line's text: once the line is edited it hides
    nothing, and `--unused` says so, while an entry that still matches is kept."""
    import yaml

    (tmp_path / "m.py").write_text("def f(x):\n    y = x + 1\n    return y\n")
    still = {
        "module": "m.py",
        "operator": "DeleteStatement",
        "before": "return y",
        "after": "pass",
        "reason": "a reason of more than ten characters",
    }
    edited = {**still, "before": "return y + 0"}
    listing = tmp_path / "equivalents.yaml"
    listing.write_text(yaml.safe_dump([still, edited]))
    monkeypatch.setattr(mutation, "REPO", tmp_path)
    monkeypatch.setattr(mutation, "EQUIVALENTS", listing)
    assert mutation.unused_equivalents(["m.py"], ["fw"]) == [edited]
    assert mutation.main(["m.py", "--unused", "--operators", "fw"]) == 1
    listing.write_text(yaml.safe_dump([still]))
    assert mutation.main(["m.py", "--unused", "--operators", "fw"]) == 0


def test_an_entry_belongs_to_the_family_whose_operator_it_names():
    """`--unused --operators fw` judges fw's entries only: a cosmic-ray entry is not
    reported unused because fw's operators never make its mutant."""
    assert mutation.family_of({"operator": "DeleteStatement"}) == "fw"
    assert mutation.family_of({"operators": ["SwapMinMax", "MoveLine"]}) == "fw"
    assert mutation.family_of({"operator": "ReplaceComparisonOperator_Lt_LtE"}) == "cosmic-ray"
    assert mutation.family_of({"operators": ["DropNoneCheck", "NumberReplacer"]}) == "cosmic-ray"


def test_a_workspace_holds_the_compiled_extensions_the_build_put_beside_the_code(tmp_path):
    """Without them a mutant's tests run numpy's fallbacks: the lines that call the
    compiled kernel never run and their mutants survive untested."""
    built = sorted(p.relative_to(mutation.REPO) for p in mutation.REPO.glob("components/**/*.so"))
    if not built:
        pytest.skip("no compiled extension in this checkout (pip install -e . builds it)")
    space = mutation.Workspace(tmp_path / "w")
    assert all((space.root / name).is_file() for name in built)
    assert (space.root / "components/robot/interpolator.py").is_file()


def test_what_a_stopped_run_caught_is_kept_for_the_same_code_only(tmp_path, monkeypatch):
    """A long run stopped halfway goes on where it stopped: the mutants it killed or
    timed out are not tested again while the module's code is unchanged; survivors are
    never kept (new specs may kill them); an edit of the module, or --fresh, starts over."""
    monkeypatch.setattr(mutation, "REPO", tmp_path)
    monkeypatch.setattr(mutation, "CACHE", tmp_path / "cache")
    (tmp_path / "m.py").write_text("x = 1\n")
    killed = mutation.Mutant("m.py", "core/NumberReplacer", 0, 1, "x = 1", "x = 2", "", "killed")
    survived = mutation.Mutant("m.py", "core/NumberReplacer", 1, 1, "x = 1", "x = 0", "")
    survived.status = "survived"
    run = mutation.Caught("m.py", "cosmic-ray")
    run.add(killed)
    run.add(survived)
    again = mutation.Caught("m.py", "cosmic-ray")
    assert again.get(killed) == "killed" and again.get(survived) == ""
    assert mutation.Caught("m.py", "fw").get(killed) == "", "each family apart"
    assert mutation.Caught("m.py", "cosmic-ray", fresh=True).get(killed) == ""
    (tmp_path / "m.py").write_text("x = 1  # edited\n")
    assert mutation.Caught("m.py", "cosmic-ray").get(killed) == ""
