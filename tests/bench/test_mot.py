"""Spec: fw's MOT metrics are the standard ones. On random sequences and on sequences
the people detector produced in the scene suite, MOTA, MOTP, IDF1, IDP, IDR, misses,
false positives and identity switches equal motmetrics' (the MOT benchmarks' own
implementation, with the same Euclidean distance and gate). And the rule that makes
switches standard: a track keeps its person while it stays within the gate, even when
another track comes closer."""

import math

import motmetrics as mm
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fw_bench.mot import MotAccumulator
from fw_bench.scenes import GATE, Scene, play

METRICS = {
    "mota": "MOTA",
    "motp": "MOTP",
    "idf1": "IDF1",
    "idp": "IDP",
    "idr": "IDR",
    "num_misses": "misses",
    "num_false_positives": "false_positives",
    "num_switches": "id_switches",
    "num_objects": "objects",
    "num_matches": "matches",
}


def both(frames, gate=GATE):
    """fw's summary and motmetrics' for the same frames [(truth, tracks)]."""
    ours = MotAccumulator(gate)
    theirs = mm.MOTAccumulator(auto_id=True)
    for truth, tracks in frames:
        ours.update(truth, tracks)
        oids, hids = list(truth), list(tracks)
        d = np.full((len(oids), len(hids)), np.nan)
        for i, o in enumerate(oids):
            for j, h in enumerate(hids):
                dist = float(np.linalg.norm(np.asarray(truth[o]) - np.asarray(tracks[h])))
                if dist <= gate:
                    d[i, j] = dist
        theirs.update(oids, hids, d)
    summary = mm.metrics.create().compute(theirs, metrics=list(METRICS), name="x")
    return ours.summary(), {ours_name: summary[name]["x"] for name, ours_name in METRICS.items()}


def assert_equal(ours, theirs):
    for name, value in theirs.items():
        if not math.isfinite(float(value)):  # no objects (or matches): undefined
            assert math.isnan(ours[name]), name
        else:
            assert ours[name] == pytest.approx(float(value), abs=1e-9), name


points = st.tuples(st.floats(-2, 2), st.floats(-2, 2))


@st.composite
def sequences(draw):
    """Objects that come and go, tracks near them (or not), ids that change."""
    frames = []
    for _ in range(draw(st.integers(1, 25))):
        truth = draw(st.dictionaries(st.integers(0, 5), points, max_size=5))
        tracks = {}
        for x, y in truth.values():
            if draw(st.booleans()):
                h = draw(st.integers(10, 17))
                tracks[h] = (x + draw(st.floats(-0.6, 0.6)), y + draw(st.floats(-0.6, 0.6)))
        tracks.update(draw(st.dictionaries(st.integers(20, 23), points, max_size=2)))
        frames.append(
            (
                {o: np.array(p) for o, p in truth.items()},
                {h: np.array(p) for h, p in tracks.items()},
            )
        )
    return frames


@settings(max_examples=150, deadline=None)
@given(sequences())
def test_random_sequences_score_as_motmetrics_scores_them(frames):
    assert_equal(*both(frames))


@pytest.mark.parametrize(
    "scene",
    [
        Scene("crowd", 6, 3, "ring", "wander", seed=7, seconds=12.0),
        Scene("wall", 8, 2, "wall", "cross", ghosts=0.1, dropout=0.04, seed=3, seconds=12.0),
        Scene("in-out", 4, 2, "thesis", "in_out", seed=5, seconds=12.0),
    ],
    ids=lambda s: s.name,
)
def test_the_detectors_own_sequences_score_as_motmetrics_scores_them(scene):
    frames = [(step.truth, step.tracks) for step in play(scene)]
    ours, theirs = both(frames)
    assert ours["objects"] > 0 and ours["hypotheses"] > 0
    assert_equal(ours, theirs)


def test_a_track_keeps_its_person_while_within_the_gate():
    """Track 20 follows person 1; track 21 appears closer to them, but 20 is still
    within the gate: no switch (re-running the assignment every frame would count
    one, and one back when 21 leaves)."""
    person = {1: np.array([0.0, 0.0])}
    frames = [
        (person, {20: np.array([0.1, 0.0])}),
        (person, {20: np.array([0.3, 0.0]), 21: np.array([0.05, 0.0])}),
        (person, {20: np.array([0.1, 0.0])}),
    ]
    ours, theirs = both(frames)
    assert ours["id_switches"] == 0 and ours["false_positives"] == 1
    assert_equal(ours, theirs)
    gone = [*frames[:2], (person, {21: np.array([0.05, 0.0])})]  # 20 lost: 21 takes over
    ours, theirs = both(gone)
    assert ours["id_switches"] == 1
    assert_equal(ours, theirs)
