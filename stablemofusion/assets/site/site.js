// The static site: text to motion in the page (runtime/smf.js on ONNX Runtime Web), played on the viewer's stick
// figure. window.smf is the page's API (for tests and pages that embed it):
//   await window.smf.generate({prompt, seconds, seed, footskate: 'off'}) -> the motion; window.smf.lastMotion
//   {joints (frames x 22 x 3 metres), fps, prompt, seed, sequence (a prompt of several parts: [[part, seconds], ...])};
//   window.smf.ready: a promise of the loaded model;
//   window.smf.timings: {loadMs, firstMotionMs, lastMotionMs, threads, backend ('webgpu' or 'wasm')}; await window.smf.file('bvh' | 'glb' | 'json') -> the
//   last motion's download (a string, or bytes for glb).
import { OrbitControls } from './vendor/three/OrbitControls.js';
import { Figure, makeStage } from './figure.js';
import { MotionRuntime } from './runtime/smf.js';
import { glbBytes } from './glb.js';

const $ = (id) => document.getElementById(id);
const started = performance.now();
const smf = { lastMotion: null, timings: {}, generate: null, ready: null, file: null };
let made = null; // the last motion, as generate returned it
window.smf = smf;

// the model: files of model/ fetched from this origin, with progress in bytes
async function load() {
  // WebAssembly on the CPU by default; ?backend=webgpu runs the graphs on WebGPU (what it cannot run falls back)
  const backend = new URLSearchParams(location.search).get('backend') || 'wasm';
  if (backend !== 'wasm' && backend !== 'webgpu') throw new Error(`backend must be wasm or webgpu, got '${backend}'`);
  if (backend === 'webgpu' && !(await fetch('vendor/onnxruntime-web/ort.webgpu.min.mjs', { method: 'HEAD' })).ok) {
    throw new Error('this site was written without ONNX Runtime Web\'s WebGPU build: write it again with '
      + '`smf site --webgpu DIR` (docs/site.md), or open the page without ?backend=webgpu');
  }
  if (backend === 'webgpu' && !(navigator.gpu && await navigator.gpu.requestAdapter().catch(() => null))) {
    throw new Error('this browser offers no WebGPU adapter: open the page without ?backend=webgpu');
  }
  const ort = await import(`./vendor/onnxruntime-web/ort.${backend}.min.mjs`);
  ort.env.logLevel = 'error';
  ort.env.wasm.wasmPaths = new URL('vendor/onnxruntime-web/', location.href).href;
  // threads need cross-origin isolation (COOP/COEP headers); a plain static server gives one thread
  ort.env.wasm.numThreads = self.crossOriginIsolated ? Math.min(4, navigator.hardwareConcurrency || 1) : 1;
  const { Tokenizer } = await import('./vendor/tokenizers/tokenizers.min.mjs');
  let got = 0;
  const read = async (name, kind) => {
    const res = await fetch(`model/${name}`);
    if (!res.ok) throw new Error(`model/${name}: ${res.status} ${res.statusText}`);
    if (kind === 'json') return res.json();
    const total = Number(res.headers.get('content-length')) || 0;
    const reader = res.body.getReader();
    const parts = [];
    let n = 0;
    for (;;) {
      const { done, value } = await reader.read();
      if (done) break;
      parts.push(value);
      n += value.length;
      got += value.length;
      status(`Loading the model: ${(got / 1e6).toFixed(0)} MB${total ? ` (${name} ${Math.round(100 * n / total)}%)` : ''}`);
    }
    const out = new Uint8Array(n);
    let o = 0;
    for (const p of parts) { out.set(p, o); o += p.length; }
    return out;
  };
  // the final stage's float64 graphs run on the WebAssembly build (the WebGPU build carries no float64 kernels)
  let cpuOrt = ort;
  if (backend === 'webgpu') {
    cpuOrt = await import('./vendor/onnxruntime-web/ort.wasm.min.mjs');
    cpuOrt.env.logLevel = 'error';
    cpuOrt.env.wasm.wasmPaths = ort.env.wasm.wasmPaths;
    cpuOrt.env.wasm.numThreads = 1;
  }
  const runtime = await MotionRuntime.load({ ort, cpuOrt, Tokenizer, read, providers: backend === 'webgpu' ? ['webgpu', 'wasm'] : ['wasm'] });
  smf.timings.loadMs = performance.now() - started;
  smf.timings.threads = ort.env.wasm.numThreads;
  smf.timings.backend = backend;
  $('licence-text').textContent = runtime.info.licence;
  // the longest length the form takes: a prompt of several parts is made window by window, one action in one window
  const one = (runtime.info.max_frames / runtime.info.fps).toFixed(1), whole = runtime.info.sequence?.max_seconds;
  if (whole) {
    $('seconds').max = String(whole);
    $('seconds').title = `leave empty: the length is predicted from the text (at most ${one} s for one action, ` +
      `${whole} s for a prompt of several parts)`;
  }
  return runtime;
}
smf.ready = load();

smf.generate = async (request) => {
  const runtime = await smf.ready;
  const t0 = performance.now();
  const motion = await runtime.generate(request);
  const ms = performance.now() - t0;
  smf.timings.lastMotionMs = ms;
  if (smf.timings.firstMotionMs === undefined) smf.timings.firstMotionMs = performance.now() - started;
  smf.lastMotion = { joints: motion.joints, fps: motion.fps, prompt: motion.prompt, seed: motion.seed,
    ...(motion.sequence ? { sequence: motion.sequence } : {}) };
  made = motion;
  show(motion, ms);
  return motion;
};

const DOWNLOADS = { bvh: ['motion.bvh', 'text/plain'], glb: ['motion.glb', 'model/gltf-binary'],
  json: ['motion.json', 'application/json'] };
smf.file = async (format) => {
  const runtime = await smf.ready;
  if (!made) throw new Error('no motion yet: generate one first');
  if (format === 'bvh') return runtime.bvh(made);
  if (format === 'glb') {
    return glbBytes(made.flat, made.frames, runtime.info.skeleton, await runtime.pose(made), made.fps, runtime.info.glb_body);
  }
  if (format === 'json') return JSON.stringify(smf.lastMotion);
  throw new Error(`no download '${format}': choose bvh, glb or json`);
};

// scene
const view = $('view');
const { renderer, scene, camera, controls } = makeStage(view, OrbitControls);
const figure = new Figure(scene);

const player = { joints: null, frames: 0, fps: 20, frame: 0, playing: true, contacts: null };
function setFrame(t) {
  if (!player.joints) return;
  player.frame = Math.max(0, Math.min(player.frames - 1, Math.round(t)));
  const J = player.joints, base = player.frame * 66;
  figure.pose(J, player.frame, player.contacts);
  const dx = J[base] - controls.target.x, dz = J[base + 2] - controls.target.z;
  controls.target.x += dx; controls.target.z += dz;
  camera.position.x += dx; camera.position.z += dz;
  $('scrub').value = String(player.frame);
  $('frame').textContent = `frame ${player.frame + 1} / ${player.frames} (${(player.frame / player.fps).toFixed(2)} s)`;
}
function show(motion, ms) {
  Object.assign(player, { joints: Float32Array.from(motion.joints.flat(2)), frames: motion.frames, fps: motion.fps });
  // the feet the cleanup held, else those its contacts graph counts as planted (footskate off)
  player.contacts = (motion.contacts ?? motion.planted).map((c) => Uint8Array.from(c));
  figure.visible = true;
  $('scrub').max = String(player.frames - 1);
  for (const id of ['scrub', 'play', ...Object.keys(DOWNLOADS)]) $(id).disabled = false;
  setFrame(0);
  // a prompt of several parts: each made in turn, and the status says how it was split
  const parts = motion.sequence ? ` (${motion.sequence.map(([p, s]) => `${p}: ${s.toFixed(1)} s`).join(', then ')})` : '';
  status(`${motion.prompt}: ${motion.frames} frames${parts}, seed ${motion.seed}, made in ${ms.toFixed(0)} ms`);
  $('warning').textContent = [...(motion.outOfDomain
    ? [`"${motion.prompt}" is unlike the actions this model knows (closest: ${motion.closest.map((c) => c[0]).join(', ')}); the motion may not follow it.`]
    : []), ...(motion.warnings ?? [])].join('\n');  // one line each (viewer.css: pre-line)
}
let last = performance.now(), clock = 0;
function loop(now) {
  const dt = (now - last) / 1000;
  last = now;
  if (player.playing && player.joints) {
    clock += dt * player.fps;
    if (clock >= 1) { setFrame((player.frame + Math.floor(clock)) % player.frames); clock -= Math.floor(clock); }
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
$('play').addEventListener('click', () => {
  player.playing = !player.playing;
  $('play').textContent = player.playing ? 'Pause' : 'Play';
});
$('scrub').addEventListener('input', () => { player.playing = false; $('play').textContent = 'Play'; setFrame(Number($('scrub').value)); });
for (const format of Object.keys(DOWNLOADS)) {
  $(format).addEventListener('click', async () => {
    try {
      const [name, type] = DOWNLOADS[format];
      // named after the prompt, as `smf generate` names its files (letters of any script, words joined by _)
      let stem = (smf.lastMotion?.prompt ?? '').toLowerCase().replace(/[^\p{L}\p{N}]+/gu, '_').replace(/^_+|_+$/g, '');
      if (stem.length > 48) { const cut = stem.slice(0, 49).lastIndexOf('_'); stem = stem.slice(0, cut > 0 ? cut : 48); }
      stem = stem || 'motion';
      const url = URL.createObjectURL(new Blob([await smf.file(format)], { type }));
      Object.assign(document.createElement('a'), { href: url, download: `${stem}${name.slice(name.indexOf('.'))}` }).click();
      setTimeout(() => URL.revokeObjectURL(url), 1000);
    } catch (e) {
      status(e.message, true);
    }
  });
}
$('form').addEventListener('submit', async (ev) => {
  ev.preventDefault();
  const seconds = $('seconds').value.trim();
  const seedText = $('seed').value.trim();
  const seed = seedText === '' ? Math.floor(Math.random() * 2 ** 31) : Number(seedText);
  $('generate').disabled = true;
  status('Generating ...');
  try {
    await smf.generate({ prompt: $('prompt').value, seconds: seconds === '' ? undefined : Number(seconds), seed });
  } catch (e) {
    status(e.message, true);
  } finally {
    $('generate').disabled = false;
  }
});
smf.ready.then(() => {
  $('generate').disabled = false;
  status(`Model loaded in ${(smf.timings.loadMs / 1000).toFixed(1)} s. Type a prompt and press Generate.`);
}, (e) => status(`The model could not be loaded: ${e.message}`, true));
