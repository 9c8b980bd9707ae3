// Motion math of the portable runtime in JavaScript, for one motion: the JavaScript twin of
// stablemofusion/motion/features.py (joints_from_features) and of the rigid stage's block-sweep fit
// (stablemofusion/motion/rigid_batch.py: closed_form_body, sweep, polar_rotation; its docstring explains them).
// Arrays are flat Float64Arrays, frame-major: joints[(t * J + j) * 3 + k] metres, Y up.

function yawRotate(c, s, v0, v1, v2, out, o) {
  // qrot(q, v) for q = (c, 0, s, 0) (a rotation about +Y), written out
  const uv0 = s * v2, uv2 = -s * v0; // u x v with u = (0, s, 0)
  const uuv0 = s * uv2, uuv2 = -s * uv0; // u x (u x v)
  out[o] = v0 + 2 * (c * uv0 + uuv0);
  out[o + 1] = v1;
  out[o + 2] = v2 + 2 * (c * uv2 + uuv2);
}

// Features (T, D) in dataset units -> joints (T, J, 3) metres through the root-relative positions.
export function jointsFromFeatures(features, T, D, J) {
  const out = new Float64Array(T * J * 3);
  const tmp = new Float64Array(3);
  let angle = 0, rx = 0, rz = 0;
  for (let t = 0; t < T; t++) {
    const f = t * D;
    if (t > 0) {
      const p = (t - 1) * D;
      angle += features[p]; // the yaw half-angle, integrated
      // the root's step of the previous frame, turned by the inverse yaw of this frame
      yawRotate(Math.cos(angle), -Math.sin(angle), features[p + 1], 0, features[p + 2], tmp, 0);
      rx += tmp[0];
      rz += tmp[2];
    }
    const c = Math.cos(angle), s = -Math.sin(angle); // qinv of (cos a, 0, sin a, 0)
    const o = t * J * 3;
    out[o] = rx;
    out[o + 1] = features[f + 3];
    out[o + 2] = rz;
    for (let j = 1; j < J; j++) {
      const q = f + 4 + 3 * (j - 1);
      yawRotate(c, s, features[q], features[q + 1], features[q + 2], out, o + 3 * j);
      out[o + 3 * j] += rx;
      out[o + 3 * j + 2] += rz;
    }
  }
  return out;
}

const EPS = 1e-12;
const GIMBAL_COS = 1e-9; // motion/rotation.py's: below it the first and third Euler axes coincide
const POLAR_STEPS = 8;

export function cross(a, b) {
  return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
}
export const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
function unit(v) {
  const n = Math.hypot(v[0], v[1], v[2]) + EPS;
  return [v[0] / n, v[1] / n, v[2] / n];
}
export const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
// a rotation as its three columns [x, y, z]: R v = x v0 + y v1 + z v2; R^T v = (x.v, y.v, z.v)
const rotate = (R, v) => [0, 1, 2].map((i) => R[0][i] * v[0] + R[1][i] * v[1] + R[2][i] * v[2]);
const rotateT = (R, v) => [dot(R[0], v), dot(R[1], v), dot(R[2], v)];

// The rotation (columns) maximising tr(R^T K), K given by columns: its polar factor by scaled Newton steps;
// `fallback` where det(K) <= 0.
export function polarRotation(K, fallback) {
  let x = K;
  let ok = null;
  for (let step = 0; step < POLAR_STEPS; step++) {
    const [a, b, c] = x;
    const cof = [cross(b, c), cross(c, a), cross(a, b)]; // det(x) x^-T, by columns
    const det = dot(a, cof[0]);
    if (ok === null) ok = det > 0;
    const safe = ok ? det : 1;
    const g = Math.pow(safe, -1 / 3);
    x = x.map((col, k) => col.map((v, i) => 0.5 * (g * v + cof[k][i] / (safe * g))));
  }
  return ok ? x : fallback;
}

// The frame (columns x, y, z) of branching joint number i of joints `at(j)`: X from its -X child to its +X child,
// Y towards its remaining child (up or down by that child's rest direction), Z = X x Y.
export function branchFrame(at, t, i) {
  const [c0, c1, c2] = t.branch_children[i];
  const x = unit(sub(at(c1), at(c0)));
  let y = sub(at(c2), at(t.branches[i])).map((v) => v * Math.sign(t.rest[c2][1]));
  const d = dot(y, x);
  y = unit(y.map((v, k) => v - d * x[k]));
  return [x, y, cross(x, y)];
}

// The skeleton's tree as the site's model description gives it (smf site: web.json "skeleton").
function prepare(tree) {
  const J = tree.parents.length;
  const subtree = Array.from({ length: J }, (_, j) => {
    const row = new Array(J).fill(0);
    row[j] = 1;
    return row;
  });
  for (let c = J - 1; c > 0; c--) for (let k = 0; k < J; k++) subtree[tree.parents[c]][k] = Math.min(1, subtree[tree.parents[c]][k] + subtree[c][k]);
  const members = subtree.map((row) => row.flatMap((v, k) => (v ? [k] : [])));
  return { ...tree, J, members };
}

// Rigid joints (T, J, 3) fitted to joints `targets` (T, J, 3) with bone `lengths` (J,): the closed-form body, then
// `sweeps` exact block sweeps.
export function fitRigid(targets, T, tree, lengths, sweeps) {
  const t = prepare(tree);
  const J = t.J;
  const at = (arr, n, j) => [arr[(n * J + j) * 3], arr[(n * J + j) * 3 + 1], arr[(n * J + j) * 3 + 2]];
  // 1. the closed form: branch frames and their children's mean offsets, bones along the targets
  const B = t.branches.length;
  const frames = [];
  for (let n = 0; n < T; n++) frames.push(t.branches.map((b, i) => branchFrame((j) => at(targets, n, j), t, i)));
  const offsets = t.branches.map((b, i) => t.branch_children[i].map((c) => {
    const m = [0, 0, 0];
    for (let n = 0; n < T; n++) {
      const local = rotateT(frames[n][i], sub(at(targets, n, c), at(targets, n, b)));
      for (let k = 0; k < 3; k++) m[k] += local[k] / T;
    }
    return unit(m).map((v) => v * lengths[c]);
  }));
  const x = new Float64Array(T * J * 3);
  for (let n = 0; n < T; n++) {
    const bones = Array.from({ length: J }, (_, j) => (j === 0 ? at(targets, n, 0)
      : unit(sub(at(targets, n, j), at(targets, n, t.parents[j]))).map((v) => v * lengths[j])));
    t.branches.forEach((b, i) => t.branch_children[i].forEach((c, k) => { bones[c] = rotate(frames[n][i], offsets[i][k]); }));
    for (let j = 0; j < J; j++) for (const k of t.members[j]) for (let d = 0; d < 3; d++) x[(n * J + k) * 3 + d] += bones[j][d];
  }
  // 2. block sweeps, frame by frame (every frame is its own problem once the offsets are fixed)
  const sizes = t.members.map((m) => m.length);
  const p = new Float64Array(J * 3);
  for (let n = 0; n < T; n++) {
    for (let s = 0; s < sweeps; s++) {
      for (let j = 0; j < J; j++) for (let d = 0; d < 3; d++) p[j * 3 + d] = x[(n * J + j) * 3 + d];
      const tg = (j) => at(targets, n, j);
      const xj = (j) => [p[j * 3], p[j * 3 + 1], p[j * 3 + 2]];
      const move = (j, delta) => { for (const k of t.members[j]) for (let d = 0; d < 3; d++) p[k * 3 + d] += delta[d]; };
      const wantOf = (j, from) => { // where j's subtree wants j, relative to `from`
        const r = [0, 0, 0];
        for (const k of t.members[j]) { const e = sub(tg(k), xj(k)); for (let d = 0; d < 3; d++) r[d] += e[d] / sizes[j]; }
        const here = xj(j), base = xj(from);
        return [0, 1, 2].map((d) => here[d] + r[d] - base[d]);
      };
      // the root block: the whole body by the mean residual
      const r = [0, 0, 0];
      for (let j = 0; j < J; j++) { const e = sub(tg(j), xj(j)); for (let d = 0; d < 3; d++) r[d] += e[d] / J; }
      move(0, r);
      for (const [free, branchIds] of t.levels) {
        for (const i of branchIds) {
          const b = t.branches[i], ch = t.branch_children[i];
          const want = ch.map((c) => wantOf(c, b));
          const K = [[0, 0, 0], [0, 0, 0], [0, 0, 0]]; // by columns: K[col j][row i] = sum_c n_c want_c[i] off_c[j]
          ch.forEach((c, k) => { for (let jj = 0; jj < 3; jj++) for (let ii = 0; ii < 3; ii++) K[jj][ii] += sizes[c] * want[k][ii] * offsets[i][k][jj]; });
          frames[n][i] = polarRotation(K, frames[n][i]);
          const base = xj(b);
          const deltas = ch.map((c, k) => { const m = rotate(frames[n][i], offsets[i][k]); return sub(m.map((v, d) => v + base[d]), xj(c)); });
          ch.forEach((c, k) => move(c, deltas[k]));
        }
        if (free.length) {
          const deltas = free.map((f) => {
            const parent = xj(t.parents[f]);
            const dir = unit(wantOf(f, t.parents[f]));
            return sub(dir.map((v, d) => parent[d] + lengths[f] * v), xj(f));
          });
          free.forEach((f, k) => move(f, deltas[k]));
        }
      }
      for (let j = 0; j < J; j++) for (let d = 0; d < 3; d++) x[(n * J + j) * 3 + d] = p[j * 3 + d];
    }
  }
  return x;
}

// Joints (T, J, 3) moved so that the first root sits at the XZ origin, where features start (in place).
export function recentre(x, T, J) {
  const ox = x[0], oz = x[2];
  for (let i = 0; i < T * J; i++) { x[i * 3] -= ox; x[i * 3 + 2] -= oz; }
  return x;
}

// ---- the pose of the rigid joints and its BVH (stablemofusion/motion/rigid_batch.py: pose_of_joints; motion/bvh.py)
const quatToMatrix = ([w, x, y, z]) => [ // rows
  [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]];
const matMul = (A, B) => A.map((row) => [0, 1, 2].map((k) => row[0] * B[0][k] + row[1] * B[1][k] + row[2] * B[2][k]));
const transpose = (A) => [0, 1, 2].map((i) => [A[0][i], A[1][i], A[2][i]]);
const apply = (A, v) => A.map((row) => dot(row, v));
const IDENTITY = [[1, 0, 0], [0, 1, 0], [0, 0, 1]];

// the rotation (rows) taking unit vector a onto b by the shortest arc (a half turn about an axis normal to a when
// they are opposite)
function shortestArc(a, b) {
  let q = [1 + dot(a, b), ...cross(a, b)];
  if (q[0] < 1e-6) {
    const k = [0, 1, 2].reduce((m, i) => (Math.abs(a[i]) < Math.abs(a[m]) ? i : m), 0);
    const e = [0, 0, 0];
    e[k] = 1;
    q = [0, ...cross(a, e)];
  }
  const n = Math.hypot(...q);
  return quatToMatrix(q.map((v) => v / n));
}

// Closed-form inverse kinematics of rigid joints (T, J, 3) with bone `lengths`: rest offsets (J x 3) and local
// rotations (T x J, 3 x 3 rows): branching joints take the frame their children span, every other bone turns by the
// shortest arc from its parent's rotation onto its bone, leaves keep their parent's rotation.
export function poseOfJoints(joints, T, tree, lengths) {
  const t = prepare(tree);
  const J = t.J;
  const at = (n, j) => [joints[(n * J + j) * 3], joints[(n * J + j) * 3 + 1], joints[(n * J + j) * 3 + 2]];
  const offsets = t.rest.map((r, j) => r.map((v) => v * lengths[j]));
  const frames = [];
  for (let n = 0; n < T; n++) frames.push(t.branches.map((b, i) => transpose(branchFrame((j) => at(n, j), t, i))));
  t.branches.forEach((b, i) => t.branch_children[i].forEach((c) => {
    const m = [0, 0, 0];
    for (let n = 0; n < T; n++) {
      const local = apply(transpose(frames[n][i]), sub(at(n, c), at(n, b)));
      for (let k = 0; k < 3; k++) m[k] += local[k] / T;
    }
    offsets[c] = unit(m).map((v) => v * lengths[c]);
  }));
  offsets[0] = [0, 0, 0];
  const depth = t.parents.map(() => 0);
  for (let j = 1; j < J; j++) depth[j] = depth[t.parents[j]] + 1;
  const order = [...Array(J).keys()].filter((j) => !t.branches.includes(j)).sort((a, b) => depth[a] - depth[b]);
  const kid = (j) => t.parents.indexOf(j);
  const local = [];
  for (let n = 0; n < T; n++) {
    const glob = new Array(J);
    t.branches.forEach((b, i) => { glob[b] = frames[n][i]; });
    for (const j of order) {
      const parentRot = t.parents[j] < 0 ? IDENTITY : glob[t.parents[j]];
      const c = kid(j);
      if (c < 0) { glob[j] = parentRot; continue; }
      glob[j] = matMul(shortestArc(apply(parentRot, t.rest[c]), unit(sub(at(n, c), at(n, j)))), parentRot);
    }
    local.push(glob.map((g, j) => (j === 0 ? g : matMul(transpose(glob[t.parents[j]]), g))));
  }
  return { offsets, local };
}

// Intrinsic Euler angles (degrees) of a rotation (rows) about the axes of `order` (R = R_a R_b R_c), as
// stablemofusion/motion/rotation.py: matrix_to_euler.
export function matrixToEuler(r, order) {
  const [i, j, k] = [...order].map((a) => 'XYZ'.indexOf(a));
  const s = (j - i + 3) % 3 === 1 ? 1 : -1;
  const cosB = Math.hypot(r[i][i], r[i][j]);
  const b = Math.atan2(s * r[i][k], cosB);
  let a = Math.atan2(-s * r[j][k], r[k][k]);
  let c = Math.atan2(-s * r[i][j], r[i][i]);
  if (cosB < GIMBAL_COS) {
    const p = (j + 1) % 3, q = (j + 2) % 3;
    const rj = [[0, 0, 0], [0, 0, 0], [0, 0, 0]];
    rj[j][j] = 1;
    rj[p][p] = rj[q][q] = Math.cos(b);
    rj[q][p] = Math.sin(b);
    rj[p][q] = -Math.sin(b);
    const ri = matMul(r, transpose(rj));
    const p2 = (i + 1) % 3, q2 = (i + 2) % 3;
    a = Math.atan2(ri[q2][p2], ri[p2][p2]);
    c = 0;
  }
  return [a, b, c].map((v) => v * 180 / Math.PI);
}

// The BVH text (metres, Y up) of rigid joints (T, J, 3): the skeleton of `poseOfJoints`, ZXY rotation channels,
// as `smf generate --format bvh` writes it.
export function bvhText(joints, T, tree, lengths, fps, precision = 6) {
  const { offsets, local } = poseOfJoints(joints, T, tree, lengths);
  const J = tree.parents.length, names = tree.names, order = 'ZXY';
  const num = (v) => (Math.round(v * 10 ** precision) / 10 ** precision + 0).toFixed(precision);
  const children = [...Array(J)].map(() => []);
  for (let j = 1; j < J; j++) children[tree.parents[j]].push(j);
  const rot = [...order].map((a) => `${a}rotation`).join(' ');
  const out = ['HIERARCHY'];
  const written = [];
  const emit = (j, depth) => {
    const ind = '\t'.repeat(depth);
    written.push(j);
    out.push(`${ind}${j === 0 ? 'ROOT' : 'JOINT'} ${names[j]}`, `${ind}{`, `${ind}\tOFFSET ${offsets[j].map(num).join(' ')}`,
      j === 0 ? `${ind}\tCHANNELS 6 Xposition Yposition Zposition ${rot}` : `${ind}\tCHANNELS 3 ${rot}`);
    for (const c of children[j]) emit(c, depth + 1);
    if (!children[j].length) {
      const len = Math.hypot(...offsets[j]);
      const site = len > 1e-9 ? offsets[j].map((v) => v * 0.05 / len) : [0, 0.05, 0];
      out.push(`${ind}\tEnd Site`, `${ind}\t{`, `${ind}\t\tOFFSET ${site.map(num).join(' ')}`, `${ind}\t}`);
    }
    out.push(`${ind}}`);
  };
  emit(0, 0);
  out.push('MOTION', `Frames: ${T}`, `Frame Time: ${Number((1 / fps).toPrecision(9))}`);
  for (let n = 0; n < T; n++) {
    const row = [joints[n * J * 3], joints[n * J * 3 + 1], joints[n * J * 3 + 2]];
    for (const j of written) row.push(...matrixToEuler(local[n][j], order));
    out.push(row.map(num).join(' '));
  }
  return out.join('\n') + '\n';
}
