"""A properties file: every name it uses is checked against its chart, and every
mistake is a located error (file:line:col), never a traceback."""

from __future__ import annotations

import pytest

from framework.cli import main
from framework.errors import FindingsError
from framework.statechart.loader import load_statechart
from framework.verify.properties import load_properties
from tests.conftest import REPO

SEEG = REPO / "statecharts/seeg.yaml"


@pytest.fixture(scope="module")
def seeg():
    return load_statechart(SEEG)


def problems(tmp_path, seeg, text: str) -> list[str]:
    path = tmp_path / "props.yaml"
    path.write_text(text)
    with pytest.raises(FindingsError) as caught:
        load_properties(path, seeg)
    return [f.one_line() for f in caught.value.findings]


def test_the_shipped_properties_load_against_their_charts(seeg):
    props = load_properties(REPO / "procedures/seeg/properties.yaml", seeg)
    assert len(props.properties) >= 8
    pick = load_statechart(REPO / "statecharts/pick_place.yaml")
    assert (
        len(load_properties(REPO / "procedures/pick_place/properties.yaml", pick).properties) >= 4
    )


@pytest.mark.parametrize(
    ("check", "where", "said"),
    [
        ("never: {in: Stoped}", "4:13", "has no state 'Stoped' (hint: did you mean 'Stopped'?)"),
        ("never: {event: e_STPO}", "4:13", "'e_STPO' is not an event of chart 'seeg'"),
        ("never: {request: move_fats}", "4:13", "did you mean 'move_fast'?"),
        ("always: {when: \"trackr == 'none'\"}", "4:14", "has no variable 'trackr'"),
        ("always: {when: \"active('Nowhere')\"}", "4:14", "has no state 'Nowhere'"),
        ('always: {when: "tracker =="}', "4:14", "syntax error in expression"),
        ("always: {event: e_STOP}", "4:14", "unknown key 'event'"),
        ("never: {in: Connect_Tracker}", "4:13", "is a junction: it is never active"),
        (
            "responds: {to: {in: Stopped}, with: {in: Fault}}",
            "4:16",
            "must name something that happens",
        ),
        ("never: {event: e_STOP, enter: Stopped}", "4:5", "one observation at a time"),
        ("never: {in: Stopped}\n    always: {in: Stopped}", "3:5", "exactly one of"),
        ("nevr: {in: Stopped}", "4:5", "did you mean 'never'?"),
    ],
)
def test_a_mistake_is_a_located_error(tmp_path, seeg, check, where, said):
    found = problems(tmp_path, seeg, f"properties: seeg\nchecks:\n  - name: a\n    {check}\n")
    assert any(f"props.yaml:{where}:" in f and said in f for f in found), found
    assert all("props.yaml:" in f for f in found)


def test_properties_about_another_chart_are_refused(tmp_path, seeg):
    found = problems(
        tmp_path, seeg, "properties: pick_place\nchecks:\n  - {name: a, never: {in: Stopped}}\n"
    )
    assert any(
        "props.yaml:1:1:" in f and "about chart 'pick_place', not 'seeg'" in f for f in found
    )


def test_fw_verify_prints_located_errors_and_exits_1(tmp_path, capsys):
    path = tmp_path / "props.yaml"
    path.write_text("properties: seeg\nchecks:\n  - name: a\n    never: {in: Stoped}\n")
    assert main(["verify", str(SEEG), "-p", str(path)]) == 1
    err = capsys.readouterr()
    assert f"{path}:4:13" in err.out + err.err
    assert "Traceback" not in err.out + err.err
