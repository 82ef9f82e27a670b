#!/usr/bin/env bash
# Screenshot of the QT GUI flowgraph examples/jade_inspector.grc on the simulated building,
# taken on a virtual X display: docs/jade_inspector.png (the README's picture).
#
#   scripts/screenshot.sh [SECONDS] [OUT.png]
#
# Compiles the flowgraph with grcc (the source tree's grc/ first on GRC_BLOCKS_PATH), runs
# its top block under xvfb-run in a 1800x1200 window for SECONDS (default 14: the building
# channel walks the corridor scene at 40 CSI frames/s and the map is published every 5
# poses), grabs the whole screen with ImageMagick's `import -window root`, then stops the
# flowgraph. Needs xvfb, xauth and imagemagick (scripts/setup-debian.sh installs them) and the
# module importable: installed, or PYTHONPATH=build/test_modules. Run from anywhere; the
# flowgraph's scene path is relative to the repository root.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
seconds="${1:-14}"
out="$(realpath -m "${2:-$here/docs/jade_inspector.png}")"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT

# Only the source tree's block descriptions and GNU Radio's own: an older installed copy of
# the thrumapper blocks must not override the ones being shown.
export GRC_BLOCKS_PATH="$here/grc"
export GR_CONF_GRC_GLOBAL_BLOCKS_PATH=/usr/share/gnuradio/grc/blocks
grcc -o "$work" "$here/examples/jade_inspector.grc" > "$work/grcc.log" 2>&1 || { cat "$work/grcc.log"; exit 1; }

# The generated main() restores the window geometry GRC flowgraphs save in QSettings; a
# fresh config directory and an explicit size make the picture the same every time.
export XDG_CONFIG_HOME="$work/config"
unset QT_QPA_PLATFORM
cat > "$work/shoot.py" <<INNER
import subprocess, sys
from PyQt5 import Qt
sys.path.insert(0, "$work")
import jade_inspector

app = Qt.QApplication(sys.argv)
tb = jade_inspector.jade_inspector()
tb.resize(1800, 1200)
tb.move(0, 0)
tb.start()
tb.show()
result = {"code": 1}

def shoot():
    result["code"] = subprocess.call(["import", "-window", "root", "$out"])
    tb.stop()
    tb.wait()
    app.quit()

Qt.QTimer.singleShot(int($seconds * 1000), shoot)
app.exec_()
sys.exit(result["code"])
INNER
cd "$here"
xvfb-run --auto-servernum --server-args="-screen 0 1800x1200x24" /usr/bin/python3 "$work/shoot.py"
echo "screenshot: wrote $out"
