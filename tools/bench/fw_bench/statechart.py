"""Statechart transition latency against depth, beside sismic (thesis Fig. 3.8).

Measured on equivalent charts, in one run:
  * events/s and p50/p99 microseconds per event for a transition whose source
    and target leaves sit at depth 1, 3, 5 and 8 (exit d states, enter d states),
    for fw and for sismic with its outer-first selection (rFSM semantics);
  * load + validate time of a 200-state chart (fw) beside sismic's YAML import;
  * load cost against size and nesting (issue 20: linear), per state for 200, 800 and
    1,600 states and per level for a chain nested 8, 16 and 31 levels deep (31 is the
    deepest a chart can be: the YAML reader refuses more than 64 levels of nesting).

The thesis' rFSM needed under 500 us for transitions shallower than depth 5.
Targets (statechart issue): >= 10x sismic throughput at depth 5, p99 <= 30 us per
event at depth 5, 200-state load+validate <= 30 ms. `fw bench statechart` runs it.
"""

from __future__ import annotations

import gc
import statistics
import time
from pathlib import Path
from typing import Any

import yaml

from framework.clock import SimulatedClock
from framework.statechart.interpreter import Interpreter
from framework.statechart.loader import load_statechart

DEPTHS = (1, 3, 5, 8)


def branch(prefix: str, depth: int, leaf_transition: dict[str, Any]) -> dict[str, Any]:
    """A chain of nested states prefix1 > prefix2 > ... > prefix<depth> (the leaf)."""
    leaf: dict[str, Any] = {"name": f"{prefix}{depth}", "transitions": [leaf_transition]}
    node = leaf
    for level in range(depth - 1, 0, -1):
        node = {"name": f"{prefix}{level}", "initial": node["name"], "states": [node]}
    return node


def fw_chart(depth: int) -> str:
    a = branch("A", depth, {"event": "go", "target": f"B{depth}"})
    b = branch("B", depth, {"event": "back", "target": f"A{depth}"})
    return yaml.safe_dump(
        {
            "statechart": f"depth{depth}",
            "events": {"go": None, "back": None},
            "initial": "A1",
            "states": [a, b],
        },
        sort_keys=False,
    )


def sismic_chart(depth: int) -> str:
    def convert(node: dict[str, Any]) -> dict[str, Any]:
        out: dict[str, Any] = {"name": node["name"]}
        if "states" in node:
            out["initial"] = node["initial"]
            out["states"] = [convert(c) for c in node["states"]]
        if "transitions" in node:
            out["transitions"] = node["transitions"]
        return out

    a = branch("A", depth, {"event": "go", "target": f"B{depth}"})
    b = branch("B", depth, {"event": "back", "target": f"A{depth}"})
    return yaml.safe_dump(
        {
            "statechart": {
                "name": f"depth{depth}",
                "root state": {"name": "root", "initial": "A1", "states": [convert(a), convert(b)]},
            }
        },
        sort_keys=False,
    )


def measure(dispatch: Any, events: int) -> dict[str, float]:
    """Per-event latencies of alternating go/back events."""
    names = ("go", "back")
    for i in range(min(2000, events)):  # warm-up
        dispatch(names[i & 1])
    samples = [0] * events
    clock = time.perf_counter_ns
    gc.collect()
    gc.disable()
    try:
        start = clock()
        for i in range(events):
            t0 = clock()
            dispatch(names[i & 1])
            samples[i] = clock() - t0
        total = clock() - start
    finally:
        gc.enable()
    samples.sort()
    return {
        "events_per_s": events / (total / 1e9),
        "p50_us": samples[len(samples) // 2] / 1e3,
        "p99_us": samples[int(len(samples) * 0.99)] / 1e3,
    }


def bench_fw(depth: int, events: int, workdir: Path) -> dict[str, float]:
    path = workdir / f"fw_depth{depth}.yaml"
    path.write_text(fw_chart(depth))
    interpreter = Interpreter(load_statechart(path), SimulatedClock())
    interpreter.start()
    return measure(interpreter.dispatch, events)


def bench_sismic(depth: int, events: int) -> dict[str, float] | None:
    try:
        from sismic.interpreter import Interpreter as SismicInterpreter
        from sismic.io import import_from_yaml
    except ImportError:
        return None

    class OuterFirst(SismicInterpreter):
        """sismic with rFSM's outer-first selection, for equal semantics."""

        def _select_transitions(self, event, states, *, eventless_first=True, inner_first=True):
            return super()._select_transitions(
                event, states, eventless_first=eventless_first, inner_first=False
            )

    interpreter = OuterFirst(import_from_yaml(text=sismic_chart(depth)))
    interpreter.execute_once()

    def dispatch(name: str) -> None:
        interpreter.queue(name)
        interpreter.execute_once()

    return measure(dispatch, events)


def big_chart(n_states: int) -> dict[str, Any]:
    """About n_states states: groups of 9 leaves, transitions inside and across groups."""
    groups, per = max(1, n_states // 10), 9
    events = {f"e{i}": None for i in range(per)}
    states = []
    for g in range(groups):
        leaves = []
        for i in range(per):
            nxt = f"G{g}_S{(i + 1) % per}"
            leaves.append(
                {
                    "name": f"G{g}_S{i}",
                    "transitions": [
                        {"event": f"e{i}", "target": nxt},
                        {
                            "event": f"e{(i + 1) % per}",
                            "guard": f"n > {i}",
                            "target": f"G{(g + 1) % groups}",
                        },
                    ],
                }
            )
        states.append({"name": f"G{g}", "initial": f"G{g}_S0", "states": leaves})
    return {
        "statechart": "big",
        "events": events,
        "variables": {"n": 0},
        "initial": "G0",
        "states": states,
    }


def bench_load(workdir: Path, repeats: int) -> dict[str, float]:
    spec = big_chart(200)
    path = workdir / "big.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    chart = load_statechart(path)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        load_statechart(path)  # parse + schema + build + validate
        times.append(time.perf_counter() - t0)
    result = {"states": len(chart.states) - 1, "fw_ms": statistics.median(times) * 1e3}
    try:
        from sismic.io import import_from_yaml

        def convert(s: dict[str, Any]) -> dict[str, Any]:
            out = {k: v for k, v in s.items() if k in ("name", "initial")}
            if "states" in s:
                out["states"] = [convert(c) for c in s["states"]]
            if "transitions" in s:
                out["transitions"] = [
                    {k: (v.replace("n >", "n >") if k == "guard" else v) for k, v in t.items()}
                    for t in s["transitions"]
                ]
            return out

        text = yaml.safe_dump(
            {
                "statechart": {
                    "name": "big",
                    "root state": {
                        "name": "root",
                        "initial": "G0",
                        "states": [convert(s) for s in spec["states"]],
                    },
                }
            }
        )
        stimes = []
        for _ in range(max(3, repeats // 4)):
            t0 = time.perf_counter()
            import_from_yaml(text=text)
            stimes.append(time.perf_counter() - t0)
        result["sismic_ms"] = statistics.median(stimes) * 1e3
    except ImportError:
        pass
    return result


def nested_chart(levels: int) -> str:
    """A chain of `levels` states, each the only child of the one above, the last final."""
    lines = ["statechart: deep", "initial: s0", "states:"]
    indent = ""
    for level in range(levels):
        lines.append(f"{indent}  - name: s{level}")
        if level == levels - 1:
            lines.append(f"{indent}    type: final")
        else:
            lines += [f"{indent}    initial: s{level + 1}", f"{indent}    states:"]
        indent += "    "
    return "\n".join(lines) + "\n"


def _median_load_ms(path: Path, repeats: int) -> float:
    load_statechart(path)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        load_statechart(path)
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3


def bench_growth(workdir: Path, repeats: int) -> list[tuple[str, int, float]]:
    """Load + validate cost per unit: (what, size, microseconds per state or per level).
    Flat rows across sizes mean the cost grows linearly."""
    out = []
    for n in (200, 800, 1600):
        path = workdir / f"big{n}.yaml"
        path.write_text(yaml.safe_dump(big_chart(n), sort_keys=False))
        states = len(load_statechart(path).states) - 1
        out.append(("states", states, _median_load_ms(path, repeats) * 1e3 / states))
    for levels in (8, 16, 31):
        path = workdir / f"deep{levels}.yaml"
        path.write_text(nested_chart(levels))
        out.append(("levels", levels, _median_load_ms(path, repeats) * 1e3 / levels))
    return out
