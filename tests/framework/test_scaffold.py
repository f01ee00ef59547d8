"""Spec: `fw new procedure NAME` makes a whole procedure that validates and whose own
specs pass (docs/tutorial.md runs it end to end on real processes), and never
overwrites anything."""

import subprocess
import sys

import pytest

from framework.cli import main
from framework.errors import FwError
from framework.scaffold import FIRST_PORT, PORTS, new_procedure


def test_a_new_procedure_validates_and_passes_its_own_specs(tmp_path, capsys):
    assert main(["new", "procedure", "pick", "--dir", str(tmp_path), "--port", "7777"]) == 0
    folder = tmp_path / "pick"
    assert sorted(p.name for p in folder.iterdir()) == [
        "pick.yaml",
        "pick_chart.yaml",
        "pick_components.py",
        "test_pick.py",
    ]
    assert "hub_port: 7777" in (folder / "pick.yaml").read_text()
    assert main(["validate", str(folder / "pick.yaml"), str(folder / "pick_chart.yaml")]) == 0
    specs = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(folder)],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=120,
    )
    assert specs.returncode == 0 and "2 passed" in specs.stdout, specs.stdout + specs.stderr


def test_nothing_existing_is_overwritten_and_names_must_be_module_names(tmp_path):
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "mine.py").write_text("keep me")
    with pytest.raises(FwError, match="already exists"):
        new_procedure("taken", tmp_path)
    assert (tmp_path / "taken" / "mine.py").read_text() == "keep me"
    for bad in ("Hello", "2fast", "pick-place", "class", ""):
        with pytest.raises(FwError, match="module name"):
            new_procedure(bad, tmp_path)


def test_the_default_port_comes_from_the_name(tmp_path):
    new_procedure("alpha", tmp_path)
    new_procedure("beta", tmp_path)
    ports = [
        int((tmp_path / n / f"{n}.yaml").read_text().split("hub_port: ")[1].split("}")[0])
        for n in ("alpha", "beta")
    ]
    assert all(FIRST_PORT <= p < FIRST_PORT + PORTS for p in ports) and ports[0] != ports[1]
