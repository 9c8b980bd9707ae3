// Paths from words in JavaScript: the twin of stablemofusion/path_plan.py (parse_path, bend; its docstring explains
// them), on the same lexicon (assets/lexicons/paths.json, given in the site's web.json as "paths", its patterns in
// JavaScript's syntax). Features are flat Float64Arrays (T x D, HumanML3D's 263 per frame).

const ZIGZAG_DEGREES = 45, ZIGZAG_LEGS = 4, ZIGZAG_END = 0.85;
const TURN_SPAN = [0.3, 0.7], BACK_SPAN = [0.42, 0.58];
const MIN_MODEL_TURN = 30, MIN_TRAVEL = 0.5;
const rad = (d) => d * Math.PI / 180;

// the lexicon's regular expressions, compiled once per lexicon
const COMPILED = new WeakMap();
function compile(lex) {
  if (!COMPILED.has(lex)) {
    COMPILED.set(lex, { paths: lex.paths.map((e) => new RegExp(`(?:${e.pattern})${lex.direction_suffix}`)),
      body: new RegExp(`${lex.body_words}(?:\\W+\\w+){0,2}\\W*$`), move: new RegExp(lex.move_words),
      side: new RegExp(`${lex.right_words}|${lex.left_words}`), right: new RegExp(lex.right_words),
      left: new RegExp(lex.left_words), run: new RegExp(lex.run_words), direction: new RegExp(lex.direction_words, 'gi') });
  }
  return COMPILED.get(lex);
}

// {kind, angle (degrees, positive left), side, prompt (what the model is given), words, seconds} or null.
export function parsePath(prompt, lex) {
  const text = prompt.toLowerCase();
  const re = compile(lex);
  for (let k = 0; k < lex.paths.length; k++) {
    const entry = lex.paths[k];
    const m = re.paths[k].exec(text);
    if (!m) continue;
    const start = m.index, end = m.index + m[0].length;
    if (re.body.test(text.slice(0, start))) continue; // the path of a body part ("swings both arms back and forth")
    const outside = `${text.slice(0, start)} ${text.slice(end)}`;
    if (entry.needs_move && !re.move.test(outside)) continue;
    const words = m[0];
    const where = re.side.test(words) ? words : text;
    const right = re.right.exec(where), left = re.left.exec(where);
    const side = right && !(left && left.index < right.index) ? 'right' : 'left';
    let angle = entry.angle === 'degrees' ? Number(m.groups.degrees) : Number(entry.angle);
    if (side === 'right') angle = -angle;
    const gait = re.run.test(text) ? 'run' : 'walk';
    const move = re.move.test(outside) ? '' : (gait === 'run' ? 'runs' : 'walks');
    const model = entry.model.replace('{side}', side).replace('{move}', move).replace('{words}', prompt.slice(start, end));
    let rest = `${prompt.slice(0, start)} ${model} ${prompt.slice(end)}`;
    rest = rest.replace(re.direction, ' ');
    rest = rest.replace(/\s+/g, ' ').replace(/\s+([,.;])/g, '$1').replace(/^[ ,]+|[ ,]+$/g, '');
    return { kind: entry.kind, angle, side, prompt: rest || prompt, words: words.trim(),
      seconds: entry.seconds ? entry.seconds[gait] : null };
  }
  return null;
}

const smoothstep = (x) => { const c = Math.min(Math.max(x, 0), 1); return c * c * (3 - 2 * c); };

// how far along the motion each frame is, 0 .. 1: by the root's travelled distance, or by time
function progress(f, T, D) {
  const u = new Float64Array(T);
  for (let t = 1; t < T; t++) u[t] = u[t - 1] + Math.hypot(f[(t - 1) * D + 1], f[(t - 1) * D + 2]);
  const total = u[T - 1];
  for (let t = 0; t < T; t++) u[t] = total < MIN_TRAVEL ? t / (T - 1) : u[t] / total;
  return u;
}

// the body's facing (radians, positive left, unwrapped): the root's heading plus the hips' facing in its frame
export function facing(f, T, D) {
  const out = new Float64Array(T);
  let heading = 0, prev = null;
  for (let t = 0; t < T; t++) {
    if (t > 0) heading -= 2 * f[(t - 1) * D];
    const ax = f[t * D + 4] - f[t * D + 7], az = f[t * D + 6] - f[t * D + 9];
    let local = Math.atan2(-az, ax);
    if (prev !== null) local += 2 * Math.PI * Math.round((prev - local) / (2 * Math.PI));
    prev = local;
    out[t] = heading + local;
  }
  return out;
}

function headingOffset(spec, f, T, D) {
  const u = progress(f, T, D), a = rad(spec.angle);
  const face0 = facing(f, T, D), face = face0.map((v) => v - face0[0]);
  const out = new Float64Array(T);
  if (spec.kind === 'turn') {
    if (Math.abs(face[T - 1]) * 180 / Math.PI >= MIN_MODEL_TURN) {
      for (let t = 0; t < T; t++) out[t] = face[t] * (a / face[T - 1] - 1);
    } else {
      for (let t = 0; t < T; t++) out[t] = a * smoothstep((t / (T - 1) - TURN_SPAN[0]) / (TURN_SPAN[1] - TURN_SPAN[0])) - face[t];
    }
    return out;
  }
  if (spec.kind === 'strafe') return face.map((v) => -v);
  for (let t = 0; t < T; t++) {
    let target;
    if (spec.kind === 'arc') target = a * u[t];
    else if (spec.kind === 'back') target = a * smoothstep((u[t] - BACK_SPAN[0]) / (BACK_SPAN[1] - BACK_SPAN[0]));
    else if (spec.kind === 'zigzag') {
      target = rad(ZIGZAG_DEGREES) * Math.min(Math.max(1.5 * Math.sin(Math.PI * ZIGZAG_LEGS * Math.min(u[t] / ZIGZAG_END, 1)), -1), 1);
    } else throw new Error(`unknown path kind ${spec.kind}`);
    out[t] = target - face[T - 1] * u[t];
  }
  return out;
}

// Raw features (T x D) whose facing follows `spec`, turned about the planted foot (a copy): `joints` the features'
// joints (T x J x 3), `planted` their contacts (4 x T, the contacts graph's), `feet` the four foot joints.
export function bend(features, joints, planted, T, D, J, spec, feet) {
  if (!spec || T < 2) return features;
  const f = Float64Array.from(features);
  const extra = headingOffset(spec, f, T, D);
  // the root's path once turned: each step with its frame, about the foot planted in both frames
  const at = (t, j) => [joints[(t * J + j) * 3], joints[(t * J + j) * 3 + 2]];
  const turn = (t, v) => [Math.cos(extra[t]) * v[0] + Math.sin(extra[t]) * v[1], -Math.sin(extra[t]) * v[0] + Math.cos(extra[t]) * v[1]];
  const path = [[0, 0]];
  for (let t = 0; t + 1 < T; t++) {
    const r0 = at(t, 0), r1 = at(t + 1, 0);
    const step = turn(t + 1, [r1[0] - r0[0], r1[1] - r0[1]]);
    const both = feet.map((j, k) => planted[k][t] && planted[k][t + 1]);
    const n = both.filter(Boolean).length;
    if (n) {
      const arm = [0, 0];
      feet.forEach((j, k) => { if (both[k]) { const p = at(t, j); arm[0] += p[0] / n; arm[1] += p[1] / n; } });
      arm[0] -= r0[0]; arm[1] -= r0[1];
      const a0 = turn(t, arm), a1 = turn(t + 1, arm);
      step[0] += a0[0] - a1[0]; step[1] += a0[1] - a1[1];
    }
    path.push([path[t][0] + step[0], path[t][1] + step[1]]);
  }
  for (let t = 0; t + 1 < T; t++) f[t * D] -= (extra[t + 1] - extra[t]) / 2;
  followPath(f, T, D, path); // each step into the body frame of the frame it leads to
  return f;
}

// ---- explicit paths: waypoints (stablemofusion/path_plan.py: Waypoints, follow_waypoints, place)
const MAX_WAYPOINTS = 256, MAX_PATH_METRES = 200, MAX_PATH_SPEED = 12, TANGENT_SPAN = 0.3;

// {points: [[x, z], ...], times: [...] | null} from a list of points or {points, times}; RangeError naming the problem.
export function readWaypoints(data) {
  const body = Array.isArray(data) ? { points: data } : (data || {});
  const extra = Object.keys(body).filter((k) => k !== 'points' && k !== 'times');
  if (extra.length) throw new RangeError(`a path has 'points' and optionally 'times', not ${extra.join(', ')}`);
  const points = body.points;
  if (!Array.isArray(points) || points.length < 2 || points.length > MAX_WAYPOINTS
      || !points.every((p) => Array.isArray(p) && p.length === 2 && p.every(Number.isFinite))) {
    throw new RangeError(`a path is 2 to ${MAX_WAYPOINTS} [x, z] points of finite numbers (metres)`);
  }
  const far = Math.max(...points.map((p) => Math.max(Math.abs(p[0]), Math.abs(p[1]))));
  if (far > MAX_PATH_METRES) throw new RangeError(`path points must lie within ${MAX_PATH_METRES} m of the origin, got ${far.toPrecision(3)} m`);
  const cum = [0];
  for (let k = 1; k < points.length; k++) {
    const step = Math.hypot(points[k][0] - points[k - 1][0], points[k][1] - points[k - 1][1]);
    if (step < 1e-6) throw new RangeError("a path's consecutive points must differ");
    cum.push(cum[k - 1] + step);
  }
  const length = cum[cum.length - 1];
  if (length > MAX_PATH_METRES || length < MIN_TRAVEL) {
    throw new RangeError(`a path must be ${MIN_TRAVEL} to ${MAX_PATH_METRES} m long, got ${length.toFixed(2)} m`);
  }
  const times = body.times ?? null;
  if (times !== null && (!Array.isArray(times) || times.length !== points.length || !times.every(Number.isFinite)
      || times[0] !== 0 || times.some((t, k) => k > 0 && t <= times[k - 1]))) {
    throw new RangeError('path times are one per point, from 0, increasing (seconds)');
  }
  if (times !== null) {
    for (let k = 1; k < points.length; k++) {
      const speed = (cum[k] - cum[k - 1]) / (times[k] - times[k - 1]);
      if (speed > MAX_PATH_SPEED) {
        throw new RangeError(`a path's times ask for ${speed.toPrecision(3)} m/s between points ${k} and ${k + 1}; at most ${MAX_PATH_SPEED} m/s`);
      }
    }
  }
  return { points, times, cum, length };
}

// How long following it takes (seconds, whole multiples of `multiple` frames at `fps`): its last time, else its length
// at the prompt's gait's speed.
export function waypointSeconds(wp, prompt, lex, fps, multiple) {
  const seconds = wp.times ? wp.times[wp.times.length - 1]
    : wp.length / lex.speeds[compile(lex).run.test(prompt.toLowerCase()) ? 'run' : 'walk'];
  return Math.max(1, Math.round(seconds * fps / multiple)) * multiple / fps;
}

const interp = (x, xs, ys) => {
  if (x <= xs[0]) return ys[0];
  for (let k = 1; k < xs.length; k++) if (x <= xs[k]) return ys[k - 1] + (ys[k] - ys[k - 1]) * (x - xs[k - 1]) / (xs[k] - xs[k - 1]);
  return ys[ys.length - 1];
};
const along = (wp, s) => [interp(s, wp.cum, wp.points.map((p) => p[0])), interp(s, wp.cum, wp.points.map((p) => p[1]))];

// Raw features whose root runs along the path, facing its way, in the features' frame; and {start, origin}: how to
// place the finished joints in the path's frame (placeJoints).
export function followWaypoints(features, T, D, wp, fps) {
  const f = Float64Array.from(features);
  const u = progress(f, T, D);
  const s = Array.from({ length: T }, (_, t) => (wp.times ? interp(t / fps, wp.times, wp.cum) : u[t] * wp.length));
  const p = s.map((v) => along(wp, v));
  const heading = new Float64Array(T);
  s.forEach((v, t) => {
    const a = along(wp, v + TANGENT_SPAN), b = along(wp, v - TANGENT_SPAN);
    let h = Math.atan2(a[0] - b[0], a[1] - b[1]);
    if (t > 0) h += 2 * Math.PI * Math.round((heading[t - 1] - h) / (2 * Math.PI));
    heading[t] = h;
  });
  const face = facing(f, T, D);
  const start = heading[0] - face[0];
  const c = Math.cos(-start), sn = Math.sin(-start);
  const local = p.map(([x, z]) => {
    const rx = x - p[0][0], rz = z - p[0][1];
    return [c * rx + sn * rz, -sn * rx + c * rz];
  });
  const extra = Array.from({ length: T }, (_, t) => heading[t] - start - face[t]);
  for (let t = 0; t + 1 < T; t++) f[t * D] -= (extra[t + 1] - extra[t]) / 2;
  followPath(f, T, D, local);
  return { features: f, start, origin: p[0] };
}

// Root velocities set so that the root follows `path` (T x [x, z], from the origin) under the features' headings.
function followPath(f, T, D, path) {
  let half = 0;
  for (let t = 0; t + 1 < T; t++) {
    half += f[t * D];
    const c = Math.cos(2 * half), s = Math.sin(2 * half);
    const dx = path[t + 1][0] - path[t][0], dz = path[t + 1][1] - path[t][1];
    f[t * D + 1] = dx * c + dz * s;
    f[t * D + 2] = -dx * s + dz * c;
  }
  f[(T - 1) * D + 1] = f[(T - 2) * D + 1];
  f[(T - 1) * D + 2] = f[(T - 2) * D + 2];
}

// Finished joints (T x J x 3, the first root at the origin) turned by `start` about +Y and moved to `origin` (in place).
export function placeJoints(x, T, J, start, origin) {
  const c = Math.cos(start), s = Math.sin(start);
  for (let i = 0; i < T * J; i++) {
    const px = x[i * 3], pz = x[i * 3 + 2];
    x[i * 3] = c * px + s * pz + origin[0];
    x[i * 3 + 2] = -s * px + c * pz + origin[1];
  }
  return x;
}
