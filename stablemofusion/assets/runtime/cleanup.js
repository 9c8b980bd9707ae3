// Footskate cleanup in JavaScript: the twin of stablemofusion/footskate/cleanup.py (clean_joints, its docstring
// explains the steps), with its kinematic contacts (footskate/contacts.py), the lean into turns (motion/lean.py) and
// the legs' two-bone IK (motion/ik.py); each function here names its Python twin, and tests compare them. Joints are
// flat Float64Arrays (T x J x 3, metres, Y up). Settings come from the model's web.json ("cleanup"), written from the
// Python defaults.

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


const smoothstep = (x) => { const c = Math.min(Math.max(x, 0), 1); return c * c * (3 - 2 * c); };
const at3 = (x, J, t, j) => [x[(t * J + j) * 3], x[(t * J + j) * 3 + 1], x[(t * J + j) * 3 + 2]];

// numpy's hanning(2r + 3)[1:-1]: a window of 2r + 1 weights
function hanningInner(r) {
  const M = 2 * r + 3, out = [];
  for (let n = 1; n < M - 1; n++) out.push(0.5 - 0.5 * Math.cos((2 * Math.PI * n) / (M - 1)));
  return out;
}

// numpy's convolve(a, k, 'same') for an odd, symmetric kernel
function convolveSame(a, k) {
  const r = (k.length - 1) / 2, out = new Float64Array(a.length);
  for (let t = 0; t < a.length; t++) {
    let s = 0;
    for (let i = 0; i < k.length; i++) { const u = t + r - i; if (u >= 0 && u < a.length) s += a[u] * k[i]; }
    out[t] = s;
  }
  return out;
}

// holds(): the place (T x 4 x [x, y, z]) and mask (T x 4) of the held foot joints
function holds(points, contacts, T, maxSlide, cutGap, framesPerMetre) {
  const place = points.map((row) => row.map((p) => p.slice())), held = Array.from({ length: T }, () => [0, 0, 0, 0]);
  for (let k = 0; k < 4; k++) {
    for (const [a, b] of runs(contacts[k])) {
      const pieces = splitContact(points.slice(a, b).map((row) => row[k]), maxSlide);
      pieces.forEach(([a2, b2], i) => {
        const lo = a + a2 + (i > 0 ? cutGap : 0), hi = a + b2 - (i < pieces.length - 1 ? cutGap : 0);
        if (hi - lo < 1) return;
        const m = [0, 0, 0];
        for (let t = lo; t < hi; t++) for (let e = 0; e < 3; e++) m[e] += points[t][k][e];
        for (let t = lo; t < hi; t++) { place[t][k] = m.map((v) => v / (hi - lo)); held[t][k] = 1; }
      });
    }
    spaceHolds(points, place, held, k, framesPerMetre);
  }
  return { place, held };
}

// _space_holds(): release the ends of consecutive holds of joint k until the foot has time to travel between them
function spaceHolds(points, place, held, k, framesPerMetre) {
  const pull = (t) => [place[t][k][0] - points[t][k][0], place[t][k][2] - points[t][k][2]];
  const spans = runs(held.map((row) => row[k]));
  for (let i = 0; i + 1 < spans.length; i++) {
    const [a1, e1] = spans[i], [s2, b2] = spans[i + 1];
    let last = e1 - 1, first = s2, turn = 0;
    for (;;) {
      if (!(last >= a1 && first < b2)) break;
      const p = pull(first), q = pull(last);
      if (!(first - last < framesPerMetre * Math.hypot(p[0] - q[0], p[1] - q[1]))) break;
      if (turn % 2 === 0) { held[last][k] = 0; last -= 1; } else { held[first][k] = 0; first += 1; }
      turn += 1;
    }
  }
}

// bridge(): offsets (T x [x, y, z]) known where held (T) -> everywhere, eased across free stretches
function bridge(offset, held, T) {
  const before = new Array(T), after = new Array(T);
  let last = -1;
  for (let t = 0; t < T; t++) { if (held[t]) last = t; before[t] = last; }
  let next = T;
  for (let t = T - 1; t >= 0; t--) { if (held[t]) next = t; after[t] = next; }
  if (last < 0) return offset.map(() => [0, 0, 0]);
  return offset.map((_, t) => {
    const b = before[t] < 0 ? after[t] : before[t], a = after[t] >= T ? before[t] : after[t];
    const s = smoothstep((t - b) / Math.max(a - b, 1));
    return [0, 1, 2].map((e) => (1 - s) * offset[b][e] + s * offset[a][e]);
  });
}

// foot_shifts(): how far to move each foot (T x 2 x [x, y, z]): heel's and toe's pulls, each bridged, blended by
// how firmly each is held around the frame
function footShifts(points, place, held, T, r) {
  const kernel = hanningInner(r);
  return [[0, 1], [2, 3]].map(([ankle, toe]) => {
    const w = [ankle, toe].map((j) => convolveSame(Float64Array.from(held, (row) => row[j]), kernel).map((v) => v + 1e-3));
    const o = [ankle, toe].map((j) => bridge(points.map((row, t) => [place[t][j][0] - row[j][0], 0,
      place[t][j][2] - row[j][2]]), held.map((row) => row[j]), T));
    return points.map((_, t) => [0, 1, 2].map((e) => (w[0][t] * o[0][t][e] + w[1][t] * o[1][t][e]) / (w[0][t] + w[1][t])));
  });
}

// bridge_lift(): how far to lift a foot (T) while it travels between two holds
function bridgeLift(shift, held, share, most, T) {
  const out = new Float64Array(T), spans = runs(held);
  for (let i = 0; i + 1 < spans.length; i++) {
    const last = spans[i][1] - 1, first = spans[i + 1][0];
    const h = Math.min(share * Math.hypot(shift[first][0] - shift[last][0], shift[first][2] - shift[last][2]), most);
    for (let t = last + 1; t < first; t++) { const x = (t - last) / (first - last); out[t] = 4 * x * (1 - x) * h; }
  }
  return out;
}

// lean.py's smooth() (features.py's gaussian_smooth, 3 sigmas): a Gaussian of sigma frames along time, edges held
function smoothGauss(values, sigma) {
  const T = values.length, r = Math.floor(3 * sigma + 0.5), k = [];
  for (let i = -r; i <= r; i++) k.push(Math.exp(-0.5 * (i / sigma) ** 2));
  const total = k.reduce((a, b) => a + b, 0);
  return Float64Array.from({ length: T }, (_, t) => {
    let s = 0;
    for (let i = 0; i < k.length; i++) s += (k[i] / total) * values[Math.min(Math.max(t + i - r, 0), T - 1)];
    return s;
  });
}

// numpy's gradient of T values (one-sided at the ends)
const gradient = (v) => Float64Array.from(v, (_, t) => (t === 0 ? v[1] - v[0] : t === v.length - 1 ? v[t] - v[t - 1]
  : (v[t + 1] - v[t - 1]) / 2));

// lean.py's lean_into_turns(): the body above the legs turned about the pelvis by the lean it lacks
function leanIntoTurns(x, T, J, fps, c) {
  const out = Float64Array.from(x);
  if (c.lean <= 0 || T < 3) return out;
  const sigma = c.lean_smooth * fps;
  const sx = smoothGauss(Float64Array.from({ length: T }, (_, t) => x[t * J * 3]), sigma);
  const sz = smoothGauss(Float64Array.from({ length: T }, (_, t) => x[t * J * 3 + 2]), sigma);
  const vx = gradient(sx).map((v) => v * fps), vz = gradient(sz).map((v) => v * fps);
  const axs = gradient(vx).map((v) => v * fps), azs = gradient(vz).map((v) => v * fps);
  const body = [];
  for (let j = 0; j < J; j++) if (!c.leg_chain_joints.includes(j)) body.push(j);
  const aheads = [], wants = [], raw = new Float64Array(T);
  for (let t = 0; t < T; t++) {
    const speed = Math.hypot(vx[t], vz[t]), ax = vx[t] / Math.max(speed, 1e-6), az = vz[t] / Math.max(speed, 1e-6);
    const aLat = axs[t] * az - azs[t] * ax;
    const m = Math.min(Math.max((speed - c.moving[0]) / (c.moving[1] - c.moving[0]), 0), 1);
    wants.push(Math.min(Math.max(c.lean * Math.atan(aLat / c.gravity) * 180 / Math.PI, -c.max_lean_deg), c.max_lean_deg)
      * m * m * (3 - 2 * m));
    aheads.push([ax, az]);
    const u = [0, 1, 2].map((e) => x[(t * J + c.neck) * 3 + e] - x[t * J * 3 + e]);
    raw[t] = Math.atan2(u[0] * az - u[2] * ax, u[1]) * 180 / Math.PI;
  }
  const have = smoothGauss(raw, sigma);
  const extra = wants.map((w, t) => Math.sign(w) * Math.max(Math.abs(w) - Math.sign(w) * have[t], 0));
  if (!extra.some((e) => Math.abs(e) > 1e-3)) return out;
  for (let t = 0; t < T; t++) {
    const th = extra[t] * Math.PI / 180, cs = Math.cos(th), sn = Math.sin(th), [ax, az] = aheads[t];
    const r0 = at3(x, J, t, 0);
    for (const j of body) {
      const p = at3(x, J, t, j), rx = p[0] - r0[0], ry = p[1] - r0[1], rz = p[2] - r0[2];
      const along = rx * ax + rz * az, lat = rx * az - rz * ax;
      const lat2 = cs * lat + sn * ry, up2 = -sn * lat + cs * ry;
      const o = (t * J + j) * 3;
      out[o] = r0[0] + along * ax + lat2 * az;
      out[o + 2] = r0[2] + along * az - lat2 * ax;
      out[o + 1] = r0[1] + up2;
    }
  }
  return out;
}

const unit = (v) => { const n = Math.max(norm3(v), 1e-9); return [v[0] / n, v[1] / n, v[2] / n]; };

// ik.py's reach_shift(): how far to move the pelvis (T x [x, y, z]) so that each leg reaches its ankle target
function reachShift(x, T, J, ankles, lengths, fps, c) {
  const need = Array.from({ length: T }, () => [0, 0, 0]);
  let any = false;
  c.legs.forEach(([h, kn, a], k) => {
    for (let t = 0; t < T; t++) {
      const d = ankles[k][t].map((v, e) => v - x[(t * J + h) * 3 + e]), dist = norm3(d), u = unit(d);
      const short = Math.max(dist - c.straight * 0.995 * (lengths[kn] + lengths[a]), 0);
      if (short > 0) any = true;
      for (let e = 0; e < 3; e++) need[t][e] += u[e] * short;
    }
  });
  if (!any) return need;
  const r = Math.max(1, Math.round(c.reach_smooth * fps)), kernel = hanningInner(r), top = Math.max(...kernel);
  const kn = kernel.map((v) => v / top), mag = need.map(norm3);
  return need.map((_, t) => {
    let best = 0, score = -Infinity;
    for (let i = 0; i < kn.length; i++) {
      const s = mag[Math.min(Math.max(t + i - r, 0), T - 1)] * kn[i];
      if (s > score) { score = s; best = i; }
    }
    return need[Math.min(Math.max(t + best - r, 0), T - 1)].map((v) => v * kn[best]);
  });
}

// ik.py's place_legs(): both legs re-posed by two-bone IK, ankles towards their targets, feet towards their toes
function placeLegs(x, T, J, ankles, toes, lengths, c) {
  c.legs.forEach(([h, kn, a, to], k) => {
    const upper = lengths[kn], lower = lengths[a];
    for (let t = 0; t < T; t++) {
      const hip = at3(x, J, t, h), knee0 = at3(x, J, t, kn);
      const d0 = ankles[k][t].map((v, e) => v - hip[e]), dist = norm3(d0), axis = d0.map((v) => v / Math.max(dist, 1e-9));
      const d = Math.min(Math.max(dist, Math.abs(upper - lower) + 1e-6), c.straight * (upper + lower));
      const ankle = hip.map((v, e) => v + axis[e] * d);
      const p = knee0.map((v, e) => v - hip[e]), pa = p[0] * axis[0] + p[1] * axis[1] + p[2] * axis[2];
      const pole = unit(p.map((v, e) => v - axis[e] * pa));
      const along = (upper ** 2 + d ** 2 - lower ** 2) / (2 * d), across = Math.sqrt(Math.max(upper ** 2 - along ** 2, 0));
      const knee = hip.map((v, e) => v + axis[e] * along + pole[e] * across);
      const foot = unit(toes[k][t].map((v, e) => v - ankle[e]));
      for (let e = 0; e < 3; e++) {
        x[(t * J + kn) * 3 + e] = knee[e];
        x[(t * J + a) * 3 + e] = ankle[e];
        x[(t * J + to) * 3 + e] = ankle[e] + foot[e] * lengths[to];
      }
    }
  });
  return x;
}

// Footskate-cleaned rigid joints of rigid joints x (T x J x 3 metres) with bone `lengths` (cleanup.py's clean_joints
// with kinematic contacts): {joints, held}, held the frames each foot joint was held (4 x T of 0/1, left ankle, left
// toe, right ankle, right toe). Never changes a bone's length.
export function cleanupRigid(x, T, lengths, fps, c) {
  const J = lengths.length;
  const contacts = kinematicContacts(x, T, J, fps, c);
  const feet = c.foot_joints;
  const points = Array.from({ length: T }, (_, t) => feet.map((j) => at3(x, J, t, j)));
  const r = Math.max(1, Math.round(c.blend * fps));
  const { place, held } = holds(points, contacts, T, c.max_slide, r, (1.5 * fps) / c.catch_up);
  const shift = footShifts(points, place, held, T, r);
  const ankles = [0, 1].map((f) => Array.from({ length: T }, (_, t) => at3(x, J, t, c.legs[f][2]).map((v, e) => v + shift[f][t][e])));
  const toes = [0, 1].map((f) => Array.from({ length: T }, (_, t) => at3(x, J, t, c.legs[f][3]).map((v, e) => v + shift[f][t][e])));
  if (c.lift > 0) {
    [[0, 1], [2, 3]].forEach(([ankle, toe], f) => {
      const up = bridgeLift(shift[f], held.map((row) => row[ankle] || row[toe]), c.lift, c.max_lift, T);
      for (let t = 0; t < T; t++) { ankles[f][t][1] += up[t]; toes[f][t][1] += up[t]; }
    });
  }
  if (c.toes_on_floor) {
    const kernel = hanningInner(r), total = kernel.reduce((a, b) => a + b, 0);
    [[0, 1], [1, 3]].forEach(([f, k]) => {
      const down = convolveSame(Float64Array.from(held, (row) => row[k]), kernel.map((v) => v / total));
      for (let t = 0; t < T; t++) {
        const y = toes[f][t][1], s = Math.min(Math.max(down[t], 0), 1);
        toes[f][t][1] = Math.max(y - s * y, 0);
      }
    });
  }
  const out = leanIntoTurns(x, T, J, fps, c);
  const move = reachShift(out, T, J, ankles, lengths, fps, c);
  for (let t = 0; t < T; t++) {
    for (let j = 0; j < J; j++) {
      if (c.leg_chain_joints.includes(j)) continue;
      for (let e = 0; e < 3; e++) out[(t * J + j) * 3 + e] += move[t][e];
    }
  }
  return { joints: placeLegs(out, T, J, ankles, toes, lengths, c), held: [0, 1, 2, 3].map((k) => held.map((row) => row[k])) };
}
