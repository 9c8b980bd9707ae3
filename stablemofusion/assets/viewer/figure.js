// The stick figure of the viewer and the static site: a HumanML3D skeleton (22 joints) drawn as coloured bones and
// joint spheres (feet green while in contact), and the floor grid.
import * as THREE from 'three';

export const PARENTS = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19];
const LEFT = new Set([1, 4, 7, 10, 13, 16, 18, 20]);
const RIGHT = new Set([2, 5, 8, 11, 14, 17, 19, 21]);
const FEET = [7, 10, 8, 11]; // left ankle, left toe, right ankle, right toe
const COLORS = { left: 0x1f77b4, right: 0xd62728, spine: 0x333333, contact: 0x2ca02c };

// A floor grid of short segments (every line cut at each crossing): software WebGL (SwiftShader) drops a
// whole line that passes behind the camera, which hid the near half of a plain GridHelper.
export function floorGrid(half, step) {
  const pts = [], cols = [];
  const major = new THREE.Color(0x888888), minor = new THREE.Color(0xbbbbbb);
  for (let a = -half; a <= half + 1e-9; a += step) {
    const c = Math.abs(a) < 1e-9 ? major : minor;
    for (let b = -half; b < half - 1e-9; b += step) {
      pts.push(a, 0, b, a, 0, b + step, b, 0, a, b + step, 0, a);
      for (let k = 0; k < 4; k++) cols.push(c.r, c.g, c.b);
    }
  }
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.Float32BufferAttribute(pts, 3));
  g.setAttribute('color', new THREE.Float32BufferAttribute(cols, 3));
  return new THREE.LineSegments(g, new THREE.LineBasicMaterial({ vertexColors: true }));
}

// The scene both pages draw in, inside element `view`: renderer, scene (floor grid, lights), camera and orbit
// controls (the OrbitControls class, imported by each page from its own copy of three.js), resized with the view.
export function makeStage(view, OrbitControls) {
  const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(window.devicePixelRatio);
  view.appendChild(renderer.domElement);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0xf4f4f2);
  const camera = new THREE.PerspectiveCamera(45, 1, 0.05, 100);
  camera.position.set(3, 1.7, 4.5);
  const controls = new OrbitControls(camera, renderer.domElement);
  controls.target.set(0, 0.9, 0);
  const floor = floorGrid(10, 0.5);
  scene.add(floor);
  scene.add(new THREE.HemisphereLight(0xffffff, 0x888880, 2.0));
  const sun = new THREE.DirectionalLight(0xffffff, 1.5);
  sun.position.set(2, 5, 3);
  scene.add(sun);
  const resize = () => {
    const w = view.clientWidth, h = view.clientHeight;
    renderer.setSize(w, h);
    camera.aspect = w / Math.max(h, 1);
    camera.updateProjectionMatrix();
  };
  window.addEventListener('resize', resize);
  new ResizeObserver(resize).observe(view); // the header may wrap to two lines
  resize();
  return { renderer, scene, camera, controls, floor };
}

export class Figure {
  constructor(scene) {
    this.positions = new Float32Array(21 * 2 * 3);
    const colors = new Float32Array(21 * 2 * 3);
    PARENTS.slice(1).forEach((p, i) => {
      const j = i + 1;
      const c = new THREE.Color(LEFT.has(j) ? COLORS.left : RIGHT.has(j) ? COLORS.right : COLORS.spine);
      for (const k of [0, 1]) colors.set([c.r, c.g, c.b], (2 * i + k) * 3);
    });
    this.geometry = new THREE.BufferGeometry();
    this.geometry.setAttribute('position', new THREE.BufferAttribute(this.positions, 3));
    this.geometry.setAttribute('color', new THREE.BufferAttribute(colors, 3));
    this.bones = new THREE.LineSegments(this.geometry, new THREE.LineBasicMaterial({ vertexColors: true }));
    scene.add(this.bones);
    this.joints = PARENTS.map((_, j) => {
      const m = new THREE.Mesh(new THREE.SphereGeometry(j === 15 ? 0.08 : 0.025, 16, 12),
        new THREE.MeshBasicMaterial({ color: COLORS.spine }));
      scene.add(m);
      return m;
    });
    this.visible = false;
  }

  set visible(on) {
    this.bones.visible = on;
    this.joints.forEach((m) => { m.visible = on; });
  }

  // Pose the figure at frame `frame` of flat joints J (frames x 22 x 3), feet coloured by `contacts`.
  pose(J, frame, contacts) {
    const base = frame * 22 * 3;
    PARENTS.slice(1).forEach((p, i) => {
      this.positions.set(J.subarray(base + p * 3, base + p * 3 + 3), (2 * i) * 3);
      this.positions.set(J.subarray(base + (i + 1) * 3, base + (i + 1) * 3 + 3), (2 * i + 1) * 3);
    });
    this.geometry.attributes.position.needsUpdate = true;
    this.geometry.computeBoundingSphere();
    this.joints.forEach((m, j) => {
      m.position.set(J[base + j * 3], J[base + j * 3 + 1], J[base + j * 3 + 2]);
      const k = FEET.indexOf(j);
      m.material.color.setHex(k >= 0 && contacts && contacts[k][frame] ? COLORS.contact : COLORS.spine);
    });
  }
}
