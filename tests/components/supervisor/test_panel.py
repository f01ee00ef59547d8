"""Spec: the robot line (the SEEG panel's and the terminal's live screen's) tells the
operator why the robot stopped and whether a RELEASE would be taken now."""

from framework.console.text import robot_line as _robot


def test_a_latched_safety_stop_says_why_and_what_keeps_release_refused():
    line = _robot(
        {
            "braked": True,
            "latched": True,
            "reason": "people_world lost (its process died or cannot be reached)",
            "problems": ["people_world lost (its process died or cannot be reached)"],
        }
    )
    assert line.startswith("SAFETY STOP: people_world lost")
    assert "not yet: people_world lost" in line


def test_once_everything_is_healthy_the_line_says_release_is_possible():
    line = _robot(
        {"braked": True, "latched": True, "reason": "supervisor: no data", "problems": []}
    )
    assert line.endswith("(RELEASE possible)")


def test_plain_brakes_and_motion():
    assert _robot({"braked": True, "latched": False, "reason": "stop"}) == "braked (stop)"
    assert _robot({"braked": False, "latched": False, "reason": ""}) == "released"
    assert _robot({}) == "-"


def test_an_old_report_never_reads_as_the_robot_side_now():
    """The robot side reports its brakes at 2 Hz and on every change; a report older
    than that (its process starved, cut off) is shown as old, never as 'released'."""
    from components.supervisor.panel import STALE_AFTER, SeegPanel

    panel = SeegPanel()
    released = {"braked": False, "latched": False, "reason": ""}
    fresh = {t.id: t for t in panel.tiles({"robot": {"data": released, "age": 0.4}})}
    assert fresh["robot"].text == "released" and not fresh["robot"].stale
    old = {t.id: t for t in panel.tiles({"robot": {"data": released, "age": STALE_AFTER + 1}})}
    assert old["robot"].text.startswith("no report for 3 s (last: released)")
    assert old["robot"].stale and old["robot"].tone == "bad"


def test_the_trace_listens_to_the_slowest_thinned_stream_fast_enough_for_it():
    """The TCP trace takes 20 points a second: it listens where the topology already
    thins the robot's 1 kHz key, not to every sample."""
    from components.supervisor.panel import thinnest

    thinned = {"robot/tcp/at_200hz": 200.0, "robot/tcp/at_50hz": 50.0, "robot/tcp/at_5hz": 5.0}
    assert thinnest("robot/tcp", thinned, 20.0) == "robot/tcp/at_50hz"
    assert thinnest("robot/tcp", thinned, 100.0) == "robot/tcp/at_200hz"
    assert thinnest("robot/tcp", thinned, 500.0) == "robot/tcp", "none fast enough: every sample"
    assert thinnest("robot/tcp", None, 20.0) == "robot/tcp"


def test_the_tracker_tile_is_calm_at_rest_and_red_only_when_a_tracker_is_needed():
    """Braked and waiting for START nobody has chosen a tracker and nothing is wrong:
    'none selected yet', neutral; from the approach on, none is 'No Sensor Available',
    red; a tracker in use is green."""
    from components.supervisor.panel import SeegPanel

    def tracker_tile(active, tracker=None):
        view = {
            "chart": {"data": {"active": active}, "age": 0.1},
            "supervisor": {"data": {"tracker": tracker, "goal": "target"}, "age": 0.1},
        }
        tile = {t.id: t for t in SeegPanel().tiles(view)}["tracker"]
        return tile.text, tile.tone

    waiting = ["System_OK.Task.Idle"]
    assert tracker_tile(waiting) == ("none selected yet", "")
    assert tracker_tile(["System_OK.Task.Tracker_Selection"]) == ("No Sensor Available", "bad")
    assert tracker_tile(["System_OK.Task.No_Tracker"]) == ("No Sensor Available", "bad")
    assert tracker_tile(["System_OK.Task.Moving.Certus_Up"], "certus") == ("certus", "ok")
