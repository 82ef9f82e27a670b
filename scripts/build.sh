#!/usr/bin/env bash
# Configures and builds gr-thrumapper in ./build (the default install prefix, /usr/local, is
# where Debian's /usr/bin/python3 finds the package). Usage: scripts/build.sh [--install]
set -euo pipefail
cd "$(dirname "$0")/.."
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release -DENABLE_DOXYGEN=OFF >/dev/null
cmake --build build -j"$(nproc)"
if [ "${1:-}" = "--install" ]; then
  $SUDO cmake --install build >/dev/null
  $SUDO ldconfig
  echo "build: installed to $(grep CMAKE_INSTALL_PREFIX: build/CMakeCache.txt | cut -d= -f2)"
fi
