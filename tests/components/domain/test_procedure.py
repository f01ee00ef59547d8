"""Spec: a procedure file is read whole or refused with file:line and the field."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from components.domain.procedure import ProcedureError, load_procedure, pose_from
from tests.conftest import REPO


def test_the_seeg_procedure_loads_with_the_thesis_speeds():
    p = load_procedure(REPO / "procedures" / "seeg.yaml")
    assert p.speeds["certus"].fast == 0.075 and p.speeds["certus"].slow == 0.010
    assert p.frame("target") == "patient" and p.frame("home") == "base"
    # on the patient where, at rest, the robot base has it 12 cm above the table, the
    # tool pointing down: the reference tool at rest is the simulated head clamp's
    from components.domain.geometry import invert
    from components.domain.rigs import standard_rigs

    in_base = invert(standard_rigs()[0].rto_from_base) @ p.target
    assert np.allclose(in_base[:3, 3], [0.60, 0.0, 0.12], atol=1e-6)
    assert np.allclose(in_base[:3, 2], [0.0, 0.0, -1.0], atol=1e-6), "the tool points down"
    assert p.navigation.max_patient_motion == 0.010


GOALS = "procedure: x\ntarget: {position: [0, 0, 0]}\nhome: {position: [0, 0, 0]}\n"


@pytest.mark.parametrize(
    ("text", "line", "message"),
    [
        ("procedure: x\n", 1, "'target' is required"),
        (
            "procedure: x\ntarget: {position: [0, 0]}\nhome: {position: [0, 0, 0]}\n"
            "trackers: {certus: {fast: 0.1, slow: 0.01}}\n",
            2,
            "needs at least 3 items, has 2",
        ),
        (
            GOALS + "critical_radius: -1\ntrackers: {certus: {fast: 0.1, slow: 0.01}}\n",
            4,
            "-1 must be more than 0",
        ),
        (GOALS + "trackers:\n  certus: {fast: 0.01, slow: 0.05}\n", 5, "slow <= fast"),
        (
            GOALS + "people: {max_near: -1}\ntrackers: {certus: {fast: 0.1, slow: 0.01}}\n",
            4,
            "-1 must be at least 0",
        ),
        (
            GOALS + "trackers: {certus: {fast: .inf, slow: 0.01}}\n",
            4,
            "must be a finite number",
        ),
        (GOALS + "trackers: {certus: {fast: 0.1, slow: 0.01}}\nspeed: 1\n", 5, "unknown key"),
        ("target: {position: [0, 0, 0]}\n", 1, "'procedure' is required"),
    ],
)
def test_bad_procedures_are_refused_with_a_located_reason(write, text, line, message):
    path = write(text, "procedure.yaml")
    with pytest.raises(ProcedureError) as err:
        load_procedure(path)
    assert f"{path}:{line}:" in str(err.value) and message in str(err.value)


def test_a_defined_target_replaces_the_goal_and_a_bad_one_is_refused():
    from framework.errors import FwError

    procedure = load_procedure(REPO / "procedures" / "seeg.yaml")
    pose = procedure.define_target((0.58, 0.02, 0.13), (0, 180, 0))
    assert procedure.target is pose and np.allclose(pose[:3, 3], [0.58, 0.02, 0.13])
    with pytest.raises(FwError, match="target refused: a pose needs 3 finite"):
        procedure.define_target((float("nan"), 0.0, 0.1), (0, 180, 0))
    assert np.allclose(procedure.target[:3, 3], [0.58, 0.02, 0.13]), "the old target stays"


@given(st.tuples(*[st.floats(-180, 180)] * 3))
def test_roll_pitch_yaw_is_scipys_fixed_axis_xyz(rpy):
    expected = Rotation.from_euler("xyz", rpy, degrees=True).as_matrix()
    assert np.allclose(pose_from((0, 0, 0), rpy)[:3, :3], expected, atol=1e-12)


def test_a_goal_frame_is_the_base_unless_said_and_must_be_a_known_one(write):
    text = GOALS + "trackers: {certus: {fast: 0.1, slow: 0.01}}\n"
    p = load_procedure(write(text, "p.yaml"))
    assert p.frame("target") == "base" and p.navigation.smoothing == 0.1
    bad = text.replace("target: {position", "target: {frame: skull, position")
    with pytest.raises(ProcedureError, match=r"p.yaml:2.*frame"):
        load_procedure(write(bad, "p.yaml"))
    with pytest.raises(Exception, match="frame 'skull' is not one of base, patient"):
        p.define_target((0, 0, 0), (0, 0, 0), "skull")
    p.define_target((0.1, 0, 0), (0, 0, 0), "patient")
    assert p.frame("target") == "patient" and p.target[0, 3] == 0.1
