"""Spec: no file a user can write crashes fw. Seeded mutants of every shipped file
kind (tools/fuzz_files.py, checked as `fw validate` checks them, in real worker
processes) all end in a clean located error or a valid load: their text, their data,
and the paths they name (a FIFO, a folder, a device, a socket, a 5 GB file, a link to
itself instead of a file), with no control character of theirs printed raw."""

import json
import os
import subprocess
import sys

from tests.conftest import REPO

FUZZ = [sys.executable, str(REPO / "tools" / "fuzz_files.py")]


def fuzz(tmp_path, *args: str) -> dict:
    done = subprocess.run(
        [*FUZZ, "--json", "--out", str(tmp_path), *args],
        capture_output=True,
        text=True,
        timeout=900,
        cwd=REPO,
    )
    assert done.stdout, done.stderr
    return json.loads(done.stdout)


def test_a_thousand_seeded_mutants_of_every_kind_end_cleanly(tmp_path):
    seed = os.environ.get("FW_FUZZ_SEED", "16")  # another seed explores other mutants
    summary = fuzz(tmp_path, "--n", "1200", "--seed", seed)
    assert summary["mutants"] == 1200
    kinds = {
        "topology",
        "statechart",
        "scenario",
        "properties",
        "procedure",
        "sensors",
        "tools",
        "cameras",
    }
    assert kinds <= set(summary["by_kind"])
    assert all(sum(c.values()) >= 150 for c in summary["by_kind"].values())
    failures = [f"{f['outcome']} {f['saved']}: {f['detail']}" for f in summary["failures"]]
    assert failures == [], "replay with fw validate FILE:\n" + "\n".join(failures)
    cleanly_refused = sum(c.get("clean", 0) for c in summary["by_kind"].values())
    assert cleanly_refused > 500, "the mutants must mostly be wrong, or they test little"


def test_the_fuzzer_sees_each_kind_of_failure(tmp_path):
    """The harness itself bites: checks that fail on purpose are charged to their
    mutant as what they are (a worker crash or hang does not end the run)."""
    summary = fuzz(tmp_path, "--n", "28", "--canary-every", "4", "--hang-after", "5")
    seen = {c["canary"]: c["outcome"] for c in summary["canaries"]}
    kinds = ("traceback", "crash", "hang", "unlocated", "unescaped", "memory", "slow")
    assert seen == {k: k for k in kinds}
    assert summary["mutants"] == 21 and summary["clean"] == 21
