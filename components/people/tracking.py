"""Persistent people tracks: identities across frames, confirmation and deletion delays.

Ghost skeletons (false positives under 1 s, thesis 3.4) are single-camera artifacts,
so a track is confirmed either when two or more cameras see the person at once, or
after `confirm_after` seconds of continuous detection by one camera; it is deleted
after `delete_after` seconds without any detection. Only confirmed tracks count as
people; a ghost never becomes one.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from components.people.fusion import gated_pairs, robust_cost


@dataclass
class Person:
    """One fused detection of a frame: joints, per-joint sigma, the cameras that saw it."""

    joints: np.ndarray
    sigma: np.ndarray
    cameras: frozenset[str]
    trusted: bool = True
    """False when only a non-master camera sees it where another camera should (a
    camera whose calibration is wrong produces exactly such misplaced copies)."""


@dataclass
class Track:
    """A person followed over time."""

    id: int
    joints: np.ndarray
    sigma: np.ndarray
    first_seen: float
    last_seen: float
    confirmed: bool = False
    cameras: frozenset[str] = field(default_factory=frozenset)
    frames: int = 0
    untrusted: int = 0


class PeopleTracker:
    """Associates each frame's people with tracks (Hungarian on the robust joint
    distance, gated) and manages their lives."""

    def __init__(
        self,
        confirm_after: float = 1.0,
        delete_after: float = 0.5,
        gate: float = 0.6,
        cameras_to_confirm: int = 2,
    ):
        self.confirm_after, self.delete_after = confirm_after, delete_after
        self.gate, self.cameras_to_confirm = gate, cameras_to_confirm
        self.tracks: list[Track] = []
        self._ids = itertools.count(1)

    def update(self, people: list[Person], now: float) -> list[Track]:
        """Feed one frame; returns the live tracks (tentative and confirmed)."""
        matched_tracks, matched_people = set(), set()
        if self.tracks and people:
            cost = robust_cost(
                np.stack([t.joints for t in self.tracks]), np.stack([p.joints for p in people])
            )
            for i, j in gated_pairs(cost, self.gate):
                track, person = self.tracks[i], people[j]
                track.joints, track.sigma = person.joints, person.sigma
                track.last_seen, track.cameras = now, person.cameras
                track.frames += 1
                track.untrusted += not person.trusted
                matched_tracks.add(i)
                matched_people.add(j)
        for j, person in enumerate(people):
            if j not in matched_people:
                self.tracks.append(
                    Track(
                        next(self._ids),
                        person.joints,
                        person.sigma,
                        now,
                        now,
                        cameras=person.cameras,
                        frames=1,
                        untrusted=int(not person.trusted),
                    )
                )
        alive = []
        for track in self.tracks:
            if now - track.last_seen > self.delete_after:
                continue
            if (
                not track.confirmed
                and track.last_seen == now
                and (
                    len(track.cameras) >= self.cameras_to_confirm
                    or (
                        track.untrusted * 2 <= track.frames  # mostly credible
                        and now - track.first_seen >= self.confirm_after
                    )
                )
            ):
                track.confirmed = True
            alive.append(track)
        self.tracks = alive
        return list(alive)

    @property
    def people(self) -> list[Track]:
        """Confirmed tracks: the people in the room."""
        return [t for t in self.tracks if t.confirmed]
