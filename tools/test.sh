#!/usr/bin/env bash
# Install everything the test suite needs (tools/install.sh --test: Debian's graphviz
# and chromium, fw with its test extras, in a virtual environment where the system's
# Python refuses pip), then lint and run the whole suite.
# Used as-is by the README and by CI (.ci/run).
#
# The whole suite runs in two parts: first the tests that start no deployment, two at a
# time (pytest-xdist, one per core); then, one at a time, those marked `serial`
# (tests/conftest.py: SERIAL): a deployment's processes watch each other's deadlines,
# and a second test beside them on two cores starves them into safety stops that are
# correct but not what the test is about. Extra arguments go to one plain pytest run
# instead (a file, -k, -x ...).
set -euo pipefail
cd "$(dirname "$0")/.."
exec bash tools/install.sh --test bash -c '
  python3 -m ruff check . && python3 -m ruff format --check . || exit
  if [ $# -gt 0 ]; then exec python3 -m pytest "$@"; fi
  echo "tests that start no deployment, two at a time:" >&2
  python3 -m pytest -n 2 -m "not serial"; first=$?
  echo "tests that start a deployment, one at a time:" >&2
  python3 -m pytest -m serial; second=$?
  [ "$first" -eq 0 ] && exit "$second" || exit "$first"
' fw-tests "$@"
