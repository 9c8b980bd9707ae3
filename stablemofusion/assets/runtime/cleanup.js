// Footskate cleanup in JavaScript: the twin of stablemofusion/footskate/cleanup.py (cleanup_rigid, its docstring
// explains the losses), with its kinematic contacts (footskate/contacts.py), the pose parametrisation of
// motion/rigid.py (optimise_pose, _PoseParams) and the L-BFGS of motion/lbfgs.py. Joints are flat Float64Arrays
// (T x J x 3, metres, Y up); the optimisation works in centimetres, as the Python does. Its settings come from the
// model's web.json ("cleanup"), written from the Python defaults.

import { branchFrame, cross, dot, sub } from './motion.js';

const CM = 100;
const norm3 = (v) => Math.hypot(v[0], v[1], v[2]);

// numpy's percentile with linear interpolation
function percentile(values, p) {
  const s = Float64Array.from(values).sort();
  const pos = (p / 100) * (s.length - 1);
  const lo = Math.floor(pos), hi = Math.min(lo + 1, s.length - 1);
  return s[lo] + (s[hi] - s[lo]) * (pos - lo);
}

// [start, stop) of every run of true in a boolean array
function runs(mask) {
  const out = [];
  for (let t = 0; t < mask.length; t++) {
    if (mask[t] && (t === 0 || !mask[t - 1])) out.push([t, t]);
    if (mask[t]) out[out.length - 1][1] = t + 1;
  }
  return out;
}

// Contacts (4 arrays of T booleans: left ankle, left toe, right ankle, right toe): low and slow, with hysteresis,
// short gaps filled and short contacts dropped.
export function kinematicContacts(x, T, J, fps, c) {
  const feet = c.foot_joints;
  const at = (t, j, d) => x[(t * J + j) * 3 + d];
  const floors = feet.map((j) => percentile(Array.from({ length: T }, (_, t) => at(t, j, 1)), c.floor_percentile));
  const floor = [0, 1, 0, 1].map((k) => Math.min(floors[k], floors[k + 2]));
  return feet.map((j, k) => {
    const enter = [], stay = [];
    for (let t = 0; t < T; t++) {
      const a = Math.max(0, t - 1), b = Math.min(T - 1, t + 1);
      let d = 0;
      for (let e = 0; e < 3; e++) d += ((at(b, j, e) - at(a, j, e)) / (b - a)) ** 2;
      const speed = Math.sqrt(d) * fps, h = at(t, j, 1) - floor[k];
      enter.push(h < c.height_on && speed < c.speed_on);
      stay.push((h < c.height_off && speed < c.speed_off) || enter[t]);
    }
    const col = [enter[0]];
    for (let t = 1; t < T; t++) col.push(col[t - 1] ? stay[t] : enter[t]);
    for (const [a, b] of runs(col.map((v) => !v))) if (a > 0 && b < T && b - a < c.min_gap_frames) col.fill(true, a, b);
    for (const [a, b] of runs(col)) if (b - a < c.min_contact_frames) col.fill(false, a, b);
    return col;
  });
}

// Split a contact's positions (n x [x, y, z]) into [start, stop) pieces whose positions stay within maxShift (m,
// horizontally) of the piece's mean.
function splitContact(points, maxShift) {
  const pieces = [];
  let a = 0;
  for (let b = 1; b <= points.length; b++) {
    let mx = 0, mz = 0;
    for (let i = a; i < b; i++) { mx += points[i][0] / (b - a); mz += points[i][2] / (b - a); }
    let far = 0;
    for (let i = a; i < b; i++) far = Math.max(far, Math.hypot(points[i][0] - mx, points[i][2] - mz));
    if (far > maxShift) { pieces.push([a, b - 1]); a = b - 1; }
  }
  pieces.push([a, points.length]);
  return pieces;
}

// The anchors (T x 4 x 3 metres) and mask (T x 4) of the planted feet.
function anchorTargets(x, T, J, contacts, lengths, c) {
  const target = new Float64Array(T * 4 * 3), mask = new Uint8Array(T * 4);
  c.foot_joints.forEach((j, k) => {
    const pts = Array.from({ length: T }, (_, t) => [x[(t * J + j) * 3], x[(t * J + j) * 3 + 1], x[(t * J + j) * 3 + 2]]);
    for (const [a, b] of runs(contacts[k])) {
      for (const [a2, b2] of splitContact(pts.slice(a, b), c.max_anchor_shift)) {
        const p = [0, 0, 0];
        for (let t = a + a2; t < a + b2; t++) for (let e = 0; e < 3; e++) p[e] += pts[t][e] / (b2 - a2);
        p[1] = c.anchor_floor && (k === 1 || k === 3) ? 0 : Math.max(0, p[1]);
        for (let t = a + a2; t < a + b2; t++) { target.set(p, (t * 4 + k) * 3); mask[t * 4 + k] = 1; }
      }
    }
    const chain = c.foot_chains[k];
    const reach = chain.slice(1).reduce((s, i) => s + lengths[i], 0) + c.reach_margin;
    for (let t = 0; t < T; t++) {
      const hip = pts[t].map((_, e) => x[(t * J + chain[0]) * 3 + e]);
      const d = norm3(sub([target[(t * 4 + k) * 3], target[(t * 4 + k) * 3 + 1], target[(t * 4 + k) * 3 + 2]], hip));
      if (d > reach) mask[t * 4 + k] = 0;
    }
  });
  return { target, mask };
}

// The cleanup loss and its gradient on joints X (T x J x 3 cm) and the root's shift (T x 3 cm).
function cleanupLoss(X0, tgt, mask, T, J, c) {
  const feet = c.foot_joints;
  let nAnchor = 0;
  for (const m of mask) nAnchor += m;
  nAnchor = Math.max(1, nAnchor);
  const wJoint = new Float64Array(J).fill(1);
  for (const j of c.leg_joints) wJoint[j] = c.leg_pose_scale;
  return (X, shift) => {
    const local = new Float64Array(T * J * 3);
    for (let t = 0; t < T; t++) for (let j = 0; j < J; j++) for (let e = 0; e < 3; e++) {
      const i = (t * J + j) * 3 + e;
      local[i] = X[i] - X0[i] - shift[t * 3 + e];
    }
    let pose = 0, anchor = 0, root = 0, offset = 0, smooth = 0, floor = 0;
    const gX = new Float64Array(T * J * 3), gShift = new Float64Array(T * 3);
    for (let t = 0; t < T; t++) for (let j = 0; j < J; j++) for (let e = 0; e < 3; e++) {
      const i = (t * J + j) * 3 + e;
      pose += local[i] * local[i] * wJoint[j];
      gX[i] = c.w_pose * 2 * local[i] * wJoint[j] / (T * J);
    }
    for (let t = 0; t + 1 < T; t++) for (let j = 0; j < J; j++) for (let e = 0; e < 3; e++) {
      const i = (t * J + j) * 3 + e, moved = local[i + J * 3] - local[i];
      smooth += moved * moved;
      const g = c.w_smooth * 2 * moved / ((T - 1) * J);
      gX[i + J * 3] += g;
      gX[i] -= g;
    }
    for (let t = 0; t < T; t++) for (let j = 0; j < J; j++) for (let e = 0; e < 3; e++) gShift[t * 3 + e] -= gX[(t * J + j) * 3 + e];
    for (let t = 0; t < T; t++) {
      for (let j = 0; j < J; j++) {
        const i = (t * J + j) * 3 + 1, below = Math.max(-X[i], 0);
        floor += below * below;
        gX[i] -= c.w_floor * 2 * below / (T * J);
      }
      feet.forEach((j, k) => {
        if (!mask[t * 4 + k]) return;
        for (let e = 0; e < 3; e++) {
          const off = X[(t * J + j) * 3 + e] - tgt[(t * 4 + k) * 3 + e];
          anchor += off * off;
          gX[(t * J + j) * 3 + e] += c.w_anchor * 2 * off / nAnchor;
        }
      });
      for (let e = 0; e < 3; e++) {
        const s = shift[t * 3 + e];
        offset += s * s;
        gShift[t * 3 + e] += c.w_root_offset * 2 * s / T;
        if (t + 1 < T) {
          const step = shift[(t + 1) * 3 + e] - s;
          root += step * step;
          const g = c.w_root * 2 * step / (T - 1);
          gShift[(t + 1) * 3 + e] += g;
          gShift[t * 3 + e] -= g;
        }
      }
    }
    const value = c.w_pose * pose / (T * J) + c.w_anchor * anchor / nAnchor + c.w_root * root / (T - 1)
      + c.w_root_offset * offset / T + c.w_smooth * smooth / ((T - 1) * J) + c.w_floor * floor / (T * J);
    return { value, gX, gShift };
  };
}


// The pose parameters of motion/rigid.py's _PoseParams for rigid joints x (metres): free bones' vectors (cm),
// branching joints' scaled 6D orientations, the root's shift (cm), as one flat vector; positions and the chain rule.
function poseParams(x, T, tree, lengths, offsets, branchScale) {
  const J = tree.parents.length, parents = tree.parents;
  const kids = parents.map((_, j) => parents.filter((p) => p === j).length);
  const branch = [...Array(J).keys()].filter((j) => kids[j] > 1);
  const free = [...Array(J).keys()].filter((c) => c > 0 && kids[parents[c]] === 1);
  const under = [...Array(J).keys()].filter((c) => c > 0 && kids[parents[c]] > 1);
  const branchOf = under.map((c) => branch.indexOf(parents[c]));
  const members = [...Array(J).keys()].map((j) => [...Array(J).keys()].filter((k) => {
    for (let a = k; a >= 0; a = parents[a]) if (a === j) return true;
    return false;
  }));
  const F = free.length, B = branch.length;
  const nU = T * F * 3, nG = T * B * 6;
  const theta0 = new Float64Array(nU + nG + T * 3);
  const at = (t, j) => [x[(t * J + j) * 3], x[(t * J + j) * 3 + 1], x[(t * J + j) * 3 + 2]];
  for (let t = 0; t < T; t++) {
    free.forEach((c, f) => theta0.set(sub(at(t, c), at(t, parents[c])).map((v) => v * CM), (t * F + f) * 3));
    branch.forEach((b, i) => { // the branch's frame (motion.js), its X and Y columns scaled
      const [xn, yn] = branchFrame((j) => at(t, j), tree, tree.branches.indexOf(b));
      theta0.set([...xn, ...yn].map((v) => v * branchScale), nU + (t * B + i) * 6);
    });
  }
  const root0 = Array.from({ length: T }, (_, t) => at(t, 0).map((v) => v * CM));
  const off = offsets.map((o) => o.map((v) => v * CM));
  const len = lengths.map((v) => v * CM);

  function positions(theta) {
    const X = new Float64Array(T * J * 3), frames = [];
    for (let t = 0; t < T; t++) {
      const bones = Array.from({ length: J }, () => [0, 0, 0]);
      const fr = branch.map((_, i) => {
        const g = theta.subarray(nU + (t * B + i) * 6, nU + (t * B + i) * 6 + 6);
        const a = [g[0] / branchScale, g[1] / branchScale, g[2] / branchScale];
        const b = [g[3] / branchScale, g[4] / branchScale, g[5] / branchScale];
        const na = norm3(a), xa = a.map((v) => v / na), w = cross(xa, b), nw = norm3(w);
        const z = w.map((v) => v / nw), y = cross(z, xa);
        return { a, b, na, x: xa, w, nw, y, z };
      });
      frames.push(fr);
      free.forEach((c, f) => {
        const u = theta.subarray((t * F + f) * 3, (t * F + f) * 3 + 3);
        const nu = Math.max(norm3(u), 1e-6);
        bones[c] = [0, 1, 2].map((e) => len[c] * u[e] / nu);
      });
      under.forEach((c, k) => {
        const r = fr[branchOf[k]];
        bones[c] = [0, 1, 2].map((e) => r.x[e] * off[c][0] + r.y[e] * off[c][1] + r.z[e] * off[c][2]);
      });
      const s = theta.subarray(nU + nG + t * 3, nU + nG + t * 3 + 3);
      for (let k = 0; k < J; k++) for (let e = 0; e < 3; e++) X[(t * J + k) * 3 + e] = root0[t][e] + s[e];
      for (let j = 0; j < J; j++) for (const k of members[j]) for (let e = 0; e < 3; e++) X[(t * J + k) * 3 + e] += bones[j][e];
    }
    return { X, frames };
  }

  function objective(loss) {
    return (theta) => {
      const { X, frames } = positions(theta);
      const shift = theta.subarray(nU + nG);
      const { value, gX, gShift } = loss(X, shift);
      const grad = new Float64Array(theta.length);
      for (let t = 0; t < T; t++) {
        const gBone = Array.from({ length: J }, (_, j) => {
          const g = [0, 0, 0];
          for (const k of members[j]) for (let e = 0; e < 3; e++) g[e] += gX[(t * J + k) * 3 + e];
          return g;
        });
        free.forEach((c, f) => {
          const u = theta.subarray((t * F + f) * 3, (t * F + f) * 3 + 3);
          const nu = Math.max(norm3(u), 1e-6), n = [u[0] / nu, u[1] / nu, u[2] / nu], gb = gBone[c];
          const d = dot(n, gb);
          for (let e = 0; e < 3; e++) grad[(t * F + f) * 3 + e] = len[c] / nu * (gb[e] - n[e] * d);
        });
        branch.forEach((_, i) => {
          const r = frames[t][i];
          const gcol = [[0, 0, 0], [0, 0, 0], [0, 0, 0]]; // d/d x, y, z (the rotation's columns)
          under.forEach((c, k) => {
            if (branchOf[k] !== i) return;
            for (let col = 0; col < 3; col++) for (let e = 0; e < 3; e++) gcol[col][e] += gBone[c][e] * off[c][col];
          });
          let [gx, gy, gz] = gcol;
          gz = gz.map((v, e) => v + cross(r.x, gy)[e]); // y = z x x
          gx = gx.map((v, e) => v + cross(gy, r.z)[e]);
          const zgz = dot(r.z, gz);
          const gw = gz.map((v, e) => (v - r.z[e] * zgz) / r.nw); // z = w / |w|
          gx = gx.map((v, e) => v + cross(r.b, gw)[e]); // w = x x b
          const gb = cross(gw, r.x);
          const xgx = dot(r.x, gx);
          const ga = gx.map((v, e) => (v - r.x[e] * xgx) / r.na); // x = a / |a|
          grad.set([...ga, ...gb].map((v) => v / branchScale), nU + (t * B + i) * 6);
        });
        for (let e = 0; e < 3; e++) {
          let g = gShift[t * 3 + e];
          for (let k = 0; k < J; k++) g += gX[(t * J + k) * 3 + e];
          grad[nU + nG + t * 3 + e] = g;
        }
      }
      return { value, grad };
    };
  }

  return { theta0, positions, objective };
}

// motion/lbfgs.py: at most `iterations` L-BFGS iterations (history 10, an Armijo backtracking line search from
// step 1, the first from min(1, 1 / |g|_1)) and 1.25 evaluations per iteration.
function lbfgs(f, x0, iterations, history = 10) {
  const vdot = (a, b) => { let s = 0; for (let i = 0; i < a.length; i++) s += a[i] * b[i]; return s; };
  let x = Float64Array.from(x0);
  let { value, grad: g } = f(x);
  let evals = 1;
  const budget = Math.floor(iterations * 1.25);
  const S = [], Y = [];
  for (let it = 0; it < iterations; it++) {
    let gmax = 0, gsum = 0;
    for (const v of g) { gmax = Math.max(gmax, Math.abs(v)); gsum += Math.abs(v); }
    if (gmax <= 1e-7 || evals >= budget) break;
    // the two-loop recursion: d = -H g
    const q = Float64Array.from(g), alphas = [];
    for (let k = S.length - 1; k >= 0; k--) {
      const a = vdot(S[k], q) / vdot(Y[k], S[k]);
      alphas.push(a);
      for (let i = 0; i < q.length; i++) q[i] -= a * Y[k][i];
    }
    if (S.length) {
      const h = vdot(S[S.length - 1], Y[Y.length - 1]) / vdot(Y[Y.length - 1], Y[Y.length - 1]);
      for (let i = 0; i < q.length; i++) q[i] *= h;
    }
    for (let k = 0; k < S.length; k++) {
      const b = vdot(Y[k], q) / vdot(Y[k], S[k]);
      const a = alphas[S.length - 1 - k];
      for (let i = 0; i < q.length; i++) q[i] += (a - b) * S[k][i];
    }
    let d = q.map((v) => -v);
    let slope = vdot(g, d);
    if (slope >= 0) { S.length = 0; Y.length = 0; d = g.map((v) => -v); slope = -vdot(g, g); }
    let step = it === 0 ? Math.min(1, 1 / gsum) : 1;
    let xNew, vNew, gNew;
    for (;;) {
      xNew = x.map((v, i) => v + step * d[i]);
      ({ value: vNew, grad: gNew } = f(xNew));
      evals += 1;
      if (vNew <= value + 1e-4 * step * slope || evals >= budget) break;
      step *= 0.5;
    }
    if (!(vNew <= value)) break;
    const s = xNew.map((v, i) => v - x[i]), y = gNew.map((v, i) => v - g[i]);
    if (vdot(s, y) > 1e-10) {
      S.push(s);
      Y.push(y);
      if (S.length > history) { S.shift(); Y.shift(); }
    }
    [x, value, g] = [xNew, vNew, gNew];
  }
  return x;
}

// Footskate-cleaned rigid joints (T x J x 3 metres) of rigid joints x with bone `lengths` and rest `offsets`
// (poseOfJoints): the rotations and the root move, never the bone lengths.
export function cleanupRigid(x, T, tree, lengths, offsets, fps, c) {
  const J = tree.parents.length;
  const contacts = kinematicContacts(x, T, J, fps, c);
  const { target, mask } = anchorTargets(x, T, J, contacts, lengths, c);
  const body = poseParams(x, T, tree, lengths, offsets, c.branch_scale);
  const loss = cleanupLoss(x.map((v) => v * CM), target.map((v) => v * CM), mask, T, J, c);
  const theta = lbfgs(body.objective(loss), body.theta0, c.iterations);
  return body.positions(theta).X.map((v) => v / CM);
}
