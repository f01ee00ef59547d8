"""Spec: YAML is read safely, with YAML 1.2 scalars and a position for every value."""

import math

import pytest
import yaml

from framework import yamlio
from framework.errors import YamlError
from framework.yamlio import load_yaml, load_yaml_text


def test_yaml_11_traps_stay_strings():
    doc = load_yaml_text("on: yes\nno: off\nt: 1:30\ny: Y\n")
    assert doc.data == {"on": "yes", "no": "off", "t": "1:30", "y": "Y"}


def test_yaml_12_core_scalars_are_resolved():
    doc = load_yaml_text("a: 010\nb: 0x1F\nc: 1.5e3\nd: true\ne: ~\nf: .inf\ng: '12'\n")
    assert doc.data == {
        "a": 10,
        "b": 31,
        "c": 1500.0,
        "d": True,
        "e": None,
        "f": math.inf,
        "g": "12",
    }


def test_every_value_has_a_line_and_column():
    doc = load_yaml_text("top:\n  items:\n    - a\n    - {b: 1}\n", "f.yaml")
    loc = doc.location(("top", "items", 1, "b"))
    assert (loc.file, loc.line, loc.column, loc.path) == ("f.yaml", 4, 8, "top.items[1].b")


def test_missing_paths_fall_back_to_the_nearest_parent():
    doc = load_yaml_text("top:\n  x: 1\n")
    assert doc.location(("top", "nope", 3)).line == 1


def test_duplicate_keys_are_refused_with_both_lines():
    with pytest.raises(YamlError) as err:
        load_yaml_text("a: 1\nb: 2\na: 3\n", "d.yaml")
    assert "d.yaml:3:1" in str(err.value) and "line 1" in str(err.value)


def test_custom_tags_are_refused():
    with pytest.raises(YamlError, match="custom YAML tag"):
        load_yaml_text("a: !!python/object:os.system x\n")


def test_syntax_errors_name_the_place():
    with pytest.raises(YamlError) as err:
        load_yaml_text("a: [1, 2\nb: 3\n", "s.yaml")
    assert str(err.value).startswith("s.yaml:2:")


def test_merge_keys_keep_explicit_values():
    doc = load_yaml_text("base: &b {x: 1, y: 2}\nuse: {<<: *b, y: 3}\n")
    assert doc.data["use"] == {"x": 1, "y": 3}


def test_unreadable_files_are_yaml_errors(tmp_path):
    with pytest.raises(YamlError, match="file not found"):
        load_yaml(tmp_path / "missing.yaml")
    bad = tmp_path / "bin.yaml"
    bad.write_bytes(b"\xff\xfe\x00bad")
    with pytest.raises(YamlError, match="cannot read"):
        load_yaml(bad)


# Hostile files: every limit ends in a located YamlError, quickly and in little memory.


def _refused(text: str, match: str, **limits) -> YamlError:
    from framework.yamlio import Limits

    with pytest.raises(YamlError, match=match) as err:
        load_yaml_text(text, "h.yaml", Limits(**limits) if limits else Limits())
    assert str(err.value).startswith("h.yaml:"), str(err.value)
    return err.value


PARSERS = ["C", "pure Python"] if yaml.__with_libyaml__ else ["pure Python"]


@pytest.fixture(params=PARSERS)
def parser(request, monkeypatch):
    """Each YAML parser fw may run on: libyaml's where PyYAML was built with it, and
    PyYAML's own (the fallback)."""
    if request.param == "pure Python":
        monkeypatch.setattr(yamlio, "_Loader", yaml.SafeLoader)
    return request.param


def test_deep_nesting_is_refused_without_recursion(parser):
    """Whichever layer refuses first (libyaml 0.2.5 stops at 1,000 levels by itself,
    PyYAML's own parser does not), the file is refused with its place, never with a
    RecursionError."""
    error = _refused("[" * 50_000 + "]" * 50_000, "nest")
    assert error.location.line == 1 and error.location.column <= 1001


@pytest.mark.parametrize("style", ["flow", "block"])
def test_fw_limits_nesting_below_what_any_parser_allows(parser, style):
    if style == "flow":
        text = "[" * 100 + "]" * 100
    else:
        text = "".join("  " * depth + "-\n" for depth in range(100)) + "  " * 100 + "- x\n"
    error = _refused(text, "nested more than 64 levels")
    assert error.location.line == (1 if style == "flow" else 65)


def test_alias_bombs_are_refused_by_the_expansion_budget():
    bomb = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join(['*' + chr(97 + i)] * 9)}]\n" for i in range(9)
    )
    error = _refused(bomb, "values \\(after expanding aliases\\)")
    assert error.location.line > 1


def test_recursive_aliases_are_refused():
    _refused("a: &r [*r]\n", "refers to the value that contains it")
    _refused("a: &m {b: *m}\n", "refers to the value that contains it")


def test_unknown_aliases_are_refused():
    _refused("a: *nowhere\n", "no anchor &nowhere")


def test_long_scalars_and_huge_integers_are_refused():
    _refused("a: " + "x" * 100, "a value of 100 characters", max_scalar=99)
    error = _refused("a: 1\nb: " + "9" * 4300 + "\n", "integer of 4300 digits")
    assert error.location.line == 2
    assert load_yaml_text("a: '" + "9" * 60 + "'\n").data == {"a": "9" * 60}


def test_nul_and_control_characters_are_located():
    error = _refused("a: 1\nb: x\0y\n", "NUL is not allowed")
    assert (error.location.line, error.location.column) == (2, 5)
    _refused("a: \x07\n", "U\\+0007")


def test_invalid_utf8_is_located(tmp_path):
    bad = tmp_path / "latin.yaml"
    bad.write_bytes(b"a: 1\nname: caf" + b"\xe9\n")
    with pytest.raises(YamlError, match="0xe9 is not UTF-8") as err:
        load_yaml(bad)
    assert (err.value.location.line, err.value.location.column) == (2, 10)


def test_oversized_files_are_refused_before_parsing(tmp_path):
    from framework.yamlio import Limits

    big = tmp_path / "big.yaml"
    big.write_text("a: 1\n" * 1000)
    with pytest.raises(YamlError, match="larger than 100 bytes"):
        load_yaml(big, Limits(max_bytes=100))


def test_collections_as_keys_and_second_documents_are_refused():
    _refused("? [a, b]\n: 1\n", "keys must be plain names")
    _refused("a: 1\n---\nb: 2\n", "one YAML document")


def test_aliases_are_copies_not_shared_objects():
    doc = load_yaml_text("a: &x {k: [1]}\nb: *x\n")
    doc.data["b"]["k"].append(2)
    assert doc.data["a"] == {"k": [1]}


def test_explicit_str_tag_keeps_text():
    assert load_yaml_text("a: !!str 10\n").data == {"a": "10"}
