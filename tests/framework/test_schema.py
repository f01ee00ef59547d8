"""Spec: the fast schema check (fastjsonschema) and the explaining one (jsonschema) agree."""

import copy

from hypothesis import given, settings
from hypothesis import strategies as st

from framework import schema
from framework.yamlio import load_yaml
from tests.conftest import REPO

SEEG = load_yaml(REPO / "statecharts" / "seeg.yaml").data
JUNK = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-3, 3),
    st.text(max_size=6),
    st.lists(st.integers(), max_size=2),
    st.dictionaries(st.text(max_size=4), st.integers(), max_size=2),
)


def paths(node, prefix=()):
    yield prefix
    if isinstance(node, dict):
        for key, value in node.items():
            yield from paths(value, (*prefix, key))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            yield from paths(value, (*prefix, i))


ALL_PATHS = [p for p in paths(SEEG) if p]


@settings(max_examples=300, deadline=None)
@given(where=st.sampled_from(ALL_PATHS), junk=JUNK, extra=st.booleans())
def test_fast_and_full_validators_agree(where, junk, extra):
    data = copy.deepcopy(SEEG)
    parent = data
    for key in where[:-1]:
        parent = parent[key]
    if extra and isinstance(parent, dict):
        parent[f"x_{junk!s}"[:8]] = junk
    else:
        parent[where[-1]] = junk
    full = schema._validator("statechart").is_valid(data)
    assert schema.is_valid(data, "statechart") == full


def test_the_shipped_chart_is_valid_both_ways():
    assert schema.is_valid(SEEG, "statechart")
    assert schema._validator("statechart").is_valid(SEEG)


def test_a_text_of_the_wrong_form_is_named_for_what_it_should_be(write):
    from framework.statechart.files import validate_file

    path = write(
        """
        statechart: forms
        initial: A
        states:
          - name: A
            configure: {tag: x, timeout: -2s}
            transitions:
              - {event: config.failed, target: B}
              - {target: B}
          - {name: B, type: final}
        """
    )
    (finding,) = [f for f in validate_file(path) if f.code == "schema"]
    assert finding.message == "'-2s' is not a duration"
    assert finding.hint == "write e.g. 2s, 500ms or 1.5min; never negative"
    path = write(
        """
        statechart: forms
        initial: A
        states:
          - {name: 2nd, type: final}
        """
    )
    (finding,) = [f for f in validate_file(path) if f.code == "schema"]
    assert finding.message == "'2nd' is not a valid name here"
    assert finding.hint == "use letters, digits and '_'"
