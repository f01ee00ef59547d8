#!/usr/bin/env bash
# Install fw for this checkout, then run COMMAND... in its environment:
#   bash tools/install.sh fw deploy topologies/seeg.yaml
#   bash tools/install.sh --test python3 -m pytest      (what tools/test.sh does)
#   bash tools/install.sh --pinned --test ...           the versions last known good
#                                                       (tools/constraints.txt)
#   bash tools/install.sh --bench fw bench --quick      with fw-bench, the experiment
#                                                       harness (tools/bench; --test has it)
# What it installs: the Debian packages a run needs when they are missing (graphviz
# draws the console's live chart; with --test also chromium for the browser tests,
# spin and gcc for `fw verify --spin`, nftables for lossy links, and python3-venv where a virtual environment must be made), then fw itself
# (with --test its test extras) into: the active virtual environment; else ./.venv if
# it exists; else, when this Python is the system's own ("externally managed", as on
# Debian 12), a new ./.venv; else this Python.
# With CI=true it always makes a new environment (./.venv-ci, emptied first) and takes
# the newest releases the dependencies allow: a release that breaks fw fails CI at once
# instead of hiding behind what a machine kept from an earlier run.
set -euo pipefail
cd "$(dirname "$0")/.."

extras=""
bench=""
constraints=()
while [ $# -gt 0 ]; do
  case "$1" in
    --test) extras="[test]"; bench=1; shift ;;
    --bench) bench=1; shift ;;
    --pinned) constraints=(-c tools/constraints.txt); shift ;;
    *) break ;;
  esac
done

if [ "$(id -u)" = 0 ]; then SUDO=""; elif command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else SUDO="none"; fi
apt_install() {
  [ $# -gt 0 ] || return 0
  if [ "$SUDO" = none ] || ! command -v apt-get >/dev/null 2>&1; then
    echo "warning: cannot install $* (no apt-get, or not root and no sudo); what needs them is skipped" >&2
    return 0
  fi
  echo "installing Debian packages: $*" >&2
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "$@" >/dev/null
}

system_python() {  # PEP 668: pip may not install into this Python
  python3 -c 'import os, sys, sysconfig; sys.exit(not os.path.exists(os.path.join(sysconfig.get_path("stdlib"), "EXTERNALLY-MANAGED")))'
}

need=()
command -v dot >/dev/null 2>&1 || need+=(graphviz)
if [ -n "$extras" ]; then
  command -v chromium >/dev/null 2>&1 || need+=(chromium)
  command -v spin >/dev/null 2>&1 || need+=(spin)   # fw verify --spin, the second checker
  command -v cc >/dev/null 2>&1 || need+=(gcc)      # SPIN's verifier; the tests' clock shim
  command -v nft >/dev/null 2>&1 || need+=(nftables) # lossy links between hosts (framework/netns.py)
fi
fresh=""
if [ "${CI:-}" = true ]; then fresh=1; fi
if { [ -n "$fresh" ] || { [ -z "${VIRTUAL_ENV:-}" ] && [ ! -d .venv ] && system_python; }; } \
  && ! python3 -c 'import ensurepip' 2>/dev/null; then
  need+=(python3-venv)
fi
apt_install "${need[@]+"${need[@]}"}"

if [ -n "$fresh" ]; then
  echo "CI: a new virtual environment in .venv-ci (the newest releases the dependencies allow)" >&2
  rm -rf .venv-ci
  python3 -m venv .venv-ci
  . .venv-ci/bin/activate
elif [ -z "${VIRTUAL_ENV:-}" ]; then
  if [ -d .venv ]; then
    . .venv/bin/activate
  elif system_python; then
    echo "making a virtual environment in .venv (this Python is the system's own)" >&2
    python3 -m venv .venv
    . .venv/bin/activate
  fi
fi
python3 -m pip install --disable-pip-version-check -q -e ".$extras" ${bench:+-e tools/bench} \
  "${constraints[@]+"${constraints[@]}"}"
[ -z "$fresh" ] || python3 -m pip freeze --exclude-editable | sed 's/^/  ci: /' | grep -iE \
  ' (numpy|scipy|pyyaml|jsonschema|eclipse-zenoh|pin|mujoco|pytest|hypothesis)==' >&2 || true
[ $# -eq 0 ] || exec "$@"
