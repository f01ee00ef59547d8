"""Spec: the mutation tool's bookkeeping: which mutants a reviewer listed as equivalent,
and the summary table of docs/results/mutation.md."""

import sys

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


def test_the_summary_has_a_row_per_reported_module():
    section = """<!-- mutation:framework/x.py -->
### `framework/x.py`

2026-11-23 (rescored: ...), tests: `tests/x.py`

| mutants | killed | timeout | survived | not run | equivalent | score |
|---|---|---|---|---|---|---|
| 100 | 80 | 2 | 8 | 1 | 9 | 90.1% |
<!-- /mutation:framework/x.py -->"""
    table = mutation.summary("# head\n\n" + section)
    assert (
        table.splitlines()[3] == "| `framework/x.py` | 100 | 9 | 9 | 90.1% | 2026-11-23, rescored |"
    )
    assert table.startswith("<!-- summary -->") and table.endswith("<!-- /summary -->")


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
    (tmp_path / "m.py").write_text(source)
    monkeypatch.setattr(mutation, "REPO", tmp_path)
    mutants = mutation.deletion_mutants("m.py")
    assert [(m.line, m.before, m.after) for m in mutants] == [
        (6, "y = x + 1", "pass"),
        (8, "print(", "pass (and 2 more line(s))"),
        (11, "return y", "pass"),
    ]
    for m in mutants:
        compile(m.code, "m.py", "exec")
        assert len(m.code.splitlines()) == len(source.splitlines())
    assert mutants[0].short == "DeleteStatement"


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
