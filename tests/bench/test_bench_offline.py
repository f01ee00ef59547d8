"""Spec: `fw bench --quick` runs the offline experiments (braking on the MuJoCo arm,
statechart, verify, people, scale) with the host's speed as their only baseline, and
writes their rows and figures. They start no deployment, so they run beside the other
tests; the deployment's experiments are in tests/bench/test_bench.py."""

import json

from framework.cli import main


def test_quick_offline_bench_writes_its_rows_and_figures_with_the_hosts_speed(tmp_path):
    offline = ["braking", "statechart", "verify", "people", "scale"]
    assert main(["bench", "--quick", *offline, "--out", str(tmp_path)]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    rows = {(r["experiment"], r["quantity"]): r for r in summary["rows"]}
    assert {e for e, _ in rows} == {"host", *offline}, "an offline run measured Zenoh hops"
    assert rows[("host", "plain Python: 10^7 additions (CPU)")]["fw"] > 0
    # braking on the MuJoCo arm: slower is shorter, and the arm returns to the STOP point
    stops = summary["series"]["braking"]
    slow = [s["displacement_mm"] for s in stops if s["speed_cm_s"] == 1.0]
    fast = [s["displacement_mm"] for s in stops if s["speed_cm_s"] == 10.0]
    assert max(slow) < min(fast)
    assert rows[("braking", "return to the STOP point: worst actual error")]["met"]
    assert rows[("people", "accuracy, 1 user")]["fw"] > 0.9
    assert any(q.startswith("depth 5: fw p50") for _, q in rows)
    assert any(q.endswith("-state chart: load + validate") for _, q in rows)
    figures = {p.name for p in tmp_path.glob("*.png")}
    assert {
        "fig4_6_4_7_behaviour.png",
        "fig4_8_braking.png",
        "fig3_8_statechart.png",
        "fig4_4_kinect_calibration.png",
    } <= figures
