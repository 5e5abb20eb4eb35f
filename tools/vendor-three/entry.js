// Everything three.js exports, plus the orbit camera controls from its examples.
export * from 'three';
export { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
