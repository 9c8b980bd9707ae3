// Paths in JavaScript: the path words read as stablemofusion/core/path_plan.py's parse_path reads them, on the same
// lexicon (assets/lexicons/paths.json, given in the site's web.json as "paths", its patterns in JavaScript's syntax),
// and explicit paths checked as its Waypoints.read checks them (the limits from web.json's "path_limits"). Bending
// and following a path are not here: they are the graphs bend.onnx and follow.onnx.

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

// {points: [[x, z], ...], times: [...] | null} from a list of points or {points, times}; RangeError naming the problem.
export function readWaypoints(data, limits) {
  const { max_points: MAX_WAYPOINTS, max_metres: MAX_PATH_METRES, max_speed: MAX_PATH_SPEED, min_travel: MIN_TRAVEL } = limits;
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
