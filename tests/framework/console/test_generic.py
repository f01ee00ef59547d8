"""Spec: the console knows no procedure. Without a `console:` section a topology gets a
button per operator event and nothing of SEEG; with one, its tiles show fields of
read-only operations and of port samples, its plots follow a port, its buttons carry
their payload and may ask for confirmation; mistakes in the section are findings at
their line, before anything starts."""

import json
import shutil
import urllib.request

import pytest

from framework.topology import check_topology
from tests.conftest import REPO, private_topology, wait_until
from tests.framework.console.conftest import served

TOY = REPO / "tests" / "data" / "toy"

CONSOLE = """
console:
  tiles:
    - {label: samples read, call: supervisor.stats.received, digits: 0}
    - {id: count, label: tracker 1 count, port: t1.out.value, digits: 1}
  plots:
    - {label: tracker 1, port: t1.out.value, unit: counts}
  buttons:
    - {event: e_SWAP, label: Swap trackers, confirm: true}
"""


def toy_with(tmp_path, section: str):
    """The toy topology with `section` appended, next to a copy of its chart."""
    shutil.copy(TOY / "toy_chart.yaml", tmp_path / "toy_chart.yaml")
    path = tmp_path / "toy.yaml"
    path.write_text((TOY / "toy.yaml").read_text() + section)
    return path


def get(server, path):
    request = urllib.request.Request(
        server.base.rstrip("/") + path, headers={"Authorization": f"Bearer {server.token}"}
    )
    with urllib.request.urlopen(request, timeout=5) as reply:
        return json.loads(reply.read())


def test_without_a_console_section_every_operator_event_gets_a_button_and_nothing_else(
    toy, tmp_path
):
    with served(toy, tmp_path) as (server, _):
        layout = get(server, "/api/layout")
        assert [(b["id"], b["event"], b["label"]) for b in layout["buttons"]] == [
            ("e-swap", "e_SWAP", "SWAP"),
            ("e-break", "e_BREAK", "BREAK"),
        ]
        assert layout["buttons"][0]["doc"] == "Use the other tracker."
        assert layout["forms"] == {} and layout["plots"] == [] and layout["panels"] == []
        assert wait_until(lambda: (get(server, "/api/state").get("health") or {}).get("data"))
        state = get(server, "/api/state")
        assert state["tiles"] == [] and state["alert"] is None
        text = json.dumps(state)
        for seeg in ("No Sensor Available", "people", "tracker in use", "supervisor/halt"):
            assert seeg not in text


def test_declared_tiles_plots_and_buttons_follow_the_deployment(bus_config, tmp_path):
    topology = private_topology(toy_with(tmp_path, CONSOLE), bus_config)
    with served(topology, tmp_path / "logs") as (server, _):
        layout = get(server, "/api/layout")
        assert [(b["id"], b["confirm"]) for b in layout["buttons"]] == [("swap-trackers", True)]
        assert layout["plots"] == [{"id": "tracker-1", "label": "tracker 1", "unit": "counts"}]

        def tiles():
            return {t["id"]: t for t in get(server, "/api/state")["tiles"]}

        assert wait_until(lambda: not tiles()["count"]["stale"], timeout=10)
        assert wait_until(lambda: tiles()["samples-read"]["text"] not in ("-", "0"), timeout=10)
        assert int(tiles()["samples-read"]["text"]) > 0
        first = float(tiles()["count"]["text"])
        assert wait_until(lambda: float(tiles()["count"]["text"]) > first, timeout=10)

        def plot():
            return get(server, "/api/state")["plots"]["tracker-1"]

        assert wait_until(lambda: len(plot()["t"]) >= 5, timeout=10)
        points = plot()
        assert len(points["values"]) == 1 and len(points["values"][0]) == len(points["t"])
        assert points["values"][0] == sorted(points["values"][0]), "tracker 1 counts up"


@pytest.mark.parametrize(
    "section, message",
    [
        (
            "console: {panels: [seg]}",
            "no console panel 'seg' is installed (hint: did you mean 'seeg'?)",
        ),
        (
            "console: {buttons: [{event: e_SWP}]}",
            "a button sends 'e_SWP', which is not one of the topology's external_events",
        ),
        (
            "console: {tiles: [{label: x, call: t1.reset}]}",
            "t1.reset changes state, so the console may not poll it",
        ),
        ("console: {tiles: [{label: x, call: t1.nothing}]}", "'t1' has no operation 'nothing'"),
        ("console: {plots: [{label: x, port: t1.outt}]}", "'t1' has no output port 'outt'"),
        (
            "console: {tiles: [{label: a, port: t1.out}, {label: a, port: t2.out}]}",
            "tile id 'a' is used twice",
        ),
    ],
)
def test_mistakes_in_the_console_section_are_findings_at_their_line(tmp_path, section, message):
    path = toy_with(tmp_path, "\n" + section + "\n")
    line = len(path.read_text().splitlines())
    _, findings = check_topology(path)
    errors = [f for f in findings if f.severity == "error"]
    assert len(errors) == 1 and message in errors[0].one_line(), errors
    assert errors[0].location.line == line
