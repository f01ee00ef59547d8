"""Judge a chart's properties a second time with SPIN, and compare with `fw verify`.

For each property: the Promela model (`framework.verify.promela`) is generated,
`spin -a` writes its verifier in C, `cc` compiles it for a depth-first safety
search (`-DSAFETY`, state vectors compressed with `-DCOLLAPSE`), and the verifier
runs with `-i` (on a violation it keeps searching for shorter ones). No assertion
violated: the property holds. One violated: SPIN wrote a trail, which `spin -t`
replays to print the inputs of the counterexample, and the caller can play them on
fw's own interpreter (`Explorer.judge`) to confirm it. Any other error of the
verifier (a full memory, a search cut short) is no verdict: `SpinFailed`.

The search is depth first because the chart's tables are `hidden` (constant, kept out
of the state vector), which SPIN's breadth-first mode refuses; a trail is therefore
short, not shortest: `fw verify`'s own counterexample is the shortest one.

SPIN is Debian's `spin` (installed by `tools/install.sh --test`); without it, or
without a C compiler, `SpinMissing` says so.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from framework.errors import FwError
from framework.statechart.model import Statechart
from framework.verify.explore import Input
from framework.verify.promela import Inputs, export
from framework.verify.properties import Property

SPIN_TIMEOUT = 600.0


class SpinMissing(FwError):
    """SPIN or a C compiler is not installed."""


class SpinFailed(FwError):
    """SPIN, the compiler or the verifier failed on a generated model."""


@dataclass
class SpinVerdict:
    """SPIN's answer for one property."""

    prop: Property
    holds: bool
    states: int = 0
    seconds: float = 0.0
    trace: list[Input] = field(default_factory=list)
    """A violation's inputs, in the explorer's terms (short, not always shortest)."""
    model: str = ""
    """Where the generated model was kept (when asked to keep it)."""


def available() -> str | None:
    """None if SPIN and a C compiler are here, else what is missing."""
    missing = [tool for tool in ("spin", "cc") if shutil.which(tool) is None]
    return f"not installed: {', '.join(missing)}" if missing else None


def check(
    chart: Statechart,
    properties: Sequence[Property],
    inputs: Inputs,
    keep: str | Path | None = None,
    jobs: int | None = None,
) -> list[SpinVerdict]:
    """SPIN's verdict on each property (in order); models are kept in `keep` if given."""
    why = available()
    if why is not None:
        raise SpinMissing(f"SPIN cross-check: {why} (Debian: apt-get install spin gcc)")
    models = [export(chart, p, inputs) for p in properties]  # export errors before any run
    jobs = jobs or max(1, min(len(properties), os.cpu_count() or 1))
    with tempfile.TemporaryDirectory(prefix="fw-spin-") as tmp:

        def one(i: int) -> SpinVerdict:
            where = Path(keep) if keep is not None else Path(tmp)
            folder = where / f"{i:02d}_{properties[i].name}"
            return _run(properties[i], models[i].text, models[i].inputs, folder)

        with ThreadPoolExecutor(jobs) as pool:
            return list(pool.map(one, range(len(properties))))


def _run(prop: Property, text: str, names: list[Input | None], folder: Path) -> SpinVerdict:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "model.pml").write_text(text)
    started = time.perf_counter()
    _call(["spin", "-a", "model.pml"], folder, "spin -a")
    _call(
        [
            "cc",
            "-O0",
            "-w",
            "-DSAFETY",
            "-DCOLLAPSE",
            "-DVECTORSZ=8192",
            "-DMEMLIM=4096",
            "-o",
            "pan",
            "pan.c",
        ],
        folder,
        "cc",
    )
    out = _call(["./pan", "-m10000000", "-w20", "-i"], folder, "the verifier")
    errors = re.search(r"errors:\s*(\d+)", out)
    stored = re.search(r"(\d+)\s+states, stored", out)
    violated = "assertion violated" in out
    if errors is None or (not violated and (int(errors.group(1)) or "Search not completed" in out)):
        raise SpinFailed(f"SPIN on {prop.name} gave no verdict:\n{out[-2000:]}")
    verdict = SpinVerdict(
        prop,
        holds=not violated,
        states=int(stored.group(1)) if stored else 0,
        model=str(folder / "model.pml"),
    )
    if not verdict.holds:
        replay = _call(["spin", "-t", "model.pml"], folder, "spin -t")
        steps = [int(n) for n in re.findall(r"STEP (\d+)", replay)]
        trace = [names[n] if 0 < n < len(names) else None for n in steps[1:]]
        if not steps or steps[0] != 0 or any(i is None for i in trace):
            raise SpinFailed(f"SPIN on {prop.name}: its trail does not replay:\n{replay[-2000:]}")
        verdict.trace = [i for i in trace if i is not None]
    verdict.seconds = time.perf_counter() - started
    return verdict


def _call(argv: list[str], cwd: Path, what: str) -> str:
    try:
        done = subprocess.run(
            argv, cwd=cwd, capture_output=True, text=True, timeout=SPIN_TIMEOUT, check=False
        )
    except subprocess.TimeoutExpired:
        raise SpinFailed(f"{what} took more than {SPIN_TIMEOUT:g} s in {cwd}") from None
    if done.returncode != 0 and what != "the verifier":
        raise SpinFailed(f"{what} failed in {cwd}:\n{(done.stdout + done.stderr)[-2000:]}")
    return done.stdout + done.stderr
