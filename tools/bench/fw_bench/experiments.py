"""The experiments of `fw bench`: each runs, keeps its series and returns its rows.

`EXPERIMENTS` maps a name to a function `(quick, context) -> rows`; `context` carries
what experiments share (the running SEEG deployment, the Zenoh hop, the series that
become `summary.json` and the figures).
"""

from __future__ import annotations

import dataclasses
import math
import statistics
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from fw_bench.files import seeg_file
from fw_bench.report import Row, stats


def run_zenoh(quick: bool, context: dict[str, Any]) -> list[Row]:
    """Raw Zenoh inter-process hop (the baseline every latency is compared with), and
    the host's speed for plain Python (the baseline every cost is read against). The
    hops only if an experiment of the run crosses processes (`context["hops"]`)."""
    from fw_bench.baseline import python_speed, stream_cost, wake_round_trip, zenoh_hop

    speed = python_speed(1 if quick else 3)
    wake = wake_round_trip(5000 if quick else 20000)
    host = [
        Row("host", "plain Python: 10^7 additions (CPU)", speed, unit="s"),
        Row("host", "a wake-up round trip between two processes", wake, unit="us"),
    ]
    if not context.get("hops", True):  # offline experiments only: nothing to compare
        return host

    hops = zenoh_hop(200 if quick else 2000)
    s = stats([h * 1e3 for h in hops])
    context["hop_ms"] = s["p50"]
    tls = zenoh_hop(200 if quick else 2000, secure=True)
    t = stats([h * 1e3 for h in tls])
    stream = stream_cost(1.0 if quick else 5.0)
    per_sample = stream["publisher_us"] + stream["subscriber_us"]
    return [
        Row("zenoh", "hop p50", s["p50"], n=len(hops)),
        Row("zenoh", "hop p99", s["p99"], n=len(hops)),
        Row("zenoh", "hop p50, mutual TLS (as fw deploy runs)", t["p50"], n=len(tls)),
        Row("zenoh", "hop p99, mutual TLS (as fw deploy runs)", t["p99"], n=len(tls)),
        Row("zenoh", "1 kHz stream: publisher CPU per sample", stream["publisher_us"], unit="us"),
        Row("zenoh", "1 kHz stream: subscriber CPU per sample", stream["subscriber_us"], unit="us"),
        Row("zenoh", "1 kHz stream between two processes", per_sample / 1000.0, unit="cores"),
        *host,
    ]


def _seeg(context: dict[str, Any]) -> Any:
    if "seeg" not in context:
        from fw_bench.baseline import zenoh_hop
        from fw_bench.seeg_run import SeegRun

        print("deploying topologies/seeg.yaml on a private bus ...", file=sys.stderr)
        context["seeg"] = SeegRun(secure=context.get("bus", "mtls") == "mtls").start()
        hops = zenoh_hop(200 if context.get("quick") else 1000)
        s = stats([h * 1e3 for h in hops])
        context.setdefault("extra_rows", []).extend(
            [
                Row("zenoh", "hop p50, SEEG deployment running", s["p50"], n=len(hops)),
                Row("zenoh", "hop p99, SEEG deployment running", s["p99"], n=len(hops)),
            ]
        )
    return context["seeg"]


def _progress(name: str) -> Callable[[int, int], None]:
    def show(done: int, total: int) -> None:
        print(f"\r{name}: {done}/{total}", end="" if done < total else "\n", file=sys.stderr)

    return show


def _stage_rows(experiment: str, trials: list[Any]) -> list[Row]:
    """p50 of each stage of the reaction chain: where the time goes."""
    names: list[str] = []
    for t in trials:
        names += [n for n in t.detail.get("stages", {}) if n not in names]
    rows = []
    for name in names:
        values = [t.detail["stages"][name] * 1e3 for t in trials if name in t.detail["stages"]]
        rows.append(
            Row(experiment, f"stage: {name}, p50", statistics.median(values), n=len(values))
        )
    return rows


def run_swap(quick: bool, context: dict[str, Any]) -> list[Row]:
    """Sensor Swap (eq. 3.12, Fig. 4.1): Certus occluded while moving -> Vicra in use."""
    from fw_bench import latency

    trials = latency.sensor_swap(_seeg(context), 5 if quick else 50, _progress("swap"))
    ms = [t.latency * 1e3 for t in trials]
    s = stats(ms)
    context.setdefault("series", {})["swap_ms"] = ms
    context["swap_latency_p50_ms"] = s["p50"]
    age = statistics.median(t.detail["sample_age"] * 1e3 for t in trials)
    return [
        Row("swap", "L p50", s["p50"], thesis=12.5, target=1.0, n=len(ms)),
        Row("swap", "L IQR", s["iqr"], thesis=5.9, n=len(ms)),
        Row("swap", "L p99", s["p99"], target=3.0, n=len(ms)),
        Row("swap", "age of the first Vicra sample p50", age, n=len(ms)),
        *_stage_rows("swap", trials),
    ]


def run_cost(quick: bool, context: dict[str, Any]) -> list[Row]:
    """What the simulated OR costs (issue 18): cores per process braked and waiting, then
    moving with people in the room; the 1 kHz arm loop's real-time factor and cycle
    intervals; with `--load N` busy loops on the host."""
    from fw_bench import cost

    load = int(context.get("load", 0))
    windows = cost.idle_and_moving(
        _seeg(context), 3.0 if quick else 20.0, 2.0 if quick else 5.0, load
    )
    context.setdefault("series", {})["cost"] = {
        "load": load,
        **{name: cost.summary(w) for name, w in windows.items()},
    }
    under = f" ({load} busy loops)" if load else ""
    rows = []
    for name, window in windows.items():
        what = "braked, waiting" if name == "idle" else "moving"
        for process, cores in sorted(window.cores.items()):
            rows.append(Row("cost", f"{what}{under}: {process}", cores, unit="cores", n=1))
        if window.interrupted:
            rows.append(
                Row(
                    "cost",
                    f"{what}{under}: motions a stop cut short before this one (reasons in "
                    "summary.json)",
                    float(len(window.interrupted)),
                    unit="",
                    n=1,
                )
            )
        rows.append(
            Row(
                "cost",
                f"{what}{under}: wake-ups, all processes (context switches per s)",
                sum(window.wakeups.values()),
                unit="/s",
                n=1,
            )
        )
        rows.append(
            Row(
                "cost",
                f"{what}{under}: total",
                window.total,
                target=0.30 if name == "idle" else 0.45,
                unit="cores",
                n=1,
            )
        )
        rows.append(
            Row(
                "cost",
                f"{what}{under}: people the detector tracked in the room (at the window's end)",
                window.people,
                unit="",
                n=1,
            )
        )
        rows.append(
            Row(
                "cost",
                f"{what}{under}: arm loop real-time factor",
                window.realtime,
                target=0.99,
                unit="x",
                n=1,
                at_least=True,
            )
        )
        rows.append(
            Row(
                "cost",
                f"{what}{under}: a process holding only a Zenoh session",
                window.zenoh_idle,
                unit="cores",
                n=1,
            )
        )
        loop = window.loop
        if loop:
            n = int(loop.get("cycles") or 0)
            work = loop.get("work_p99_us")
            if work is not None:
                rows.append(
                    Row(
                        "cost",
                        f"{what}{under}: robot loop, Python per cycle p99 ({loop.get('scheduling')})",
                        work / 1000.0,
                        target=0.1 if name == "moving" else None,
                        n=min(n, 2000),
                    )
                )
            for level in ("p50", "p99"):
                after = loop.get(f"after_cycle_{level}_us")
                if after is not None:
                    rows.append(
                        Row(
                            "cost",
                            f"{what}{under}: robot loop, after the command (deferred puts, "
                            f"goals; before the next measurement) {level}",
                            after / 1000.0,
                            n=min(n, 2000),
                        )
                    )
            for stage, q in sorted((loop.get("stages_us") or {}).items()):
                for level in ("p50", "p99"):
                    if q.get(level) is not None:
                        rows.append(
                            Row(
                                "cost",
                                f"{what}{under}: robot loop stage {stage} {level}",
                                q[level] / 1000.0,
                                n=min(n, 2000),
                            )
                        )
        if window.fri:
            fri = window.fri
            rows.append(
                Row(
                    "cost",
                    f"{what}{under}: FRI answers missed or late at the KRC "
                    f"(quality at the end: {fri['quality_end']})",
                    fri["missed"] + fri["late"],
                    unit="",
                    n=1,
                )
            )
        rows.extend(_margin_rows(f"{what}{under}", window.safety))
        cycles = window.cycle_ms
        if not cycles:  # no interval was measured: no figure, and no target said met
            continue
        s = stats(cycles)
        rows.append(Row("cost", f"{what}{under}: arm cycle interval p50", s["p50"], n=len(cycles)))
        rows.append(
            Row(
                "cost",
                f"{what}{under}: arm cycle interval p99",
                s["p99"],
                target=1.5,
                n=len(cycles),
            )
        )
    return rows


def _margin_rows(what: str, safety: dict[str, Any]) -> list[Row]:
    """The safety monitor's trips and its tightest watch, since it armed (the deployment
    is healthy throughout `cost`: every trip is a false one, and the longest silence a
    healthy producer showed is the margin its deadline leaves)."""
    from fw_bench import cost

    if not safety:
        return []
    rows = [
        Row(
            "cost",
            f"{what}: safety trips since the monitor armed (a healthy run: false trips)",
            float(safety.get("trips") or 0),
            target=0.0,
            unit="",
            n=1,
        )
    ]
    tight = cost.tightest_watch(safety)
    if tight is not None:
        name, worst, deadline = tight
        rows.append(
            Row(
                "cost",
                f"{what}: longest silence since the monitor armed, of the watch nearest "
                f"its deadline ({name}; every watch in summary.json)",
                worst,
                target=deadline,
                n=1,
            )
        )
    return rows


def run_nosensor(quick: bool, context: dict[str, Any]) -> list[Row]:
    """No Sensor To Stop (eq. 3.13, Fig. 4.1): the only tracker occluded while moving."""
    from fw_bench import latency

    trials = latency.no_sensor_to_stop(_seeg(context), 3 if quick else 50, _progress("nosensor"))
    ms = [t.latency * 1e3 for t in trials]
    s = stats(ms)
    context.setdefault("series", {})["nosensor_ms"] = ms
    brake = stats([t.detail["brake"] * 1e3 for t in trials])
    context["series"]["nosensor_brake_ms"] = [t.detail["brake"] * 1e3 for t in trials]
    return [
        Row("nosensor", "L p50", s["p50"], thesis=7.3, target=0.5, n=len(ms)),
        Row("nosensor", "L IQR", s["iqr"], thesis=2.2, n=len(ms)),
        Row("nosensor", "L p99", s["p99"], n=len(ms)),
        Row("nosensor", "to the braking cycle p50", brake["p50"], n=len(ms)),
        Row("nosensor", "to the braking cycle p99", brake["p99"], n=len(ms)),
        *_stage_rows("nosensor", trials),
    ]


PREEMPTED = "leans stopped by speed and separation monitoring first"
"""The collision experiment's count of leans the robot's own separation monitoring
stopped before the Supervisor's collision halt (`latency.collision_reaction`)."""


def run_collision(quick: bool, context: dict[str, Any]) -> list[Row]:
    """Collision Reaction (eq. 3.18, Fig. 4.5): a surgeon leans over the moving robot."""
    from fw_bench import latency

    every = latency.collision_reaction(_seeg(context), 3 if quick else 50, _progress("collision"))
    trials = [t for t in every if not t.detail.get("preempted")]
    preempted = len(every) - len(trials)
    if not trials:  # the Supervisor's path, the thesis's, was never what stopped the arm
        return [Row("collision", PREEMPTED, float(preempted), unit="", n=preempted)]
    ms = [t.latency * 1e3 for t in trials]
    brake = [t.detail["brake"] * 1e3 for t in trials]
    s, b = stats(ms), stats(brake)
    context.setdefault("series", {})["collision_ms"] = ms
    context["series"]["collision_brake_ms"] = brake
    return [
        Row("collision", PREEMPTED, float(preempted), unit="", n=len(every)),
        Row("collision", "L p50", s["p50"], thesis=1.1, target=0.3, n=len(ms)),
        Row("collision", "L IQR", s["iqr"], thesis=0.3, n=len(ms)),
        Row("collision", "L p99", s["p99"], target=1.0, n=len(ms)),
        Row("collision", "to the braking cycle p50", b["p50"], n=len(ms)),
        Row("collision", "to the braking cycle p99", b["p99"], n=len(ms)),
        *_stage_rows("collision", trials),
    ]


def _median_and_p99(
    experiment: str,
    what: str,
    values: list[float],
    targets: tuple[float | None, float | None] = (None, None),
    after: str = "",
) -> list[Row]:
    """The p50 and p99 rows of `values` (ms): "`what` p50`after`", "`what` p99`after`",
    with their targets (p50, p99)."""
    q = stats(values)
    return [
        Row(experiment, f"{what} {level}{after}", q[level], target=target, n=len(values))
        for level, target in zip(("p50", "p99"), targets, strict=True)
    ]


def run_ssm(quick: bool, context: dict[str, Any]) -> list[Row]:
    """Protective stops (issue 18): a person appears beside the moving arm; speed and
    separation monitoring stops it in the robot interface's own cycle."""
    from fw_bench import latency

    trials = latency.protective_stops(_seeg(context), 3 if quick else 30, _progress("ssm"))
    ms = [t.latency * 1e3 for t in trials]
    published = [t.detail["published"] * 1e3 for t in trials if t.detail["published"] is not None]
    if not published:
        from fw_bench.seeg_run import BenchError

        raise BenchError("ssm: the bench heard none of the frames that decided the stops")
    context.setdefault("series", {})["ssm_ms"] = ms
    return [
        *_median_and_p99("ssm", "envelopes taken by the loop -> braking cycle", ms),
        *_median_and_p99(
            "ssm", "the detector's frame published -> braking cycle", published, (None, 2.0)
        ),
        *_median_and_p99(
            "ssm",
            "their camera frame -> braking cycle",
            [t.detail["frame"] * 1e3 for t in trials],
            after=" (the detection within)",
        ),
        *_median_and_p99("ssm", "the separation check", [t.detail["check"] * 1e3 for t in trials]),
        *_median_and_p99(
            "ssm",
            "detection -> stop command",
            [t.detail["command"] * 1e3 for t in trials],
            (0.1, 1.0),
        ),
    ]


def run_repeated(quick: bool, context: dict[str, Any]) -> list[Row]:
    """Repeated Sensor Failure (eq. 3.14, Fig. 4.3): repetitions of consecutive swaps."""
    from fw_bench import latency

    repetitions, swaps = (2, 3) if quick else (context.get("repetitions", 30), 50)
    blocks = latency.repeated_swaps(_seeg(context), repetitions, swaps, _progress("repeated"))
    ms = [[t.latency * 1e3 for t in block] for block in blocks]
    context.setdefault("series", {})["repeated_ms"] = ms
    medians = [statistics.median(b) for b in ms]
    iqrs = [stats(b)["iqr"] for b in ms]
    n = sum(len(b) for b in ms)
    everything = stats([v for b in ms for v in b])
    return [
        Row("repeated", "all swaps p50", everything["p50"], target=1.0, n=n),
        Row("repeated", "all swaps p99", everything["p99"], target=3.0, n=n),
        Row("repeated", "median of the repetition medians", statistics.median(medians), n=n),
        Row("repeated", "worst repetition median", max(medians), thesis=14.6, n=n),
        Row("repeated", "best repetition median", min(medians), thesis=11.1, n=n),
        Row("repeated", "widest repetition IQR", max(iqrs), thesis=10.55, n=n),
        Row("repeated", "narrowest repetition IQR", min(iqrs), thesis=1.45, n=n),
    ]


def run_motion(quick: bool, context: dict[str, Any]) -> list[Row]:
    """Swap during motion (Fig. 4.2): the pose jump at each swap, from calibrations."""
    from fw_bench import latency

    data = latency.swap_during_motion(_seeg(context), 1 if quick else 5, _progress("motion"))
    context.setdefault("series", {})["motion"] = data
    jumps = [s["jump_m"] * 1e3 for s in data["swaps"]]
    if not jumps:
        return [Row("motion", "swaps seen", 0.0, unit="", n=0)]
    s = stats(jumps)
    return [
        Row("motion", "pose jump at a swap p50", s["p50"], unit="mm", n=len(jumps)),
        Row("motion", "pose jump at a swap max", s["max"], unit="mm", n=len(jumps)),
    ]


def run_braking(quick: bool, context: dict[str, Any]) -> list[Row]:
    """Behavioural control on the MuJoCo arm (Fig. 4.6-4.8), on the simulated clock."""
    from fw_bench import braking

    stops = braking.stops(2 if quick else 20)
    trace = braking.behaviour_trace()
    series = context.setdefault("series", {})
    series["braking"] = stops
    series["behaviour"] = {
        "t": trace.t[::5],
        "commanded": trace.commanded[::5],
        "actual": trace.actual[::5],
        "speed": trace.speed[::5],
        "events": trace.events,
    }
    # the arm is the thesis' (its lag is fitted to Fig. 4.8, docs/seeg.md): the actual
    # TCP's figures are the arm's, reproduced within 30%; fw's own part is the
    # command's return to the STOP point
    thesis_rmse = {1.0: (0.64, 0.36), 10.0: (5.9, 3.4)}
    thesis_displacement = {10.0: 6.0}
    targets = {1.0: 1.0}  # sub-millimetric in the critical area (thesis 5)
    rows = []
    for speed in sorted({s["speed_cm_s"] for s in stops}):
        mine = [s for s in stops if s["speed_cm_s"] == speed]
        rmse_x, rmse_y = thesis_rmse.get(speed, (None, None))
        for key, quantity, thesis, target in (
            (
                "displacement_mm",
                "actual TCP displacement after STOP",
                thesis_displacement.get(speed),
                targets.get(speed),
            ),
            ("rmse_x_mm", "RMSE actual vs command while braking, x", rmse_x, None),
            ("rmse_y_mm", "RMSE actual vs command while braking, y", rmse_y, None),
        ):
            median = statistics.median(s[key] for s in mine)
            rows.append(
                Row(
                    "braking",
                    f"{speed:g} cm/s: {quantity} p50",
                    median,
                    thesis=thesis,
                    target=target,
                    unit="mm",
                    n=len(mine),
                )
            )
    rows.append(
        Row(
            "braking",
            "return to the STOP point: worst actual error",
            max(s["return_error_mm"] for s in stops),
            target=0.1,
            unit="mm",
            n=len(stops),
        )
    )
    return rows


def run_statechart(quick: bool, context: dict[str, Any]) -> list[Row]:
    """Transition latency against depth, beside sismic (Fig. 3.8)."""
    import tempfile

    from fw_bench import statechart

    events = 2000 if quick else 20000
    rows, series = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for depth in statechart.DEPTHS:
            fw = statechart.bench_fw(depth, events, Path(tmp))
            sm = statechart.bench_sismic(depth, max(events // 10, 500))
            series.append({"depth": depth, "fw": fw, "sismic": sm})
            rows.append(
                Row("statechart", f"depth {depth}: fw p50", fw["p50_us"], unit="us", n=events)
            )
            rows.append(
                Row("statechart", f"depth {depth}: fw p99", fw["p99_us"], unit="us", n=events)
            )
            if sm:
                rows.append(
                    Row(
                        "statechart",
                        f"depth {depth}: sismic p50",
                        sm["p50_us"],
                        unit="us",
                        n=events // 10,
                    )
                )
        load = statechart.bench_load(Path(tmp), 5 if quick else 20)
        growth = statechart.bench_growth(Path(tmp), 3 if quick else 10)
    for what, size, per_unit in growth:
        unit = "state" if what == "states" else "level"
        rows.append(
            Row("statechart", f"load + validate per {unit}, {size} {what}", per_unit, unit="us")
        )
    context.setdefault("series", {})["statechart"] = series
    rows.append(
        Row(
            "statechart",
            f"{load['states']}-state chart: load + validate",
            load["fw_ms"],
            target=30.0,
            n=5 if quick else 20,
        )
    )
    return rows


def _suite_rows(quick: bool, context: dict[str, Any]) -> list[Row]:
    """The scene suite (issue 19): per scene MOTA, IDF1, identity switches and frames
    with phantom people near the table; then the worst, median and best scene."""
    from fw_bench import scenes

    chosen = scenes.suite(context.get("variant", 0))
    if quick:
        chosen = [dataclasses.replace(s, seconds=8.0) for s in chosen[::8]]
    results = scenes.run_all(chosen, _progress("people suite"))
    context["people_suite"] = results
    rows = []
    for name, r in results.items():
        rows += [
            Row("people suite", f"{name}: MOTA", r["MOTA"], unit="", target=0.95, at_least=True),
            Row("people suite", f"{name}: IDF1", r["IDF1"], unit="", target=0.90, at_least=True),
            Row("people suite", f"{name}: identity switches", r["id_switches"], unit=""),
            Row(
                "people suite",
                f"{name}: frames with a phantom near the table",
                r["phantom_near_frames"],
                unit="",
                target=0.0,
            ),
            Row(
                "people suite",
                f"{name}: frames with someone missing near the table",
                r["missed_near_frames"],
                unit="",
            ),
            Row(
                "people suite",
                f"{name}: frames the count is wrong though a camera reports everyone there",
                r["count_wrong_all_seen_frames"],
                unit="",
                target=0.0,
            ),
        ]
    for metric, target in (("MOTA", 0.95), ("IDF1", 0.90)):
        values = sorted(r[metric] for r in results.values())
        rows += [
            Row(
                "people suite",
                f"{metric} worst scene",
                values[0],
                unit="",
                target=target,
                at_least=True,
                n=len(values),
            ),
            Row(
                "people suite",
                f"{metric} median scene",
                statistics.median(values),
                unit="",
                n=len(values),
            ),
            Row("people suite", f"{metric} best scene", values[-1], unit="", n=len(values)),
        ]
    for key, what in (
        ("ghost_track_frames", "frames a track counted on no one (a ghost), all scenes"),
        ("duplicate_track_frames", "frames a second track counted on someone, all scenes"),
    ):
        rows.append(
            Row(
                "people suite",
                what,
                sum(r[key] for r in results.values()),
                unit="",
                n=len(results),
            )
        )
    phantoms = sum(r["phantom_near_frames"] > 0 for r in results.values())
    rows.append(
        Row(
            "people suite",
            "scenes with a phantom near the table",
            phantoms,
            unit="",
            target=0.0,
            n=len(results),
        )
    )
    return rows


def run_people(quick: bool, context: dict[str, Any]) -> list[Row]:
    """People detection (Tables 4.1/4.2), frame cost and the Kinect calibration (Fig. 4.4)."""
    from components.people.cli import cameras_of
    from components.people.cli import run as calibrate
    from fw_bench import people, scenes

    trials = 3 if quick else 30
    one, two = people.protocol(1, trials), people.protocol(2, trials)
    crowd = scenes.crowd(10.0 if quick else 60.0, "hungarian")
    cost = people.frame_cost(8, 16, 60 if quick else 300, "hungarian")
    _, report = calibrate(
        cameras_of(str(seeg_file("topologies", "seeg.yaml"))),
        "kinect_0",
        4,
        16,
        0,
        0.05,
        {"center": [0.0, 0.0], "radius": 1.5},
    )
    if context.get("suite"):
        context.setdefault("extra_rows", []).extend(_suite_rows(quick, context))
    residuals = {n: r["residual_mm"] for n, r in report.items() if n != "robot"}
    context.setdefault("series", {})["kinect_residuals"] = residuals
    rows = [
        Row("people", "accuracy, 1 user", one["accuracy"], thesis=0.923, unit="", n=trials),
        Row("people", "accuracy, 2 users", two["accuracy"], thesis=0.992, unit="", n=trials),
        Row("people", "sensitivity, 1 user", one["sensitivity"], unit="", n=trials),
        Row("people", "specificity, 1 user", one["specificity"], unit="", n=trials),
        Row("people", "crowd MOTA (6 people, 3 cameras)", crowd["MOTA"], unit="", n=1),
        Row("people", "frame p99, 8 cameras x 16 people", cost["p99_ms"], target=3.0, n=1),
    ]
    for name, r in residuals.items():
        rows.append(
            Row("people", f"{name} board residual median", r["median"], thesis=35.0, unit="mm")
        )
        rows.append(
            Row("people", f"{name} board residual IQR", r["p75"] - r["p25"], thesis=20.0, unit="mm")
        )
    return rows


def run_scale(quick: bool, context: dict[str, Any]) -> list[Row]:
    """How the per-cycle costs grow: 2-16 trackers, 2-8 cameras x 16 people."""
    from fw_bench import people, scale

    cycles, frames = (2000, 60) if quick else (20000, 300)
    rows = []
    for n in (2, 4, 8, 16):
        c = scale.cycle_times(n, cycles)
        rows.append(
            Row(
                "scale",
                f"Sensor Manager cycle, {n} trackers, p99",
                c["p99_us"],
                unit="us",
                n=cycles,
            )
        )
    for cams in (2, 4, 8):
        c = people.frame_cost(cams, 16, frames, "hungarian")
        rows.append(Row("scale", f"people frame, {cams} cameras x 16, p99", c["p99_ms"], n=frames))
    return rows


def run_chaos(quick: bool, context: dict[str, Any]) -> list[Row]:
    """Every process crashed or hung while moving (docs/safety.md); a fresh deployment
    per case. Fails the run (exit 1) if any case ends unbraked or moves before RELEASE."""
    from fw_bench import chaos

    repetitions = 1 if quick else context.get("chaos_repetitions", 6)
    if context.get("hosts"):
        return _chaos_on_hosts(repetitions, context)
    cases, setups = chaos.chaos(repetitions, _progress("chaos"))
    context.setdefault("series", {})["chaos"] = [
        {**c.__dict__, "name": c.name, "ok": c.ok} for c in cases
    ]
    context["series"]["chaos_setups_failed"] = setups
    bad = [c for c in cases if not c.ok]
    if bad:
        context["failed"] = [
            f"chaos: {c.process} {c.name}: {c.detail or 'not braked'}" for c in bad
        ]
    rows = []
    for kind, target in (("KILL", 20.0), ("STOP", 60.0), ("LINK", None)):
        times = [
            c.to_braking_ms
            for c in cases
            if c.signal == kind and c.to_braking_ms is not None and c.process != "arm"
        ]
        if times:
            s = stats(times)
            label = {"KILL": "crash", "STOP": "hang", "LINK": "FRI link fault"}[kind]
            rows += [
                Row("chaos", f"{label} -> first braking cycle p50", s["p50"], n=len(times)),
                Row(
                    "chaos",
                    f"{label} -> first braking cycle p99",
                    s["p99"],
                    target=target,
                    n=len(times),
                ),
            ]
    kinds = [(p, n) for p in chaos.PROCESSES for n in ("KILL", "STOP 2s", "STOP 0.3s")]
    kinds += [("fri", link[0]) for link in chaos.LINK_FAULTS]
    for process, name in kinds:
        mine = [c for c in cases if c.process == process and c.name == name]
        times = [c.to_braking_ms for c in mine if c.to_braking_ms is not None]
        if times:
            rows.append(Row("chaos", f"{process} {name}: to braking, max", max(times), n=len(mine)))
    rows.append(_setups_row("chaos", setups, len(cases)))
    moved = sum(c.moved_without_release for c in cases)
    rows.append(
        Row(
            "chaos",
            "motions after a fault without RELEASE",
            moved,
            target=0.0,
            unit="",
            n=len(cases),
        )
    )
    rows.append(
        Row(
            "chaos",
            "cases ending unbraked (of those that must brake)",
            sum(not c.ended_braked for c in cases if c.must_brake),
            target=0.0,
            unit="",
            n=len(cases),
        )
    )
    return rows


def _setups_row(experiment: str, setups: list[str], cases: int) -> Row:
    """The count of a chaos run's fresh deployments that never began the approach."""
    return Row(
        experiment,
        "fresh deployments that never began the approach (no fault injected; run "
        "again; why in summary.json)",
        float(len(setups)),
        unit="",
        n=cases + len(setups),
    )


def _chaos_on_hosts(repetitions: int, context: dict[str, Any]) -> list[Row]:
    """`chaos --hosts` (fw_bench/hosts_chaos.py): every host cut off or made lossy
    while moving. Fails the run (exit 1) if any case ends unbraked or moves before
    RELEASE; a stop before the fault (a starved host) is counted, not timed."""
    from fw_bench import hosts_chaos

    kinds = tuple(context.get("host_faults") or ())
    cases, skipped, setups = hosts_chaos.chaos_on_hosts(
        repetitions, _progress("chaos --hosts"), kinds
    )
    context.setdefault("series", {})["chaos_hosts"] = [
        {**c.__dict__, "name": c.name, "ok": c.ok} for c in cases
    ]
    context["series"]["chaos_hosts_setups_failed"] = setups
    bad = [c for c in cases if not c.ok]
    if bad:
        context["failed"] = [f"chaos --hosts: {c.process} {c.name}: {c.detail}" for c in bad]
    for c in cases:
        if any(c.recording_gaps.values()):
            context.setdefault("failed", []).append(
                f"chaos --hosts: {c.process} {c.name}: missing from the recording: "
                f"{c.recording_gaps}"
            )
    rows = []
    for name, _ in hosts_chaos.FAULTS:
        times = [c.to_braking_ms for c in cases if c.name == name and c.to_braking_ms is not None]
        if times:
            s = stats(times)
            rows += [
                Row("chaos --hosts", f"{name} -> first braking cycle p50", s["p50"], n=len(times)),
                Row("chaos --hosts", f"{name} -> first braking cycle p99", s["p99"], n=len(times)),
            ]
    partitions = [c for c in cases if c.name.startswith("partition")]
    beyond = [b for b in map(hosts_chaos.beyond_deadline, partitions) if b is not None]
    if beyond:
        s = stats(beyond)
        rows += [  # the target: p99 <= the watch deadline + 2 ms, >= 50 partitions
            Row(
                "chaos --hosts",
                "partition -> first braking cycle, beyond the deadline that tripped, p99",
                s["p99"],
                target=2.0,
                n=len(beyond),
            ),
            Row(
                "chaos --hosts",
                "partition -> first braking cycle, beyond the deadline that tripped, max",
                max(beyond),
                n=len(beyond),
            ),
        ]
    judged = [c for c in cases if hosts_chaos.judged(c)]
    rows += [
        _setups_row("chaos --hosts", setups, len(cases)),
        Row(
            "chaos --hosts",
            "cases without a verdict (the control host's run did not end, a report "
            "unanswered: in summary.json)",
            len(cases) - len(judged),
            unit="",
            n=len(cases),
        ),
    ]
    for host in hosts_chaos.HOSTS:
        for name, _ in hosts_chaos.FAULTS:
            mine = [c for c in cases if c.process == host and c.name == name]
            times = [c.to_braking_ms for c in mine if c.to_braking_ms is not None]
            if times:
                rows.append(
                    Row("chaos --hosts", f"{host} {name}: to braking, max", max(times), n=len(mine))
                )
    recorded = [c for c in cases if c.recording_gaps]
    if recorded:
        rows.append(
            Row(
                "chaos --hosts",
                "chart records, requests and answers missing from the control host's recording",
                float(sum(sum(c.recording_gaps.values()) for c in recorded)),
                target=0.0,
                unit="",
                n=len(recorded),
            )
        )
    early = sum(c.detail.startswith("tripped") for c in cases)
    rows.append(
        Row(
            "chaos --hosts",
            "cases stopped before the fault (not timed)",
            early,
            unit="",
            n=len(cases),
        )
    )
    rows.append(
        Row(
            "chaos --hosts",
            "motions after a fault without RELEASE (of the cases judged)",
            sum(c.moved_without_release for c in judged),
            target=0.0,
            unit="",
            n=len(judged),
        )
    )
    for why in skipped:  # said, and kept in summary.json
        print(f"chaos --hosts: {why}", file=sys.stderr)
    context["series"]["chaos_hosts_not_injected"] = skipped
    return rows


def run_navigation(quick: bool, context: dict[str, Any]) -> list[Row]:
    """Navigation on the patient (issue 17): the real arm's error at the target by who
    steers, a head bump, a swap during motion; on the simulated clock."""
    import numpy as np

    from fw_bench import navigation

    count = 1 if quick else 20
    seeds = 1 if quick else 10
    errors = navigation.final_errors(count, _progress("navigation"))
    steering = ("certus",) if quick else ("certus", "vicra")  # quick: the same code once
    bumps = {who: navigation.head_bump(tracker=who) for who in steering}
    swaps = {
        v: [navigation.swap_transient(v, seed, trace=seed == 0) for seed in range(seeds)]
        for v in (0.075, 0.10)
    }
    # beside what `bumps` (run first) keeps there, not over it
    context.setdefault("series", {}).setdefault("navigation", {}).update(
        {
            "final_errors_mm": errors,
            "head_bump": bumps,
            "swaps": {f"{v * 100:g} cm/s": runs for v, runs in swaps.items()},
        }
    )
    rows = []
    for mode, values in errors.items():
        s = stats(values)
        who = "joints alone" if mode == "joints" else f"{mode}-guided"
        joints = mode == "joints"  # the realistic arm: at least 2 mm off, p50
        rows.append(
            Row(
                "navigation",
                f"target error, {who} p50",
                s["p50"],
                target=2.0 if joints else None,
                unit="mm",
                n=count,
                at_least=True,
            )
        )
        rows.append(
            Row(
                "navigation",
                f"target error, {who} p95",
                float(np.percentile(values, 95)),  # type: ignore[arg-type]
                target={"joints": None, "certus": 0.5, "vicra": 1.0}[mode],
                unit="mm",
                n=count,
            )
        )
    for who, bump in bumps.items():
        rows.append(
            Row(
                "navigation",
                f"5 mm head bump, {who}: back within 0.5 mm of the error before",
                bump["recovery_s"],
                target=1.0,
                unit="s",
                n=1,
            )
        )
        rows.append(
            Row(
                "navigation",
                f"5 mm head bump, {who}: fastest command (limit 1 cm/s)",
                round(bump["fastest_command_m_s"] * 100, 9),  # the limit itself, not float noise
                target=1.0,
                unit="cm/s",
                n=1,
            )
        )
    for velocity, runs in swaps.items():
        transients = [run["transient_mm"] for run in runs]
        for label, value in (
            ("p50", float(np.median(transients))),
            ("worst", float(max(transients))),
        ):
            rows.append(
                Row(
                    "navigation",
                    f"swap at {velocity * 100:g} cm/s: transient {label}",
                    value,
                    target=0.3 if velocity <= 0.075 and label == "worst" else None,
                    unit="mm",
                    n=len(runs),
                )
            )
    for who in steering:
        rows.append(
            Row(
                "navigation",
                f"head breathing 1 mm / 4 s, {who}: largest error",
                navigation.breathing(who),
                unit="mm",
                n=1,
            )
        )
    quiet = [
        navigation.swap_transient(0.075, seed, quiet=True)["transient_mm"] for seed in range(seeds)
    ]
    rows.append(
        Row(
            "navigation",
            "swap at 7.5 cm/s, noise-free Vicra (the swap's own part): transient worst",
            float(max(quiet)),
            unit="mm",
            n=len(quiet),
        )
    )
    latency = context.get("swap_latency_p50_ms")  # when the swap experiment ran before
    if latency is not None:
        rows.append(
            Row(
                "navigation",
                "untracked motion at a swap, 10 cm/s",
                navigation.untracked_motion(0.10, latency),
                thesis=2.0,
                unit="mm",
                n=1,
            )
        )
    return rows


def run_bumps(quick: bool, context: dict[str, Any]) -> list[Row]:
    """Head bumps on the deployed system (tools/bench/fw_bench/bumps.py), part of
    `navigation`: each tracker steering, the worst recovery, every false fault or swap,
    a real fault's detection."""
    from fw_bench import bumps

    count = 2 if quick else 60  # quick: one bump out and back per tracker
    result = bumps.deployed(_seeg(context), count, _progress("navigation: deployed bumps"))
    context.setdefault("series", {}).setdefault("navigation", {})["deployed_bumps"] = result
    rows = []
    every = [b for runs in result["bumps"].values() for b in runs]
    for tracker, runs in result["bumps"].items():
        back = [b["back_s"] if b["back_s"] is not None else math.inf for b in runs]
        within = sum(t <= 1.0 for t in back)
        label = f"deployed, 5 mm bumps (50 ms ramp, 26 directions), {tracker} steering"
        rows += [
            Row(
                "navigation",
                f"{label}: back within 0.5 mm, p50",
                stats(back)["p50"],
                unit="s",
                n=len(runs),
            ),
            Row(
                "navigation",
                f"{label}: back within 0.5 mm, worst",
                max(back),
                target=1.0,
                unit="s",
                n=len(runs),
            ),
            Row(
                "navigation",
                f"{label}: share back within 1 s",
                100.0 * within / len(runs),
                target=100.0,
                unit="%",
                n=len(runs),
                at_least=True,
            ),
        ]
    rows += [
        Row(
            "navigation",
            "deployed bumps: calibration faults said",
            float(sum(len(b["faults"]) for b in every)),
            target=0.0,
            unit="",
            n=len(every),
        ),
        Row(
            "navigation",
            "deployed bumps: tracker swaps",
            float(sum(bool(b["swaps"]) for b in every)),
            target=0.0,
            unit="",
            n=len(every),
        ),
        Row(
            "navigation",
            "deployed: procedure stops while waiting for a tracker to steer (RELEASEd; "
            "reasons in summary.json)",
            float(len(result.get("stops_while_settling", []))),
            target=0.0,
            unit="",
            n=1,
        ),
        Row(
            "navigation",
            "deployed bumps re-run after a stop on a late input (the host fell behind; "
            "reasons in summary.json)",
            float(len(result.get("rerun_after_late_input", []))),
            target=0.0,
            unit="",
            n=len(every),
        ),
        Row(
            "navigation",
            "deployed bumps after which the procedure had stopped (the next tracker's "
            "bumps start from a RELEASE)",
            float(sum(b["state"] != "Target_Reached" for b in every)),
            target=0.0,
            unit="",
            n=len(every),
        ),
    ]
    detected = result["real_fault"]["detected_s"]
    rows.append(
        Row(
            "navigation",
            "deployed: a reference tool slipped 6 mm on one tracker, found after",
            math.inf if detected is None else detected * 1e3,
            target=100.0,  # two Vicra periods
            n=1,
        )
    )
    return rows


def run_verify(quick: bool, context: dict[str, Any]) -> list[Row]:
    """`fw verify` on SEEG with its shipped properties: the whole reachable state space
    (at most 2 requests unanswered at once), timed end to end, repeated."""
    import time

    from framework.statechart.loader import load_statechart
    from framework.verify.explore import Environment, Explorer
    from framework.verify.properties import load_properties

    chart = load_statechart(seeg_file("statecharts", "seeg.yaml"))
    props = load_properties(seeg_file("procedures", "seeg", "properties.yaml"), chart)
    runs = []
    for _ in range(1 if quick else 5):
        explorer = Explorer(chart, props.properties, Environment.of(chart), props.unanswered)
        started = time.perf_counter()
        result = explorer.run()
        runs.append((time.perf_counter() - started, result))
    seconds = [t for t, _ in runs]
    result = runs[-1][1]
    held = sum(v.holds for v in result.verdicts)
    print(
        f"verify: SEEG {result.states} states, {result.transitions} transitions, "
        f"{held}/{len(result.verdicts)} properties hold; median {statistics.median(seconds):.2f} s, "
        f"max {max(seconds):.2f} s over {len(seconds)} run(s)",
        file=sys.stderr,
    )
    return [
        Row(
            "verify",
            "SEEG whole state space: median",
            statistics.median(seconds),
            target=10.0,
            unit="s",
            n=len(seconds),
        ),
        Row(
            "verify",
            "SEEG whole state space: worst",
            max(seconds),
            target=10.0,
            unit="s",
            n=len(seconds),
        ),
        Row("verify", "SEEG states explored", float(result.states), unit="states", n=1),
        Row(
            "verify",
            "SEEG properties violated",
            float(len(result.verdicts) - held),
            target=0.0,
            unit="",
            n=len(result.verdicts),
        ),
    ]


def run_ros2(quick: bool, context: dict[str, Any]) -> list[Row]:
    """The SEEG deployment seen from ROS 2 (fw_bench/ros2.py): /joint_states as a ROS
    node receives it, and a ROS pose's way onto fw's bus beside the hops it is made of."""
    from fw_bench import ros2

    return ros2.run(quick, context)


def run_hosts(quick: bool, context: dict[str, Any]) -> list[Row]:
    """The network's figures on five hosts beside one (fw_bench/hosts_figures.py)."""
    from fw_bench import hosts_figures

    return hosts_figures.run(quick, context, context.get("lan_delay", hosts_figures.LAN))


OPT_IN = ("chaos", "ros2", "hosts")
"""Experiments run only when named (long and destructive: a deployment per case)."""

EXPERIMENTS: dict[str, Callable[[bool, dict[str, Any]], list[Row]]] = {
    "zenoh": run_zenoh,
    "cost": run_cost,  # first on the deployment: it measures the robot waiting for START
    "swap": run_swap,
    "nosensor": run_nosensor,
    "collision": run_collision,
    "ssm": run_ssm,
    "repeated": run_repeated,
    "motion": run_motion,
    "braking": run_braking,
    "navigation": run_navigation,
    "bumps": run_bumps,  # navigation's bumps on the deployed system
    "statechart": run_statechart,
    "verify": run_verify,
    "people": run_people,
    "scale": run_scale,
    "chaos": run_chaos,
    "ros2": run_ros2,
    "hosts": run_hosts,
}
