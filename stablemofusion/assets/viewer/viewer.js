// stablemofusion viewer: a three.js skeleton player for the HTTP API (POST /v1/generate, /v1/timeline, /v1/convert)
// and its live mode (WebSocket /v1/stream: the character keeps moving; a new prompt and Enter change what it does).
import * as THREE from 'three';
import { OrbitControls } from '/viewer/vendor/OrbitControls.js';
import { loadGlb, glbJoints } from '/viewer/glb.js';
import { Figure, makeStage } from '/viewer/figure.js';

const JOINT_NAMES = ['pelvis', 'left_hip', 'right_hip', 'spine1', 'left_knee', 'right_knee', 'spine2', 'left_ankle',
  'right_ankle', 'spine3', 'left_foot', 'right_foot', 'neck', 'left_collar', 'right_collar', 'head', 'left_shoulder',
  'right_shoulder', 'left_elbow', 'right_elbow', 'left_wrist', 'right_wrist']; // the .glb's joint nodes
const DOWNLOADS = { bvh: 'motion.bvh', npy: 'motion_joints.npy', glb: 'motion.glb' };
const LIVE_KEEP = 1200; // frames of a live stream kept for the contacts and the frame counter (60 s at 20 fps)

const $ = (id) => document.getElementById(id);
const state = { joints: null, frames: 0, fps: 20, frame: 0, playing: true, contacts: null, request: null, ready: false,
  character: null, live: null };
window.smf = state; // for tests and the console

// scene
const view = $('view');
const { renderer, scene, camera, controls, floor } = makeStage(view, OrbitControls);
const figure = new Figure(scene);

// a path drawn on the floor: click points with "path" ticked; sent as the request's "path" (docs/paths.md)
const drawn = { points: [], line: null, marks: [] };
const pathMaterial = new THREE.LineBasicMaterial({ color: 0x1f77b4 });
const markGeometry = new THREE.SphereGeometry(0.06, 12, 8);
function showPath() {
  if (drawn.line) scene.remove(drawn.line);
  drawn.marks.forEach((m) => scene.remove(m));
  drawn.marks = drawn.points.map(([x, z]) => {
    const m = new THREE.Mesh(markGeometry, pathMaterial);
    m.position.set(x, 0.01, z);
    scene.add(m);
    return m;
  });
  drawn.line = new THREE.Line(new THREE.BufferGeometry().setFromPoints(drawn.points.map(([x, z]) => new THREE.Vector3(x, 0.01, z))),
    pathMaterial);
  scene.add(drawn.line);
  $('clear-path').hidden = drawn.points.length === 0;
}
const floorPlane = new THREE.Plane(new THREE.Vector3(0, 1, 0), 0);
renderer.domElement.addEventListener('click', (ev) => {
  if (!$('draw').checked) return;
  const r = renderer.domElement.getBoundingClientRect();
  const ndc = new THREE.Vector2(((ev.clientX - r.left) / r.width) * 2 - 1, -((ev.clientY - r.top) / r.height) * 2 + 1);
  const ray = new THREE.Raycaster();
  ray.setFromCamera(ndc, camera);
  const hit = ray.ray.intersectPlane(floorPlane, new THREE.Vector3());
  if (!hit) return;
  drawn.points.push([Math.round(hit.x * 100) / 100, Math.round(hit.z * 100) / 100]);
  showPath();
  status(`path: ${drawn.points.length} point${drawn.points.length > 1 ? 's' : ''} (tick off "path" to move the camera)`);
});
$('clear-path').addEventListener('click', () => { drawn.points = []; showPath(); });
$('draw').addEventListener('change', () => {
  controls.enabled = !$('draw').checked;  // clicks place points, not turn the camera
  if ($('draw').checked) $('seconds').value = '';  // the path's own length unless one is typed
});
window.smf.path = drawn;


// motion
// `contacts`: the feet the server's footskate cleanup held, or its detector counts as planted (4 x frames of 0/1);
// none for a .glb read in the page
function setMotion(joints, frames, fps, label, contacts = null) {
  state.joints = Float32Array.from(joints.flat(2));
  state.frames = frames;
  state.fps = fps;
  state.contacts = contacts ? contacts.map((c) => Uint8Array.from(c)) : null;
  $('scrub').max = String(frames - 1);
  $('scrub').disabled = false;
  $('play').disabled = false;
  figure.visible = true;
  const r = state.joints;
  controls.target.set(r[0], 0.85, r[2]);
  camera.position.set(r[0] + 3, 1.7, r[2] + 4.5);
  setFrame(0);
  state.playing = true;
  $('play').textContent = 'Pause';
  status(label);
  state.ready = true;
}

function setFrame(t) {
  if (!state.joints) return;
  state.frame = Math.max(0, Math.min(state.frames - 1, Math.round(t)));
  const base = state.frame * 22 * 3, J = state.joints;
  figure.pose(J, state.frame, state.contacts);
  // follow the root over the floor: the camera keeps its offset from the body as it travels
  const dx = J[base] - controls.target.x, dz = J[base + 2] - controls.target.z;
  controls.target.x += dx;
  controls.target.z += dz;
  camera.position.x += dx;
  camera.position.z += dz;
  if (state.live) floor.position.set(Math.round(J[base] / 0.5) * 0.5, 0, Math.round(J[base + 2] / 0.5) * 0.5);
  if (state.character) state.character.mixer.setTime(state.frame / state.fps);
  $('scrub').value = String(state.frame);
  $('frame').textContent = `frame ${state.frame + 1} / ${state.frames} (${(state.frame / state.fps).toFixed(2)} s)`;
}
window.smf.setFrame = setFrame;

let last = performance.now(), clock = 0;
function loop(now) {
  const dt = (now - last) / 1000;
  last = now;
  if (state.live && state.live.start !== null) {  // live: the frame of the play clock (held if none arrived yet)
    const t = Math.floor((now - state.live.start) / 1000 * state.fps) - state.live.offset;
    setFrame(Math.min(t, state.frames - 1));
  } else if (state.playing && state.joints) {
    clock += dt * state.fps;
    if (clock >= 1) {
      setFrame((state.frame + Math.floor(clock)) % state.frames);
      clock -= Math.floor(clock);
    }
  }
  controls.update();
  renderer.render(scene, camera);
  requestAnimationFrame(loop);
}
requestAnimationFrame(loop);

// UI
function status(text, error = false) {
  $('status').textContent = text;
  $('status').className = error ? 'error' : '';
}

async function post(url, body, headers) {
  const res = await fetch(url, { method: 'POST', body, headers });
  if (!res.ok) {
    let message = `${res.status} ${res.statusText}`;
    try { message = (await res.json()).error || message; } catch (e) { /* not JSON */ }
    throw new Error(message);
  }
  return res;
}

// "walk forward:4; wave both hands:3" -> [{prompt, seconds}, ...]; null for a plain prompt (one without ';'
// that does not end in ':SECONDS')
function parseTimeline(text) {
  if (!text.includes(';') && !/:\s*\d+(\.\d+)?\s*$/.test(text)) return null;
  const segments = [];
  for (const part of text.split(';').map((p) => p.trim()).filter(Boolean)) {
    const i = part.lastIndexOf(':');
    const seconds = i < 0 ? NaN : Number(part.slice(i + 1));
    if (i <= 0 || !Number.isFinite(seconds) || part.slice(i + 1).trim() === '') {
      throw new Error(`timeline entry "${part}" is not PROMPT:SECONDS`);
    }
    segments.push({ prompt: part.slice(0, i).trim(), seconds });
  }
  return segments;
}

$('form').addEventListener('submit', async (ev) => {
  ev.preventDefault();
  if ($('live').checked) { livePrompt($('prompt').value); return; }
  const common = { footskate: $('footskate').value };
  if ($('seed').value.trim() !== '') common.seed = Number($('seed').value);  // else the server draws one
  if ($('adapter').value !== '') common.adapter = $('adapter').value;  // else the base model
  state.ready = false;
  $('generate').disabled = true;
  status('generating...');
  $('warning').textContent = '';
  try {
    const segments = parseTimeline($('prompt').value);
    let body = { ...common, segments };
    if (!segments) {  // one prompt; no seconds: the model predicts the length from the text (or the path's)
      body = { ...common, prompt: $('prompt').value };
      if ($('seconds').value.trim() !== '') body.seconds = Number($('seconds').value);
      if (drawn.points.length >= 2) body.path = drawn.points;
    }
    const endpoint = segments ? '/v1/timeline' : '/v1/generate';
    const res = await post(endpoint, JSON.stringify(body), { 'Content-Type': 'application/json' });
    const m = await res.json();
    state.request = { ...body, seed: m.seed };
    state.endpoint = endpoint;
    setMotion(m.joints, m.frames, m.fps, `"${m.prompt}": ${m.frames} frames, seed ${m.seed}`, m.contacts);
    for (const f of Object.keys(DOWNLOADS)) $(f).disabled = false;
    await showCharacter();  // the server converts the motion it just made (no second generation)
    // the answer's warnings (out of domain, a length clamped) and how a prompt of several parts was split
    const warnings = m.warnings ?? (m.warning ? [m.warning] : []);
    const notes = [...warnings.map((w) => `Warning: ${w}`),
      ...(m.sequence ? [`made part after part: ${m.sequence.map((p) => `"${p.prompt}" ${p.seconds.toFixed(1)} s`).join(', then ')}`] : [])];
    if (notes.length) status(`${$('status').textContent}. ${notes.join('. ')}`, warnings.length > 0);
    $('warning').textContent = notes.join('\n');  // the banner above the view, one line each
  } catch (e) {
    status(e.message, true);
  } finally {
    $('generate').disabled = false;
  }
});

$('play').addEventListener('click', () => {
  state.playing = !state.playing;
  $('play').textContent = state.playing ? 'Pause' : 'Play';
});
$('scrub').addEventListener('input', () => {
  state.playing = false;
  $('play').textContent = 'Play';
  setFrame(Number($('scrub').value));
});

async function download(format) {
  if (!state.request) return;
  try {
    const res = await post(`${state.endpoint}?format=${format}`, JSON.stringify(state.request),
      { 'Content-Type': 'application/json' });
    const a = document.createElement('a');
    a.href = URL.createObjectURL(await res.blob());
    a.download = DOWNLOADS[format];
    a.click();
    URL.revokeObjectURL(a.href);
  } catch (e) {
    status(e.message, true);
  }
}
for (const f of Object.keys(DOWNLOADS)) $(f).addEventListener('click', () => download(f));

// the skinned character: the same request as a .glb (or a dropped .glb), loaded with three.js's GLTFLoader and
// played in step with the skeleton
function dropCharacter() {
  if (state.character) scene.remove(state.character.root);
  state.character = null;
}
async function setCharacter(buffer) {
  dropCharacter();
  state.character = await loadGlb(scene, buffer);
  state.character.root.visible = $('body').checked;
  setFrame(state.frame);
}
async function showCharacter() {
  dropCharacter();
  if (!$('body').checked || !state.request) return;
  const res = await post(`${state.endpoint}?format=glb`, JSON.stringify(state.request),
    { 'Content-Type': 'application/json' });
  await setCharacter(await res.arrayBuffer());
}
$('body').addEventListener('change', () => {
  if (state.character) state.character.root.visible = $('body').checked;
  else showCharacter().catch((e) => status(e.message, true));
});
window.smf.glbJoints = (f) => (state.character ? glbJoints(state.character, JOINT_NAMES, f) : null);

// drop a local .bvh or .npy: the server reads it (never unpickled) and returns its joints
window.addEventListener('dragover', (ev) => { ev.preventDefault(); document.body.classList.add('dragging'); });
window.addEventListener('dragleave', () => document.body.classList.remove('dragging'));
window.addEventListener('drop', async (ev) => {
  ev.preventDefault();
  document.body.classList.remove('dragging');
  const file = ev.dataTransfer.files[0];
  if (!file) return;
  state.ready = false;
  status(`reading ${file.name}...`);
  try {
    if (file.name.toLowerCase().endsWith('.glb')) {  // read here: the character and its joints, frame by frame
      state.request = null;
      await setCharacter(await file.arrayBuffer());
      const c = state.character;
      const frames = c.frames || Math.round(c.duration * c.fps) + 1;
      const joints = Array.from({ length: frames }, (_, f) => glbJoints(c, JOINT_NAMES, f));
      for (const f of Object.keys(DOWNLOADS)) $(f).disabled = true;
      setMotion(joints, frames, c.fps, `${file.name}: ${frames} frames`);
      return;
    }
    dropCharacter();
    const res = await post(`/v1/convert?filename=${encodeURIComponent(file.name)}`, await file.arrayBuffer(),
      { 'Content-Type': 'application/octet-stream' });
    const m = await res.json();
    state.request = null;
    for (const f of Object.keys(DOWNLOADS)) $(f).disabled = true;
    setMotion(m.joints, m.frames, m.fps, `${file.name}: ${m.frames} frames`, m.contacts);
  } catch (e) {
    status(e.message, true);
  }
});

// live mode: one endless motion over the WebSocket /v1/stream; frames arrive a little ahead of their play time
// and are appended; the play clock starts with the first frames
function liveAppend(m) {
  const L = state.live;
  if (L.base) continueFrom(m, L);
  const flat = Float32Array.from(m.joints.flat(2));
  const keep = state.joints && state.frames ? state.joints.subarray(0, state.frames * 66) : new Float32Array(0);
  let joints = new Float32Array(keep.length + flat.length);
  joints.set(keep);
  joints.set(flat, keep.length);
  // the planted feet the server found for these frames, after those kept
  let contacts = m.contacts.map((c, k) => Uint8Array.from([...(state.contacts ? state.contacts[k].subarray(0, state.frames) : []), ...c]));
  let frames = state.frames + m.joints.length;
  if (frames > LIVE_KEEP) {  // drop the oldest frames (the clock keeps counting from the stream's start)
    const drop = frames - LIVE_KEEP;
    joints = joints.slice(drop * 66);
    contacts = contacts.map((c) => c.slice(drop));
    frames -= drop;
    L.offset += drop;
  }
  state.joints = joints;
  state.frames = frames;
  state.fps = m.fps;
  state.contacts = contacts;
  L.received = m.start + m.joints.length;
  L.index = m.prompt_index;
  if (L.start === null) {
    L.start = performance.now();
    figure.visible = true;
    controls.target.set(joints[0], 0.85, joints[2]);
    camera.position.set(joints[0] + 3, 1.7, joints[2] + 4.5);
    state.ready = true;
  }
  // frames that arrive after their play time: the stream is behind (a busy machine); said, never hidden
  const playing = ((performance.now() - L.start) / 1000) * m.fps;  // the play clock, in stream frames
  const late = Math.max(0, Math.min(m.joints.length, Math.ceil(playing - m.start)));
  L.late += late;
  const p = L.prompts[m.prompt_index];
  if (p === undefined) return;
  if (late > 0) status(`live: "${p}" (frame ${L.received}): behind by ${((playing - m.start) / m.fps).toFixed(1)} s, ${L.late} late frames`, true);
  else status(`live: "${p}" (frame ${L.received})`);
}

function livePrompt(text) {
  if (!state.live) liveStart();
  const L = state.live;
  const first = { prompt: text };
  if ($('seed').value.trim() !== '') first.seed = Number($('seed').value);
  if (!L.prompts.length) L.seed = first.seed;
  const message = JSON.stringify(L.prompts.length ? { prompt: text } : first);
  L.prompts.push(text);
  if (L.ws.readyState === WebSocket.OPEN) L.ws.send(message);
  else L.ws.addEventListener('open', () => L.ws.send(message), { once: true });
}

// a stream that broke (its server died: behind a load balancer another replica takes the new connection) is opened
// again with its prompt and seed; the new stream starts from rest at the origin, so its frames are turned and moved
// to continue from where the character stands, and its frames and prompts counted after the old ones
const LIVE_RECONNECTS = 5; // tries in a row without a frame in between
function continueFrom(m, L) {
  if (!L.place) {
    const last = state.joints.subarray((state.frames - 1) * 66, state.frames * 66);
    const first = m.joints[0];
    const heading = (hips) => Math.atan2(hips[2] - hips[5], hips[0] - hips[3]); // left hip minus right hip (x, z)
    const turn = heading(last.subarray(3, 9)) - heading([...first[1], ...first[2]]);
    L.place = { c: Math.cos(turn), s: Math.sin(turn), fx: first[0][0], fz: first[0][2], tx: last[0], tz: last[2] };
  }
  const { c, s, fx, fz, tx, tz } = L.place;
  m.joints = m.joints.map((frame) => frame.map(([x, y, z]) => {
    const px = x - fx, pz = z - fz;
    return [tx + c * px - s * pz, y, tz + s * px + c * pz];
  }));
  m.start += L.base;
  m.prompt_index += L.indexBase;
}

function liveConnect() {
  const L = state.live;
  const proto = location.protocol === 'https:' ? 'wss:' : 'ws:';
  const ws = new WebSocket(`${proto}//${location.host}/v1/stream`);
  L.ws = ws;
  const current = () => state.live !== null && state.live.ws === ws;  // not stopped or replaced since
  ws.addEventListener('message', (ev) => {
    if (!current()) return;  // frames already in flight when the stream was stopped
    const m = JSON.parse(ev.data);
    if (m.type === 'frames') { L.tries = 0; liveAppend(m); }
    else if (m.type === 'error') { state.live.failed = true; status(m.error, true); }
  });
  ws.addEventListener('close', (ev) => {
    if (!current()) return;
    // 1000: ended on purpose; 1013: the server's limit of streams; an error said: stop. Anything else: connect again
    if (ev.code === 1000 || ev.code === 1013 || L.failed || !L.prompts.length || L.tries >= LIVE_RECONNECTS) {
      liveStop(false);
      return;
    }
    L.tries += 1;
    L.reconnects += 1;
    status(`live: the connection broke; connecting again (${L.tries} of ${LIVE_RECONNECTS})`, true);
    setTimeout(() => {
      if (!current()) return;
      L.base = L.received;
      L.indexBase = L.prompts.length - 1;
      L.place = null;
      const first = { prompt: L.prompts[L.prompts.length - 1] };
      if (L.seed !== undefined) first.seed = L.seed;
      liveConnect();
      L.ws.addEventListener('open', () => L.ws.send(JSON.stringify(first)), { once: true });
    }, 300 * L.tries);
  });
  return ws;
}

function liveStart() {
  dropCharacter();
  state.request = null;
  for (const f of Object.keys(DOWNLOADS)) $(f).disabled = true;
  state.joints = null;
  state.frames = 0;
  state.ready = false;
  $('scrub').disabled = true;
  $('play').disabled = true;
  $('generate').textContent = 'Send';
  state.live = { ws: null, start: null, offset: 0, received: 0, index: -1, prompts: [], late: 0, tries: 0,
                 reconnects: 0, base: 0, indexBase: 0, place: null, seed: undefined };
  liveConnect();
  status('live: connecting...');
}

function liveStop(send = true) {
  const L = state.live;
  if (!L) return;
  state.live = null;
  floor.position.set(0, 0, 0);
  if (send && L.ws.readyState === WebSocket.OPEN) L.ws.send(JSON.stringify({ stop: true }));
  $('generate').textContent = 'Generate';
  $('live').checked = false;
  if (state.joints) {  // what was streamed stays, to play and scrub
    $('scrub').max = String(state.frames - 1);
    $('scrub').disabled = false;
    $('play').disabled = false;
    state.playing = true;
    $('play').textContent = 'Pause';
  }
  // a server's error stays on screen; a stream that only ran late says so beside its end
  if (!L.failed) status(`live stream ended: ${L.received} frames${L.late ? ` (${L.late} arrived late)` : ''}`, L.late > 0);
}

$('live').addEventListener('change', () => {
  if ($('live').checked) {
    $('generate').textContent = 'Send';
    livePrompt($('prompt').value);
  } else {
    liveStop();
  }
});

// the adapters the server loaded (smf serve --adapter): offered beside the base model; the footskate modes its
// runtime runs (the portable runtime has no 'loop')
(async () => {
  try {
    const health = await (await fetch('/v1/health')).json();
    const modes = health.limits && health.limits.footskate;
    if (modes) for (const option of [...$('footskate').options]) option.hidden = !modes.includes(option.value);
    for (const name of health.adapters || []) {
      const option = document.createElement('option');
      option.value = option.textContent = name;
      $('adapter').append(option);
    }
    $('adapter-label').hidden = !(health.adapters || []).length;
  } catch (e) { /* no health: the base model only */ }
})();
