#!/usr/bin/env bash
# Builds the Debian package a lab installs (`cpack -G DEB`) and checks it:
# its dependencies come from dpkg-shlibdeps, and tests/integration/install_test.sh
# --deb extracts it (`dpkg-deb -x`), checks its contents and that every
# program's libraries resolve, runs the installed server on the ligament,
# serves the installed pages and verifies the installed systemd units.
#
#   deploy/package.sh                 build/package (portable, /usr), the .deb in out/
#   BUILD_DIR=build/ci deploy/package.sh   reuse a configured tree (its install
#                                     prefix becomes /usr; only what the package
#                                     holds is built, and of that only
#                                     common/core/install_paths.cc recompiles)
#   JOBS=2 deploy/package.sh          parallel build (default 1)
#
# The package is portable (no -march=native: the ci preset's flags), built
# with tests and benchmarks off unless BUILD_DIR names a tree that has them.
set -euo pipefail
cd "$(dirname "$0")/.."

build="${BUILD_DIR:-build/package}"
jobs="${JOBS:-1}"
out="${OUT_DIR:-out}"

./deploy/install-deps.sh

echo "== configure $build (install prefix /usr)"
# Installing needs only the packaged programs built, not the tests.
if [ -f "$build/CMakeCache.txt" ]; then
  cmake -S . -B "$build" -DCMAKE_INSTALL_PREFIX=/usr -DCMAKE_SKIP_INSTALL_ALL_DEPENDENCY=ON >/dev/null
else
  cmake --preset ci -B "$build" -DCMAKE_INSTALL_PREFIX=/usr -DCMAKE_SKIP_INSTALL_ALL_DEPENDENCY=ON \
    -DCUTSIM_BUILD_TESTS=OFF -DCUTSIM_BUILD_BENCH=OFF >/dev/null
fi
echo "== build $build (-j $jobs)"
# The programs; cutsim-haptic brings its device plugins.
cmake --build "$build" -j "$jobs" --target cutsim-server cutsim-haptic cutsim-viewer cutsim-man
echo "== cpack -G DEB"
(cd "$build" && cpack -G DEB) > "$build/cpack.log" 2>&1 || { tail -n 30 "$build/cpack.log" >&2; exit 1; }
deb="$(ls -t "$build"/cutsim_*.deb | head -n 1)"
mkdir -p "$out"
cp "$deb" "$out/"
deb="$out/$(basename "$deb")"
echo "== check $deb"
tests/integration/install_test.sh --deb "$deb"
echo "package: $deb ($(du -h "$deb" | cut -f1)); install with: sudo apt install ./$deb"
