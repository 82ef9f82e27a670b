#!/usr/bin/env bash
# Installs everything gr-thrumapper needs on a fresh Debian 12 (bookworm) machine.
# Run as root (or with sudo). Safe to run again: it only adds what is missing.
#
#  * build and runtime dependencies from Debian's own packages (GNU Radio 3.10, UHD, VOLK,
#    Eigen, pybind11, numpy/scipy/matplotlib, ...);
#  * the SigMF library (`sigmf`, only on PyPI) into a virtual environment made from Debian's
#    /usr/bin/python3 with --system-site-packages, at $THRUMAPPER_VENV
#    (default /usr/local/lib/thrumapper/venv), installed without dependencies because Debian
#    already provides them (numpy, jsonschema, defusedxml);
#  * a one-line .pth file in /usr/local/lib/python3.11/dist-packages that adds the venv's
#    site-packages to Debian's /usr/bin/python3, so `import sigmf` works beside
#    `from gnuradio import thrumapper` in GRC, in scripts and in the tests. Nothing from PyPI
#    is written into a directory that apt manages.
set -euo pipefail

SIGMF_VERSION="${SIGMF_VERSION:-1.14.0}"
VENV="${THRUMAPPER_VENV:-/usr/local/lib/thrumapper/venv}"
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi

PACKAGES=(
  build-essential cmake pkg-config git
  gnuradio-dev libuhd-dev uhd-host libvolk2-dev libeigen3-dev pybind11-dev
  libboost-test-dev libfftw3-dev libspdlog-dev libgmp-dev liblog4cpp5-dev
  python3 python3-dev python3-venv python3-pip
  python3-numpy python3-scipy python3-matplotlib python3-yaml python3-tqdm
  python3-jsonschema python3-defusedxml python3-pyqt5 python3-zmq
  xvfb xauth imagemagick
)
missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ "${#missing[@]}" -gt 0 ]; then
  echo "setup: installing from Debian: ${missing[*]}"
  $SUDO apt-get update
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends "${missing[@]}"
fi

PY=/usr/bin/python3
if ! "$PY" -c "import sigmf, sys; sys.exit(0 if sigmf.__version__ == '${SIGMF_VERSION}' else 1)" 2>/dev/null; then
  echo "setup: installing sigmf ${SIGMF_VERSION} into ${VENV}"
  $SUDO "$PY" -m venv --system-site-packages "$VENV"
  $SUDO "$VENV/bin/python" -m pip install --quiet --no-deps "sigmf==${SIGMF_VERSION}"
  site_dir=$("$VENV/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['purelib'])")
  local_site=$("$PY" -c "import sys; print(f'/usr/local/lib/python{sys.version_info.major}.{sys.version_info.minor}/dist-packages')")
  $SUDO mkdir -p "$local_site"
  echo "$site_dir" | $SUDO tee "$local_site/thrumapper-venv.pth" >/dev/null
fi
"$PY" -c "import sigmf, numpy, scipy, matplotlib, yaml; from gnuradio import gr; print('setup: ok (GNU Radio', gr.version() + ', sigmf', sigmf.__version__ + ')')"
