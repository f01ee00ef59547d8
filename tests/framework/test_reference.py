"""Spec: `fw describe` and docs/reference.md say what an integrator may wire, set and call
on each component class, read from the classes' own declarations."""

from framework.cli import main
from framework.component import Component, In, Out, operation
from framework.messages import EventMessage, Scalar
from framework.properties import prop
from framework.reference import component_reference
from tests.conftest import REPO

SHIPPED = [
    "framework.coordinator:Coordinator",
    "framework.configurator:Configurator",
    "topologies/seeg.yaml",
    "topologies/tracking.yaml",
    "topologies/people.yaml",
    "topologies/demo.yaml",
    "topologies/seeg_ros2.yaml",
]


class Gauge(Component):
    """Reads a level and says when it is too high.

    More words that the reference leaves out."""

    hosts_safety_monitor = True
    limit = prop(float, 2.5, unit="m", min=0.5, max=10.0, doc="too high above this")
    mode = prop(str, "fast", choices=["fast", "slow"], doc="how to read")
    source = prop(str, "", required=True, doc="where the level comes from")
    level = In(Scalar, doc="the level", policy={"type": "buffer", "size": 8})
    alarm = Out(EventMessage, doc="too high")

    @operation(readonly=True)
    def reading(self, smoothed: bool = False) -> float:
        """The last level (m).

        Not in the reference."""
        return 0.0

    @operation(exclusive=False)
    def wait_level(self, timeout: float = 1.0) -> bool:
        """Wait for a level."""
        return True

    @operation
    def reset(self) -> None:
        """Forget the last level."""


def test_the_shipped_reference_is_what_the_classes_declare(tmp_path, capsys):
    out = tmp_path / "reference.md"
    assert main(["describe", *SHIPPED, "-o", str(out)]) == 0
    regenerate = f"fw describe {' '.join(SHIPPED)} -o docs/reference.md"
    assert (REPO / "docs" / "reference.md").read_text() == out.read_text(), (
        f"docs/reference.md is out of date: run `{regenerate}`"
    )


def test_a_class_is_described_by_its_purpose_properties_ports_and_operations():
    text = component_reference(Gauge)
    assert text.startswith(
        f"## `{__name__}:Gauge`\n\nReads a level and says when it is too high.\n"
    )
    assert "More words" not in text and "Not in the reference" not in text
    assert "- may host the topology's safety monitor" in text
    assert "| `limit` | float | `2.5` | m | [0.5, 10] | too high above this |" in text
    assert "| `mode` | str | `'fast'` |  | one of 'fast', 'slow' | how to read |" in text
    assert "| `source` | str | `''` |  |  | **required**. where the level comes from |" in text
    assert (
        "| `level` | in | Scalar | the level (policy: "
        "{'type': 'buffer', 'size': 8, 'overflow': 'drop_oldest'}) |" in text
    )
    assert "| `alarm` | out | EventMessage | too high |" in text
    assert "| `reading(smoothed: bool = False)` | reads only | The last level (m). |" in text
    assert "| `wait_level(timeout: float = 1.0)` | may change state, concurrent |" in text
    assert "| `reset()` | may change state | Forget the last level. |" in text


def test_a_class_that_cannot_be_found_is_a_one_line_error(capsys):
    assert main(["describe", "nowhere.module:Thing"]) == 1
    assert "cannot import 'nowhere.module'" in capsys.readouterr().err
    assert main(["describe", "framework.messages:Pose"]) == 1
    assert "is not a Component class" in capsys.readouterr().err
