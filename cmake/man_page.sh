#!/usr/bin/env bash
# Writes PROGRAM's man page (gzip'd) from its own --help text with help2man,
# at build time, so the page cannot drift from the program. The NAME line
# is the help's first line ("cutsim-x: what it does").
#
#   cmake/man_page.sh PROGRAM OUT.1.gz VERSION
set -euo pipefail
program="$1" out="$2" version="$3"
name="$(basename "$program")"
help="$("$program" --help 2>&1)"
summary="$(printf '%s\n' "$help" | sed -n "1s/^$name: *//p")"
[ -n "$summary" ] || { echo "man_page.sh: $program --help printed nothing" >&2; exit 1; }
tmp="$(mktemp)"
trap 'rm -f "$tmp"' EXIT
help2man --no-info --no-discard-stderr --version-string="$version" --name="$summary" \
  --section=1 --source="cutsim $version" --manual="cutsim" -o "$tmp" "$program"
gzip -9nc "$tmp" >"$out"
