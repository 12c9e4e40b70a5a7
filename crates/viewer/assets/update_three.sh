#!/usr/bin/env bash
# Copies the three.js files the viewer serves from npm's node_modules into assets/three/
# (committed, compiled into the binary with include_bytes!, so nothing is fetched at run
# time). Run after changing the `three` version in crates/viewer/package.json:
#   cd crates/viewer && npm ci && assets/update_three.sh
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
src="$here/../node_modules/three"
[ -f "$src/build/three.module.min.js" ] || { echo "run 'npm ci' in crates/viewer first" >&2; exit 1; }
cp "$src/build/three.module.min.js" "$here/three/three.module.min.js"
cp "$src/examples/jsm/controls/OrbitControls.js" "$here/three/OrbitControls.js"
cp "$src/LICENSE" "$here/three/LICENSE"
node -e "console.log(require('$src/package.json').version)" > "$here/three/VERSION"
echo "three.js $(cat "$here/three/VERSION") copied to $here/three"
