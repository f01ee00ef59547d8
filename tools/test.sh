#!/usr/bin/env bash
# Install everything the test suite needs (tools/install.sh --test: Debian's graphviz
# and chromium, fw with its test extras, in a virtual environment where the system's
# Python refuses pip), then lint and run the whole suite.
# Used as-is by the README and by CI (.ci/run). Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
exec bash tools/install.sh --test bash -c \
  'python3 -m ruff check . && python3 -m ruff format --check . && python3 -m pytest "$@"' \
  fw-tests "$@"
