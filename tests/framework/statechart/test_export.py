"""Spec: charts are drawn as DOT (and SVG/PNG via Graphviz), PlantUML and Mermaid."""

import shutil

import pytest

from framework.statechart.export import ExportError, render, to_dot, to_mermaid, to_plantuml
from framework.statechart.loader import load_statechart
from tests.conftest import REPO


@pytest.fixture(scope="module")
def seeg():
    return load_statechart(REPO / "statecharts" / "seeg.yaml")


def test_dot_has_clusters_for_composites_and_every_transition(seeg):
    dot = to_dot(seeg)
    assert "subgraph cluster_s_System_OK" in dot and "subgraph cluster_s_System_OK_Task" in dot
    assert dot.count(" -> ") >= len(seeg.transitions())
    assert "lhead=cluster_s_System_OK" in dot
    assert "configure: tracker_1_up" in dot


def test_active_states_are_highlighted(seeg):
    plain = to_dot(seeg)
    lit = to_dot(seeg, ["System_OK", "System_OK.Task", "System_OK.Task.Stopped"])
    assert plain.count("#9be58a") == 0 and lit.count("#9be58a") == 1
    assert "darkgreen" in lit
    assert "class s_System_OK_Task_Stopped active" in to_mermaid(seeg, ["System_OK.Task.Stopped"])
    assert "s_System_OK_Task_Stopped #9be58a" in to_plantuml(seeg, ["System_OK.Task.Stopped"])


def test_plantuml_and_mermaid_are_well_formed(seeg):
    puml = to_plantuml(seeg)
    assert puml.startswith("@startuml") and puml.rstrip().endswith("@enduml")
    assert puml.count("{") == puml.count("}") and "<<choice>>" in puml
    mmd = to_mermaid(seeg)
    assert mmd.startswith("stateDiagram-v2") and mmd.count("{") == mmd.count("}")


@pytest.mark.skipif(shutil.which("dot") is None, reason="Graphviz is installed by tools/test.sh")
@pytest.mark.parametrize("suffix", [".svg", ".png"])
def test_graphviz_renders_images(seeg, tmp_path, suffix):
    out = render(seeg, tmp_path / f"seeg{suffix}")
    data = out.read_bytes()
    assert data.startswith(b"\x89PNG") if suffix == ".png" else b"<svg" in data


@pytest.mark.parametrize("suffix", [".dot", ".puml", ".mmd"])
def test_text_formats_are_written(seeg, tmp_path, suffix):
    out = render(seeg, tmp_path / "sub" / f"seeg{suffix}")
    assert out.read_text().strip()


def test_unknown_formats_are_refused(seeg, tmp_path):
    with pytest.raises(ExportError, match="unknown output format"):
        render(seeg, tmp_path / "seeg.jpg")
