"""The thesis' figures, drawn from one `fw bench` run (PNG, matplotlib, no display).

Each function takes the run's `series` (what `summary.json` holds) and writes one
PNG; a figure whose data the run did not produce is skipped. `draw` returns the
files written.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only: no display, no GUI toolkit

import matplotlib.pyplot as plt


def _save(fig: Any, out: Path, name: str) -> Path:
    path = out / name
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def latencies(series: dict[str, Any], out: Path) -> Path | None:
    """Fig. 4.1 and 4.5: reaction latencies, fw's boxes beside the thesis' medians."""
    panels = [
        ("swap_ms", "Sensor Swap", 12.5),
        ("nosensor_ms", "No Sensor To Stop", 7.3),
        ("collision_ms", "Collision Reaction", 1.1),
    ]
    panels = [p for p in panels if series.get(p[0])]
    if not panels:
        return None
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    ax.boxplot([series[k] for k, _, _ in panels], showfliers=True)
    ax.scatter(
        range(1, len(panels) + 1),
        [t for _, _, t in panels],
        marker="*",
        s=120,
        color="tab:red",
        label="thesis median",
        zorder=3,
    )
    ax.set_xticks(range(1, len(panels) + 1), [n for _, n, _ in panels])
    ax.set_ylabel("latency (ms)")
    ax.set_yscale("log")
    ax.set_title("Reaction latencies: fw (boxes) and the thesis (stars)")
    ax.legend()
    return _save(fig, out, "fig4_1_latencies.png")


def repeated(series: dict[str, Any], out: Path) -> Path | None:
    """Fig. 4.3: swap latency per repetition."""
    blocks = series.get("repeated_ms")
    if not blocks:
        return None
    fig, ax = plt.subplots(figsize=(9, 3.6))
    ax.boxplot(blocks, showfliers=True, flierprops={"marker": "*", "markeredgecolor": "tab:red"})
    ax.set_yscale("log")
    ax.set_xlabel("repetition")
    ax.set_ylabel("Sensor Swap latency (ms)")
    ax.set_title("Repeated sensor failure (median, IQR; stars: outliers)")
    return _save(fig, out, "fig4_3_repeated.png")


def motion(series: dict[str, Any], out: Path) -> Path | None:
    """Fig. 4.2: the robot pose seen by the best tracker across swaps."""
    data = series.get("motion")
    if not data or not data.get("trace"):
        return None
    trace = data["trace"]
    t0 = trace[0][0]
    fig, axes = plt.subplots(3, 1, figsize=(7, 5.5), sharex=True)
    for i, axis in enumerate("xyz"):
        axes[i].plot([p[0] - t0 for p in trace], [p[1 + i] * 1e3 for p in trace], lw=1)
        for swap in data.get("swaps", []):
            axes[i].axvline(swap["t"] - t0, color="tab:red", lw=0.8)
        axes[i].set_ylabel(f"{axis} (mm)")
    axes[-1].set_xlabel("time (s)")
    axes[0].set_title("TCP in the master frame during the approach; red: tracker swaps")
    return _save(fig, out, "fig4_2_swap_during_motion.png")


def navigation(series: dict[str, Any], out: Path) -> Path | None:
    """Fig. 4.2 in the patient frame: the real TCP around the target, with and without a
    Certus-to-Vicra swap at 7.5 cm/s; and the error after a 5 mm head bump by who
    steers."""
    data = series.get("navigation")
    runs = (data or {}).get("swaps", {}).get("7.5 cm/s", [])
    swap = next((run["trace"] for run in runs if "trace" in run), None)
    if swap is None:
        return None
    fig, axes = plt.subplots(4, 1, figsize=(7, 7.5))
    for i, axis in enumerate("xyz"):
        ax = axes[i]
        ax.plot(
            swap["t"],
            [p[i] for p in swap["without_swap_mm"]],
            color="tab:blue",
            label="Certus throughout",
        )
        ax.plot(
            swap["t"],
            [p[i] for p in swap["with_swap_mm"]],
            color="tab:red",
            ls="--",
            label="swap to the Vicra",
        )
        ax.axvline(swap["swap_t"], color="grey", lw=0.8)
        ax.set_ylabel(f"{axis} (mm)")
    axes[0].set_title("Real TCP relative to the target, patient frame (7.5 cm/s); grey: swap")
    axes[0].legend(fontsize=7)
    axes[2].set_xlabel("time (s)")
    for who, bump in data.get("head_bump", {}).items():
        axes[3].plot(bump["t"], bump["error_mm"], label=f"{who}-guided")
    axes[3].set_xlabel("time after a 5 mm head bump (s)")
    axes[3].set_ylabel("error (mm)")
    axes[3].legend(fontsize=7)
    return _save(fig, out, "fig4_2_navigation_patient_frame.png")


def behaviour(series: dict[str, Any], out: Path) -> Path | None:
    """Fig. 4.6/4.7: commanded and actual TCP and the commanded speed, with the speed
    changes and the STOP."""
    data = series.get("behaviour")
    if not data:
        return None
    t = data["t"]
    end = max(at for at, _ in data["events"]) + 1.0 if data["events"] else t[-1]
    keep = sum(1 for x in t if x <= end)  # the motion and one second after the STOP
    t = t[:keep]
    fig, axes = plt.subplots(4, 1, figsize=(7, 7), sharex=True)
    for i, axis in enumerate("xyz"):
        axes[i].plot(
            t, [p[i] * 1e3 for p in data["commanded"][:keep]], color="tab:red", label="command"
        )
        axes[i].plot(
            t,
            [p[i] * 1e3 for p in data["actual"][:keep]],
            color="tab:blue",
            ls="--",
            label="actual",
        )
        axes[i].set_ylabel(f"{axis} (mm)")
    axes[3].plot(t, [v * 100 for v in data["speed"][:keep]], color="tab:green")
    axes[3].set_ylabel("speed (cm/s)")
    axes[3].set_xlabel("time (s)")
    for at, what in data["events"]:
        for ax in axes:
            ax.axvline(at, color="grey", lw=0.7)
        axes[0].annotate(
            what, (at, 1), xycoords=("data", "axes fraction"), fontsize=7, va="bottom", rotation=20
        )
    axes[0].legend(fontsize=7)
    return _save(fig, out, "fig4_6_4_7_behaviour.png")


def braking(series: dict[str, Any], out: Path) -> Path | None:
    """Fig. 4.8: displacement after STOP and RMSE against the command, by speed."""
    stops = series.get("braking")
    if not stops:
        return None
    speeds = sorted({s["speed_cm_s"] for s in stops})
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    axes[0].boxplot([[s["displacement_mm"] for s in stops if s["speed_cm_s"] == v] for v in speeds])
    axes[0].set_xticks(range(1, len(speeds) + 1), [f"{v:g}" for v in speeds])
    axes[0].set_xlabel("speed (cm/s)")
    axes[0].set_ylabel("actual TCP displacement after STOP (mm)")
    for axis in "xyz":
        axes[1].plot(
            speeds,
            [
                sorted(s[f"rmse_{axis}_mm"] for s in stops if s["speed_cm_s"] == v)[
                    len([s for s in stops if s["speed_cm_s"] == v]) // 2
                ]
                for v in speeds
            ],
            marker="o",
            label=axis,
        )
    axes[1].plot([1, 10], [0.64, 5.9], "r*", ms=10, label="thesis (x)")
    axes[1].set_xlabel("speed (cm/s)")
    axes[1].set_ylabel("RMSE actual vs command (mm)")
    axes[1].set_yscale("log")
    axes[1].legend(fontsize=8)
    return _save(fig, out, "fig4_8_braking.png")


def statechart(series: dict[str, Any], out: Path) -> Path | None:
    """Fig. 3.8: transition latency against depth, fw beside sismic."""
    rows = series.get("statechart")
    if not rows:
        return None
    depths = [r["depth"] for r in rows]
    fig, ax = plt.subplots(figsize=(6, 3.6))
    ax.plot(depths, [r["fw"]["p50_us"] for r in rows], marker="o", label="fw p50")
    ax.plot(depths, [r["fw"]["p99_us"] for r in rows], marker="o", ls=":", label="fw p99")
    if all(r.get("sismic") for r in rows):
        ax.plot(depths, [r["sismic"]["p50_us"] for r in rows], marker="s", label="sismic p50")
    ax.axhline(500, color="tab:red", ls="--", label="thesis rFSM bound below depth 5")
    ax.set_yscale("log")
    ax.set_xlabel("transition depth")
    ax.set_ylabel("latency per event (µs)")
    ax.legend(fontsize=8)
    return _save(fig, out, "fig3_8_statechart.png")


def calibration(series: dict[str, Any], out: Path) -> Path | None:
    """Fig. 4.4: Kinect-to-Kinect board residuals (median, IQR) per camera pair."""
    pairs = series.get("kinect_residuals")
    if not pairs:
        return None
    stats = [
        {
            "label": name,
            "med": r["median"],
            "q1": r["p25"],
            "q3": r["p75"],
            "whislo": r["p25"],
            "whishi": r["p90"],
            "fliers": [],
        }
        for name, r in pairs.items()
    ]
    fig, ax = plt.subplots(figsize=(4.5, 3.6))
    ax.bxp(stats, showfliers=False)
    ax.axhline(35, color="tab:red", ls="--", label="thesis median")
    ax.set_ylabel("board residual (mm); whisker: p90")
    ax.legend(fontsize=8)
    return _save(fig, out, "fig4_4_kinect_calibration.png")


FIGURES = (latencies, repeated, motion, navigation, behaviour, braking, statechart, calibration)


def draw(series: dict[str, Any], out: Path) -> list[Path]:
    """Every figure the run has data for."""
    return [p for figure in FIGURES if (p := figure(series, out)) is not None]
