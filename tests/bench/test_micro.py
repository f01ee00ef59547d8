"""Spec: the micro-benchmarks (`python -m fw_bench.micro NAME`) are there and runnable:
each one imports against today's fw and answers --help with its options; an unknown
name is refused with the list. (Their figures are benchmarks, never asserted here.)"""

import subprocess
import sys

import pytest

from fw_bench.micro.__main__ import BENCHMARKS
from tests.conftest import REPO


def micro(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "fw_bench.micro", *args],
        capture_output=True, text=True, cwd=REPO, timeout=120,
    )  # fmt: skip


@pytest.mark.parametrize("name", sorted(BENCHMARKS))
def test_every_micro_benchmark_answers_help(name):
    out = micro(name, "--help")
    assert out.returncode == 0, out.stderr
    assert "--out" in out.stdout and "Traceback" not in out.stderr


def test_an_unknown_micro_benchmark_is_refused_with_the_list():
    out = micro("runtim")
    assert out.returncode == 2
    assert "no benchmark named 'runtim'" in out.stderr
    assert all(name in out.stdout for name in BENCHMARKS)
