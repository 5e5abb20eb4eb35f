#!/usr/bin/env bash
# Rebuild the vendored three.js of the viewer: quatmotion/viz/static/three.min.js, its glTF loader
# (GLTFLoader.min.js) and their licence.
#
# three.js ships ES modules only (build/three.module.js imports ./three.core.js), and a module's
# relative imports cannot be resolved from a script inlined in a standalone HTML page, so the
# viewer needs one classic script: esbuild joins the library and OrbitControls into an IIFE that
# defines the global THREE. Versions are pinned in package.json and package-lock.json (with
# their registry integrity hashes). Needs node and npm; run from anywhere:
#     tools/vendor-three/build.sh
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
static="$here/../../quatmotion/viz/static"
cd "$here"
npm ci --no-audit --no-fund
version="$(node -p "require('./node_modules/three/package.json').version")"
{
  printf '/*! three.js %s (https://threejs.org), MIT licence: see LICENSE.three.txt beside this file.\n' "$version"
  printf ' * Bundled with examples/jsm/controls/OrbitControls.js by tools/vendor-three/build.sh. */\n'
  npx esbuild entry.js --bundle --minify --format=iife --global-name=THREE \
    --legal-comments=inline --target=es2020 --log-level=warning
} > "$static/three.min.js"
# The glTF loader: a script of its own, loaded after three.min.js (the viewer does not need it).
{
  printf '/*! three.js %s GLTFLoader (examples/jsm/loaders/GLTFLoader.js), MIT licence: see\n' "$version"
  printf ' * LICENSE.three.txt beside this file. Bundled by tools/vendor-three/build.sh; needs three.min.js. */\n'
  npx esbuild gltf-entry.js --bundle --minify --format=iife --global-name=THREE_GLTF \
    --alias:three=./three-global.cjs --legal-comments=inline --target=es2020 --log-level=warning
} > "$static/GLTFLoader.min.js"
cp node_modules/three/LICENSE "$static/LICENSE.three.txt"
for script in three.min.js GLTFLoader.min.js; do
  if grep -qi '</script' "$static/$script"; then
    echo "$script contains '</script' and cannot be inlined in a page" >&2
    exit 1
  fi
  echo "wrote $static/$script (three.js $version, $(wc -c < "$static/$script") bytes)"
done
