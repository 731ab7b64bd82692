#!/usr/bin/env bash
# The package into a fresh Debian 12 root, as a lab installs it: a minimal
# bookworm root made with Debian's own debootstrap (--variant=minbase, from
# the mirror apt already uses, made once and cached outside the source tree),
# copied afresh for each run, the .deb installed in it with `dpkg -i` and its
# missing dependencies with `apt-get -f install` (chroot), then the installed
# server run on the shipped ligament headless, the installed man pages
# rendered, and `systemd-analyze verify` on the installed units.
#
#   deploy/verify-package.sh [DEB]        (default: the newest out/cutsim_*.deb)
#   CUTSIM_ROOT_CACHE=DIR                 where the pristine root is kept
#                                         (default /var/cache/cutsim-verify)
#   deploy/verify-package.sh --root-only  make (or check) the cached root only
#
# Needs root (chroot, mounts), debootstrap and systemd-analyze on the host.
# Network: debootstrap and apt inside the root talk only to the Debian
# mirror of the host's apt sources. Too slow for the CI suite (a first run
# downloads the base system); the bench runs it, or run it by hand.
set -euo pipefail
root_dir="$(cd "$(dirname "$0")/.." && pwd)"
cache="${CUTSIM_ROOT_CACHE:-/var/cache/cutsim-verify}"
pristine="$cache/bookworm-minbase"

die() { echo "verify-package: $*" >&2; exit 1; }
[ "$(id -u)" -eq 0 ] || die "needs root (debootstrap, chroot, mounts)"
command -v debootstrap >/dev/null || die "debootstrap is not installed (apt-get install debootstrap)"

# The mirror the host's apt uses for bookworm (deb822 or one-line sources).
mirror() {
  local m
  m="$(grep -hs '^URIs:' /etc/apt/sources.list.d/*.sources | awk '{print $2}' | grep -v security | head -n 1)"
  [ -n "$m" ] || m="$(grep -hs '^deb ' /etc/apt/sources.list | awk '{print $2}' | grep -v security | head -n 1)"
  [ -n "$m" ] || die "no Debian mirror in /etc/apt/sources.list{,.d}"
  echo "$m"
}

# Makes the pristine root once; a half-made one (no marker) is made again.
make_root() {
  if [ -f "$pristine/.cutsim-complete" ]; then
    echo "== root: $pristine (cached, made $(cat "$pristine/.cutsim-complete"))"
    return
  fi
  local m
  m="$(mirror)"
  echo "== root: debootstrap --variant=minbase bookworm $pristine $m"
  rm -rf "$pristine"
  mkdir -p "$cache"
  debootstrap --variant=minbase bookworm "$pristine" "$m" >"$cache/debootstrap.log" 2>&1 ||
    { tail -n 20 "$cache/debootstrap.log" >&2; die "debootstrap failed (log: $cache/debootstrap.log)"; }
  echo "deb $m bookworm main" >"$pristine/etc/apt/sources.list"
  date -u +%Y-%m-%dT%H:%M:%SZ >"$pristine/.cutsim-complete"
}

make_root
[ "${1:-}" = "--root-only" ] && exit 0

deb="${1:-$(ls -t "$root_dir"/out/cutsim_*.deb 2>/dev/null | head -n 1)}"
[ -n "$deb" ] && [ -f "$deb" ] || die "no package: build it with deploy/package.sh, or name the .deb"
deb="$(cd "$(dirname "$deb")" && pwd)/$(basename "$deb")"

work="$(mktemp -d "$cache/run.XXXXXX")"
target="$work/root"
mounted=()
cleanup() {
  for ((i = ${#mounted[@]} - 1; i >= 0; i--)); do umount -l "${mounted[$i]}" 2>/dev/null || true; done
  rm -rf "$work"
}
trap cleanup EXIT
echo "== fresh copy of the root in $target"
cp -a "$pristine" "$target"
for fs in proc sys dev; do
  mount --rbind "/$fs" "$target/$fs"
  mounted+=("$target/$fs")
done
cp /etc/resolv.conf "$target/etc/resolv.conf"
in_root() { chroot "$target" /usr/bin/env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin HOME=/root LANG=C.UTF-8 "$@"; }

echo "== dpkg -i $(basename "$deb") (its dependencies are not there yet)"
cp "$deb" "$target/tmp/"
in_root dpkg -i "/tmp/$(basename "$deb")" >"$work/dpkg.log" 2>&1 || true
grep -E "depends on|not installed" "$work/dpkg.log" | sed 's/^/   /' | head -n 5 || true
echo "== apt-get update && apt-get -f install"
in_root apt-get update -qq >"$work/apt.log" 2>&1 || { cat "$work/apt.log" >&2; die "apt-get update failed"; }
DEBIAN_FRONTEND=noninteractive in_root apt-get -f install -y -qq --no-install-recommends >>"$work/apt.log" 2>&1 ||
  { tail -n 20 "$work/apt.log" >&2; die "apt-get -f install failed"; }
status="$(in_root dpkg-query -W -f='${Status} ${Version}' cutsim)"
echo "   cutsim: $status"
[[ "$status" == "install ok installed"* ]] || die "cutsim is not installed: $status"

echo "== every installed program's libraries resolve"
for p in cutsim-server cutsim-haptic cutsim-viewer; do
  if in_root ldd "/usr/bin/$p" | grep -q 'not found'; then
    in_root ldd "/usr/bin/$p" | grep 'not found' >&2
    die "$p: unresolved libraries"
  fi
  echo "   /usr/bin/$p: ok"
done

echo "== the installed server on the ligament, headless"
in_root /usr/bin/cutsim-server --scene /usr/share/cutsim/scenes/ligament.pbtxt --headless --duration 0.2 \
  --no-progress >"$work/server.json" 2>"$work/server.log" || { cat "$work/server.log" >&2; die "the server failed"; }
python3 - "$work/server.json" <<'PY'
import json, sys
s = json.loads(open(sys.argv[1]).read().strip().splitlines()[-1])
print("   " + ", ".join(f"{k}: {s[k]}" for k in ("scene", "sim_time", "steps", "status") if k in s))
PY

echo "== man pages render"
for p in cutsim-server cutsim-haptic cutsim-viewer; do
  page="$target/usr/share/man/man1/$p.1.gz"
  [ -f "$page" ] || die "no man page $p.1.gz"
  MANWIDTH=80 man -l "$page" 2>/dev/null | grep -q -- '--help' || die "$p.1.gz does not render"
  echo "   $p.1.gz: ok"
done

echo "== systemd-analyze verify (the installed units)"
# The host's systemd-analyze reads each unit as installed, its programs'
# paths pointed into the root (a minbase root has no systemd); templates
# are verified as an instance.
mkdir -p "$work/units"
for u in "$target"/lib/systemd/system/cutsim-*; do
  name="$(basename "$u")"
  case "$name" in *@.service) name="${name%@.service}@lab1.service" ;; esac
  sed "s#=/usr/bin/#=$target/usr/bin/#g; s#=-/etc/cutsim/#=-$target/etc/cutsim/#g" "$u" >"$work/units/$name"
done
if ! systemd-analyze verify --man=no "$work"/units/* >"$work/verify.log" 2>&1 || [ -s "$work/verify.log" ]; then
  cat "$work/verify.log" >&2
  die "systemd-analyze verify failed"
fi
echo "   $(ls "$work/units" | tr '\n' ' ')ok"
echo "verify-package: $(basename "$deb") installs into a fresh Debian 12 root, runs, and its units verify"
