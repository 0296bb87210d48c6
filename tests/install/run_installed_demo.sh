#!/bin/sh
# The installed package stands on its own (issue 53): install to a fresh prefix, hide the source
# and build trees, and run `PREFIX/bin/terramap run` (the embedded demo) from an empty folder.
# Usage: run_installed_demo.sh BUILD_DIR SOURCE_DIR. Exit 77 (skip) where the trees cannot be
# hidden (no unprivileged user and mount namespaces).
set -eu
build=$1 src=$2
# Outside both trees, which are hidden below.
work=$(mktemp -d "${TMPDIR:-/tmp}/terramap_installed.XXXXXX")
trap 'rm -rf "$work"' EXIT
mkdir -p "$work/prefix" "$work/empty"
cmake --install "$build" --prefix "$work/prefix" > "$work/install.log"
if ! unshare -rm true 2> /dev/null; then
  echo "SKIP: cannot hide the source tree (unshare -rm refused)"
  exit 77
fi
# In a private mount namespace (nobody else sees it) an empty tmpfs covers the checkout and the
# build tree, so anything the package still reads from them is missing.
cd "$work/empty"
unshare -rm sh -c '
  set -eu
  mount -t tmpfs none "$1"
  case "$2" in "$1"/*) ;; *) mount -t tmpfs none "$2" ;; esac
  test -z "$(ls -A "$1")"
  TERRAMAP_PLUGIN_PATH= "$3/bin/terramap" run --no-progress
' hide "$src" "$build" "$work/prefix" > "$work/run.log" 2>&1 || {
  cat "$work/run.log"
  echo "FAIL: the installed terramap did not run with the checkout hidden"
  exit 1
}
cat "$work/run.log"
for f in map.tif elevation.png truth_elevation.png report.json; do
  test -s "out/demo/$f" || { echo "FAIL: ./out/demo/$f missing"; exit 1; }
done
grep -q "^wrote out/demo/map.tif" "$work/run.log" || { echo "FAIL: the demo did not write ./out/demo"; exit 1; }
echo "OK: the installed terramap ran the demo from an empty folder into ./out/demo"
