#!/usr/bin/env bash
# Sets up a Debian 12 machine, builds gr-thrumapper and runs every test (C++ unit tests of the
# core, gr_unittest QA of the blocks, the command-line tools) through ctest.
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/setup-debian.sh
/usr/bin/python3 tools/update_binding_hashes.py --check
./scripts/build.sh
cd build
ctest --output-on-failure -j2
