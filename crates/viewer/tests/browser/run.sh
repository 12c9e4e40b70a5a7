#!/usr/bin/env bash
# Browser test of the viewer: builds semrecon, makes a tiny synthetic dataset, serves it with
# `semrecon view`, drives the page with headless chromium (viewer.test.mjs), then does the
# same for the static page of `semrecon export-viewer` opened from a file:// URL.
#
# Needs: /usr/bin/chromium (Debian package `chromium`) and `npm ci` run in crates/viewer
# (playwright-core). Without them it prints why and exits 0 (skipped), unless
# SEMRECON_REQUIRE_BROWSER=1, when it fails.
# Screenshots go to $SCREENSHOTS (default: target/viewer-browser-test).
set -euo pipefail
root="$(cd "$(dirname "$0")/../../../.." && pwd)"
here="$root/crates/viewer/tests/browser"
chromium="${CHROMIUM:-/usr/bin/chromium}"
skip() {
  echo "viewer browser test skipped: $1"
  if [ "${SEMRECON_REQUIRE_BROWSER:-0}" = 1 ]; then exit 1; fi
  exit 0
}
[ -x "$chromium" ] || skip "$chromium not found (apt-get install -y chromium)"
command -v node >/dev/null || skip "node not found"
[ -d "$root/crates/viewer/node_modules/playwright-core" ] || skip "playwright-core missing (cd crates/viewer && npm ci)"

cd "$root"
cargo build --release -p semrecon
bin="$root/target/release/semrecon"
work="$(mktemp -d)"
shots="${SCREENSHOTS:-$root/target/viewer-browser-test}"
server_pid=""
cleanup() {
  if [ -n "$server_pid" ]; then kill "$server_pid" 2>/dev/null || true; wait "$server_pid" 2>/dev/null || true; fi
  rm -rf "$work"
}
trap cleanup EXIT

"$bin" synth --out "$work/room" --frames 2 --size 64x48 >/dev/null
: > "$work/view.log"
"$bin" view "$work/room" > "$work/view.log" 2>&1 &
server_pid=$!
url=""
for _ in $(seq 100); do
  url="$(grep -o 'http://127.0.0.1:[0-9]*/' "$work/view.log" || true)"
  [ -n "$url" ] && break
  kill -0 "$server_pid" 2>/dev/null || { cat "$work/view.log"; echo "semrecon view exited"; exit 1; }
  sleep 0.1
done
[ -n "$url" ] || { cat "$work/view.log"; echo "semrecon view printed no address"; exit 1; }

echo "== served page $url"
CHROMIUM="$chromium" node "$here/viewer.test.mjs" "$url" "$shots/served"

"$bin" export-viewer "$work/room" --out "$work/export" >/dev/null
echo "== static page file://$work/export/index.html"
CHROMIUM="$chromium" node "$here/viewer.test.mjs" "file://$work/export/index.html" "$shots/static" --static
echo "screenshots in $shots"
