#!/usr/bin/env bash
# Sets up a Debian 12 machine, builds and installs gr-thrumapper, then runs the main job:
#  1. a simulated survey of the paper's §4.3 geometry (a corridor wall with a hidden wall
#     behind it), JADE on it, the paths found printed next to the geometric truth, and the
#     angle x delay surface written as a PNG;
#  2. a simulated corridor scan past a room (§4.4-4.5) mapped with thrumapper-map and scored
#     against the truth with thrumapper-eval.
# Output goes to ./out (or $1).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:-out}"
./scripts/setup-debian.sh
./scripts/build.sh --install
/usr/bin/python3 examples/hidden_wall_demo.py --out "$OUT"
echo
/usr/bin/python3 examples/corridor_map_demo.py --out "$OUT"
