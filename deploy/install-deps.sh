#!/usr/bin/env bash
# Installs every Debian package cutsim needs to build, test, run its demo and
# its benchmarks. Idempotent: does nothing when all are present, and runs
# `apt-get update` once, only when something is missing.
#
#   deploy/install-deps.sh           the default set
#   deploy/install-deps.sh --bench   also CalculiX (ccx), which produces the
#                                    independent FE references in
#                                    bench/reference/ (CUTSIM_BENCH_DEPS=1 does
#                                    the same)
set -euo pipefail

with_bench="${CUTSIM_BENCH_DEPS:-0}"
for arg in "$@"; do
  case "$arg" in
    --bench) with_bench=1 ;;
    *) echo "install-deps: unknown argument '$arg' (known: --bench)" >&2; exit 2 ;;
  esac
done

packages=(
  # toolchain
  build-essential cmake ninja-build pkg-config git
  # the linker of the test presets (CUTSIM_LINKER=lld in CMakePresets.json)
  lld
  # maths and utilities
  libeigen3-dev libcli11-dev libspdlog-dev libfmt-dev
  # sparse Cholesky (CHOLMOD) and the BLAS it runs on, for the implicit step
  libsuitesparse-dev libopenblas-dev
  # wire: schema, haptic link, observers
  libprotobuf-dev protobuf-compiler
  liblcm-dev liblcm-bin libglib2.0-dev
  # access control: HMAC-SHA256 of tool messages (libcrypto)
  libssl-dev
  # the lab's score history per trainee (SQLite, common/record)
  libsqlite3-dev
  # haptic devices: 3D mice through spacenavd (the spacenav device plugin)
  libspnav-dev
  cyclonedds-dev cyclonedds-tools
  # meshes: gmsh for .msh I/O and for tetrahedralising surfaces
  libgmsh-dev gmsh
  # offscreen rendering and images
  libosmesa6-dev libpng-dev
  # browser observers: HTTP/WebSocket server (Boost.Beast), and the headless
  # browser their tests drive
  libboost-dev chromium
  # video frames from the viewer (optional at run time; tests of the encoder use it)
  ffmpeg
  # tests and benchmarks; clang builds the libFuzzer targets (tests/fuzz),
  # which need its sanitizer and fuzzer runtimes and its OpenMP runtime
  libgtest-dev libgmock-dev libbenchmark-dev clang libclang-rt-dev libomp-dev
  python3 python3-meshio python3-numpy python3-matplotlib
  # multi-host tests: namespaces, veth, packet loss
  iproute2 nftables
  # deploy files: `systemd-analyze verify` of the shipped units (tests)
  systemd
  # the Debian package (deploy/package.sh): dpkg-shlibdeps finds its
  # dependencies, `file` tells CPack which files are programs
  dpkg-dev file
  # man pages made from each program's --help at build time (cmake), and
  # `man -l` that the test renders them with
  help2man man-db
  # deploy/verify-package.sh: a fresh Debian 12 root to install the package in
  debootstrap
)

# Optional: the reference solver of bench/reference/run_calculix.py; its
# ctest check skips when ccx is absent.
if [ "$with_bench" = 1 ]; then
  packages+=(calculix-ccx)
fi

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed'; then
    missing+=("$p")
  fi
done

# Node.js and npm fetch the observer page's WebGL library (three.js) and its
# test driver; any Node.js ≥ 18 will do, Debian's when none is present.
if ! command -v npm >/dev/null 2>&1; then
  missing+=(nodejs npm)
fi

if [ ${#missing[@]} -gt 0 ]; then
  echo "install-deps: installing ${missing[*]}" >&2
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

# The page's npm packages, pinned by web/observer/package-lock.json; again
# only when the lockfile changed since the last install.
web="$(cd "$(dirname "$0")/.." && pwd)/web/observer"
if [ -f "$web/package-lock.json" ] && \
   { [ ! -f "$web/node_modules/.package-lock.json" ] || [ "$web/package-lock.json" -nt "$web/node_modules/.package-lock.json" ]; }; then
  echo "install-deps: npm ci in web/observer" >&2
  (cd "$web" && npm ci --no-audit --no-fund --loglevel=error >/dev/null)
fi
exit 0

