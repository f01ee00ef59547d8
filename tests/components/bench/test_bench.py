"""Spec: `fw bench --quick` runs the latency experiments on the real SEEG deployment
and writes a report and a JSON summary; stamps are causal (effect after cause)."""

import json

from framework.cli import main


def test_quick_bench_measures_swap_and_no_sensor_latencies_on_the_deployment(tmp_path, capsys):
    assert main(["bench", "--quick", "--out", str(tmp_path)]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    rows = {(r["experiment"], r["quantity"]): r for r in summary["rows"]}
    assert rows[("swap", "L p50")]["thesis"] == 12.5 and rows[("swap", "L p50")]["n"] == 5
    assert rows[("nosensor", "L p50")]["n"] == 3
    assert rows[("zenoh", "hop p50")]["fw"] > 0
    # the new tracker's first sample arrives after the fault verdict, the stop after it
    assert all(v > 0 for v in summary["series"]["swap_ms"])
    assert all(v > 0 for v in summary["series"]["nosensor_ms"])
    report = (tmp_path / "report.md").read_text()
    assert "| swap | L p50 (ms) | 12.5 |" in report and "x Zenoh hop" in report


def test_an_unknown_experiment_is_refused_with_the_list(capsys):
    assert main(["bench", "swapp"]) == 2
    assert "unknown experiment(s) swapp: one of zenoh, swap, nosensor" in capsys.readouterr().err
