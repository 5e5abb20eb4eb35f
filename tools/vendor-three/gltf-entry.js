// three.js's glTF 2.0 loader, for pages that already load three.min.js (the global THREE): the
// loader's own imports of 'three' resolve to three-global.cjs (build.sh's --alias), so the
// library is not bundled a second time. The loader itself is imported by relative path, which
// the alias leaves alone.
export { GLTFLoader } from './node_modules/three/examples/jsm/loaders/GLTFLoader.js';
