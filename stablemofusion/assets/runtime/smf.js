// Text to motion in JavaScript on the portable graphs (a folder written by `smf site`, model/): the JavaScript twin
// of the Python ONNX backend (stablemofusion/backends/onnx_backend.py) for one prompt: the same tokenizer, graphs, sampler table and seeded noise,
// so the same prompt, seed and length give the same joints. The final stage is not written here: following a path
// (bend.onnx, follow.onnx), decoding and the rigid fit (rigid.onnx), the cleanup (cleanup.onnx) and the contacts
// (contacts.onnx) are the Python's own functions exported as graphs, run like the model's. It runs in a browser and
// in Node.js; the caller passes ONNX Runtime (onnxruntime-web) and the Tokenizer class (@huggingface/tokenizers) and
// a function that reads a file of the folder.
import { normal, uniform } from './noise.js';
import { parsePath, placeJoints, readWaypoints, waypointSeconds } from './paths.js';
import { bvhText, recentre } from './motion.js';
import { planWindows, roundHalfEven, shareSeconds, splitSequence, spreadSeconds } from './sequence.js';

const SCRIPTS = ['Cyrillic', 'Greek', 'Arabic', 'Hebrew', 'Devanagari', 'Thai', 'Armenian', 'Georgian', 'Bengali',
  'Tamil', 'Ethiopic'];

// Why a prompt is not English ('Cyrillic script', 'French words', 'no words'), or null: the Python's rule
// (stablemofusion/core/language.py) on its word lists (web.json's "languages").
export function notEnglish(prompt, lex) {
  const letters = prompt.match(/\p{L}/gu) ?? [];
  if (!letters.length) return 'no words';
  const other = letters.find((c) => !/\p{Script=Latin}/u.test(c));
  if (other) {
    if (/[\p{Script=Han}\p{Script=Hiragana}\p{Script=Katakana}\p{Script=Hangul}]/u.test(other)) return 'Chinese, Japanese or Korean script';
    return `${SCRIPTS.find((s) => new RegExp(`\\p{Script=${s}}`, 'u').test(other)) ?? 'Another'} script`;
  }
  const words = prompt.toLowerCase().match(/\p{L}+/gu) ?? [];
  const count = (code) => words.filter((w) => lex.words[code].includes(w)).length;
  const english = count('en');
  let best = 0, language = null;
  for (const code of Object.keys(lex.words)) {
    if (code === 'en') continue;
    const c = count(code);
    if (c > best || (c === best && c > 0 && code > language)) [best, language] = [c, code];  // ties: as Python's max
  }
  if ((best >= lex.min_words && best > english) || (best >= 1 && english === 0 && words.length >= lex.min_words_alone)) {
    return `${lex.names[language]} words`;
  }
  return null;
}

// A length in seconds given by the user, as a number; RangeError unless it is a finite number above 0.
function checkSeconds(seconds) {
  const s = Number(seconds);
  if (!(s > 0) || !Number.isFinite(s)) throw new RangeError(`seconds must be more than 0, got ${seconds}`);
  return s;
}

export class MotionRuntime {
  // read(name, kind) -> Promise of the file `name` of the model folder: kind 'json' (an object) or 'bytes'
  // (a Uint8Array); onProgress(loaded, total) after each file; providers: ONNX Runtime's execution providers
  // (['webgpu', 'wasm'] with its WebGPU build: what WebGPU cannot run falls back to WebAssembly); cpuOrt: the ONNX
  // Runtime that runs the final stage's float64 graphs (its WebAssembly build; `ort` unless that is the WebGPU build).
  static async load({ ort, cpuOrt = ort, Tokenizer, read, onProgress = () => {}, providers = ['wasm'] }) {
    const info = await read('web.json', 'json');
    const files = Object.keys(info.files);
    const total = files.length + 2;
    let loaded = 0;
    const step = () => onProgress(++loaded, total);
    const tokenizer = new Tokenizer(await read(info.tokenizer, 'json'), {});
    step();
    const actions = new Float32Array((await read(info.actions.embeddings, 'bytes')).slice().buffer);
    step();
    const sessions = {}, later = {};
    for (const name of files) {
      const bytes = await read(info.files[name], 'bytes');
      // the final stage's graphs compute in float64 on the CPU (WebAssembly), whatever runs the model; each is made
      // ready when first used (a path's and the pose's only for a path or a download)
      if (info.final_stage.includes(name)) later[name] = bytes;
      else sessions[name] = await ort.InferenceSession.create(bytes, { executionProviders: providers, graphOptimizationLevel: 'all' });
      step();
    }
    return new MotionRuntime(ort, tokenizer, sessions, info, actions, cpuOrt, later);
  }

  constructor(ort, tokenizer, sessions, info, actions, cpuOrt = ort, later = {}) {
    Object.assign(this, { ort, cpuOrt, tokenizer, sessions, info, actions, later });
    this.cache = new Map(); // prompt -> its encoding (most recent last)
  }

  get fps() { return this.info.fps; }

  // Frozen tokens (1, L, C), mask (L) and unit sentence embedding of a prompt (cached).
  async encode(prompt) {
    if (this.cache.has(prompt)) return this.cache.get(prompt);
    let ids = this.tokenizer.encode(prompt).ids;
    if (ids.length > this.info.max_tokens) ids = [...ids.slice(0, this.info.max_tokens - 1), ids[ids.length - 1]];
    const L = ids.length;
    const T = this.ort.Tensor;
    const out = await this.sessions.text_encoder.run({
      input_ids: new T('int64', BigInt64Array.from(ids.map(BigInt)), [1, L]),
      attention_mask: new T('int64', new BigInt64Array(L).fill(1n), [1, L]),
    });
    const enc = { tokens: out.tokens, L, sentence: out.sentence.data };
    this.cache.set(prompt, enc);
    if (this.cache.size > 256) this.cache.delete(this.cache.keys().next().value);
    return enc;
  }

  mask(n) { return new this.ort.Tensor('bool', new Uint8Array(n).fill(1), [1, n]); }

  // A graph of the final stage (float64, on the CPU): feeds {name: [type, values, dims]} -> its outputs.
  async stage(name, feeds) {
    this.sessions[name] ??= this.cpuOrt.InferenceSession.create(this.later[name], // a promise: made once
      { executionProviders: ['wasm'], graphOptimizationLevel: 'all' });
    const T = this.cpuOrt.Tensor;
    return (await this.sessions[name]).run(Object.fromEntries(Object.entries(feeds).map(([k, [type, v, dims]]) => [k, new T(type, v, dims)])));
  }

  // The final stage's graphs on flat joints (T x J x 3 metres): 4 x T arrays of 0/1 (left ankle, left toe, right
  // ankle, right toe) from a (1, T, 4) bool output.
  perFoot(out, T) {
    return [0, 1, 2, 3].map((k) => Uint8Array.from({ length: T }, (_, t) => (out.data[t * 4 + k] ? 1 : 0)));
  }

  // The feet the cleanup counts as planted (contacts.onnx: footskate/contacts.py's contacts_of_feet).
  async contactsOf(flat, T, J) {
    const out = await this.stage('contacts', { joints: ['float64', Float64Array.from(flat), [1, T, J, 3]] });
    return this.perFoot(out.contacts, T);
  }

  // The footskate cleanup of rigid joints (cleanup.onnx: footskate/cleanup.py's clean_joints): {joints, held}.
  async cleanup(flat, T, J, lengths) {
    const out = await this.stage('cleanup', { joints: ['float64', Float64Array.from(flat), [1, T, J, 3]],
      bone_lengths: ['float64', Float64Array.from(lengths), [1, J]] });
    return { joints: Float64Array.from(out.joints_out.data), held: this.perFoot(out.held, T) };
  }

  // The closest known actions, the in-domain score, whether the prompt is out of domain, and the clip caption of a
  // taught action the prompt is answered with (`asked`: the text encoded; text/known.py's DomainCheck.answer).
  async domain(enc, asked) {
    const a = this.info.actions, C = enc.sentence.length;
    const best = new Array(a.names.length).fill(-1);
    a.owner.forEach((k, e) => {
      let s = 0;
      for (let c = 0; c < C; c++) s += enc.sentence[c] * this.actions[e * C + c];
      best[k] = Math.max(best[k], s);
    });
    const order = best.map((s, k) => [a.names[k], s]).sort((x, y) => y[1] - x[1]).slice(0, a.top);
    const out = await this.sessions.ood.run({ sentence: new this.ort.Tensor('float32', Float32Array.from(enc.sentence), [1, C]) });
    const score = out.score.data[0];
    // an adapter's actions (after taught_from): a prompt close to one of their captions is in domain
    const taught = best.slice(a.taught_from ?? best.length).some((s) => s >= a.taught_similarity);
    return { similarity: score, closest: order, outOfDomain: score < a.threshold && !taught, answer: this.answer(enc, order, asked) };
  }

  // The nearest clip caption of the taught action closest to the prompt, where it leads the next closest by the
  // taught margin, and it is not the prompt itself; else null.
  answer(enc, order, asked) {
    const a = this.info.actions, C = enc.sentence.length;
    const clips = a.answers?.[order[0]?.[0]];
    if (!clips || (order.length > 1 && order[0][1] - order[1][1] < a.taught_margin)) return null;
    let best = -Infinity, caption = null;
    for (const [row, text] of clips) {
      let s = 0;
      for (let c = 0; c < C; c++) s += enc.sentence[c] * this.actions[row * C + c];
      if (s > best) [best, caption] = [s, text];
    }
    return caption === asked ? null : caption;
  }

  // The warning of a prompt answered with a taught caption (DomainCheck.answer_message).
  answerWarning(prompt, domain) {
    return `'${prompt}' is answered as '${domain.answer}': its closest action, ${domain.closest[0][0]}, is one an adapter ` +
      "taught, and an adapter draws its move surely only for its clips' captions";
  }

  // The length model's frames for an encoding, within the model's range: its distribution's quantile at the level of
  // the seed's stream (the Python's predict_seconds with length_level(seed, stream)).
  async predicted(enc, seed, stream = 0) {
    return this.quantile(enc, uniform(seed, { stream, draw: this.info.length_draw }));
  }

  // The length model's frames for an encoding at a `level` of its distribution (0.5: the median), within the range.
  async quantile(enc, level) {
    const i = this.info, T = this.ort.Tensor;
    const out = await this.sessions.length.run({ tokens: enc.tokens, mask: this.mask(enc.L),
      level: new T('float32', Float32Array.of(level), [1]) });
    return Math.min(Math.max(Math.trunc(Number(out.frames.data[0])), i.min_frames), i.max_frames);
  }

  // A length from path words for a seed and stream: spread as the length model spreads the text's (spread_seconds).
  async spread(seconds, enc, seed, stream = 0) {
    const i = this.info;
    return spreadSeconds(seconds, (await this.predicted(enc, seed, stream)) / i.fps, (await this.quantile(enc, 0.5)) / i.fps,
      i.fps, i.min_frames, i.max_frames, i.length_multiple);
  }

  // The length of a motion in frames: `seconds` rounded as every runtime rounds it, or the length model's for the seed.
  async frames(enc, seconds, seed) {
    const i = this.info;
    let n;
    if (seconds === undefined || seconds === null || seconds === '') {
      n = await this.predicted(enc, seed);
    } else {
      n = Math.round(checkSeconds(seconds) * i.fps);
    }
    n = Math.floor(Math.max(n, i.min_frames) / i.length_multiple) * i.length_multiple;
    if (n > i.max_frames) throw new RangeError(`this page makes motions of at most ${(i.max_frames / i.fps).toFixed(1)} s`);
    return n;
  }

  // The model's raw features (n x D, dataset units, float32 values) for an encoded prompt: the sampler table on the
  // portable noise (stream 0 of the seed), frames padded to pad_multiple. `start`: the first K frames known (K x D
  // features of the motion so far), imposed on every prediction (the Python's x0 hook of a prefix edit).
  async sample(enc, n, seed, start = null) {
    const i = this.info, T = this.ort.Tensor;
    const cond = await this.sessions.condition.run({ tokens: enc.tokens, mask: this.mask(enc.L),
      guidance: new T('float32', Float32Array.of(i.guidance), [1]) });
    const D = i.motion_dim, P = Math.ceil(n / i.pad_multiple) * i.pad_multiple;
    const tab = i.table;
    const motionMask = new Uint8Array(P);
    motionMask.fill(1, 0, n);
    const inputs = { features: cond.features, text_mask: this.mask(enc.L), keep: new T('bool', Uint8Array.of(1), [1]),
      motion_mask: new T('bool', motionMask, [1, P]) };
    if (cond.sentence) inputs.sentence = cond.sentence;
    // the known frames normalised, in float32 as the Python computes them
    const known = start && Float32Array.from(start, (v, e) => Math.fround(Math.fround(v) - i.mean[e % D]) / i.std[e % D]);
    let x = normal(seed, n * D, { stream: 0, draw: 0 }).map((v) => v * tab.init_sigma);
    let prev = new Float32Array(n * D);
    for (let k = 0; k < tab.t.length; k++) {
      const xin = new Float32Array(P * D);
      for (let e = 0; e < n * D; e++) xin[e] = x[e] * tab.c_in[k];
      const out = await this.sessions.denoise.run({ ...inputs, x: new T('float32', xin, [1, P, D]),
        t: new T('float32', Float32Array.of(tab.t[k]), [1]) });
      const x0 = Float32Array.from(out.x0.data.subarray(0, n * D));
      if (known) x0.set(known);
      const noise = tab.stochastic ? normal(seed, n * D, { stream: 0, draw: 1 + k }) : null;
      const next = new Float32Array(n * D);
      for (let e = 0; e < n * D; e++) next[e] = tab.a[k] * x[e] + tab.b[k] * x0[e] + tab.c[k] * prev[e] + (noise ? tab.d[k] * noise[e] : 0);
      prev = x0;
      x = next;
    }
    const features = new Float64Array(n * D);
    // in float32, as the Python runtime computes it (its sampler works in float32 throughout)
    for (let e = 0; e < n * D; e++) features[e] = Math.fround(Math.fround(x[e] * i.std[e % D]) + i.mean[e % D]);
    return features;
  }

  // A prompt's parts: split at its sequence words (sequence.js), unless the whole prompt is nearly one of the
  // model's example sentences (the Python's TextToMotionPipeline.parts).
  async parts(prompt) {
    const i = this.info, q = i.sequence;
    const parts = q ? splitSequence(prompt, q) : [prompt];
    if (parts.length < 2) return parts;
    const spec = parsePath(prompt, i.paths);
    const whole = await this.domain(await this.encode(spec ? spec.prompt : prompt));
    return (whole.closest?.[0]?.[1] ?? 0) >= q.one_action_similarity ? [prompt] : parts;
  }

  // The segments of a prompt's parts: each part as long as its path words say, else as the length model predicts
  // (part k at the level of stream k of the seed); a length given for the whole (`total` seconds, or null) shared
  // among them (the Python's TextToMotionPipeline.segments and segment_frames). [{prompt, asked (without path words),
  // spec, seconds, frames}].
  async segments(parts, total, seed) {
    const i = this.info, q = i.sequence;
    const specs = parts.map((p) => parsePath(p, i.paths));
    const own = [];
    for (let k = 0; k < parts.length; k++) {
      const enc = await this.encode(parts[k]);
      own.push(specs[k]?.seconds ? await this.spread(specs[k].seconds, enc, seed, k) : (await this.predicted(enc, seed, k)) / i.fps);
    }
    const shortest = i.min_frames / i.fps;
    const shared = total === null ? own : shareSeconds(total, own, shortest);
    if (Math.min(...shared) < shortest) {
      throw new RangeError(`${parts.length} parts (${parts.join('; ')}) need at least ${shortest} s each; ${total} s is too short for them`);
    }
    const sum = shared.reduce((a, b) => a + b, 0);
    if (!(sum <= q.max_seconds)) throw new RangeError(`a timeline's total seconds must be more than 0 and at most ${q.max_seconds} s, got ${sum}`);
    return parts.map((p, k) => ({ prompt: p, asked: specs[k] ? specs[k].prompt : p, spec: specs[k], seconds: shared[k],
      frames: roundHalfEven(shared[k] * i.fps) }));
  }

  // The raw features of a timeline of segments, window after window (seed + j for window j), each later window
  // continuing the motion so far: its first frames known while sampling, then continue.onnx (the Python's
  // TimelinePipeline, steps 2-3).
  async timeline(segs, seed) {
    const i = this.info, q = i.sequence, D = i.motion_dim;
    const windows = planWindows(segs.map((s) => [s.asked, s.frames]), i.max_frames, q.overlap_frames, q.tail);
    const total = segs.reduce((a, s) => a + s.frames, 0);
    const out = new Float64Array(total * D);
    let made = 0;
    for (let j = 0; j < windows.length; j++) {
      const w = windows[j];
      const frames = Math.max(w.keep + w.new + w.tail, i.min_frames);
      const start = w.keep ? out.slice((made - w.keep) * D, made * D) : null;
      let raw = await this.sample(await this.encode(w.prompt), frames, seed + j, start);
      if (start) {
        const known = new Float64Array(frames * D);
        known.set(start);
        const got = await this.stage('continue', { features: ['float64', raw, [1, frames, D]],
          known: ['float64', known, [1, frames, D]], keep: ['int64', BigInt64Array.of(BigInt(w.keep)), [1]] });
        raw = Float64Array.from(got.features_out.data, Math.fround);
      }
      out.set(raw.subarray(w.keep * D, (w.keep + w.new) * D), made * D);
      made += w.new;
    }
    return out;
  }

  // A warning when the closest known action of a prompt's domain is one the model draws badly (its reliability table,
  // web.json), by the Python's margin and at least its floor; else null.
  weakWarning(prompt, domain) {
    const i = this.info;
    const weak = i.weak_actions?.actions ?? {};
    const [action, similarity] = domain.closest?.[0] ?? [null, 0];
    const wellDrawn = (domain.closest ?? []).filter(([a]) => !(a in weak)).map(([, s]) => s);
    if (domain.outOfDomain || !(action in weak) || !(similarity >= i.weak_actions.floor) ||
        !(similarity - (wellDrawn.length ? Math.max(...wellDrawn) : 0) > i.weak_actions.margin)) return null;
    const w = weak[action];
    return `"${prompt}" is closest to "${action}", which this model draws badly (it was taught by ${w.clips} ` +
      `clip${w.clips === 1 ? '' : 's'}${w.accuracy === null ? '' : `; ${Math.round(w.accuracy * 100)}% of its motions for ` +
      'other wordings were judged right'}): the motion may not show it`;
  }

  // One motion: {joints (T x J x 3 nested arrays, metres), frames, fps, prompt, seed, similarity, closest,
  // outOfDomain, warnings, sequence (a prompt of several parts: [[part, seconds], ...]), contacts}.
  // `path`: a root path to follow ([[x, z], ...] metres, or {points, times}), its length the motion's unless seconds
  // are given. A prompt that asks for one thing after another ("... then ...") is made as a timeline of its parts.
  async generate({ prompt, seconds, seed = 0, footskate = 'post', path = null }) {
    const i = this.info;
    prompt = String(prompt ?? '').trim();
    if (!prompt) throw new RangeError('the prompt must be a non-empty text');
    if (/[\uD800-\uDFFF]/u.test(prompt)) throw new RangeError('the prompt must be valid text: it holds a lone surrogate');
    // characters as the Python counts them (code points), not UTF-16 units: an emoji is one
    if ([...prompt].length > i.max_prompt_chars) throw new RangeError(`the prompt must be at most ${i.max_prompt_chars} characters`);
    if (!Number.isSafeInteger(seed) || seed < 0) throw new RangeError(`seed must be a whole number from 0 to 2**53 - 1, got ${seed}`);
    if (footskate !== 'off' && footskate !== 'post') {
      throw new RangeError(`footskate must be 'post' or 'off' here, got '${footskate}' ('loop' runs in the torch sampler)`);
    }
    // 1. text: the parts ("... then ..."), path words (the model is given the prompt without them), domains, lengths
    // (a path's, else the length model's on the whole prompt or part)
    const unset = seconds === undefined || seconds === null || seconds === '';
    if (!unset) checkSeconds(seconds);
    const wp = path === null || path === undefined ? null : readWaypoints(path, i.path_limits);
    const parts = await this.parts(prompt);
    const warnings = [];
    let n, features, segs = null, domain, spec = null;
    if (parts.length === 1) {
      spec = i.paths ? parsePath(prompt, i.paths) : null;
      const enc = await this.encode(spec ? spec.prompt : prompt);
      domain = await this.domain(enc, spec ? spec.prompt : prompt);
      const whole = spec ? await this.encode(prompt) : enc;  // the length model reads the whole prompt
      const own = wp ? waypointSeconds(wp, prompt, i.paths, i.fps, i.length_multiple)
        : spec && spec.seconds && unset ? await this.spread(spec.seconds, whole, seed) : null;
      n = await this.frames(whole, unset && own ? own : seconds, seed);
      // 2. denoise (a prompt answered with a taught caption: the caption)
      features = await this.sample(domain.answer ? await this.encode(domain.answer) : enc, n, seed);
      const weak = this.weakWarning(prompt, domain);
      if (weak) warnings.push(weak);
      if (domain.answer) warnings.push(this.answerWarning(prompt, domain));
    } else {
      segs = await this.segments(parts, !unset ? Number(seconds) : wp ? waypointSeconds(wp, prompt, i.paths, i.fps, i.length_multiple) : null, seed);
      const domains = [];
      for (const s of segs) domains.push(await this.domain(await this.encode(s.asked), s.asked));
      domain = domains.reduce((a, d) => (d.similarity < a.similarity ? d : a));
      for (const [k, d] of domains.entries()) {
        const weak = this.weakWarning(segs[k].prompt, d);
        if (weak && !warnings.includes(weak)) warnings.push(weak);
      }
      for (const [k, d] of domains.entries()) {  // a part without path words answered with a taught caption
        if (d.answer && !segs[k].spec) {
          segs[k].asked = d.answer;
          warnings.push(this.answerWarning(segs[k].prompt, d));
        }
      }
      n = segs.reduce((a, s) => a + s.frames, 0);
      // 2. denoise window after window, each continuing the motion so far
      features = await this.timeline(segs, seed);
    }
    // 3. the final stage, each step a graph: the path followed (explicit points, else the path words' of the prompt or
    // of each part), decoded and fitted with one skeleton of fixed bone lengths, the cleanup; then the first root at
    // the origin
    const D = i.motion_dim, J = i.skeleton.parents.length, sk = i.skeleton;
    const f64 = (v, dims) => ['float64', Float64Array.from(v), dims];
    const bend = async (f, s, T) => (await this.stage('bend', { features: f64(f, [1, T, D]),
      kind: ['int64', BigInt64Array.of(BigInt(i.path_kinds.indexOf(s.kind))), [1]],
      angle: f64([s.angle * (Math.PI / 180)], [1]) })).features_out.data;
    let placing = null;
    if (wp) {
      const K = wp.points.length;
      const out = await this.stage('follow', { features: f64(features, [1, n, D]), points: f64(wp.points.flat(), [1, K, 2]),
        times: f64(wp.times ?? new Array(K).fill(0), [1, K]), timed: ['bool', Uint8Array.of(wp.times ? 1 : 0), [1]] });
      features = out.features_out.data;
      placing = { start: out.start.data[0], origin: Array.from(out.origin.data) };
    } else if (spec) {
      features = await bend(features, spec, n);
    } else if (segs) {
      // each part bent by its own path words (the Python's bend_segments: features are body-relative, so a later
      // part continues from where the bent one leaves the body)
      features = Float64Array.from(features);
      let a = 0;
      for (const s of segs) {
        const b = Math.min(a + s.frames, n);
        if (s.spec && b - a >= 2) features.set(await bend(features.subarray(a * D, b * D), s.spec, b - a), a * D);
        a = b;
      }
    }
    let flat = Float64Array.from((await this.stage('rigid', { features: f64(features, [1, n, D]),
      bone_lengths: f64(sk.bone_lengths, [1, J]) })).joints.data);
    let contacts = null;
    if (footskate === 'post') ({ joints: flat, held: contacts } = await this.cleanup(flat, n, J, sk.bone_lengths));
    const planted = contacts ?? await this.contactsOf(flat, n, J);
    recentre(flat, n, J);
    if (placing) placeJoints(flat, n, J, placing.start, placing.origin);
    const joints = [];
    for (let f = 0; f < n; f++) {
      const frame = [];
      for (let j = 0; j < J; j++) frame.push([flat[(f * J + j) * 3], flat[(f * J + j) * 3 + 1], flat[(f * J + j) * 3 + 2]]);
      joints.push(frame);
    }
    // 4. what the motion carries for the user: its prompt not English, an action the model draws badly
    const foreign = i.languages ? notEnglish(prompt, i.languages) : null;
    if (foreign) {
      warnings.unshift(`"${prompt}" does not look like English (${foreign}): the model knows English prompts only, so ` +
        'the motion may not follow it');
    }
    // contacts: the frames the cleanup held each foot joint (left ankle, left toe, right ankle, right toe), 4 x T 0/1
    const motion = { joints, frames: n, fps: i.fps, prompt, seed, ...domain, warnings,
      ...(segs ? { sequence: segs.map((s) => [s.prompt, s.seconds]) } : {}),
      ...(contacts ? { contacts: contacts.map((c) => Array.from(c)) } : {}) };
    Object.defineProperty(motion, 'flat', { value: flat }); // (T x J x 3) as one array, not serialised
    Object.defineProperty(motion, 'planted', { value: planted }); // the feet the cleanup held or would count planted
    return motion;
  }

  // The pose of a motion made by `generate` (pose.onnx): {offsets: J x [x, y, z] metres, rotations: (T x J x 3 x 3,
  // flat) each joint's rotation in its parent's frame (rows), euler: the same as BVH channel angles (T x J x 3, flat,
  // degrees, order web.json's bvh_order)}.
  async pose(motion) {
    const J = this.info.skeleton.parents.length, T = motion.frames;
    const out = await this.stage('pose', { joints: ['float64', motion.flat, [1, T, J, 3]],
      bone_lengths: ['float64', Float64Array.from(this.info.skeleton.bone_lengths), [1, J]] });
    const o = out.offsets.data;
    return { offsets: Array.from({ length: J }, (_, j) => [o[j * 3], o[j * 3 + 1], o[j * 3 + 2]]),
      rotations: out.rotations.data, euler: out.euler.data };
  }

  // The BVH text of a motion made by `generate`, as `smf generate --format bvh` writes it.
  async bvh(motion) {
    const { offsets, euler } = await this.pose(motion);
    return bvhText(motion.flat, motion.frames, this.info.skeleton, offsets, euler, this.info.bvh_order, motion.fps);
  }
}
