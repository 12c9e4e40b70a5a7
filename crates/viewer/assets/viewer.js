// The semrecon viewer page: the labelled mesh, the camera trajectory, the class legend and
// the material table; a click throws a ball. Served by `semrecon view` (data from /api/...,
// throws simulated by the server) or exported by `semrecon export-viewer` (data embedded in
// window.SEMRECON_STATIC, precomputed throws replayed). World frame: metres, up from /api/info (z for generated rooms).
//
// Behind `semrecon run --serve` the scene is live: the page polls /api/version and loads
// the mesh and trajectory again when the version changes, keeping the camera where the
// user put it (until the user moves it, each new mesh is framed as a whole).
//
// window.viewerState exposes what the browser test checks (ready, mode, balls in flight).

import * as THREE from 'three';
import { OrbitControls } from 'three/addons/OrbitControls.js';

const STATIC = window.SEMRECON_STATIC || null;
const UNLABELLED = 255;
const CEILING = 0;
const MAX_BALLS = 12;

const state = {
  ready: false,
  error: null,
  static: !!STATIC,
  mode: 'color',
  triangles: 0,
  labelled: false,
  throws: 0,
  frames: 0,
  ball: { active: false, position: null, time: 0 },
  lastThrow: null,
  live: false,
  version: null,
};
window.viewerState = state;

const $ = (id) => document.getElementById(id);

function showError(message) {
  state.error = message;
  const div = document.createElement('div');
  div.className = 'error';
  div.textContent = message;
  $('notes').appendChild(div);
}

function setStatus(text) {
  $('status').textContent = text;
}

// ---------------------------------------------------------------- data

async function fetchJSON(path, options) {
  const response = await fetch(path, options);
  const body = await response.json().catch(() => ({ error: `${path}: not JSON` }));
  if (!response.ok) throw new Error(body.error || `${path}: HTTP ${response.status}`);
  return body;
}

function base64ToBuffer(text) {
  const bin = atob(text);
  const bytes = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
  return bytes.buffer;
}

async function loadData() {
  if (STATIC) {
    return {
      info: STATIC.info,
      materials: STATIC.materials,
      trajectory: STATIC.trajectory,
      scene: base64ToBuffer(STATIC.scene),
    };
  }
  const [info, materials, scene] = await Promise.all([
    fetchJSON('/api/info'),
    fetchJSON('/api/materials'),
    fetch('/api/scene').then((r) => {
      if (!r.ok) throw new Error(`/api/scene: HTTP ${r.status}`);
      return r.arrayBuffer();
    }),
  ]);
  let trajectory = null;
  if (info.has_trajectory) trajectory = await fetchJSON('/api/trajectory');
  return { info, materials, trajectory, scene };
}

// The binary layout of crates/viewer/src/scene_binary.rs (SRM1, little endian).
function decodeMesh(buffer) {
  const view = new DataView(buffer);
  const magic = String.fromCharCode(...new Uint8Array(buffer, 0, 4));
  if (magic !== 'SRM1') throw new Error(`mesh data: bad magic ${magic}`);
  const n = view.getUint32(4, true);
  const t = view.getUint32(8, true);
  const labelled = (view.getUint32(12, true) & 1) === 1;
  const pad4 = (x) => Math.ceil(x / 4) * 4;
  let at = 16;
  const positions = new Float32Array(buffer, at, 3 * n);
  at += 12 * n;
  const colors = new Uint8Array(buffer, at, 3 * n);
  at += pad4(3 * n);
  const labels = new Uint8Array(buffer, at, n);
  at += pad4(n);
  const indices = new Uint32Array(buffer, at, 3 * t);
  return { n, t, labelled, positions, colors, labels, indices };
}

// ---------------------------------------------------------------- scene

THREE.Object3D.DEFAULT_UP.set(0, 0, 1);
const container = $('view');
let renderer;
try {
  renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
} catch (e) {
  showError(`WebGL is not available in this browser: ${e.message}`);
  throw e;
}
renderer.setPixelRatio(Math.min(window.devicePixelRatio, 2));
renderer.setSize(window.innerWidth, window.innerHeight);
renderer.setClearColor(0x1d2026);
container.appendChild(renderer.domElement);

const scene = new THREE.Scene();
const camera = new THREE.PerspectiveCamera(55, window.innerWidth / window.innerHeight, 0.02, 500);
camera.up.set(0, 0, 1);
const controls = new OrbitControls(camera, renderer.domElement);
controls.enableDamping = true;
scene.add(new THREE.HemisphereLight(0xffffff, 0x606070, 1.6));
const headlight = new THREE.DirectionalLight(0xffffff, 1.4);
camera.add(headlight);
headlight.position.set(0.3, 0.5, 0);
scene.add(camera);

let meshObject = null;
let meshData = null;
let colorBuffers = {};
let indexAll = null;
let indexNoCeiling = null;
let palette = [];
let trajectoryLine = null;
const balls = [];
let ballGeometry = null;
const pathMaterial = new THREE.LineBasicMaterial({ color: 0xffffff, transparent: true, opacity: 0.45 });

function srgbToLinear(c) {
  return c < 0.04045 ? c * 0.0773993808 : Math.pow(c * 0.9478672986 + 0.0521327014, 2.4);
}

function buildMesh(mesh, info, keepCamera) {
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.BufferAttribute(mesh.positions, 3));
  indexAll = new THREE.BufferAttribute(mesh.indices, 1);
  geometry.setIndex(indexAll);
  geometry.computeVertexNormals();

  // Colours as linear floats (three.js lights in linear space; the file's colours are sRGB).
  const lut = new Float32Array(256);
  for (let i = 0; i < 256; i++) lut[i] = srgbToLinear(i / 255);
  const vertexColors = new Float32Array(3 * mesh.n);
  for (let i = 0; i < 3 * mesh.n; i++) vertexColors[i] = lut[mesh.colors[i]];
  const classColors = new Float32Array(3 * mesh.n);
  const grey = [160, 160, 160];
  for (let v = 0; v < mesh.n; v++) {
    const entry = palette[mesh.labels[v]];
    const c = entry ? entry.color : grey;
    for (let k = 0; k < 3; k++) classColors[3 * v + k] = lut[c[k]];
  }
  colorBuffers = {
    color: new THREE.BufferAttribute(vertexColors, 3),
    classes: new THREE.BufferAttribute(classColors, 3),
  };
  geometry.setAttribute('color', colorBuffers.color);

  // Triangles without the ceiling, so the room can be seen from above.
  if (mesh.labelled) {
    const kept = [];
    for (let i = 0; i < mesh.indices.length; i += 3) {
      const a = mesh.indices[i], b = mesh.indices[i + 1], c = mesh.indices[i + 2];
      if (!(mesh.labels[a] === CEILING && mesh.labels[b] === CEILING && mesh.labels[c] === CEILING)) {
        kept.push(a, b, c);
      }
    }
    indexNoCeiling = new THREE.BufferAttribute(new Uint32Array(kept), 1);
  }

  // Front faces only by default: reconstructed and generated rooms face their inside, so
  // from outside the near walls disappear and the room is seen like a doll's house.
  const material = new THREE.MeshLambertMaterial({ vertexColors: true, side: THREE.FrontSide });
  meshObject = new THREE.Mesh(geometry, material);
  scene.add(meshObject);
  geometry.computeBoundingSphere();
  geometry.computeBoundingBox();
  if (!keepCamera) frameCamera(geometry.boundingBox);
  buildFloorGrid(geometry.boundingBox, info);
  // Drawn at least 1 % of the room's size: a 4 cm ball is a speck in a whole-room view.
  const diag = geometry.boundingBox.getSize(new THREE.Vector3()).length();
  ballGeometry = new THREE.SphereGeometry(Math.max(info.ball_radius || 0.04, 0.01 * diag), 24, 16);
}

// The scene's up direction (info.up: a reconstruction keeps its dataset's frame, where up is
// rarely +z; generated rooms are z up). The orbit turns about it and throws start above the
// floor along it.
const sceneUp = new THREE.Vector3(0, 0, 1);

function setSceneUp(up) {
  const u = Array.isArray(up) && up.length === 3 ? new THREE.Vector3(...up) : new THREE.Vector3(0, 0, 1);
  if (!(u.lengthSq() > 1e-12)) u.set(0, 0, 1);
  u.normalize();
  if (u.distanceTo(sceneUp) < 1e-6) return;
  sceneUp.copy(u);
  camera.up.copy(u);
  // OrbitControls takes its orbit axis from camera.up when it is made.
  controls._quat.setFromUnitVectors(camera.up, new THREE.Vector3(0, 1, 0));
  controls._quatInverse.copy(controls._quat).invert();
}

// Heights along the scene's up of a box's eight corners: [lowest, highest].
function heightRange(box) {
  let lo = Infinity, hi = -Infinity;
  for (let c = 0; c < 8; c++) {
    const p = new THREE.Vector3(c & 1 ? box.max.x : box.min.x, c & 2 ? box.max.y : box.min.y, c & 4 ? box.max.z : box.min.z);
    const h = p.dot(sceneUp);
    lo = Math.min(lo, h);
    hi = Math.max(hi, h);
  }
  return [lo, hi];
}

// The ground plane the physics puts under the scan's floor (info.floor_height along the
// scene's up, info.floor_plane_drop below it), drawn as a faint grid of 50 cm squares over the
// room's extent, so that a ball bouncing where the scan has a hole bounces on something seen.
let floorGrid = null;

function buildFloorGrid(box, info) {
  if (typeof info.floor_height !== 'number') return;
  const size = box.getSize(new THREE.Vector3()).length();
  const cells = Math.max(2, Math.ceil(size / 0.5));
  floorGrid = new THREE.GridHelper(cells * 0.5, cells, 0x8a8f99, 0x8a8f99);
  floorGrid.material.transparent = true;
  floorGrid.material.opacity = 0.25;
  floorGrid.material.depthWrite = false;
  // GridHelper lies in its local x-z plane (normal +y): turn +y onto the scene's up.
  floorGrid.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), sceneUp);
  const centre = box.getCenter(new THREE.Vector3());
  const height = info.floor_height - (info.floor_plane_drop || 0);
  floorGrid.position.copy(centre).addScaledVector(sceneUp, height - centre.dot(sceneUp));
  scene.add(floorGrid);
}

function frameCamera(box) {
  const centre = box.getCenter(new THREE.Vector3());
  const size = box.getSize(new THREE.Vector3());
  const diag = Math.max(size.length(), 0.1);
  controls.target.copy(centre);
  // Above a corner of the room: back along a horizontal direction, up along the scene's up.
  const side = new THREE.Vector3(-0.55 * size.x - 0.2 * diag, -0.75 * size.y - 0.3 * diag, 0);
  side.addScaledVector(sceneUp, -side.dot(sceneUp));
  const top = heightRange(box)[1];
  camera.position.copy(centre).add(side).addScaledVector(sceneUp, top - centre.dot(sceneUp) + 0.7 * diag);
  camera.near = diag / 500;
  camera.far = diag * 20;
  camera.updateProjectionMatrix();
  controls.update();
}

function setMode(mode) {
  if (!meshObject || !['color', 'classes', 'geometry'].includes(mode)) return;
  state.mode = mode;
  const material = meshObject.material;
  if (mode === 'geometry') {
    material.vertexColors = false;
    material.color.set(0xd8d8d8);
  } else {
    material.vertexColors = true;
    material.color.set(0xffffff);
    meshObject.geometry.setAttribute('color', colorBuffers[mode]);
  }
  material.needsUpdate = true;
  const radio = document.querySelector(`input[name=mode][value=${mode}]`);
  if (radio) radio.checked = true;
}
window.viewerSetMode = setMode;

function setCeiling(visible) {
  if (!meshObject || !indexNoCeiling) return;
  meshObject.geometry.setIndex(visible ? indexAll : indexNoCeiling);
}

function buildTrajectory(trajectory) {
  if (!trajectory || trajectory.positions.length < 1) return;
  const points = trajectory.positions.map((p) => new THREE.Vector3(p[0], p[1], p[2]));
  const group = new THREE.Group();
  const line = new THREE.Line(
    new THREE.BufferGeometry().setFromPoints(points),
    new THREE.LineBasicMaterial({ color: 0xff9f1c }),
  );
  group.add(line);
  // Viewing directions every few poses, short ticks.
  const ticks = [];
  const step = Math.max(1, Math.floor(points.length / 40));
  for (let i = 0; i < points.length; i += step) {
    const f = trajectory.forward[i];
    ticks.push(points[i], points[i].clone().add(new THREE.Vector3(f[0], f[1], f[2]).multiplyScalar(0.15)));
  }
  group.add(new THREE.LineSegments(
    new THREE.BufferGeometry().setFromPoints(ticks),
    new THREE.LineBasicMaterial({ color: 0xffd27f }),
  ));
  const start = new THREE.Mesh(new THREE.SphereGeometry(0.05, 12, 8), new THREE.MeshBasicMaterial({ color: 0xff9f1c }));
  start.position.copy(points[0]);
  group.add(start);
  trajectoryLine = group;
  scene.add(group);
}

// ---------------------------------------------------------------- panel

function swatch(color) {
  const s = document.createElement('span');
  s.className = 'swatch';
  s.style.background = `rgb(${color[0]},${color[1]},${color[2]})`;
  return s;
}

function fillPanel(info, materials, mesh, trajectory) {
  $('notes').innerHTML = '';
  $('legend').innerHTML = '';
  const counts = new Array(256).fill(0);
  for (let v = 0; v < mesh.n; v++) counts[mesh.labels[v]]++;
  const summary = [`${info.mesh}: ${info.triangles.toLocaleString()} triangles`];
  if (info.display_triangles < info.triangles) summary.push(`(${info.display_triangles.toLocaleString()} drawn)`);
  if (trajectory) summary.push(`· ${trajectory.positions.length} poses`);
  if (info.static) summary.push('· static export');
  if (info.live) summary.push(`· live, update ${info.version}`);
  $('summary').textContent = summary.join(' ');
  for (const note of info.notes) {
    const div = document.createElement('div');
    div.className = 'note';
    div.textContent = note;
    $('notes').appendChild(div);
  }

  const legend = $('legend');
  for (const entry of info.palette) {
    const tr = document.createElement('tr');
    if (!counts[entry.id]) tr.className = 'absent';
    const name = document.createElement('td');
    name.appendChild(swatch(entry.color));
    name.appendChild(document.createTextNode(entry.name));
    const share = document.createElement('td');
    share.className = 'num';
    share.textContent = counts[entry.id] ? `${((100 * counts[entry.id]) / mesh.n).toFixed(1)} %` : '';
    tr.append(name, share);
    legend.appendChild(tr);
  }
  if (!info.labelled) {
    const tr = document.createElement('tr');
    tr.innerHTML = '<td colspan="2" class="note">no labels in this mesh</td>';
    legend.prepend(tr);
  }

  const table = $('materials');
  table.innerHTML = '<tr><th>class</th><th class="num">restitution</th><th class="num">friction</th></tr>';
  const row = (color, name, m) => {
    const tr = document.createElement('tr');
    const td = document.createElement('td');
    if (color) td.appendChild(swatch(color));
    td.appendChild(document.createTextNode(name));
    const e = document.createElement('td');
    e.className = 'num';
    e.textContent = m.restitution.toFixed(2);
    const f = document.createElement('td');
    f.className = 'num';
    f.textContent = m.friction.toFixed(2);
    tr.append(td, e, f);
    table.appendChild(tr);
  };
  for (const c of materials.classes) row(c.color, c.name, c);
  row(null, info.labelled ? 'unlabelled' : 'unlabelled (used everywhere)', materials.unlabelled);
}

// ---------------------------------------------------------------- throws

const raycaster = new THREE.Raycaster();

function clickRay(event) {
  const rect = renderer.domElement.getBoundingClientRect();
  const ndc = new THREE.Vector2(
    ((event.clientX - rect.left) / rect.width) * 2 - 1,
    -((event.clientY - rect.top) / rect.height) * 2 + 1,
  );
  raycaster.setFromCamera(ndc, camera);
  const hits = meshObject ? raycaster.intersectObject(meshObject, false) : [];
  return { ray: raycaster.ray.clone(), hit: hits.length ? hits[0].point : null };
}

// The ball starts at the camera when the camera is inside the room; from an outside view it
// starts 1.5 m before the clicked point along the view ray (inside the room), so that it
// does not bounce off the outside of a wall or the ceiling.
function throwStart(ray, hit) {
  const box = meshObject.geometry.boundingBox;
  if (box.containsPoint(camera.position)) {
    return ray.origin.clone().add(ray.direction.clone().multiplyScalar(0.15));
  }
  if (!hit) return null;
  const back = Math.min(1.5, 0.8 * hit.distanceTo(ray.origin));
  const start = hit.clone().sub(ray.direction.clone().multiplyScalar(back));
  const lowest = heightRange(box)[0] + 0.2;
  const h = start.dot(sceneUp);
  if (h < lowest) start.addScaledVector(sceneUp, lowest - h);
  return start;
}

async function onClick(event) {
  if (!state.ready) return;
  const { ray, hit } = clickRay(event);
  if (STATIC) {
    replayNearest(hit);
    return;
  }
  const start = throwStart(ray, hit);
  if (!start) {
    setStatus('click on the mesh to throw a ball');
    return;
  }
  const dir = hit ? hit.clone().sub(start).normalize() : ray.direction.clone();
  const speed = parseFloat($('speed').value);
  setStatus('simulating…');
  try {
    const result = await fetchJSON('/api/throw', {
      method: 'POST',
      headers: { 'Content-Type': 'application/json' },
      body: JSON.stringify({ from: start.toArray(), dir: dir.toArray(), speed }),
    });
    launch(result);
  } catch (e) {
    setStatus(`throw failed: ${e.message}`);
  }
}

function replayNearest(hit) {
  const throws = STATIC.throws || [];
  if (!throws.length) {
    setStatus('this export has no precomputed throws');
    return;
  }
  let best = state.throws % throws.length;
  if (hit) {
    let bestDistance = Infinity;
    throws.forEach((t, i) => {
      const c = t.throw.contacts.length ? t.throw.contacts[0].position : t.throw.positions[t.throw.positions.length - 1];
      const d = hit.distanceTo(new THREE.Vector3(c[0], c[1], c[2]));
      if (d < bestDistance) {
        bestDistance = d;
        best = i;
      }
    });
  }
  launch(throws[best].throw, `precomputed throw ${best + 1}/${throws.length} (static page: nearest to the click)`);
}

function launch(t, label) {
  if (!t.positions || t.positions.length < 2) {
    setStatus('the throw has no trajectory');
    return;
  }
  const mesh = new THREE.Mesh(ballGeometry, new THREE.MeshLambertMaterial({ color: 0xffe14d, emissive: 0x886600 }));
  const path = new THREE.Line(
    new THREE.BufferGeometry().setFromPoints(t.positions.map((p) => new THREE.Vector3(p[0], p[1], p[2]))),
    pathMaterial,
  );
  path.visible = false;
  scene.add(mesh, path);
  const ball = { mesh, path, throw: t, start: performance.now() };
  balls.push(ball);
  while (balls.length > MAX_BALLS) {
    const old = balls.shift();
    scene.remove(old.mesh, old.path);
  }
  state.throws += 1;
  state.lastThrow = { samples: t.positions.length, contacts: t.contacts.length, duration: t.times[t.times.length - 1] };
  setStatus(label || `throw ${state.throws}: ${t.contacts.length} contacts`);
  showBounces(t);
  updateBall(ball, performance.now());
}

function showBounces(t) {
  const div = $('bounces');
  div.innerHTML = '';
  const colorOf = Object.fromEntries(palette.filter(Boolean).map((p) => [p.name, p.color]));
  for (const c of t.contacts.slice(0, 8)) {
    const line = document.createElement('div');
    line.appendChild(swatch(colorOf[c.class] || [160, 160, 160]));
    line.appendChild(document.createTextNode(`${c.time.toFixed(2)} s  ${c.class}  e=${c.restitution.toFixed(2)}`));
    div.appendChild(line);
  }
  if (t.contacts.length > 8) div.appendChild(document.createTextNode(`… ${t.contacts.length - 8} more`));
  for (const w of t.warnings || []) {
    const line = document.createElement('div');
    line.className = 'note';
    line.textContent = w;
    div.appendChild(line);
  }
}

// Position at the elapsed time, linear between samples.
function updateBall(ball, now) {
  const t = ball.throw;
  const elapsed = (now - ball.start) / 1000 + t.times[0];
  const last = t.times.length - 1;
  let i = 0;
  let lo = 0, hi = last;
  if (elapsed >= t.times[last]) {
    i = last;
  } else {
    while (hi - lo > 1) {
      const mid = (lo + hi) >> 1;
      if (t.times[mid] <= elapsed) lo = mid; else hi = mid;
    }
    i = lo;
  }
  const p = t.positions[i];
  let pos = new THREE.Vector3(p[0], p[1], p[2]);
  if (i < last) {
    const q = t.positions[i + 1];
    const span = t.times[i + 1] - t.times[i];
    const f = span > 0 ? Math.min(1, Math.max(0, (elapsed - t.times[i]) / span)) : 0;
    pos.lerp(new THREE.Vector3(q[0], q[1], q[2]), f);
  }
  ball.mesh.position.copy(pos);
  ball.path.visible = true;
  ball.active = i < last;
  if (ball === balls[balls.length - 1]) {
    state.ball = { active: ball.active, position: pos.toArray(), time: elapsed };
  }
}

// ---------------------------------------------------------------- interaction

let down = null;
renderer.domElement.addEventListener('pointerdown', (e) => {
  down = { x: e.clientX, y: e.clientY, t: performance.now(), button: e.button };
});
renderer.domElement.addEventListener('pointerup', (e) => {
  // A click, not the end of an orbit drag.
  if (down && down.button === 0 && Math.hypot(e.clientX - down.x, e.clientY - down.y) < 5 && performance.now() - down.t < 600) {
    onClick(e);
  }
  down = null;
});
document.querySelectorAll('input[name=mode]').forEach((r) => r.addEventListener('change', () => setMode(r.value)));
$('show-trajectory').addEventListener('change', (e) => {
  if (trajectoryLine) trajectoryLine.visible = e.target.checked;
});
$('show-ceiling').addEventListener('change', (e) => setCeiling(e.target.checked));
$('cull').addEventListener('change', (e) => {
  if (!meshObject) return;
  meshObject.material.side = e.target.checked ? THREE.FrontSide : THREE.DoubleSide;
  meshObject.material.needsUpdate = true;
});
$('speed').addEventListener('input', (e) => {
  $('speed-value').textContent = e.target.value;
});
window.addEventListener('keydown', (e) => {
  const mode = { 1: 'color', 2: 'classes', 3: 'geometry' }[e.key];
  if (mode) setMode(mode);
});
window.addEventListener('resize', () => {
  camera.aspect = window.innerWidth / window.innerHeight;
  camera.updateProjectionMatrix();
  renderer.setSize(window.innerWidth, window.innerHeight);
});

function animate() {
  requestAnimationFrame(animate);
  controls.update();
  const now = performance.now();
  for (const b of balls) updateBall(b, now);
  renderer.render(scene, camera);
  state.frames += 1;
}

// Colour statistics of the last frame, for the browser test: the share of drawn pixels
// (not background) and, per class, the share of pixels whose chromaticity matches the
// class colour (lighting scales a colour but keeps its chromaticity).
window.viewerPixelStats = () => {
  renderer.render(scene, camera);
  const gl = renderer.getContext();
  const w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
  const px = new Uint8Array(4 * w * h);
  gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
  const bg = [0x1d, 0x20, 0x26];
  let drawn = 0;
  const perClass = {};
  const chroma = (r, g, b) => { const s = r + g + b + 1e-6; return [r / s, g / s]; };
  const classes = palette.filter(Boolean).map((p) => ({ name: p.name, c: chroma(...p.color), grey: Math.max(...p.color) - Math.min(...p.color) < 30 }));
  for (let i = 0; i < px.length; i += 4) {
    const r = px[i], g = px[i + 1], b = px[i + 2];
    if (Math.abs(r - bg[0]) + Math.abs(g - bg[1]) + Math.abs(b - bg[2]) < 6) continue;
    drawn++;
    const c = chroma(r, g, b);
    for (const k of classes) {
      if (k.grey) continue;
      if (Math.abs(c[0] - k.c[0]) < 0.02 && Math.abs(c[1] - k.c[1]) < 0.02 && r + g + b > 60) {
        perClass[k.name] = (perClass[k.name] || 0) + 1;
      }
    }
  }
  const total = w * h;
  for (const k of Object.keys(perClass)) perClass[k] /= total;
  return { width: w, height: h, drawn: drawn / total, classes: perClass };
};

// ---------------------------------------------------------------- live updates

const POLL_MS = 1500;
let userMovedCamera = false;
controls.addEventListener('start', () => { userMovedCamera = true; });

function clearScene() {
  if (meshObject) {
    scene.remove(meshObject);
    meshObject.geometry.dispose();
    meshObject.material.dispose();
    meshObject = null;
  }
  if (trajectoryLine) {
    scene.remove(trajectoryLine);
    trajectoryLine.traverse((o) => { if (o.geometry) o.geometry.dispose(); });
    trajectoryLine = null;
  }
  if (floorGrid) {
    scene.remove(floorGrid);
    floorGrid.geometry.dispose();
    floorGrid.material.dispose();
    floorGrid = null;
  }
  indexNoCeiling = null;
}

// Shows loaded data; a later call (live update) replaces the scene but keeps the view
// settings (mode, ceiling) and, once the user has moved it, the camera.
function showScene(data) {
  const first = meshObject === null;
  setSceneUp(data.info.up);
  palette = [];
  for (const p of data.info.palette) palette[p.id] = p;
  const mesh = decodeMesh(data.scene);
  clearScene();
  meshData = mesh;
  state.triangles = meshData.t;
  state.labelled = meshData.labelled;
  buildMesh(meshData, data.info, userMovedCamera);
  buildTrajectory(data.trajectory);
  fillPanel(data.info, data.materials, meshData, data.trajectory);
  $('show-ceiling').disabled = !meshData.labelled;
  document.querySelector('input[name=mode][value=classes]').parentElement.title =
    meshData.labelled ? '' : 'this mesh has no labels';
  if (first && meshData.labelled) {
    // Seen from above (the initial view) the ceiling hides the room.
    $('show-ceiling').checked = false;
  }
  if (meshData.labelled) setCeiling($('show-ceiling').checked);
  setMode(state.mode === 'classes' && !meshData.labelled ? 'color' : state.mode);
}

// The server's {version, live, ready}; a server without the route is a fixed scene.
async function fetchVersion() {
  if (STATIC) return { version: 0, live: false, ready: true };
  try {
    return await fetchJSON('/api/version');
  } catch (e) {
    return { version: 0, live: false, ready: true };
  }
}

async function pollLive() {
  try {
    const v = await fetchJSON('/api/version');
    if (v.ready && v.version !== state.version) {
      // The version read before loading: the data is at least this new, so a newer
      // update that lands during the load is caught by the next poll.
      const data = await loadData();
      showScene(data);
      state.version = v.version;
      state.ready = true;
      setStatus('live: click the room to throw a ball');
    } else if (!v.ready) {
      setStatus('live: waiting for the first mesh…');
    }
  } catch (e) {
    setStatus(`live: no answer from the server (${e.message})`);
  }
  setTimeout(pollLive, POLL_MS);
}

async function main() {
  try {
    const v = await fetchVersion();
    state.live = !!v.live;
    if (state.live) {
      $('summary').textContent = 'live reconstruction';
      pollLive();
    } else {
      const data = await loadData();
      showScene(data);
      state.version = v.version;
      setStatus(STATIC ? 'click the room to replay a precomputed throw' : 'click the room to throw a ball');
      state.ready = true;
    }
  } catch (e) {
    showError(`cannot load the scene: ${e.message}`);
    $('summary').textContent = '';
  }
  animate();
}

main();
