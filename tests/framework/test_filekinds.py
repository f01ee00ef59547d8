"""Spec: `fw validate` checks every kind of fw file, told by its keys or by --kind."""

import subprocess
import sys

import pytest

from framework.filekinds import detect, kinds
from tests.conftest import REPO

SHIPPED = sorted(
    p
    for pattern in ("topologies/*.yaml", "statecharts/**/*.yaml", "procedures/**/*.yaml")
    for p in REPO.glob(pattern)
)


def test_the_components_kinds_come_through_entry_points():
    assert {"procedure", "sensors", "tools", "cameras"} <= set(kinds())
    assert list(kinds())[-1] == "statechart", "tried last: every topology names one too"


@pytest.mark.parametrize(
    ("file", "kind"),
    [
        ("topologies/seeg.yaml", "topology"),
        ("statecharts/seeg.yaml", "statechart"),
        ("procedures/seeg.yaml", "procedure"),
        ("procedures/seeg/sensors.yaml", "sensors"),
        ("procedures/seeg/tools.yaml", "tools"),
        ("procedures/seeg/cameras.yaml", "cameras"),
        ("procedures/seeg/scenarios/nominal.yaml", "scenario"),
    ],
)
def test_a_files_kind_is_told_by_its_keys(file, kind):
    assert detect(REPO / file).name == kind


def test_every_shipped_file_is_valid_for_its_kind():
    for path in SHIPPED:
        kind = detect(path)
        assert kind is not None, path
        if kind.name != "statechart":
            assert kind.check(str(path)) == [], path


def fw(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "framework.cli", *args],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
    )


def test_fw_validate_checks_domain_files_with_located_errors(tmp_path):
    bad = tmp_path / "sensors.yaml"
    bad.write_text(
        "sensors:\n  a:\n    priority: 1\n    rate: 5\n    keys: {cto: x, rto: y}\n"
        "    calibration:\n      C:\n        quaternion:\n"
    )
    done = fw("validate", str(bad))
    assert done.returncode == 1
    assert f"{bad}:8:9: sensors.a.calibration.C.quaternion: error[schema]" in done.stdout
    assert "Traceback" not in done.stderr


def test_fw_validate_kind_overrides_detection(tmp_path):
    odd = tmp_path / "odd.yaml"
    odd.write_text("tools: {cto: {markers: [[0, 0, 0], [1, 0, 0], [0, 1, 0]]}}\n")
    assert fw("validate", str(odd)).returncode == 0
    as_procedure = fw("validate", "--kind", "procedure", str(odd))
    assert as_procedure.returncode == 1 and "'procedure' is required" in as_procedure.stdout
    unknown = fw("validate", "--kind", "nope", str(odd))
    assert unknown.returncode == 1 and "not one of" in unknown.stderr


def test_fw_validate_lists_the_kinds():
    done = fw("validate", "--kinds")
    assert done.returncode == 0
    assert all(name in done.stdout for name in ("sensors", "cameras", "procedure", "topology"))
