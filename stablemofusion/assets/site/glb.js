// The .glb of a motion in the page, as `smf generate --format glb` writes it (stablemofusion/motion/gltf.py): named
// joint nodes, a skin, a capsule body, one animation with a rotation per joint and the root's translation; metres,
// Y up. Written with three.js's GLTFExporter.
import * as THREE from 'three';
import { GLTFExporter } from './vendor/three/exporters/GLTFExporter.js';

function capsule(a, b, radius, joint, out, rings = 4, sides = 10) {
  const axis = b.clone().sub(a);
  const y = axis.length() > 1e-9 ? axis.clone().normalize() : new THREE.Vector3(0, 1, 0);
  const ay = [Math.abs(y.x), Math.abs(y.y), Math.abs(y.z)];
  const helper = new THREE.Vector3().setComponent(ay.indexOf(Math.min(...ay)), 1);
  const x = new THREE.Vector3().crossVectors(helper, y).normalize();
  const z = new THREE.Vector3().crossVectors(x, y);
  const base = out.positions.length / 3;
  const lats = [];
  for (let r = 0; r <= rings; r++) lats.push([-Math.PI / 2 + (Math.PI / 2) * r / rings, false]);
  for (let r = 0; r <= rings; r++) lats.push([(Math.PI / 2) * r / rings, true]);
  for (const [lat, top] of lats) {
    for (let s = 0; s < sides; s++) {
      const lon = 2 * Math.PI * s / sides;
      const n = x.clone().multiplyScalar(Math.cos(lat) * Math.cos(lon)).addScaledVector(y, Math.sin(lat))
        .addScaledVector(z, Math.cos(lat) * Math.sin(lon));
      const p = (top ? b : a).clone().addScaledVector(n, radius);
      out.positions.push(p.x, p.y, p.z);
      out.normals.push(n.x, n.y, n.z);
      out.joints.push(joint, 0, 0, 0);
      out.weights.push(1, 0, 0, 0);
    }
  }
  for (let i = 0; i < lats.length - 1; i++) {
    for (let s = 0; s < sides; s++) {
      const v00 = base + i * sides + s, v01 = base + i * sides + (s + 1) % sides;
      out.index.push(v00, v00 + sides, v01 + sides, v00, v01 + sides, v01);
    }
  }
}

// `sizes`: the capsule body's sizes (m) and colour, motion/gltf.py's, from web.json ("glb_body")
export async function glbBytes(joints, T, tree, pose, fps, sizes) {
  const { offsets, rotations } = pose;
  const { bone_radius: BONE_RADIUS, default_radius: DEFAULT_RADIUS, head_radius: HEAD_RADIUS, hand_length: HAND_LENGTH,
    colour: BODY_COLOUR } = sizes;
  const J = tree.parents.length, names = tree.names, parents = tree.parents;
  // the skeleton at rest (identity rotations), its root at its first position
  const bones = names.map((name) => Object.assign(new THREE.Bone(), { name }));
  bones.forEach((bone, j) => {
    if (parents[j] >= 0) bones[parents[j]].add(bone);
    bone.position.fromArray(parents[j] < 0 ? [joints[0], joints[1], joints[2]] : offsets[j]);
  });
  const rest = [];
  names.forEach((_, j) => { rest.push(parents[j] < 0 ? new THREE.Vector3(...offsets[0]) : rest[parents[j]].clone().add(new THREE.Vector3(...offsets[j]))); });
  const body = { positions: [], normals: [], joints: [], weights: [], index: [] };
  parents.forEach((p, c) => { if (p >= 0) capsule(rest[p], rest[c], BONE_RADIUS[names[c]] ?? DEFAULT_RADIUS, p, body); });
  names.forEach((name, j) => {
    if (parents.includes(j)) return;
    if (name === 'head') capsule(rest[j], rest[j], HEAD_RADIUS, j, body);
    else if (name.endsWith('wrist')) {
      const d = new THREE.Vector3(...offsets[j]).normalize();
      capsule(rest[j], rest[j].clone().addScaledVector(d, HAND_LENGTH), BONE_RADIUS[name] ?? DEFAULT_RADIUS, j, body);
    }
  });
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.Float32BufferAttribute(body.positions, 3));
  g.setAttribute('normal', new THREE.Float32BufferAttribute(body.normals, 3));
  g.setAttribute('skinIndex', new THREE.Uint16BufferAttribute(body.joints, 4));
  g.setAttribute('skinWeight', new THREE.Float32BufferAttribute(body.weights, 4));
  g.setIndex(body.index);
  const mesh = new THREE.SkinnedMesh(g, new THREE.MeshStandardMaterial({ color: new THREE.Color(...BODY_COLOUR),
    metalness: 0, roughness: 0.8 }));
  mesh.name = 'body';
  const root = bones[parents.indexOf(-1)];
  const scene = new THREE.Scene();
  scene.name = 'motion';
  scene.add(root, mesh);
  // the bind pose is the rest: the root's node at the origin while binding (motion/gltf.py's inverse bind matrices)
  root.position.fromArray(offsets[0]);
  scene.updateMatrixWorld(true);
  mesh.bind(new THREE.Skeleton(bones));
  // one animation: a rotation per joint (keys kept in one hemisphere), the root's translation
  const times = Float32Array.from({ length: T }, (_, n) => n / fps);
  const tracks = [];
  const m4 = new THREE.Matrix4(), q = new THREE.Quaternion();
  names.forEach((name, j) => {
    const values = new Float32Array(T * 4);
    let prev = null;
    for (let n = 0; n < T; n++) {
      const r = rotations.subarray((n * J + j) * 9, (n * J + j + 1) * 9); // rows
      m4.set(r[0], r[1], r[2], 0, r[3], r[4], r[5], 0, r[6], r[7], r[8], 0, 0, 0, 0, 1);
      q.setFromRotationMatrix(m4);
      if (prev && prev.dot(q) < 0) q.set(-q.x, -q.y, -q.z, -q.w);
      prev = q.clone();
      values.set([q.x, q.y, q.z, q.w], n * 4);
      if (n === 0) bones[j].quaternion.copy(q);
    }
    tracks.push(new THREE.QuaternionKeyframeTrack(`${name}.quaternion`, times, values));
  });
  const rootPath = new Float32Array(T * 3);
  for (let n = 0; n < T; n++) rootPath.set([joints[n * J * 3], joints[n * J * 3 + 1], joints[n * J * 3 + 2]], n * 3);
  tracks.push(new THREE.VectorKeyframeTrack(`${root.name}.position`, times, rootPath));
  root.position.fromArray(rootPath.subarray(0, 3));
  const clip = new THREE.AnimationClip('motion', (T - 1) / fps, tracks);
  return new Uint8Array(await new GLTFExporter().parseAsync(scene, { binary: true, animations: [clip] }));
}
