"""Spec: a topology may lay itself over another (`extends:`), as topologies/seeg_hosts.yaml
places seeg.yaml's processes on hosts: mappings merge key by key and its values win; a
finding is located in the file that wrote the value; a missing or circular base is a
located error."""

import shutil

import pytest

from framework.errors import FindingsError
from framework.topology import check_topology, load_topology
from tests.conftest import REPO

TOY = REPO / "tests" / "data" / "toy"


@pytest.fixture
def toy_copy(tmp_path):
    for name in ("toy.yaml", "toy_chart.yaml"):
        shutil.copy(TOY / name, tmp_path / name)
    return tmp_path


def test_an_overlay_places_processes_and_changes_properties_and_keeps_the_rest(toy_copy):
    (toy_copy / "hosts.yaml").write_text(
        "extends: toy.yaml\n"
        "topology: toy_hosts\n"
        "bus: {address: 10.77.0.1}\n"
        "hosts: {cart: {address: 10.77.0.2}}\n"
        "processes: {trackers: {host: cart}}\n"
        "components:\n  t1:\n    properties: {step: 5.0}\n"
    )
    topo = load_topology(toy_copy / "hosts.yaml")
    assert topo.name == "toy_hosts" and topo.bus.host == "10.77.0.1"
    assert topo.hosts == {"cart": "10.77.0.2"}
    assert topo.processes["trackers"] == {"host": "cart"}
    assert topo.processes["control_side"] == {"shutdown": "first"}, "kept from the base"
    assert topo.components["t1"].properties["step"] == 5.0
    assert topo.components["t2"].properties["step"] == -1.0
    assert topo.statechart == toy_copy / "toy_chart.yaml", "relative to the file that says it"
    assert set(topo.configurations) == set(load_topology(toy_copy / "toy.yaml").configurations)


def test_a_finding_is_located_in_the_file_that_wrote_the_value(toy_copy):
    (toy_copy / "hosts.yaml").write_text(
        "extends: toy.yaml\ncomponents:\n  t1:\n    properties: {step: nope}\n"
    )
    _, findings = check_topology(toy_copy / "hosts.yaml")
    wrong = [f for f in findings if f.severity == "error"]
    assert wrong and all(f.location.file.endswith("hosts.yaml") for f in wrong)
    assert wrong[0].location.line == 4
    (toy_copy / "toy.yaml").write_text(
        (toy_copy / "toy.yaml")
        .read_text()
        .replace("class: components.demo:Sink", "class: components.demo:Sinc")
    )
    (toy_copy / "hosts.yaml").write_text("extends: toy.yaml\ntopology: toy_hosts\n")
    _, findings = check_topology(toy_copy / "hosts.yaml")
    wrong = [f for f in findings if f.severity == "error"]
    assert wrong and wrong[0].location.file.endswith("toy.yaml"), "the base's own line"
    assert "Sinc" in (toy_copy / "toy.yaml").read_text().splitlines()[wrong[0].location.line - 1]


@pytest.mark.parametrize(
    ("files", "said"),
    [
        ({"a.yaml": "extends: nowhere.yaml\n"}, "names no readable file"),
        ({"a.yaml": "extends: b.yaml\n", "b.yaml": "extends: a.yaml\n"}, "in a circle"),
        ({"a.yaml": "extends: a.yaml\n"}, "in a circle"),
        ({"a.yaml": "extends: folder\n", "folder/x": ""}, "names no readable file"),
    ],
)
def test_a_missing_or_circular_base_is_a_located_error(tmp_path, files, said):
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(exist_ok=True)
        (tmp_path / name).write_text(text)
    with pytest.raises(FindingsError) as caught:
        load_topology(tmp_path / "a.yaml")
    finding = caught.value.findings[0]
    assert said in finding.message and finding.location.line == 1
