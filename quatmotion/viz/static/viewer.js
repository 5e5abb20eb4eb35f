/*
 * quatmotion viewer: skeleton clips animated in 3D with three.js (vendored as THREE).
 *
 * A classic script (no modules, so the standalone page opens from file:// with every script
 * inline). It exposes window.QuatmotionViewer:
 *
 *   QuatmotionViewer.decodeClip(payload)        -> Promise<Clip>    (quatmotion-frames/1)
 *   QuatmotionViewer.decodeErrors(errorsPayload) -> Promise<Float32Array>  (T * P, cm)
 *   QuatmotionViewer.mount(element, options)    -> Viewer
 *       options: {clips: [Clip], pairs: [{reference, compared, errors, arms_cm, max_cm}
 *                 (errors null and no_error, the reason, when there is no per-frame error)],
 *                 layout: 'side' | 'overlay', ghost: N (0 = off), autoplay: bool, loop: bool}
 *   QuatmotionViewer.show(element, data)         -> Promise<Viewer>  (data: viewer.view_data)
 *   QuatmotionViewer.boot()   standalone page: reads <script id="quatmotion-data"> and shows it.
 *   Viewer: play(), pause(), toggle(), seek(frame), step(n), setSpeed(x), setLoop(b),
 *           setFollow(b), setLayout(s), setGhost(n), cameraPreset('front'|'side'|'top'),
 *           frame (0-based master frame), nFrames, dispose(), onFrame(callback),
 *           projectedPoints() (where each viewport draws its clips' points, for tests).
 *
 * Units: centimetres, Y up (as forward_kinematics gives them). Frames count from 0.
 * Timing: the master clock runs at the first clip's fps and lasts as long as the longest clip;
 * every clip shows the frame at the same time, and a clip that has ended holds its last frame.
 * Framing (quatmotion.viz.framing): each payload names the point the viewer follows (the
 * body's centre, `follow`), the bones to draw and the points to hide (a root the body leaves
 * behind). The camera is fitted to what the clips cover over the whole clip: the body around
 * the followed point when following, else every point of every frame.
 * Overlay: a pair with a per-frame error is drawn where it is (the error is the distance
 * drawn); other clips sharing a viewport are moved horizontally so that each starts where the
 * viewport's first clip starts (its followed point at frame 0), and their labels say so.
 */
(function (global) {
  'use strict';
  const THREE = global.THREE;
  const FORMAT = 'quatmotion-frames/1';

  const PALETTE = [0x1f5fd6, 0xe07b00, 0x8e44ad, 0xc0392b, 0x16a085, 0x7f8c8d];
  const COMPARE_BLUE = 0x1f5fd6;
  const COMPARE_GREEN = 0x22a33a;
  const SPEEDS = [0.1, 0.25, 0.5, 1, 2, 4];
  const MAX_GHOSTS = 600; // beyond this a trail is unreadable and only costs draw time

  // ---------------------------------------------------------------- decoding
  function base64ToBytes(text) {
    if (typeof Uint8Array.fromBase64 === 'function') return Uint8Array.fromBase64(text);
    const binary = atob(text);
    const out = new Uint8Array(binary.length);
    for (let i = 0; i < binary.length; i++) out[i] = binary.charCodeAt(i);
    return out;
  }

  async function inflate(bytes) {
    // The browser's own zlib: nothing to ship, and it runs off the main thread.
    const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream('deflate'));
    return new Uint8Array(await new Response(stream).arrayBuffer());
  }

  /** A block (see quatmotion.viz.frames) as a Float32Array of T * C values, row-major. */
  async function decodeBlock(block) {
    const raw = await inflate(base64ToBytes(block.data));
    const T = block.shape[0], C = block.shape[1], n = T * C;
    if (block.encoding === 'float32-planes') {
      if (raw.length !== 4 * n) throw new Error('float32 block has ' + raw.length + ' bytes, expected ' + 4 * n);
      const bytes = new Uint8Array(4 * n);
      for (let i = 0; i < n; i++) {
        bytes[4 * i] = raw[i]; bytes[4 * i + 1] = raw[n + i];
        bytes[4 * i + 2] = raw[2 * n + i]; bytes[4 * i + 3] = raw[3 * n + i];
      }
      return new Float32Array(bytes.buffer); // little-endian, as every browser's typed arrays
    }
    if (block.encoding === 'uint16-delta-planes') {
      if (raw.length !== 2 * n) throw new Error('uint16 block has ' + raw.length + ' bytes, expected ' + 2 * n);
      const offset = block.offset, step = block.step, L = offset.length;
      const level = new Uint16Array(C);
      const out = new Float32Array(n);
      for (let t = 0, i = 0; t < T; t++) {
        for (let c = 0; c < C; c++, i++) {
          const v = (level[c] + (raw[i] | (raw[n + i] << 8))) & 0xffff;
          level[c] = v;
          out[i] = offset[c % L] + v * step[c % L];
        }
      }
      return out;
    }
    throw new Error('unknown block encoding ' + block.encoding);
  }

  async function decodeClip(payload) {
    if (payload.format !== FORMAT) throw new Error('not a ' + FORMAT + ' payload: ' + payload.format);
    const [root, rel] = await Promise.all([decodeBlock(payload.root), decodeBlock(payload.relative)]);
    const T = payload.n_frames, P = payload.point_names.length;
    const positions = rel; // made absolute in place: relative + root
    for (let t = 0; t < T; t++) {
      const rx = root[3 * t], ry = root[3 * t + 1], rz = root[3 * t + 2];
      const base = t * P * 3;
      for (let p = 0; p < P; p++) {
        positions[base + 3 * p] += rx; positions[base + 3 * p + 1] += ry; positions[base + 3 * p + 2] += rz;
      }
    }
    const hidden = new Set(payload.hidden || []);
    const visible = [];
    for (let p = 0; p < P; p++) if (!hidden.has(p)) visible.push(p);
    const follow = Number.isInteger(payload.follow) && payload.follow >= 0 && payload.follow < P ? payload.follow : 0;
    return {
      name: payload.name, fps: payload.fps, nFrames: T, nPoints: P, nJoints: payload.n_joints,
      pointNames: payload.point_names, bones: payload.bones, positions: positions,
      quantisationCm: payload.max_quantisation_cm, follow: follow, visible: visible,
    };
  }

  function decodeErrors(errors) { return decodeBlock(errors.block); }

  // ---------------------------------------------------------------- helpers
  function clipStats(clip) {
    // The shown points' extent over the clip, the body's height and the followed point's
    // travel: for the camera, the grid and follow mode.
    const pos = clip.positions, P = clip.nPoints, T = clip.nFrames, visible = clip.visible;
    let minX = Infinity, maxX = -Infinity, minY = Infinity, maxY = -Infinity, minZ = Infinity, maxZ = -Infinity;
    let fx0 = Infinity, fx1 = -Infinity, fz0 = Infinity, fz1 = -Infinity;
    let height = 0, highestLow = -Infinity;
    for (let t = 0; t < T; t++) {
      let lo = Infinity, hi = -Infinity;
      for (const p of visible) {
        const i = (t * P + p) * 3, x = pos[i], y = pos[i + 1], z = pos[i + 2];
        if (x < minX) minX = x; if (x > maxX) maxX = x;
        if (y < minY) minY = y; if (y > maxY) maxY = y;
        if (z < minZ) minZ = z; if (z > maxZ) maxZ = z;
        if (y < lo) lo = y; if (y > hi) hi = y;
      }
      height = Math.max(height, hi - lo);
      highestLow = Math.max(highestLow, lo);
      const f = (t * P + clip.follow) * 3;
      fx0 = Math.min(fx0, pos[f]); fx1 = Math.max(fx1, pos[f]); fz0 = Math.min(fz0, pos[f + 2]); fz1 = Math.max(fz1, pos[f + 2]);
    }
    if (!(minX <= maxX)) { minX = maxX = minY = maxY = minZ = maxZ = 0; fx0 = fx1 = fz0 = fz1 = 0; }
    // The floor is y = 0, unless the figure stays under it all clip long (deeper than a tenth
    // of its height at every frame: a root read as absolute that was relative, issue 29): then
    // the floor follows the feet, at the clip's lowest point, and says so (data-floor).
    const under = T > 0 && highestLow < -0.1 * (height || 170);
    return {
      minX, maxX, minY, maxY, minZ, maxZ,
      floor: under ? minY : 0,
      centre: new THREE.Vector3((minX + maxX) / 2, 0, (minZ + maxZ) / 2),
      height: height || 170,
      travel: Math.max(fx1 - fx0, fz1 - fz0),
    };
  }

  /** Camera distance at which `box` (relative to the target, a Box3) fills at most `fill` of a
   * viewport of aspect `aspect` seen along `dir` (target to camera) with vertical field `fovDeg`. */
  function fitDistance(box, dir, fovDeg, aspect, fill) {
    const m = new THREE.Matrix4().lookAt(dir, new THREE.Vector3(0, 0, 0), new THREE.Vector3(0, 1, 0));
    const right = new THREE.Vector3(), up = new THREE.Vector3(), back = new THREE.Vector3();
    m.extractBasis(right, up, back);
    const tanV = Math.tan((fovDeg * Math.PI) / 360) * fill, tanH = tanV * aspect;
    let d = 0;
    const v = new THREE.Vector3();
    for (let k = 0; k < 8; k++) {
      v.set(k & 1 ? box.max.x : box.min.x, k & 2 ? box.max.y : box.min.y, k & 4 ? box.max.z : box.min.z);
      const z = v.dot(back);
      d = Math.max(d, z + Math.abs(v.dot(right)) / tanH, z + Math.abs(v.dot(up)) / tanV);
    }
    return d;
  }

  /**
   * A square grid on the floor (y = 0), `divisions` cells of `cell` cm a side, centred on the
   * origin, its two centre lines darker. Unlike THREE.GridHelper, each line is cut into pieces
   * of at most a few cells: a line that runs from in front of the camera to behind it
   * (following a walk, the camera stands over the grid) vanished whole in Chromium's
   * SwiftShader WebGL, where only the piece behind the camera should.
   */
  function floorGrid(divisions, cell) {
    const half = (divisions * cell) / 2, pieceCells = Math.max(1, Math.ceil(divisions / 48));
    const pieces = Math.ceil(divisions / pieceCells), piece = (divisions * cell) / pieces;
    const vertices = new Float32Array((divisions + 1) * pieces * 12), colours = new Float32Array(vertices.length);
    const light = new THREE.Color(0xd0d3d8), dark = new THREE.Color(0x9aa0a8);
    let k = 0;
    for (let i = 0; i <= divisions; i++) {
      const a = -half + i * cell, c = 2 * i === divisions ? dark : light;
      for (let j = 0; j < pieces; j++) {
        const s0 = -half + j * piece, s1 = s0 + piece;
        for (const [x, z] of [[a, s0], [a, s1], [s0, a], [s1, a]]) {
          vertices[k] = x; vertices[k + 1] = 0; vertices[k + 2] = z;
          colours[k] = c.r; colours[k + 1] = c.g; colours[k + 2] = c.b;
          k += 3;
        }
      }
    }
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(vertices, 3));
    geometry.setAttribute('color', new THREE.BufferAttribute(colours, 3));
    return new THREE.LineSegments(geometry, new THREE.LineBasicMaterial({ vertexColors: true }));
  }

  function niceCeil(x) {
    if (!(x > 0)) return 1;
    const e = Math.pow(10, Math.floor(Math.log10(x)));
    for (const m of [1, 2, 5, 10]) if (m * e >= x) return m * e;
    return 10 * e;
  }

  const _c0 = new THREE.Color(COMPARE_GREEN), _c1 = new THREE.Color(0xf2c40f), _c2 = new THREE.Color(0xd62020);
  function errorColour(value, scale, out) {
    // Green (no error, the compared skeleton's colour) through yellow to red at `scale` cm.
    const s = Math.min(Math.max(value / scale, 0), 1);
    if (s < 0.5) return out.copy(_c0).lerp(_c1, s * 2);
    return out.copy(_c1).lerp(_c2, (s - 0.5) * 2);
  }

  function el(tag, attrs, children) {
    const node = document.createElement(tag);
    for (const k in attrs || {}) {
      if (k === 'text') node.textContent = attrs[k];
      else if (k === 'class') node.className = attrs[k];
      else node.setAttribute(k, attrs[k]);
    }
    for (const c of children || []) node.appendChild(c);
    return node;
  }

  // ---------------------------------------------------------------- one skeleton
  const _up = new THREE.Vector3(0, 1, 0), _a = new THREE.Vector3(), _b = new THREE.Vector3(),
    _d = new THREE.Vector3(), _q = new THREE.Quaternion(), _s = new THREE.Vector3(),
    _m = new THREE.Matrix4(), _col = new THREE.Color();

  class SkeletonFigure {
    constructor(clip, colour, radius) {
      this.clip = clip;
      this.colour = new THREE.Color(colour);
      this.radius = radius;
      this.group = new THREE.Group();
      const boneGeometry = new THREE.CylinderGeometry(1, 1, 1, 10, 1, false);
      const jointGeometry = new THREE.SphereGeometry(1, 12, 8);
      const material = new THREE.MeshLambertMaterial({ color: 0xffffff });
      this.bones = new THREE.InstancedMesh(boneGeometry, material, clip.bones.length);
      this.joints = new THREE.InstancedMesh(jointGeometry, material, clip.visible.length);
      for (const mesh of [this.bones, this.joints]) {
        mesh.instanceMatrix.setUsage(THREE.DynamicDrawUsage);
        mesh.frustumCulled = false; // instances move every frame; a cached bound would go stale
        for (let i = 0; i < mesh.count; i++) mesh.setColorAt(i, this.colour);
        this.group.add(mesh);
      }
      this.ghost = null;
    }

    /** Pose at frame t (the group carries the clip's offset), coloured by `errors` if given. */
    update(t, errors, errorScale) {
      const clip = this.clip, pos = clip.positions, base = t * clip.nPoints * 3, r = this.radius;
      const bones = clip.bones;
      for (let i = 0; i < bones.length; i++) {
        const ia = base + 3 * bones[i][0], ib = base + 3 * bones[i][1];
        _a.set(pos[ia], pos[ia + 1], pos[ia + 2]);
        _b.set(pos[ib], pos[ib + 1], pos[ib + 2]);
        _d.subVectors(_b, _a);
        const length = _d.length();
        if (length > 1e-6) _q.setFromUnitVectors(_up, _d.divideScalar(length)); else _q.identity();
        _s.set(r, length, r);
        _m.compose(_a.add(_b).multiplyScalar(0.5), _q, _s);
        this.bones.setMatrixAt(i, _m);
        if (errors) this.bones.setColorAt(i, errorColour(errors[t * clip.nPoints + bones[i][1]], errorScale, _col));
      }
      _q.identity();
      _s.set(1.5 * r, 1.5 * r, 1.5 * r);
      const visible = clip.visible;
      for (let k = 0; k < visible.length; k++) {
        const p = visible[k], i = base + 3 * p;
        _a.set(pos[i], pos[i + 1], pos[i + 2]);
        _m.compose(_a, _q, _s);
        this.joints.setMatrixAt(k, _m);
        if (errors) this.joints.setColorAt(k, errorColour(errors[t * clip.nPoints + p], errorScale, _col));
      }
      this.bones.instanceMatrix.needsUpdate = true;
      this.joints.instanceMatrix.needsUpdate = true;
      if (errors) { this.bones.instanceColor.needsUpdate = true; this.joints.instanceColor.needsUpdate = true; }
    }

    resetColours() {
      for (const mesh of [this.bones, this.joints]) {
        for (let i = 0; i < mesh.count; i++) mesh.setColorAt(i, this.colour);
        mesh.instanceColor.needsUpdate = true;
      }
    }

    /** Faint poses every `every` frames as line segments (0 removes the trail). */
    setGhost(every) {
      if (this.ghost) { this.group.remove(this.ghost); this.ghost.geometry.dispose(); this.ghost = null; }
      if (!(every > 0)) return 0;
      const clip = this.clip, pos = clip.positions, P = clip.nPoints;
      const step = Math.max(every, Math.ceil(clip.nFrames / MAX_GHOSTS));
      const frames = [];
      for (let t = 0; t < clip.nFrames; t += step) frames.push(t);
      const vertices = new Float32Array(frames.length * clip.bones.length * 6);
      let k = 0;
      for (const t of frames) {
        for (const [a, b] of clip.bones) {
          for (const p of [a, b]) {
            const i = (t * P + p) * 3;
            vertices[k++] = pos[i]; vertices[k++] = pos[i + 1]; vertices[k++] = pos[i + 2];
          }
        }
      }
      const geometry = new THREE.BufferGeometry();
      geometry.setAttribute('position', new THREE.BufferAttribute(vertices, 3));
      const material = new THREE.LineBasicMaterial({ color: this.colour, transparent: true, opacity: 0.28, depthWrite: false });
      this.ghost = new THREE.LineSegments(geometry, material);
      this.group.add(this.ghost);
      return step;
    }

    dispose() {
      this.setGhost(0);
      for (const mesh of [this.bones, this.joints]) { mesh.geometry.dispose(); mesh.dispose(); }
      this.bones.material.dispose();
    }
  }

  // ---------------------------------------------------------------- the viewer
  class Viewer {
    constructor(element, options) {
      this.element = element;
      this.clips = options.clips;
      if (!this.clips || !this.clips.length) throw new Error('the viewer needs at least one clip');
      this.pairs = options.pairs || [];
      this.fps = this.clips[0].fps;
      const duration = Math.max(...this.clips.map((c) => c.nFrames / c.fps));
      this.nFrames = Math.max(1, Math.round(duration * this.fps));
      this.position = 0; // master frame, fractional while playing
      this.frame = 0;
      this.playing = false;
      this.speed = 1;
      this.loop = options.loop !== false;
      this.follow = false; // set after the clips' extents are known
      this.layout = options.layout || (this.pairs.length ? 'side' : (this.clips.length > 1 ? 'side' : 'overlay'));
      this.errorColours = true;
      this.firstPlayMs = null;
      this.listeners = [];
      this._dirty = true;
      this._last = null;

      this.stats = this.clips.map(clipStats);
      const height = Math.max(...this.stats.map((s) => s.height));
      this.bodyHeight = height;
      // A body that travels further than twice its height: follow it (its centre, the
      // payload's `follow` point, never a root left behind at the origin). Unfollowed, the
      // camera takes in the whole path, and a walk towards it shows the far end small.
      const travel = Math.max(...this.stats.map((s) => s.travel));
      this.follow = options.follow !== undefined ? !!options.follow : travel > 2 * height;
      this.offsets = this.clips.map(() => new THREE.Vector3());
      // Per-pair colours: reference blue, compared green; other clips from the palette.
      const colours = this.clips.map((_, i) => PALETTE[i % PALETTE.length]);
      for (const pair of this.pairs) { colours[pair.reference] = COMPARE_BLUE; colours[pair.compared] = COMPARE_GREEN; }
      this.figures = this.clips.map((clip, i) => new SkeletonFigure(clip, colours[i], height * 0.011));
      for (const pair of this.pairs) {
        if (pair.errorValues && !pair.errorScale) pair.errorScale = niceCeil(percentile(pair.errorValues, 0.99) || pair.max_cm || 1);
      }
      this._errorPairs = this.pairs.filter((p) => p.errorValues);

      this._buildScene();
      this._buildUi();
      this.setGhost(options.ghost || 0);
      this.preset = 'front';
      this.setLayout(this.layout); // places the clips and fits the camera
      this.seek(0);
      this._onResize = () => this._resize();
      global.addEventListener('resize', this._onResize);
      // The stage also changes size without the window (the error panel below it fills in).
      this._resizeObserver = typeof ResizeObserver === 'function' ? new ResizeObserver(this._onResize) : null;
      if (this._resizeObserver) this._resizeObserver.observe(this.canvas.parentElement);
      this._resize();
      this._loop = this._loop.bind(this);
      this._raf = requestAnimationFrame(this._loop);
      if (options.autoplay !== false) this.play();
    }

    // ---- scene
    _buildScene() {
      const canvasHolder = this.element.querySelector('.qmv-canvas');
      this.renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
      this.renderer.setPixelRatio(Math.min(global.devicePixelRatio || 1, 2));
      this.renderer.setClearColor(0xf4f5f7);
      canvasHolder.appendChild(this.renderer.domElement);
      this.canvas = this.renderer.domElement;
      this.scene = new THREE.Scene();
      this.scene.add(new THREE.HemisphereLight(0xffffff, 0x8a8f98, 2.2));
      const sun = new THREE.DirectionalLight(0xffffff, 1.4);
      sun.position.set(0.4, 1, 0.7);
      this.scene.add(sun);
      for (const f of this.figures) this.scene.add(f.group);
      this.grid = null;
      this.camera = new THREE.PerspectiveCamera(40, 1, 1, 1e6);
      this.renderCamera = this.camera.clone();
      this.controls = new THREE.OrbitControls(this.camera, this.canvas);
      this.controls.enableDamping = false;
      this.controls.addEventListener('change', () => { this._dirty = true; });
      this.controls.addEventListener('start', () => { this._cameraMoved = true; });
    }

    _buildGrid() {
      // Ground grid over every clip's floor area (where it is drawn), 50 cm cells (1 m when the
      // area is large).
      if (this.grid) { this.scene.remove(this.grid); this.grid.geometry.dispose(); this.grid.material.dispose(); }
      let minX = Infinity, maxX = -Infinity, minZ = Infinity, maxZ = -Infinity;
      this.stats.forEach((s, i) => {
        const o = this.offsets[i];
        minX = Math.min(minX, s.minX + o.x); maxX = Math.max(maxX, s.maxX + o.x);
        minZ = Math.min(minZ, s.minZ + o.z); maxZ = Math.max(maxZ, s.maxZ + o.z);
      });
      const margin = this.bodyHeight;
      const size = Math.max(maxX - minX, maxZ - minZ) + 2 * margin;
      const cell = size > 3000 ? 100 : 50;
      const divisions = Math.min(600, Math.ceil(size / cell));
      this.grid = floorGrid(divisions, cell);
      const floor = Math.min(...this.stats.map((s) => s.floor));
      document.documentElement.dataset.floor = String(Math.round(floor * 10) / 10);
      this.grid.position.set((minX + maxX) / 2, floor, (minZ + maxZ) / 2);
      this.scene.add(this.grid);
    }

    /** Viewports: lists of clip indices drawn together. */
    _groups() {
      if (this.layout === 'overlay') {
        if (!this.pairs.length) return [this.clips.map((_, i) => i)];
        const groups = this.pairs.map((p) => [p.reference, p.compared]);
        const used = new Set(groups.flat());
        this.clips.forEach((_, i) => { if (!used.has(i)) groups.push([i]); });
        return groups;
      }
      return this.clips.map((_, i) => [i]);
    }

    /** Horizontal shift of each clip: in an overlaid viewport, a clip that is not half of a
     * pair with a per-frame error starts where the viewport's first clip starts. */
    _placeClips() {
      this.offsets.forEach((o) => o.set(0, 0, 0));
      this.moved = this.clips.map(() => false);
      if (this.layout === 'overlay') {
        for (const group of this._groups()) {
          if (this._errorPairs.some((p) => group.includes(p.reference) && group.includes(p.compared))) continue;
          const lead = this.clips[group[0]], lf = lead.follow * 3;
          for (const i of group.slice(1)) {
            const clip = this.clips[i], f = clip.follow * 3;
            this.offsets[i].set(lead.positions[lf] - clip.positions[f], 0, lead.positions[lf + 2] - clip.positions[f + 2]);
            this.moved[i] = this.offsets[i].lengthSq() > 1e-6;
          }
        }
      }
      this.figures.forEach((f, i) => f.group.position.copy(this.offsets[i]));
      this._buildGrid();
    }

    /** Where a viewport's camera is carried to: the followed point of its first clip (follow)
     * or the centre of its clips' floor area, at master frame `frame`. */
    _anchor(group, frame, out) {
      const lead = group[0];
      if (this.follow) {
        const clip = this.clips[lead], i = (this._clipFrameAt(lead, frame) * clip.nPoints + clip.follow) * 3;
        return out.set(clip.positions[i], 0, clip.positions[i + 2]).add(this.offsets[lead]);
      }
      let minX = Infinity, maxX = -Infinity, minZ = Infinity, maxZ = -Infinity;
      for (const i of group) {
        const s = this.stats[i], o = this.offsets[i];
        minX = Math.min(minX, s.minX + o.x); maxX = Math.max(maxX, s.maxX + o.x);
        minZ = Math.min(minZ, s.minZ + o.z); maxZ = Math.max(maxZ, s.maxZ + o.z);
      }
      return out.set((minX + maxX) / 2, 0, (minZ + maxZ) / 2);
    }

    /** What a viewport shows over the whole clip, relative to its anchor (a Box3). */
    _extent(group) {
      const box = new THREE.Box3(), anchor = new THREE.Vector3(), v = new THREE.Vector3();
      const n = this.nFrames, stride = Math.max(1, Math.floor(n / 1500));
      const frames = [];
      for (let f = 0; f < n; f += stride) frames.push(f);
      if (frames[frames.length - 1] !== n - 1) frames.push(n - 1);
      for (const f of frames) {
        this._anchor(group, f, anchor);
        for (const i of group) {
          const clip = this.clips[i], pos = clip.positions, base = this._clipFrameAt(i, f) * clip.nPoints * 3, o = this.offsets[i];
          for (const p of clip.visible) {
            const k = base + 3 * p;
            box.expandByPoint(v.set(pos[k] + o.x - anchor.x, pos[k + 1], pos[k + 2] + o.z - anchor.z));
          }
        }
      }
      return box;
    }

    _clipFrameAt(i, frame) {
      // The clip's frame at the master frame's time; a clip that has ended holds its last.
      return Math.min(this._clipTime(i, frame), this.clips[i].nFrames - 1);
    }

    _clipTime(i, frame) {
      const clip = this.clips[i];
      return clip.fps === this.fps ? frame : Math.floor(((frame + 1e-6) / this.fps) * clip.fps);
    }

    _clipFrame(i) { return this._clipFrameAt(i, this.frame); }

    /** renderCamera set up for viewport g of `count` (the orbit camera carried to `centre`). */
    _viewportCamera(centre, g, count, width, height) {
      const w = width / count;
      this.renderCamera.position.copy(this.camera.position).add(centre);
      this.renderCamera.quaternion.copy(this.camera.quaternion);
      this.renderCamera.aspect = w / height;
      this.renderCamera.updateProjectionMatrix();
      this.renderCamera.updateMatrixWorld();
      return { x: Math.round(g * w), width: Math.round(w) };
    }

    /**
     * Where the current frame's shown points land on the canvas, per viewport: {width, height,
     * viewports: [{x, width, clips, points: [[clip, point, px, py, inFront]]}]}, pixels from
     * the canvas's top left (CSS pixels). For tests: every point of a figure in its viewport.
     */
    projectedPoints() {
      const width = this.canvas.clientWidth, height = this.canvas.clientHeight;
      const groups = this._groups(), centre = new THREE.Vector3(), v = new THREE.Vector3();
      const viewports = groups.map((group, g) => {
        this._anchor(group, this.frame, centre);
        const port = this._viewportCamera(centre, g, groups.length, width, height);
        const points = [];
        for (const i of group) {
          const clip = this.clips[i], base = this._clipFrame(i) * clip.nPoints * 3, o = this.offsets[i];
          for (const p of clip.visible) {
            const k = base + 3 * p;
            v.set(clip.positions[k] + o.x, clip.positions[k + 1] + o.y, clip.positions[k + 2] + o.z).project(this.renderCamera);
            points.push([i, p, port.x + ((v.x + 1) / 2) * port.width, ((1 - v.y) / 2) * height, v.z > -1 && v.z < 1]);
          }
        }
        return { x: port.x, width: port.width, clips: group, points };
      });
      return { width, height, viewports };
    }

    _render() {
      const width = this.canvas.clientWidth, height = this.canvas.clientHeight;
      if (!width || !height) return;
      for (let i = 0; i < this.figures.length; i++) {
        const pair = this._errorPairs.find((p) => p.compared === i);
        const errors = pair && this.errorColours ? pair.errorValues : null;
        this.figures[i].update(this._clipFrame(i), errors, pair ? pair.errorScale : 1);
      }
      const groups = this._groups();
      this.renderer.setScissorTest(true);
      const centre = new THREE.Vector3();
      groups.forEach((group, g) => {
        this.figures.forEach((f, i) => { f.group.visible = group.includes(i); });
        // The orbit camera circles its target near the origin; each viewport carries it to
        // its anchor (the followed body, or the centre of its clips' floor area).
        this._anchor(group, this.frame, centre);
        const port = this._viewportCamera(centre, g, groups.length, width, height);
        this.renderer.setViewport(port.x, 0, port.width, height);
        this.renderer.setScissor(port.x, 0, port.width, height);
        this.renderer.render(this.scene, this.renderCamera);
        const label = this.labels[g];
        if (label) {
          label.style.left = (port.x + 8) + 'px';
          label.style.maxWidth = Math.max(80, port.width - 16) + 'px';
          label.textContent = group.map((i) => this._label(i)).join('  vs  ');
        }
      });
      this.labels.forEach((label, g) => { label.style.display = g < groups.length ? '' : 'none'; });
      this.renderer.setScissorTest(false);
    }

    _label(i) {
      const clip = this.clips[i], t = this._clipFrame(i);
      const notes = [];
      if (clip.fps !== this.fps) notes.push('frame ' + t + ' at ' + clip.fps + ' fps');
      if (this._clipTime(i, this.frame) > clip.nFrames - 1) notes.push('ended, holds frame ' + t);
      if (this.moved && this.moved[i]) notes.push('start aligned with ' + this.clips[this._groups().find((g) => g.includes(i))[0]].name);
      return clip.name + (notes.length ? ' (' + notes.join('; ') + ')' : '');
    }

    _resize() {
      const holder = this.canvas.parentElement;
      this.renderer.setSize(holder.clientWidth, holder.clientHeight, false);
      this.canvas.style.width = '100%';
      this.canvas.style.height = '100%';
      // The fit depends on the viewports' shape: fit again unless the user moved the camera.
      if (this.preset && !this._cameraMoved) this.cameraPreset(this.preset);
      this._drawStrips();
      this._dirty = true;
    }

    _loop(now) {
      this._raf = requestAnimationFrame(this._loop);
      if (this.playing) {
        const dt = this._last === null ? 0 : Math.min((now - this._last) / 1000, 0.25);
        let position = this.position + dt * this.fps * this.speed;
        if (position >= this.nFrames) {
          if (this.loop) position %= this.nFrames;
          else { position = this.nFrames - 1; this.pause(); }
        }
        this._setPosition(position);
      }
      this._last = now;
      if (this._dirty) {
        this._render();
        this._dirty = false;
        if (this.playing && this.firstPlayMs === null) {
          this.firstPlayMs = performance.now();
          document.documentElement.dataset.firstPlayMs = String(Math.round(this.firstPlayMs));
        }
      }
    }

    _setPosition(position) {
      this.position = position;
      const frame = Math.min(this.nFrames - 1, Math.max(0, Math.floor(position)));
      if (frame !== this.frame) { this.frame = frame; this._dirty = true; }
      this._updateUi();
    }

    // ---- public controls
    play() {
      if (this.frame >= this.nFrames - 1 && !this.loop) this.position = 0;
      this.playing = true; this._last = null; this._dirty = true; this._updateUi();
    }
    pause() { this.playing = false; this._updateUi(); }
    toggle() { if (this.playing) this.pause(); else this.play(); }
    seek(frame) {
      frame = Math.min(this.nFrames - 1, Math.max(0, Math.round(frame)));
      this.position = frame; this.frame = frame; this._dirty = true; this._updateUi();
    }
    step(n) { this.pause(); this.seek(this.frame + n); }
    setSpeed(x) { this.speed = x; this._updateUi(); }
    setLoop(b) { this.loop = !!b; this._updateUi(); }
    setFollow(b) {
      this.follow = !!b;
      if (this.preset) this.cameraPreset(this.preset); // re-frame: the body, or the whole area
      this._dirty = true; this._updateUi();
    }
    setLayout(layout) {
      this.layout = layout === 'overlay' ? 'overlay' : 'side';
      this._placeClips();
      if (this.preset) this.cameraPreset(this.preset); // the viewports changed shape
      this._dirty = true; this._updateUi();
    }
    setGhost(every) {
      every = Math.max(0, Math.round(every || 0));
      let used = 0;
      for (const f of this.figures) used = Math.max(used, f.setGhost(every));
      this.ghost = every;
      this.ghostUsed = used;
      this._dirty = true; this._updateUi();
    }
    setErrorColours(b) {
      this.errorColours = !!b;
      if (!b) for (const p of this._errorPairs) this.figures[p.compared].resetColours();
      this._dirty = true;
    }
    cameraPreset(name) {
      // Fitted to what every viewport shows over the whole clip, relative to its anchor:
      // following, the body around its centre; otherwise every point of every frame.
      this.preset = name;
      this._cameraMoved = false;
      const groups = this._groups();
      const box = new THREE.Box3();
      for (const group of groups) box.union(this._extent(group));
      if (box.isEmpty()) box.set(new THREE.Vector3(-50, 0, -50), new THREE.Vector3(50, this.bodyHeight, 50));
      const target = box.getCenter(new THREE.Vector3());
      box.translate(target.clone().negate());
      const directions = { front: [0, 0.15, 1], side: [1, 0.15, 0], top: [0, 1, 0.001] };
      const dir = new THREE.Vector3(...(directions[name] || directions.front)).normalize();
      const width = this.canvas.clientWidth || 640, height = this.canvas.clientHeight || 480;
      const aspect = width / groups.length / height;
      const d = Math.max(fitDistance(box, dir, this.camera.fov, aspect, 0.86), this.bodyHeight * 0.5);
      this.controls.target.copy(target);
      this.camera.position.copy(target).addScaledVector(dir, d);
      this.camera.up.set(0, 1, 0);
      this.controls.update();
      this._dirty = true;
    }
    onFrame(callback) { this.listeners.push(callback); }
    dispose() {
      cancelAnimationFrame(this._raf);
      global.removeEventListener('resize', this._onResize);
      if (this._resizeObserver) this._resizeObserver.disconnect();
      document.removeEventListener('keydown', this._onKey);
      this.controls.dispose();
      for (const f of this.figures) f.dispose();
      this.renderer.dispose();
      this.element.replaceChildren();
    }

    // ---- user interface
    _buildUi() {
      const root = this.element;
      const q = (s) => root.querySelector(s);
      this.ui = {
        play: q('.qmv-play'), prev: q('.qmv-prev'), next: q('.qmv-next'), counter: q('.qmv-counter'),
        time: q('.qmv-time'), scrub: q('.qmv-scrub'), speed: q('.qmv-speed'), loop: q('.qmv-loop'),
        follow: q('.qmv-follow'), layout: q('.qmv-layout'), ghost: q('.qmv-ghost'),
        errorPanel: q('.qmv-error'), strips: q('.qmv-strips'), errorColours: q('.qmv-error-colours'),
        labels: q('.qmv-labels'), goto: q('.qmv-goto'),
      };
      const ui = this.ui;
      ui.scrub.max = String(this.nFrames - 1);
      ui.scrub.step = '1';
      for (const s of SPEEDS) ui.speed.appendChild(el('option', { value: String(s), text: s + '\u00d7' }));
      ui.speed.value = '1';
      ui.play.addEventListener('click', () => this.toggle());
      ui.prev.addEventListener('click', () => this.step(-1));
      ui.next.addEventListener('click', () => this.step(1));
      ui.scrub.addEventListener('input', () => { const f = Number(ui.scrub.value); this.pause(); this.seek(f); });
      ui.speed.addEventListener('change', () => this.setSpeed(Number(ui.speed.value)));
      ui.loop.addEventListener('change', () => this.setLoop(ui.loop.checked));
      ui.follow.addEventListener('change', () => this.setFollow(ui.follow.checked));
      ui.layout.addEventListener('change', () => this.setLayout(ui.layout.value));
      ui.ghost.addEventListener('change', () => this.setGhost(Number(ui.ghost.value)));
      ui.goto.addEventListener('change', () => { const f = Number(ui.goto.value); this.pause(); this.seek(f); });
      if (ui.errorColours) ui.errorColours.addEventListener('change', () => this.setErrorColours(ui.errorColours.checked));
      for (const b of root.querySelectorAll('[data-camera]')) b.addEventListener('click', () => this.cameraPreset(b.dataset.camera));
      ui.layout.disabled = this.clips.length < 2;
      this.labels = this.clips.map(() => ui.labels.appendChild(el('div', { class: 'qmv-label' })));
      root.classList.toggle('qmv-compare', this._errorPairs.length > 0);
      // Error strips: one per pair with a per-frame error, under the scrub bar, sharing its cursor.
      this.strips = this._errorPairs.map((pair) => {
        const canvas = el('canvas', { class: 'qmv-strip', title: 'error per frame, click to seek' });
        ui.strips.appendChild(canvas);
        const seekFrom = (ev) => {
          const r = canvas.getBoundingClientRect();
          this.pause();
          this.seek(((ev.clientX - r.left) / r.width) * (this.nFrames - 1));
        };
        canvas.addEventListener('pointerdown', (ev) => { canvas.setPointerCapture(ev.pointerId); seekFrom(ev); });
        canvas.addEventListener('pointermove', (ev) => { if (ev.buttons) seekFrom(ev); });
        return { canvas, pair, summary: frameSummary(pair, this.clips[pair.compared]) };
      });
      this._onKey = (ev) => {
        const tag = (ev.target && ev.target.tagName) || '';
        if ((tag === 'INPUT' && ev.target.type !== 'range' && ev.target.type !== 'checkbox') || tag === 'SELECT') return;
        const big = ev.shiftKey ? 10 : 1;
        if (ev.code === 'Space') { this.toggle(); }
        else if (ev.key === 'ArrowRight') { this.step(big); }
        else if (ev.key === 'ArrowLeft') { this.step(-big); }
        else if (ev.key === 'Home') { this.pause(); this.seek(0); }
        else if (ev.key === 'End') { this.pause(); this.seek(this.nFrames - 1); }
        else return;
        ev.preventDefault();
      };
      document.addEventListener('keydown', this._onKey);
    }

    _updateUi() {
      const ui = this.ui, f = this.frame;
      ui.play.textContent = this.playing ? '\u275a\u275a' : '\u25b6';
      ui.play.title = this.playing ? 'pause (Space)' : 'play (Space)';
      ui.counter.textContent = 'frame ' + f + ' / ' + (this.nFrames - 1);
      ui.time.textContent = (f / this.fps).toFixed(3) + ' s / ' + ((this.nFrames - 1) / this.fps).toFixed(2) + ' s @ ' + this.fps + ' fps';
      if (document.activeElement !== ui.scrub || !this.playing) ui.scrub.value = String(f);
      if (document.activeElement !== ui.goto) ui.goto.value = String(f);
      ui.loop.checked = this.loop;
      ui.follow.checked = this.follow;
      ui.layout.value = this.layout;
      ui.speed.value = String(this.speed);
      if (document.activeElement !== ui.ghost) ui.ghost.value = String(this.ghost || 0);
      ui.ghost.title = this.ghostUsed && this.ghostUsed !== this.ghost ? 'every ' + this.ghostUsed + ' frames (at most ' + MAX_GHOSTS + ' poses)' : 'a faint pose every N frames; 0 = off';
      document.documentElement.dataset.frame = String(f);
      document.documentElement.dataset.playing = String(this.playing);
      this._updateErrorPanel();
      this._drawCursors();
      for (const cb of this.listeners) cb(f);
    }

    _updateErrorPanel() {
      const panel = this.ui.errorPanel;
      if (!this.pairs.length) { panel.hidden = true; return; }
      panel.hidden = false;
      const lines = this.pairs.map((pair) => {
        const clip = this.clips[pair.compared], ref = this.clips[pair.reference];
        const title = '<div class="qmv-error-title"><span class="qmv-swatch" style="background:#1f5fd6"></span>' + escapeHtml(ref.name) +
          ' vs <span class="qmv-swatch" style="background:#22a33a"></span>' + escapeHtml(clip.name) + '</div>';
        if (!pair.errorValues) {
          return title + '<div class="qmv-no-error">no per-frame error: ' + escapeHtml(pair.no_error || 'the clips cannot be compared frame by frame') +
            '.</div><div class="qmv-small">Each plays at its own length on one clock; the shorter holds its last frame.</div>';
        }
        const t = this._clipFrame(pair.compared), P = clip.nPoints, e = pair.errorValues;
        let sum = 0, worst = 0, worstAt = 0;
        const order = [];
        for (let p = 0; p < P; p++) {
          const v = e[t * P + p];
          sum += v * v; order.push(p);
          if (v > worst) { worst = v; worstAt = p; }
        }
        order.sort((a, b) => e[t * P + b] - e[t * P + a]);
        const top = order.slice(0, 3).map((p) => clip.pointNames[p] + ' ' + e[t * P + p].toFixed(2)).join(', ');
        return title +
          '<div>frame ' + t + ': RMS <b class="qmv-frame-rms">' + Math.sqrt(sum / P).toFixed(2) + ' cm</b>, max <b>' + worst.toFixed(2) +
          ' cm</b> (' + escapeHtml(clip.pointNames[worstAt]) + ')</div>' +
          '<div class="qmv-small">worst joints (cm): ' + escapeHtml(top) + '</div>' +
          '<div class="qmv-small">whole clip: ARMS ' + pair.arms_cm.toFixed(3) + ' cm, max ' + pair.max_cm.toFixed(2) + ' cm ' +
          '<span class="qmv-legend"><span>0</span><span class="qmv-ramp"></span><span>\u2265 ' + pair.errorScale + ' cm</span></span></div>';
      });
      panel.innerHTML = lines.map((l) => '<div class="qmv-pair">' + l + '</div>').join('');
    }

    _drawStrips() {
      for (const strip of this.strips || []) {
        const { canvas, summary } = strip;
        const ratio = global.devicePixelRatio || 1;
        const w = Math.max(1, Math.round(canvas.clientWidth * ratio)), h = Math.max(1, Math.round(canvas.clientHeight * ratio));
        canvas.width = w; canvas.height = h;
        // The envelope per pixel column, so a long clip's peaks stay visible.
        const image = document.createElement('canvas');
        image.width = w; image.height = h;
        const g = image.getContext('2d');
        g.fillStyle = '#ffffff'; g.fillRect(0, 0, w, h);
        const top = summary.maxOfMax > 0 ? niceCeil(summary.maxOfMax) : 1;
        const T = summary.rms.length;
        const pad = 14 * ratio;
        const y = (v) => h - 1 - (v / top) * (h - pad);
        for (let x = 0; x < w; x++) {
          const a = Math.floor((x / w) * T), b = Math.max(a + 1, Math.floor(((x + 1) / w) * T));
          let mx = 0, rm = 0;
          for (let t = a; t < b && t < T; t++) { mx = Math.max(mx, summary.max[t]); rm = Math.max(rm, summary.rms[t]); }
          g.fillStyle = 'rgba(214,32,32,0.35)'; g.fillRect(x, y(mx), 1, h - y(mx));
          g.fillStyle = 'rgba(34,163,58,0.9)'; g.fillRect(x, y(rm), 1, h - y(rm));
        }
        g.fillStyle = '#333'; g.font = (10 * ratio) + 'px sans-serif';
        g.fillText('error per frame (cm): RMS over joints (green), max joint (red); top = ' + top + ' cm', 4 * ratio, 11 * ratio);
        strip.image = image;
      }
      this._drawCursors();
    }

    _drawCursors() {
      for (const strip of this.strips || []) {
        if (!strip.image) continue;
        const { canvas } = strip;
        const g = canvas.getContext('2d');
        g.drawImage(strip.image, 0, 0);
        const x = Math.round((this.frame / Math.max(1, this.nFrames - 1)) * (canvas.width - 1));
        g.fillStyle = '#111'; g.fillRect(x - 1, 0, 2, canvas.height);
      }
    }
  }

  function frameSummary(pair, clip) {
    const e = pair.errorValues, P = clip.nPoints, T = clip.nFrames;
    const rms = new Float32Array(T), max = new Float32Array(T);
    let maxOfMax = 0;
    for (let t = 0; t < T; t++) {
      let s = 0, m = 0;
      for (let p = 0; p < P; p++) { const v = e[t * P + p]; s += v * v; if (v > m) m = v; }
      rms[t] = Math.sqrt(s / P); max[t] = m; if (m > maxOfMax) maxOfMax = m;
    }
    return { rms, max, maxOfMax };
  }

  function percentile(values, q) {
    // Of an even sample of at most ~20,000 values: it only sets the colour scale.
    if (!values || !values.length) return 0;
    const stride = Math.max(1, Math.floor(values.length / 20000));
    const sample = [];
    for (let i = 0; i < values.length; i += stride) sample.push(values[i]);
    sample.sort((a, b) => a - b);
    return sample[Math.min(sample.length - 1, Math.floor(q * sample.length))];
  }

  function escapeHtml(s) {
    return String(s).replace(/[&<>"']/g, (c) => ({ '&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;', "'": '&#39;' }[c]));
  }

  /** The viewer's controls, for pages that do not write their own (the standalone page does). */
  const TEMPLATE =
    '<div class="qmv-stage"><div class="qmv-canvas"></div><div class="qmv-labels"></div></div>' +
    '<div class="qmv-error" hidden></div>' +
    '<div class="qmv-bar">' +
    '<button class="qmv-prev" title="previous frame (\u2190, Shift \u00d710)">\u25c0\u25c0</button>' +
    '<button class="qmv-play">\u25b6</button>' +
    '<button class="qmv-next" title="next frame (\u2192, Shift \u00d710)">\u25b6\u25b6</button>' +
    '<span class="qmv-counter"></span><input class="qmv-goto" type="number" min="0" title="go to frame (counted from 0)">' +
    '<span class="qmv-time"></span>' +
    '<label>speed <select class="qmv-speed"></select></label>' +
    '<label><input class="qmv-loop" type="checkbox"> loop</label>' +
    '<label title="keep the centre of the body (its hips) in view"><input class="qmv-follow" type="checkbox"> follow body</label>' +
    '<span class="qmv-cams">camera <button data-camera="front" title="from +Z (the front of a CMU rest pose)">front</button>' +
    '<button data-camera="side" title="from +X">side</button><button data-camera="top" title="from above (+Y)">top</button></span>' +
    '<label>layout <select class="qmv-layout"><option value="side">side by side</option><option value="overlay">overlay</option></select></label>' +
    '<label title="a faint pose every N frames; 0 = off">ghost every <input class="qmv-ghost" type="number" min="0" step="1" value="0"> frames</label>' +
    '<label class="qmv-compare-only"><input class="qmv-error-colours" type="checkbox" checked> error colours</label>' +
    '</div>' +
    '<input class="qmv-scrub" type="range" min="0" value="0" aria-label="frame">' +
    '<div class="qmv-strips"></div>' +
    '<div class="qmv-help">Space play/pause \u00b7 \u2190/\u2192 step a frame (Shift: 10) \u00b7 Home/End \u00b7 ' +
    'drag to orbit, right-drag to pan, wheel to zoom \u00b7 frames count from 0</div>';

  async function mount(element, options) {
    if (!element.querySelector('.qmv-canvas')) element.innerHTML = TEMPLATE;
    element.classList.add('qmv');
    const pairs = await Promise.all((options.pairs || []).map(async (p) => Object.assign({}, p, { errorValues: p.errors ? await decodeErrors(p.errors) : null })));
    return new Viewer(element, Object.assign({}, options, { pairs }));
  }

  /**
   * Decode a view document (quatmotion.viz.viewer.view_data: {clips, pairs, layout, ghost,
   * autoplay, loop}) and mount a viewer on `element`. A web page fetches the document from an
   * API and calls this; the standalone page calls it through boot().
   */
  async function show(element, data) {
    const clips = await Promise.all(data.clips.map(decodeClip));
    performance.mark('quatmotion-decoded');
    return mount(element, {
      clips, pairs: data.pairs, layout: data.layout, ghost: data.ghost, autoplay: data.autoplay, loop: data.loop,
    });
  }

  /** Standalone page: the document in <script id="quatmotion-data">, shown on #quatmotion-viewer. */
  async function boot() {
    const status = document.getElementById('quatmotion-status');
    try {
      performance.mark('quatmotion-boot');
      const data = JSON.parse(document.getElementById('quatmotion-data').textContent);
      const viewer = await show(document.getElementById('quatmotion-viewer'), data);
      global.quatmotionViewer = viewer;
      if (status) status.remove();
      return viewer;
    } catch (err) {
      if (status) status.textContent = 'Cannot show this file: ' + err.message;
      document.documentElement.dataset.error = err.message;
      throw err;
    }
  }

  global.QuatmotionViewer = { decodeClip, decodeErrors, decodeBlock, mount, show, boot, TEMPLATE, FORMAT };
})(window);
