"""Spec: the scene suite is reproducible and physically possible: people are bodies,
nobody walks through anybody, and nobody stays stuck."""

import dataclasses

import numpy as np
import pytest

from fw_bench import scenes

SUITE = scenes.suite()


def _walk(scene: scenes.Scene) -> tuple[float, int, int]:
    """Least torso distance over the scene, frames some walker waited, frames walked."""
    script = scenes.Script(scene)
    least, waited, walked = np.inf, 0, 0
    before = {pid: p.position.copy() for pid, p in script.people.items()}
    for k in range(int(scene.seconds / scenes.FRAME)):
        skeletons = script.advance(k * scenes.FRAME, scenes.FRAME)
        torsos = np.array([s[2, :2] for s in skeletons.values()])
        if len(torsos) > 1:
            d = np.linalg.norm(torsos[:, None] - torsos[None], axis=2)
            least = min(least, float(d[~np.eye(len(torsos), dtype=bool)].min()))
        for pid, person in script.people.items():
            if person.waypoints:
                walked += 1
                waited += bool(np.allclose(person.position, before[pid]))
            before[pid] = person.position.copy()
    return least, waited, walked


def test_the_suite_has_forty_scenes_of_every_layout_and_behaviour():
    assert len(SUITE) >= 40
    assert {s.layout for s in SUITE} == set(scenes.LAYOUTS)
    assert {s.behaviour for s in SUITE} == set(scenes.BEHAVIOURS)
    assert min(s.people for s in SUITE) == 1 and max(s.people for s in SUITE) == 10
    assert len({s.name for s in SUITE}) == len(SUITE)


@pytest.mark.parametrize(
    "scene",
    [s for s in SUITE if s.people >= 6 and s.behaviour in ("wander", "cross", "pass", "table")][:5],
    ids=lambda s: s.name,
)
def test_people_keep_a_body_width_apart_and_are_never_stuck_for_long(scene):
    scene = dataclasses.replace(scene, seconds=12.0)
    least, waited, walked = _walk(scene)
    assert least >= scenes.PERSONAL - 1e-9
    assert waited <= 0.1 * walked, "crowds flow: walkers rarely wait"


def test_a_scene_plays_the_same_twice():
    scene = dataclasses.replace(SUITE[5], seconds=3.0)
    first = [(s.t, sorted(s.tracks)) for s in scenes.play(scene)]
    again = [(s.t, sorted(s.tracks)) for s in scenes.play(scene)]
    assert first == again and first


def test_the_suite_in_parallel_scores_each_scene_as_one_at_a_time():
    chosen = [dataclasses.replace(s, seconds=4.0) for s in (SUITE[2], SUITE[6])]
    one_at_a_time = {s.name: scenes.run(s) for s in chosen}
    assert all(r["objects"] > 0 for r in one_at_a_time.values()), "people to score"
    assert scenes.run_all(chosen, workers=2) == one_at_a_time


def test_other_variants_are_other_scenes_of_every_kind():
    other = scenes.suite(3)
    assert len(other) == len(SUITE)
    assert {s.layout for s in other} == set(scenes.LAYOUTS)
    assert {s.behaviour for s in other[:24]} == set(scenes.BEHAVIOURS)
    assert not {s.seed for s in other} & {s.seed for s in SUITE}
    assert all(1 <= s.people <= 10 and 2 <= s.cameras <= 4 for s in other)
    assert scenes.suite(3) == other, "reproducible"
