#!/usr/bin/env bash
# Sets up a Debian 12 machine, builds and installs gr-thrumapper, then runs the main job:
# a simulated survey of the paper's §4.3 geometry (a corridor wall with a hidden wall
# behind it), JADE on it, the paths found printed next to the geometric truth, and the
# angle x delay surface written as a PNG. Output goes to ./out (or $1).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:-out}"
./scripts/setup-debian.sh
./scripts/build.sh --install
/usr/bin/python3 examples/hidden_wall_demo.py --out "$OUT"
