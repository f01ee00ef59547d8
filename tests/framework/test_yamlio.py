"""Spec: YAML is read safely, with YAML 1.2 scalars and a position for every value."""

import math

import pytest

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
