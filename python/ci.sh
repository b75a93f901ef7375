#!/usr/bin/env bash
# Builds the `gman` Python package the way a user installs it (`pip install ./python` in a
# fresh venv: one release build of the wheel) and runs its pytest suite with the venv's own
# pytest, so that the tests import the installed package, not this source tree.
#
#   python/ci.sh            (from the repository root; CI sets CI=1 so nothing is skipped)
#
# GMAN_DATA names the data directory (default ../shared/data/gman beside the clone); GMAN_BIN
# the `gman` binary the tests compare against (default target/release or target/debug).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
venv=${GMAN_PY_VENV:-$(mktemp -d)/venv}
python3 -m venv "$venv"
"$venv/bin/pip" install -q --upgrade pip
# The root workspace's target directory: the host crates' dependencies are shared with the
# Rust build instead of compiled a second time.
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$root/target}
"$venv/bin/pip" install -q ./python pytest gymnasium numpy hypothesis moviepy
cd "$root/python/tests"
"$venv/bin/pytest" -q -p no:cacheprovider .
