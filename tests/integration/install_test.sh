#!/usr/bin/env bash
# An installed cutsim tree, checked as a lab machine would use it:
#  1. its contents: the three programs, the device plugins, every shipped
#     scene, the web pages with the three.js files they load (and no tests,
#     no npm tree), the DDS configurations, the systemd units and the lab's
#     environment file, none naming the build machine's source tree;
#  2. every program's and plugin's shared libraries resolve (ldd);
#  3. the installed server runs the ligament headless from the tree, the
#     installed viewer and haptic station find their pages and plugins in
#     the tree (not in the source tree), and serve the pages;
#  4. `systemd-analyze verify` on an instance of each installed unit;
#  5. each program's man page renders (`man -l`) and names every option its
#     --help lists.
#
#   tests/integration/install_test.sh --cmake-install BUILD_DIR
#       `DESTDIR=TMP cmake --install BUILD_DIR`, then the checks (quick:
#       part of the default test run)
#   tests/integration/install_test.sh --deb FILE.deb
#       the package: its control fields (dependencies from dpkg-shlibdeps,
#       conffiles), then `dpkg-deb -x` into TMP and the checks
#       (deploy/package.sh runs this)
set -uo pipefail

src="$(cd "$(dirname "$0")/../.." && pwd)"

fail() { echo "install_test: FAILED: $*" >&2; exit 1; }

if [ "${1:-}" = "--inside" ]; then
  # Inside deploy/netns-run.sh (loopback only): the installed haptic station
  # loads a plugin by name, the installed viewer serves the observer page and
  # the haptic station the trainee page.
  # $2 = work dir, $3 = bin dir of the installed tree.
  work="$2" bin="$3"
  "$bin/cutsim-haptic" --device evdev --no-rt > "$work/haptic-plugin.log" 2>&1
  "$bin/cutsim-viewer" --session inst --serve 127.0.0.1:0 --duration 30 > "$work/viewer.out" 2> "$work/viewer.log" &
  vpid=$!
  head -c 32 /dev/urandom | od -An -tx1 | tr -d ' \n' > "$work/session.key"
  "$bin/cutsim-haptic" --session inst --device browser --serve 127.0.0.1:0 --key-file "$work/session.key" \
    --url-file "$work/trainee.url" --no-page-view --no-rt > "$work/haptic.out" 2> "$work/haptic.log" &
  hpid=$!
  deadline=$((SECONDS + 30))
  until grep -q "^observers: http" "$work/viewer.out" 2>/dev/null && [ -s "$work/trainee.url" ]; do
    if [ "$SECONDS" -ge "$deadline" ] || ! kill -0 "$vpid" 2>/dev/null || ! kill -0 "$hpid" 2>/dev/null; then
      kill -TERM "$vpid" "$hpid" 2>/dev/null
      echo "install_test: the installed viewer or haptic station did not serve its page" >&2
      exit 1
    fi
    sleep 0.05
  done
  observer="$(sed -n 's/^observers: //p' "$work/viewer.out" | head -n 1)"
  trainee="$(cat "$work/trainee.url")"
  {
    "$src/tests/integration/http_get.py" "$observer" "$work/observer.html"
    "$src/tests/integration/http_get.py" "${observer}vendor/three.module.js"
    "$src/tests/integration/http_get.py" "${observer}vendor/OrbitControls.js"
    "$src/tests/integration/http_get.py" "${observer}common/mesh_frames.js"
    "$src/tests/integration/http_get.py" "$trainee" "$work/trainee.html"
    "$src/tests/integration/http_get.py" "${trainee%%\?*}vendor/three.core.js?${trainee#*\?}"
  } > "$work/http.codes"
  kill -TERM "$vpid" "$hpid"
  wait "$vpid" "$hpid"
  exit 0
fi

mode="${1:?usage: $0 --cmake-install BUILD_DIR | --deb FILE.deb}"
input="${2:?usage: $0 --cmake-install BUILD_DIR | --deb FILE.deb}"
work="$(mktemp -d /tmp/cutsim-install.XXXXXX)"
trap 'rc=$?; if [ $rc -ne 0 ] && [ $rc -ne 77 ]; then for f in "$work"/*.log; do [ -f "$f" ] && { echo "---- $f"; tail -n 20 "$f"; }; done >&2; fi; rm -rf "$work"; exit $rc' EXIT
root="$work/root"

case "$mode" in
  --cmake-install)
    # DESTDIR keeps every file, /etc and /lib/systemd included, under $root;
    # the tree then lies elsewhere than it was configured for, as an
    # extracted package does.
    configured="$(sed -n 's/^CMAKE_INSTALL_PREFIX:PATH=//p' "$input/CMakeCache.txt")"
    [ -n "$configured" ] || fail "no CMAKE_INSTALL_PREFIX in $input/CMakeCache.txt"
    DESTDIR="$root" cmake --install "$input" > "$work/install.log" 2>&1 || fail "cmake --install $input (see install.log)"
    prefix="$root$configured"
    ;;
  --deb)
    [ -f "$input" ] || fail "no package $input"
    dpkg-deb -c "$input" > "$work/contents" || fail "dpkg-deb -c $input"
    depends="$(dpkg-deb -f "$input" Depends)"
    echo "install_test: Depends: $depends"
    # The CMake code lists no dependency: dpkg-shlibdeps reads them from the
    # programs' and plugins' libraries, with the versions their symbols need.
    for pkg in libc6 libstdc++6 libprotobuf liblcm libddsc libosmesa6 libssl3 libcholmod libsqlite3 libspnav; do
      grep -q "$pkg" <<< "$depends" || fail "Depends lacks $pkg (dpkg-shlibdeps): $depends"
    done
    grep -q "libc6 (>= " <<< "$depends" || fail "Depends has no version for libc6: $depends"
    dpkg-deb -e "$input" "$work/control" || fail "dpkg-deb -e $input"
    grep -qx "/etc/cutsim/cutsim.env" "$work/control/conffiles" || fail "/etc/cutsim/cutsim.env is not a conffile"
    for s in postinst prerm postrm; do [ -x "$work/control/$s" ] || fail "no executable $s in the package"; done
    grep -q "^./lib/systemd/system/cutsim-server@.service$" <(awk '{print $6}' "$work/contents") \
      || fail "the package lacks /lib/systemd/system/cutsim-server@.service"
    dpkg-deb -x "$input" "$root" || fail "dpkg-deb -x $input"
    prefix="$root/usr"
    ;;
  *) fail "unknown mode $mode (--cmake-install or --deb)" ;;
esac

# Where this tree keeps things: the plugin folder is lib/<multiarch>/… under
# /usr and lib/… elsewhere; configuration and units under /etc and /lib for
# /usr, inside the prefix otherwise.
bin="$prefix/bin"
data="$prefix/share/cutsim"
plugins="$(find "$prefix/lib" -type d -path '*/cutsim/devices' | head -n 1)"
units="$(find "$root" -type d -path '*/lib/systemd/system' | head -n 1)"
envfile="$(find "$root" -type f -path '*/etc/cutsim/cutsim.env' | head -n 1)"
[ -n "$plugins" ] || fail "no cutsim/devices folder under $prefix/lib"
[ -n "$units" ] || fail "no lib/systemd/system folder in the tree"
[ -n "$envfile" ] || fail "no etc/cutsim/cutsim.env in the tree"

# ---- 1. contents -------------------------------------------------------------
need=("$bin/cutsim-server" "$bin/cutsim-haptic" "$bin/cutsim-viewer"
      "$plugins/libcutsim_device_example_spring.so" "$plugins/libcutsim_device_evdev.so"
      "$data/web/observer/index.html" "$data/web/observer/observer.js" "$data/web/observer/observer.css"
      "$data/web/trainee/index.html" "$data/web/trainee/trainee.js" "$data/web/trainee/trainee.css"
      "$data/web/lab/index.html" "$data/web/lab/lab.js" "$data/web/lab/lab.css"
      "$data/web/common/mesh_frames.js" "$data/web/common/scalpel.js" "$data/web/common/plan_line.js"
      "$data/web/observer/node_modules/three/build/three.module.js"
      "$data/web/observer/node_modules/three/build/three.core.js"
      "$data/web/observer/node_modules/three/examples/jsm/controls/OrbitControls.js"
      "$data/web/observer/node_modules/three/LICENSE"
      "$data/dds/cyclonedds-loopback.xml" "$data/dds/cyclonedds-unicast.xml" "$data/dds/cyclonedds-lan.xml"
      "$prefix/share/doc/cutsim/README.md" "$prefix/share/doc/cutsim/lab-guide.md"
      "$units/cutsim-server@.service" "$units/cutsim-haptic@.service" "$units/cutsim-bridge@.service"
      "$units/cutsim-lab.service")
# Every shipped scene and tool path.
for f in "$src"/scenes/*.pbtxt "$src"/scenes/*.path "$src"/scenes/*.lcm "$src"/scenes/README.md; do
  need+=("$data/scenes/$(basename "$f")")
done
for f in "${need[@]}"; do [ -f "$f" ] || fail "missing ${f#"$root"}"; done
if [ -n "$(find "$data/web" -path '*/test/*' -o -name '*.mjs' -o -path '*/node_modules/.bin*' -o -name package-lock.json)" ]; then
  fail "test files or npm's tree in $data/web: $(find "$data/web" -path '*/test/*' -o -name '*.mjs' | head -n 3)"
fi
if grep -rl -- "$src" "$units" "$envfile" > /dev/null; then fail "a unit or cutsim.env names the source tree $src"; fi
grep -q "^ExecStart=/[^ ]*/bin/cutsim-server " "$units/cutsim-server@.service" || fail "cutsim-server@.service: ExecStart"
echo "install_test: contents: ok (${#need[@]} files checked)"

# ---- 2. shared libraries ------------------------------------------------------
elves=("$bin"/cutsim-server "$bin"/cutsim-haptic "$bin"/cutsim-viewer "$plugins"/*.so)
for f in "${elves[@]}"; do
  ldd "$f" > "$work/ldd.log" 2>&1 || fail "ldd $f: $(cat "$work/ldd.log")"
  if grep -q "not found" "$work/ldd.log"; then fail "${f#"$root"}: $(grep 'not found' "$work/ldd.log" | tr '\n' ' ')"; fi
done
echo "install_test: libraries of ${#elves[@]} programs and plugins resolve"

# ---- 3. the installed programs, from the tree -------------------------------------
for p in server haptic viewer; do
  "$bin/cutsim-$p" --help > "$work/help-$p.log" 2>&1 || fail "cutsim-$p --help"
  grep -q -- "--session" "$work/help-$p.log" || fail "cutsim-$p --help lacks --session"
done
# The viewer's default page folder is the tree's, not the source tree's.
grep -q -- "$data/web/observer" "$work/help-viewer.log" || fail "cutsim-viewer --help: default --web-root is not $data/web/observer"
"$bin/cutsim-server" --headless --scene "$data/scenes/ligament.pbtxt" --duration 0.05 --threads 1 --no-progress \
  --out "$work/ligament.vtu" --stats-json "$work/ligament.json" > "$work/server.log" 2>&1 \
  || fail "the installed server on the installed ligament (see server.log)"
[ -s "$work/ligament.vtu" ] || fail "the installed server wrote no $work/ligament.vtu"
grep -q '"nodes"' "$work/ligament.json" || fail "the installed server's stats have no nodes: $(head -c 300 "$work/ligament.json")"
echo "install_test: the installed server ran the ligament headless"
"$src/deploy/netns-run.sh" "$0" --inside "$work" "$bin"
rc=$?
if [ "$rc" -eq 77 ]; then
  echo "install_test: no network namespace here; the pages were not served" >&2
elif [ "$rc" -ne 0 ]; then
  fail "serving the installed pages"
else
  # A plugin by name: found in the tree's plugin folder; evdev then refuses
  # the missing path argument, naming it (no device is opened).
  grep -q "evdev: --device-arg needs path=" "$work/haptic-plugin.log" \
    || fail "cutsim-haptic --device evdev did not load the tree's plugin: $(tail -n 3 "$work/haptic-plugin.log")"
  codes="$(tr '\n' ' ' < "$work/http.codes")"
  [ "$codes" = "200 200 200 200 200 200 " ] || fail "HTTP codes (observer, three, OrbitControls, common, trainee, three.core): $codes"
  grep -q "cutsim observer" "$work/observer.html" || fail "the observer page is not the observer page"
  grep -q "<html" "$work/trainee.html" || fail "the trainee page is not a page"
  echo "install_test: the installed viewer and haptic station serve their pages and three.js; plugins load"
fi

# ---- 5. the man pages ----------------------------------------------------------
# Each renders, and names every option of the installed program's --help
# (both spellings of a short and long pair). C locale: plain hyphens.
for p in server haptic viewer; do
  page="$prefix/share/man/man1/cutsim-$p.1.gz"
  [ -f "$page" ] || fail "no man page $page"
  LC_ALL=C MANWIDTH=200 man -l "$page" > "$work/man-$p.txt" 2> "$work/man-$p.err" || fail "man -l $page: $(cat "$work/man-$p.err")"
  grep -q "^NAME" "$work/man-$p.txt" || fail "cutsim-$p.1.gz rendered without a NAME section"
  options="$(grep -E '^ +-' "$work/help-$p.log" | grep -oE -- '(^|[ ,])--?[A-Za-z][A-Za-z0-9-]*' | tr -d ' ,' | sort -u)"
  [ "$(echo "$options" | wc -l)" -ge 5 ] || fail "cutsim-$p --help lists too few options to check: $options"
  for o in $options; do
    grep -qE -- "(^|[ ,])$o([ ,={]|$)" "$work/man-$p.txt" || fail "cutsim-$p.1.gz does not name $o (its --help does)"
  done
done
echo "install_test: every program's man page renders and names each option of its --help"

# ---- 4. the installed units -----------------------------------------------------
if command -v systemd-analyze > /dev/null; then
  mkdir -p "$work/units"
  unit_bin="$(sed -n 's#^ExecStart=\(/.*\)/cutsim-server .*#\1#p' "$units/cutsim-server@.service")"
  for u in server haptic bridge; do
    sed "s#$unit_bin/#$bin/#g" "$units/cutsim-$u@.service" > "$work/units/cutsim-$u@lab1.service"
  done
  if ! systemd-analyze verify --man=no "$work"/units/*.service > "$work/verify.log" 2>&1 || [ -s "$work/verify.log" ]; then
    fail "systemd-analyze verify: $(cat "$work/verify.log")"
  fi
  echo "install_test: systemd-analyze verify of the installed units: ok"
fi
echo "install_test: pass ($mode)"
