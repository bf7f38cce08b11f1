// robot-server live web view: 3D robot (three.js), joint plots (uPlot), status, traffic, fault buttons.
// One WebSocket, `ws` beside the page (/ws, or /c/NAME/ws in a fleet); docs/web.md describes its messages.
// Every address is relative, so that the page works wherever it is served.

import * as THREE from 'three';
import { OrbitControls } from './vendor/three/OrbitControls.js';

const uPlot = window.uPlot;

// ---------------------------------------------------------------------------------------------
// state exposed for tests

const webview = {
  connected: false,
  hello: null,
  // whether this page may send commands (the hello says; false until it does)
  commands: false,
  samples: 0,
  lastTime: null,
  plots: [],
  traffic: 0,
  renders: 0,
  waypoints: 0,
  // the tool frame of group g drawn at the newest sample's actual position: {q, pose (16 numbers,
  // row-major)}, for tests to check the 3D chain against the controller's kinematics
  toolPose: (g = 0) => {
    const robot = view.robots[g];
    const sg = data.latest && data.latest.groups ? data.latest.groups[g] : null;
    if (!robot || !sg) return null;
    setChain(robot.actual, sg.ap);
    robot.actual.root.updateMatrixWorld(true);
    return { q: sg.ap, pose: robot.actual.tool.matrixWorld.clone().transpose().toArray() };
  },
};
window.webview = webview;

const MAX_TRAFFIC_ROWS = 200;
const TRAFFIC_BUFFER = 2000;
const JOINT_COLORS = [
  '#4e9af1', '#f28e2b', '#59c15f', '#e15759', '#b07ad1', '#edc948',
  '#76d7d2', '#ff9da7', '#c0956f', '#a0a0ff', '#9be36b', '#f0f0f0',
];
const SIGNALS = ['cp', 'cv', 'ca', 'ap', 'av', 'aa', 'fe'];

const $ = (sel) => document.querySelector(sel);

function jointColor(index) {
  return JOINT_COLORS[index % JOINT_COLORS.length];
}

// ---------------------------------------------------------------------------------------------
// data model: samples of the last window, as columns

const data = {
  window: 10,
  t: [],
  // cols[g][j] = {cp: [], cv: [], ...}
  cols: [],
  waypoints: [],
  latest: null,
  dirty: false,
};

let hello = null;
let jointIndex = []; // flat list of {g, j, index, label, name, type}
let selected = new Set(); // keys "g:j"

function resetData(h) {
  data.window = Number(h && h.emulator && h.emulator.window) > 0 ? Number(h.emulator.window) : 10;
  data.t = [];
  data.cols = (h.groups || []).map((g) => (g.joints || []).map(() => {
    const c = {};
    for (const s of SIGNALS) c[s] = [];
    return c;
  }));
  data.waypoints = [];
  data.latest = null;
  data.dirty = true;
  webview.lastTime = null;
}

function num(v) {
  return typeof v === 'number' && Number.isFinite(v) ? v : null;
}

function addSample(sample) {
  if (!sample || typeof sample.t !== 'number') return;
  const n = data.t.length;
  if (n > 0 && sample.t < data.t[n - 1]) return; // the controller time is monotonic
  webview.samples += 1;
  webview.lastTime = sample.t;
  data.latest = sample;
  data.t.push(sample.t);
  const groups = sample.groups || [];
  for (let g = 0; g < data.cols.length; g++) {
    const sg = groups[g] || {};
    const gcols = data.cols[g];
    for (let j = 0; j < gcols.length; j++) {
      const c = gcols[j];
      for (const s of SIGNALS) {
        const arr = sg[s];
        c[s].push(arr ? num(arr[j]) : null);
      }
    }
  }
  trimData();
  data.dirty = true;
}

function trimData() {
  const n = data.t.length;
  if (n === 0) return;
  const start = data.t[n - 1] - data.window;
  let i = 0;
  while (i < n - 1 && data.t[i] < start) i++;
  if (i > 0) {
    data.t.splice(0, i);
    for (const gcols of data.cols) {
      for (const c of gcols) {
        for (const s of SIGNALS) c[s].splice(0, i);
      }
    }
  }
  let k = 0;
  while (k < data.waypoints.length && data.waypoints[k].t < start) k++;
  if (k > 0) data.waypoints.splice(0, k);
}

function addWaypoints(list) {
  if (!Array.isArray(list) || list.length === 0) return;
  for (const w of list) {
    if (w && typeof w.t === 'number' && Array.isArray(w.p)) {
      data.waypoints.push(w);
      webview.waypoints += 1;
    }
  }
  data.waypoints.sort((a, b) => a.t - b.t);
  trimData();
  data.dirty = true;
}

// ---------------------------------------------------------------------------------------------
// 3D view

const view = {
  ok: false,
  container: null,
  renderer: null,
  scene: null,
  camera: null,
  controls: null,
  world: null, // everything built from a hello
  robots: [], // per group: {actual: chain, ghost: chain}
  width: 0,
  height: 0,
  signature: null,
};

function initView() {
  const container = $('#robot3d');
  view.container = container;
  let renderer;
  try {
    renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  } catch (err) {
    const msg = document.createElement('div');
    msg.className = 'overlay no-webgl';
    msg.textContent = 'WebGL is not available: no 3D view';
    container.appendChild(msg);
    return;
  }
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  renderer.setClearColor(0x15191e, 1);
  container.insertBefore(renderer.domElement, container.firstChild);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0x15191e);
  const camera = new THREE.PerspectiveCamera(45, 1, 0.01, 100);
  camera.up.set(0, 0, 1);
  camera.position.set(1.5, -2, 1.2);
  const controls = new OrbitControls(camera, renderer.domElement);
  controls.target.set(0, 0, 0.3);
  controls.update();

  scene.add(new THREE.AmbientLight(0xffffff, 0.9));
  const sun = new THREE.DirectionalLight(0xffffff, 2.2);
  sun.position.set(2, -3, 5);
  scene.add(sun);
  const fill = new THREE.DirectionalLight(0xbfd4ff, 0.8);
  fill.position.set(-3, 2, 1);
  scene.add(fill);

  Object.assign(view, { ok: true, renderer, scene, camera, controls });
}

function matrixFrom(values) {
  const m = new THREE.Matrix4();
  if (Array.isArray(values) && values.length === 16) m.set(...values.map(Number));
  return m;
}

function fixedNode(values, name) {
  const o = new THREE.Object3D();
  o.name = name || '';
  o.matrixAutoUpdate = false;
  o.matrix.copy(matrixFrom(values));
  o.matrixWorldNeedsUpdate = true;
  return o;
}

function translationOf(values) {
  if (!Array.isArray(values) || values.length !== 16) return new THREE.Vector3();
  return new THREE.Vector3(Number(values[3]), Number(values[7]), Number(values[11]));
}

const Y_UP = new THREE.Vector3(0, 1, 0);

// a cylinder from a to b (in the parent's frame); null if shorter than 1 mm
function linkMesh(a, b, radius, material, geometry) {
  const d = new THREE.Vector3().subVectors(b, a);
  const len = d.length();
  if (len < 1e-3) return null;
  const mesh = new THREE.Mesh(geometry, material);
  mesh.position.copy(a).addScaledVector(d, 0.5);
  mesh.quaternion.setFromUnitVectors(Y_UP, d.clone().normalize());
  mesh.scale.set(radius, len, radius);
  return mesh;
}

function materials(ghost, color) {
  if (ghost) {
    return new THREE.MeshLambertMaterial({
      color: color || 0xa8c8ff, transparent: true, opacity: 0.22, depthWrite: false,
    });
  }
  return new THREE.MeshLambertMaterial({ color: color || 0x9aa0a6 });
}

// Builds one group's chain. Returns {root, motions: [{node, type, axis, offset}], length}.
function buildChain(group, gIndex, jointBase, ghost, radius, geoms) {
  const root = fixedNode(group.base, `g${gIndex} base`);
  const linkMat = materials(ghost);
  const motions = [];
  let length = 0;
  const joints = group.joints || [];

  if (!ghost) {
    const plate = new THREE.Mesh(geoms.cyl, materials(false, 0x3a4048));
    plate.scale.set(radius * 3, radius * 0.8, radius * 3);
    plate.quaternion.setFromUnitVectors(Y_UP, new THREE.Vector3(0, 0, 1));
    plate.position.set(0, 0, -radius * 0.4);
    root.add(plate);
  }

  let parent = root;
  for (let j = 0; j < joints.length; j++) {
    const joint = joints[j];
    const color = jointColor(jointBase + j);
    const pre = fixedNode(joint.pre, `g${gIndex} j${j + 1} pre`);
    parent.add(pre);
    if (j === 0) {
      // from the base to the first joint (a URDF's first origin; D-H puts it in post instead)
      const preT = translationOf(joint.pre);
      const l0 = linkMesh(new THREE.Vector3(), preT, radius, linkMat, geoms.cyl);
      if (l0) { root.add(l0); length += preT.length(); }
    }
    const axis = new THREE.Vector3(...(joint.axis || [0, 0, 1]).map(Number));
    if (axis.lengthSq() < 1e-12) axis.set(0, 0, 1);
    axis.normalize();
    const prismatic = joint.type === 'prismatic';

    // the joint marker at the pre node, aligned with the axis
    const jointMat = ghost ? materials(true, color) : materials(false, color);
    let marker;
    if (prismatic) {
      marker = new THREE.Mesh(geoms.box, jointMat);
      marker.scale.set(radius * 2.6, radius * 3.2, radius * 2.6);
    } else {
      marker = new THREE.Mesh(geoms.cyl, jointMat);
      marker.scale.set(radius * 1.7, radius * 3.6, radius * 1.7);
    }
    marker.quaternion.setFromUnitVectors(Y_UP, axis);
    pre.add(marker);
    if (!ghost) {
      const arrowLen = radius * 6;
      const arrow = new THREE.ArrowHelper(axis, axis.clone().multiplyScalar(-radius * 2.5), arrowLen,
        new THREE.Color(color), radius * 1.2, radius * 0.7);
      pre.add(arrow);
    }

    const motion = new THREE.Object3D();
    motion.name = `g${gIndex} j${j + 1} motion`;
    pre.add(motion);
    // a prismatic joint's extension: a rod from the pre node to the motion node, sized each frame
    let rod = null;
    if (prismatic) {
      rod = new THREE.Mesh(geoms.cyl, linkMat);
      rod.quaternion.setFromUnitVectors(Y_UP, axis);
      rod.scale.set(radius * 0.7, 1, radius * 0.7);
      rod.visible = false;
      pre.add(rod);
    }
    motions.push({ node: motion, type: prismatic ? 'prismatic' : 'revolute', axis, offset: Number(joint.offset) || 0, rod });

    const origin = new THREE.Vector3();
    const postT = translationOf(joint.post);
    const l1 = linkMesh(origin, postT, radius, linkMat, geoms.cyl);
    if (l1) { motion.add(l1); length += postT.length(); }

    const post = fixedNode(joint.post, `g${gIndex} j${j + 1} post`);
    motion.add(post);
    const nextT = j + 1 < joints.length ? translationOf(joints[j + 1].pre) : translationOf(group.tool);
    const l2 = linkMesh(origin, nextT, radius, linkMat, geoms.cyl);
    if (l2) { post.add(l2); length += nextT.length(); }
    parent = post;
  }
  const tool = fixedNode(group.tool, `g${gIndex} tool`);
  parent.add(tool);
  if (!ghost) {
    const axes = new THREE.AxesHelper(0.1);
    tool.add(axes);
    const flange = new THREE.Mesh(geoms.cyl, materials(false, 0x6b7280));
    flange.scale.set(radius * 1.1, radius * 0.5, radius * 1.1);
    flange.quaternion.setFromUnitVectors(Y_UP, new THREE.Vector3(0, 0, 1));
    flange.position.set(0, 0, -radius * 0.25);
    tool.add(flange);
  }
  if (ghost) root.traverse((o) => { o.renderOrder = 1; });
  return { root, motions, length, tool };
}

function setChain(chain, positions) {
  if (!chain || !Array.isArray(positions)) return;
  const m = chain.motions;
  for (let j = 0; j < m.length; j++) {
    const q = positions[j];
    if (typeof q !== 'number' || !Number.isFinite(q)) continue;
    const v = q + m[j].offset;
    if (m[j].type === 'prismatic') {
      m[j].node.position.copy(m[j].axis).multiplyScalar(v);
      const rod = m[j].rod;
      rod.visible = Math.abs(v) >= 1e-3;
      rod.position.copy(m[j].axis).multiplyScalar(v / 2);
      rod.scale.y = Math.abs(v) || 1;
    } else {
      m[j].node.quaternion.setFromAxisAngle(m[j].axis, v);
    }
  }
}

function zoneObjects(zones, gridSize, center) {
  const out = [];
  if (!zones) return out;
  const boxOf = (z) => {
    const lo = new THREE.Vector3(...z.lower.map(Number));
    const hi = new THREE.Vector3(...z.upper.map(Number));
    const size = new THREE.Vector3().subVectors(hi, lo);
    const mid = new THREE.Vector3().addVectors(lo, hi).multiplyScalar(0.5);
    return { size, mid };
  };
  const valid = (z) => z && Array.isArray(z.lower) && Array.isArray(z.upper) && z.lower.length === 3 && z.upper.length === 3;
  if (valid(zones.allowed)) {
    const { size, mid } = boxOf(zones.allowed);
    const geo = new THREE.EdgesGeometry(new THREE.BoxGeometry(size.x, size.y, size.z));
    const lines = new THREE.LineSegments(geo, new THREE.LineBasicMaterial({ color: 0x3ddc84, transparent: true, opacity: 0.85 }));
    lines.position.copy(mid);
    lines.name = `allowed ${zones.allowed.name || ''}`;
    out.push(lines);
  }
  for (const f of zones.forbidden || []) {
    if (!valid(f)) continue;
    const { size, mid } = boxOf(f);
    const box = new THREE.Mesh(new THREE.BoxGeometry(size.x, size.y, size.z),
      new THREE.MeshLambertMaterial({ color: 0xe5484d, transparent: true, opacity: 0.28, depthWrite: false }));
    box.position.copy(mid);
    box.renderOrder = 2;
    box.name = `forbidden ${f.name || ''}`;
    out.push(box);
    const edges = new THREE.LineSegments(new THREE.EdgesGeometry(new THREE.BoxGeometry(size.x, size.y, size.z)),
      new THREE.LineBasicMaterial({ color: 0xff6b6b }));
    edges.position.copy(mid);
    out.push(edges);
  }
  if (typeof zones.floor === 'number' && Number.isFinite(zones.floor)) {
    const plane = new THREE.Mesh(new THREE.PlaneGeometry(gridSize, gridSize),
      new THREE.MeshBasicMaterial({
        color: 0x8fb3d9, transparent: true, opacity: 0.12, depthWrite: false, side: THREE.DoubleSide,
        polygonOffset: true, polygonOffsetFactor: 1, polygonOffsetUnits: 1,
      }));
    plane.position.set(center.x, center.y, zones.floor);
    plane.renderOrder = 3;
    plane.name = 'floor';
    out.push(plane);
  }
  return out;
}

function disposeObject(root) {
  root.traverse((o) => {
    if (o.geometry) o.geometry.dispose();
    if (o.material) {
      if (Array.isArray(o.material)) o.material.forEach((m) => m.dispose());
      else o.material.dispose();
    }
  });
}

function buildWorld(h) {
  if (!view.ok) return;
  if (view.world) {
    view.scene.remove(view.world);
    disposeObject(view.world);
  }
  const world = new THREE.Group();
  world.name = 'world';
  view.robots = [];
  const groups = h.groups || [];

  // the scale: the sum of link lengths (largest group), from the translations of the fixed parts
  let scale = 0;
  for (const g of groups) {
    let s = 0;
    for (const j of g.joints || []) s += translationOf(j.pre).length() + translationOf(j.post).length();
    s += translationOf(g.tool).length();
    scale = Math.max(scale, s);
  }
  if (!(scale > 0.05)) scale = 1;
  const radius = 0.03 * Math.min(2, Math.max(0.5, scale));
  const geoms = {
    cyl: new THREE.CylinderGeometry(1, 1, 1, 20),
    box: new THREE.BoxGeometry(1, 1, 1),
  };

  let jointBase = 0;
  groups.forEach((g, gi) => {
    const actual = buildChain(g, gi, jointBase, false, radius, geoms);
    const ghost = buildChain(g, gi, jointBase, true, radius, geoms);
    world.add(actual.root);
    world.add(ghost.root);
    view.robots.push({ actual, ghost });
    jointBase += (g.joints || []).length;
  });

  // the robots' extent at load (q = 0), for the grid and the camera
  world.updateMatrixWorld(true);
  const bbox = new THREE.Box3();
  for (const r of view.robots) bbox.expandByObject(r.actual.root);
  const center = bbox.isEmpty() ? new THREE.Vector3(0, 0, 0) : bbox.getCenter(new THREE.Vector3());
  const reach = Math.max(Math.abs(bbox.min.x), Math.abs(bbox.max.x), Math.abs(bbox.min.y), Math.abs(bbox.max.y), 0);
  const gridSize = Math.max(2, Math.ceil(2 * (reach + scale) * 2) / 2);
  const step = scale > 3 ? 0.5 : 0.1;
  const grid = new THREE.GridHelper(gridSize, Math.round(gridSize / step), 0x4a5563, 0x2a313a);
  grid.rotation.x = Math.PI / 2;
  grid.name = 'grid';
  world.add(grid);
  const axes = new THREE.AxesHelper(Math.min(0.25, gridSize / 8));
  axes.name = 'world axes';
  world.add(axes);

  for (const g of groups) {
    for (const o of zoneObjects(g.zones, gridSize, new THREE.Vector3())) world.add(o);
  }

  view.scene.add(world);
  view.world = world;

  // fit the camera (only when the model changes, so that a reconnect keeps the user's view)
  const signature = JSON.stringify(groups.map((g) => [g.base, g.tool, (g.joints || []).map((j) => [j.pre, j.post, j.axis])]));
  if (signature !== view.signature) {
    view.signature = signature;
    const dir = new THREE.Vector3(1.2, -1.7, 0.85).normalize();
    // far enough for the sum of link lengths, and for all groups' bases when there are several
    const sphere = bbox.isEmpty() ? 0 : bbox.getSize(new THREE.Vector3()).length() / 2;
    const fov = THREE.MathUtils.degToRad(view.camera.fov);
    const dist = Math.max(1.4 * scale, (1.15 * sphere) / Math.sin(fov / 2));
    view.controls.target.copy(center);
    view.camera.position.copy(center).addScaledVector(dir, dist);
    view.camera.near = scale / 200;
    view.camera.far = scale * 200;
    view.camera.updateProjectionMatrix();
    view.controls.maxDistance = scale * 50;
    view.controls.update();
  }
  const info = $('#view-info');
  if (info) info.textContent = groups.map((g) => `${g.name} (${(g.joints || []).length} joints)`).join(', ');
}

function poseRobots() {
  const s = data.latest;
  if (!s || !Array.isArray(s.groups)) return;
  view.robots.forEach((r, g) => {
    const sg = s.groups[g];
    if (!sg) return;
    setChain(r.actual, sg.ap);
    setChain(r.ghost, sg.cp);
  });
}

function resizeView() {
  const c = view.container;
  const w = c.clientWidth;
  const h = c.clientHeight;
  if (w === view.width && h === view.height) return;
  view.width = w;
  view.height = h;
  if (w === 0 || h === 0) return;
  view.renderer.setSize(w, h);
  view.camera.aspect = w / h;
  view.camera.updateProjectionMatrix();
}

// ---------------------------------------------------------------------------------------------
// plots

// floor: the smallest y span shown (a signal at rest is drawn as a flat line in the middle)
const PLOTS = [
  { key: 'position', label: 'position (rad)', short: 'pos. (rad)', cmd: 'cp', act: 'ap', waypoints: true, floor: 0.1 },
  { key: 'velocity', label: 'velocity (rad/s)', short: 'vel. (rad/s)', cmd: 'cv', act: 'av', floor: 0.1 },
  { key: 'acceleration', label: 'acceleration (rad/s²)', short: 'acc. (rad/s²)', cmd: 'ca', act: 'aa', floor: 0.5 },
  { key: 'error', label: 'following error (rad)', short: 'error (rad)', act: 'fe', floor: 0.002 },
];
const LABEL_FONT = '11px system-ui, sans-serif';
const X_AXIS = 20; // px, the x axis of the upper plots
const X_AXIS_LAST = 36; // px, the bottom plot's (with its label)

const plotState = { cells: [], sizes: [], short: [] };

function plotLabel(def, short) {
  const text = short ? def.short : def.label;
  const anyPrismatic = jointIndex.some((ji) => selected.has(ji.key) && ji.type === 'prismatic');
  const anyRevolute = jointIndex.some((ji) => selected.has(ji.key) && ji.type !== 'prismatic');
  if (!anyPrismatic) return text;
  return text.replace('(rad', anyRevolute ? '(rad | m' : '(m');
}

let measureCtx = null;

// whether the full y label does not fit along the plotting area of a plot this high
function needsShortLabel(def, height) {
  if (!measureCtx) measureCtx = document.createElement('canvas').getContext('2d');
  measureCtx.font = LABEL_FONT;
  const xAxis = def === PLOTS[PLOTS.length - 1] ? X_AXIS_LAST : X_AXIS;
  return measureCtx.measureText(plotLabel(def, false)).width + 6 > height - xAxis - 4;
}

function yRange(floor) {
  return (u, min, max) => {
    if (min == null || max == null || !Number.isFinite(min) || !Number.isFinite(max)) return [-floor, floor];
    if (max - min < floor) {
      const mid = (min + max) / 2;
      min = mid - floor / 2;
      max = mid + floor / 2;
    }
    return uPlot.rangeNum(min, max, 0.1, true);
  };
}

function selectedJoints() {
  return jointIndex.filter((ji) => selected.has(ji.key));
}

function drawWaypoints(u) {
  const wps = data.waypoints;
  if (!wps.length) return;
  const joints = selectedJoints();
  if (!joints.length) return;
  const { ctx, bbox } = u;
  const pr = window.devicePixelRatio || 1;
  const r = 3.2 * pr;
  ctx.save();
  ctx.beginPath();
  ctx.rect(bbox.left, bbox.top, bbox.width, bbox.height);
  ctx.clip();
  ctx.lineWidth = 1.5 * pr;
  for (const ji of joints) {
    ctx.strokeStyle = ji.color;
    ctx.fillStyle = '#15191e';
    for (const w of wps) {
      if (w.g !== ji.g) continue;
      const p = w.p[ji.j];
      if (typeof p !== 'number' || !Number.isFinite(p)) continue;
      const x = u.valToPos(w.t, 'x', true);
      const y = u.valToPos(p, 'y', true);
      if (!Number.isFinite(x) || !Number.isFinite(y)) continue;
      ctx.beginPath();
      ctx.arc(x, y, r, 0, 2 * Math.PI);
      ctx.fill();
      ctx.stroke();
    }
  }
  ctx.restore();
}

function plotData(def) {
  const out = [data.t];
  for (const ji of selectedJoints()) {
    const c = data.cols[ji.g] && data.cols[ji.g][ji.j];
    if (!c) continue;
    if (def.cmd) out.push(c[def.cmd]);
    out.push(c[def.act]);
  }
  return out;
}

function xRange() {
  const n = data.t.length;
  const hi = n ? data.t[n - 1] : data.window;
  return [hi - data.window, hi];
}

function buildPlots() {
  for (const u of webview.plots) u.destroy();
  webview.plots.length = 0;
  if (!uPlot) return;
  const cells = Array.from(document.querySelectorAll('#plot-stack .plot-cell'));
  plotState.cells = cells;
  plotState.sizes = cells.map(() => [0, 0]);
  const axisStyle = {
    stroke: '#aab4c0',
    font: LABEL_FONT,
    labelFont: LABEL_FONT,
    grid: { stroke: '#2b323b', width: 1 },
    ticks: { stroke: '#3a434e', width: 1, size: 4 },
  };
  PLOTS.forEach((def, i) => {
    const cell = cells[i];
    if (!cell) return;
    cell.replaceChildren();
    const series = [{ label: 't' }];
    for (const ji of selectedJoints()) {
      if (def.cmd) {
        series.push({ label: `${ji.label} cmd`, stroke: ji.color, width: 1.2, dash: [5, 4], points: { show: false } });
      }
      series.push({ label: def.cmd ? `${ji.label} act` : ji.label, stroke: ji.color, width: 1.6, points: { show: false } });
    }
    const w = Math.max(cell.clientWidth, 100);
    const h = Math.max(cell.clientHeight, 60);
    const last = i === PLOTS.length - 1;
    const short = needsShortLabel(def, h);
    plotState.short[i] = short;
    const opts = {
      width: w,
      height: h,
      pxAlign: 0,
      legend: { show: false },
      cursor: { sync: { key: 'joints' }, drag: { x: false, y: false }, points: { show: false } },
      scales: { x: { time: false, range: () => xRange() }, y: { auto: true, range: yRange(def.floor) } },
      axes: [
        { ...axisStyle, size: last ? X_AXIS_LAST : X_AXIS, label: last ? 'controller time (s)' : undefined, labelSize: last ? 14 : 0, labelGap: 0 },
        { ...axisStyle, size: 52, space: 18, label: plotLabel(def, short), labelSize: 16, labelGap: 0, values: (u, vals) => vals.map(fmtTick) },
      ],
      series,
      hooks: def.waypoints ? { draw: [drawWaypoints] } : {},
    };
    const u = new uPlot(opts, plotData(def), cell);
    plotState.sizes[i] = [w, h];
    webview.plots.push(u);
  });
  data.dirty = false;
}

function fmtTick(v) {
  if (v == null) return '';
  const a = Math.abs(v);
  if (a === 0) return '0';
  if (a >= 1000 || a < 0.001) return v.toExponential(0);
  return String(Number(v.toPrecision(4)));
}

function updatePlots() {
  const plots = webview.plots;
  for (let i = 0; i < plots.length; i++) {
    const cell = plotState.cells[i];
    const w = cell.clientWidth;
    const h = cell.clientHeight;
    const [pw, ph] = plotState.sizes[i];
    if ((w !== pw || h !== ph) && w > 0 && h > 0) {
      if (needsShortLabel(PLOTS[i], h) !== plotState.short[i]) {
        buildPlots(); // the y label changes: make the plots again, at the new size
        return;
      }
      plotState.sizes[i] = [w, h];
      plots[i].setSize({ width: w, height: h });
    }
  }
  if (!data.dirty) return;
  data.dirty = false;
  PLOTS.forEach((def, i) => {
    if (plots[i]) plots[i].setData(plotData(def));
  });
}

function buildJointSelect(h) {
  const box = $('#joint-select');
  box.replaceChildren();
  jointIndex = [];
  const groups = h.groups || [];
  const several = groups.length > 1;
  let index = 0;
  groups.forEach((g, gi) => {
    (g.joints || []).forEach((joint, j) => {
      const key = `${gi}:${j}`;
      const label = several ? `g${gi + 1} j${j + 1}` : `j${j + 1}`;
      jointIndex.push({ g: gi, j, key, label, name: joint.name, type: joint.type, color: jointColor(index) });
      index += 1;
    });
  });
  selected = new Set(jointIndex.filter((ji) => ji.g === 0).map((ji) => ji.key));
  for (const ji of jointIndex) {
    const lab = document.createElement('label');
    lab.className = 'joint-check';
    lab.title = `${groups[ji.g].name || `group ${ji.g + 1}`}: ${ji.name} (${ji.type})`;
    const cb = document.createElement('input');
    cb.type = 'checkbox';
    cb.checked = selected.has(ji.key);
    cb.dataset.joint = ji.key;
    cb.dataset.group = String(ji.g);
    cb.dataset.index = String(ji.j);
    cb.addEventListener('change', () => {
      if (cb.checked) selected.add(ji.key); else selected.delete(ji.key);
      buildPlots();
    });
    const sw = document.createElement('span');
    sw.className = 'swatch';
    sw.style.background = ji.color;
    lab.append(cb, sw, document.createTextNode(ji.label));
    box.appendChild(lab);
  }
}

// ---------------------------------------------------------------------------------------------
// status, clients

function setLight(name, value) {
  const el = document.querySelector(`[data-light="${name}"]`);
  if (!el) return;
  el.dataset.state = value === true ? 'on' : value === false ? 'off' : 'unknown';
}

const LIGHTS = ['drives_powered', 'e_stopped', 'in_error', 'in_motion', 'motion_possible'];

function showStatus(status) {
  if (!status) return;
  for (const name of LIGHTS) setLight(name, status[name]);
  const code = Number(status.error_code) || 0;
  $('#error-code').textContent = code !== 0 ? String(status.error_code) : '';
  setText('#mode', status.mode != null ? String(status.mode) : '–');
  const mode = $('#mode');
  mode.dataset.mode = String(status.mode || '').toLowerCase();
}

function resetStatus() {
  for (const name of LIGHTS) setLight(name, undefined);
  $('#error-code').textContent = '';
  setText('#mode', '–');
  setText('#queue', '–');
  setText('#ctime', '–');
}

function setText(sel, text) {
  const el = $(sel);
  if (el && el.textContent !== text) el.textContent = text;
}

let clientsKey = null;

function showClients(clients) {
  if (!Array.isArray(clients)) return;
  const key = JSON.stringify(clients);
  if (key === clientsKey) return;
  clientsKey = key;
  const tbody = $('#clients tbody');
  const rows = clients.map((c) => {
    const tr = document.createElement('tr');
    const cells = [
      c.port ?? '',
      c.peer ?? '',
      c.profile ?? '',
      c.byte_order ?? '',
      c.float64 === true ? 'float64' : c.float64 === false ? 'float32' : '',
    ];
    for (const v of cells) {
      const td = document.createElement('td');
      td.textContent = String(v);
      tr.appendChild(td);
    }
    return tr;
  });
  tbody.replaceChildren(...rows);
  setText('#clients-count', `(${rows.length})`);
}

function showEmulator(h) {
  const e = h.emulator || {};
  const ports = e.ports ? Object.entries(e.ports).map(([k, v]) => `${k} :${v}`).join(', ') : '';
  const parts = [
    e.profile,
    e.byte_order ? `${e.byte_order}-endian` : null,
    e.float64 === true ? 'float64' : e.float64 === false ? 'float32' : null,
    ports,
    e.speedup != null && Number(e.speedup) !== 1 ? `speedup ×${e.speedup}` : null,
  ].filter(Boolean);
  setText('#emulator-info', parts.join(' · '));
  $('#emulator-info').title = e.ready || '';
  if (e.policy) setText('#policy', String(e.policy));
}

// in a fleet (the hello names the controller): its name, and the way back to the fleet's index
function showName(e) {
  const name = typeof e.name === 'string' && e.name ? e.name : '';
  setText('#controller-name', name ? ` · ${name}` : '');
  document.title = name ? `${name} · robot-server` : 'robot-server';
  const link = $('#fleet-link');
  link.hidden = !name;
  if (name) link.href = '../../' + (TOKEN ? `?token=${encodeURIComponent(TOKEN)}` : '');
}

function showQueue(queue) {
  if (!Array.isArray(queue)) return;
  setText('#queue', queue.map((q) => `${q.fill} / ${q.capacity}`).join(', ') || '–');
}

// ---------------------------------------------------------------------------------------------
// traffic

const traffic = {
  frames: [], // newest last, at most TRAFFIC_BUFFER
  paused: false,
  hideTopics: false,
  skipped: 0,
};

function pad(n, w) {
  return String(n).padStart(w, '0');
}

function fmtTime(seconds) {
  if (typeof seconds !== 'number' || !Number.isFinite(seconds)) return '';
  const d = new Date(seconds * 1000);
  return `${pad(d.getHours(), 2)}:${pad(d.getMinutes(), 2)}:${pad(d.getSeconds(), 2)}.${pad(d.getMilliseconds(), 3)}`;
}

function frameName(f) {
  return f.name != null && f.name !== '' ? String(f.name) : String(f.msg_type ?? '');
}

function frameRow(f) {
  const tr = document.createElement('tr');
  const name = frameName(f);
  tr.dataset.name = name;
  tr.dataset.comm = String(f.comm ?? '');
  tr.dataset.dir = String(f.dir ?? '');
  if (f.n != null) tr.dataset.n = String(f.n);
  const cells = [
    [fmtTime(f.time), 'time'],
    [`${f.port ?? ''} ${f.peer ?? ''}`.trim(), 'link'],
    [f.dir === 'in' ? '→' : f.dir === 'out' ? '←' : String(f.dir ?? ''), 'dir'],
    [name, f.name == null ? 'name unknown' : 'name'],
    [String(f.comm ?? ''), 'comm'],
    [String(f.reply ?? ''), `reply reply-${String(f.reply ?? '').toLowerCase()}`],
    [String(f.summary ?? ''), 'summary'],
  ];
  for (const [text, cls] of cells) {
    const td = document.createElement('td');
    td.className = cls;
    td.textContent = text;
    if (cls === 'summary' || cls === 'link') td.title = text;
    tr.appendChild(td);
  }
  if (f.dir === 'in' || f.dir === 'out') tr.title = f.dir === 'in' ? 'to the controller' : 'from the controller';
  return tr;
}

function visible(f) {
  return !(traffic.hideTopics && f.comm === 'TOPIC');
}

function rebuildTraffic() {
  const rows = [];
  for (let i = traffic.frames.length - 1; i >= 0 && rows.length < MAX_TRAFFIC_ROWS; i--) {
    const f = traffic.frames[i];
    if (visible(f)) rows.push(frameRow(f));
  }
  $('#traffic tbody').replaceChildren(...rows);
}

function addTraffic(frames) {
  if (!Array.isArray(frames) || frames.length === 0) return;
  webview.traffic += frames.length;
  for (const f of frames) if (f && typeof f === 'object') traffic.frames.push(f);
  if (traffic.frames.length > TRAFFIC_BUFFER) traffic.frames.splice(0, traffic.frames.length - TRAFFIC_BUFFER);
  setText('#traffic-count', `${webview.traffic} frames`);
  if (traffic.paused) return;
  const tbody = $('#traffic tbody');
  const fresh = [];
  for (let i = frames.length - 1; i >= 0 && fresh.length < MAX_TRAFFIC_ROWS; i--) {
    const f = frames[i];
    if (f && typeof f === 'object' && visible(f)) fresh.push(frameRow(f));
  }
  if (!fresh.length) return;
  if (fresh.length >= MAX_TRAFFIC_ROWS) {
    tbody.replaceChildren(...fresh);
    return;
  }
  const frag = document.createDocumentFragment();
  frag.append(...fresh);
  tbody.insertBefore(frag, tbody.firstChild);
  while (tbody.rows.length > MAX_TRAFFIC_ROWS) tbody.deleteRow(-1);
}

function showSkipped(skipped) {
  if (typeof skipped !== 'number') return;
  traffic.skipped = skipped;
  const el = $('#traffic-skipped');
  if (skipped > 0) {
    el.hidden = false;
    setText('#traffic-skipped', `${skipped} skipped`);
  } else {
    el.hidden = true;
  }
}

function initTrafficControls() {
  const btn = $('#traffic-pause');
  btn.addEventListener('click', () => {
    traffic.paused = !traffic.paused;
    btn.textContent = traffic.paused ? 'Resume' : 'Pause';
    btn.setAttribute('aria-pressed', traffic.paused ? 'true' : 'false');
    btn.classList.toggle('active', traffic.paused);
    if (!traffic.paused) rebuildTraffic();
  });
  const cb = $('#traffic-hide-topics');
  traffic.hideTopics = cb.checked;
  $('#traffic').classList.toggle('hide-topics', traffic.hideTopics);
  cb.addEventListener('change', () => {
    traffic.hideTopics = cb.checked;
    // while paused the rows stay, only TOPIC rows hide or show (CSS); otherwise rebuild
    $('#traffic').classList.toggle('hide-topics', traffic.hideTopics);
    if (!traffic.paused) rebuildTraffic();
  });
}

// ---------------------------------------------------------------------------------------------
// commands

let socket = null;

// the web view's token, from this page's address (?token=...): offered when the WebSocket opens
const TOKEN = new URLSearchParams(location.search).get('token');

// commands allowed or not (control: the hello's {commands, why}); disabled until the hello says
function showControl(control) {
  const allowed = !!(control && control.commands === true);
  webview.commands = allowed;
  for (const btn of document.querySelectorAll('button[data-command]')) {
    btn.disabled = !allowed;
    btn.title = allowed ? (btn.dataset.title || '') : 'read-only';
  }
  const note = $('#read-only');
  const why = control && typeof control.why === 'string' ? control.why : '';
  note.hidden = allowed || !why;
  note.textContent = allowed ? '' : why;
  note.title = note.textContent;
}

function initCommands() {
  for (const btn of document.querySelectorAll('button[data-command]')) {
    btn.dataset.title = btn.title || '';
    btn.disabled = true;
    btn.addEventListener('click', () => {
      const command = btn.dataset.command;
      const out = $('#command-result');
      if (!webview.commands) return;
      if (!socket || socket.readyState !== WebSocket.OPEN) {
        out.textContent = `${command}: not connected`;
        out.dataset.ok = 'false';
        return;
      }
      socket.send(JSON.stringify({ type: 'command', command }));
      out.textContent = `${command}…`;
      out.dataset.ok = 'pending';
    });
  }
}

function showResult(msg) {
  const out = $('#command-result');
  if (msg.ok) {
    out.textContent = String(msg.text ?? 'ok');
    out.dataset.ok = 'true';
  } else {
    out.textContent = String(msg.error ?? 'failed');
    out.dataset.ok = 'false';
  }
  out.title = out.textContent;
}

// ---------------------------------------------------------------------------------------------
// WebSocket

let reconnectDelay = 0.5;
let reconnectTimer = null;

function setConnection(state) {
  const el = $('#connection');
  el.dataset.state = state;
  el.textContent = state === 'open' ? 'connected' : state === 'closed' ? 'disconnected' : 'connecting';
  webview.connected = state === 'open';
}

function connect() {
  reconnectTimer = null;
  setConnection('connecting');
  let ws;
  try {
    const url = new URL('ws', location.href);
    url.protocol = location.protocol === 'https:' ? 'wss:' : 'ws:';
    url.search = TOKEN ? `?token=${encodeURIComponent(TOKEN)}` : '';
    url.hash = '';
    ws = new WebSocket(url.href);
  } catch (err) {
    scheduleReconnect();
    return;
  }
  socket = ws;
  ws.addEventListener('open', () => {
    if (socket !== ws) return;
    reconnectDelay = 0.5;
    setConnection('open');
  });
  ws.addEventListener('message', (ev) => {
    if (socket !== ws || typeof ev.data !== 'string') return;
    let msg;
    try {
      msg = JSON.parse(ev.data);
    } catch (err) {
      return;
    }
    handleMessage(msg);
  });
  ws.addEventListener('close', () => {
    if (socket !== ws) return;
    socket = null;
    showControl(null);
    setConnection('closed');
    scheduleReconnect();
  });
  ws.addEventListener('error', () => {
    // a close event follows; nothing to report
  });
}

function scheduleReconnect() {
  if (reconnectTimer != null) return;
  const delay = reconnectDelay;
  reconnectDelay = Math.min(reconnectDelay * 2, 5);
  reconnectTimer = setTimeout(connect, delay * 1000);
}

function handleMessage(msg) {
  if (!msg || typeof msg !== 'object') return;
  switch (msg.type) {
    case 'hello': onHello(msg); break;
    case 'update': onUpdate(msg); break;
    case 'result': showResult(msg); break;
    default: break;
  }
}

const PROTOCOL_VERSION = 1;

function onHello(msg) {
  if (msg.version !== PROTOCOL_VERSION) {
    // another version of the messages (docs/web.md): say so rather than draw nonsense
    const out = $('#command-result');
    out.textContent = `this page reads version ${PROTOCOL_VERSION} of the web view's messages; the server sent ${msg.version}: reload the page`;
    out.dataset.ok = 'false';
    hello = null;
    return;
  }
  hello = msg;
  webview.hello = msg;
  showControl(msg.control || { commands: true, why: null });
  showName(msg.emulator || {});
  resetData(msg);
  resetStatus();
  clientsKey = null;
  $('#clients tbody').replaceChildren();
  traffic.frames = [];
  $('#traffic tbody').replaceChildren();
  showSkipped(0);
  buildJointSelect(msg);
  buildWorld(msg);
  showEmulator(msg);
  for (const s of msg.history || []) addSample(s);
  addWaypoints(msg.waypoints);
  addTraffic(msg.traffic);
  if (traffic.paused) rebuildTraffic(); // a new connection starts with a fresh table
  buildPlots();
  showTime();
}

function onUpdate(msg) {
  if (!hello) return;
  if (Array.isArray(msg.samples)) for (const s of msg.samples) addSample(s);
  if (msg.sample) addSample(msg.sample);
  addWaypoints(msg.waypoints);
  showStatus(msg.status);
  if (msg.policy != null) setText('#policy', String(msg.policy));
  showQueue(msg.queue);
  showClients(msg.clients);
  addTraffic(msg.traffic);
  showSkipped(msg.skipped);
  showTime();
}

function showTime() {
  if (webview.lastTime != null) setText('#ctime', `${webview.lastTime.toFixed(2)} s`);
}

// ---------------------------------------------------------------------------------------------
// animation loop: render the latest sample at the display rate; at most one setData per frame

function frame() {
  requestAnimationFrame(frame);
  if (view.ok) {
    resizeView();
    poseRobots();
    if (view.width > 0 && view.height > 0) {
      view.controls.update();
      view.renderer.render(view.scene, view.camera);
      webview.renders += 1;
    }
  }
  updatePlots();
}

initView();
initTrafficControls();
initCommands();
connect();
requestAnimationFrame(frame);
