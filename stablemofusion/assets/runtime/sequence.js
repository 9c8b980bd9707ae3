// Prompts that ask for one thing after another ("a tired man walks in a circle then waves"), in JavaScript: split as
// stablemofusion/core/sequence_plan.py splits them (its patterns and words from web.json's "sequence") and planned as
// stablemofusion/core/timeline_plan.py plans a timeline's windows. Node tests hold these answers equal to the
// Python's. The windows' continuation (the kept frames and the seam) is the graph continue.onnx, not written here.

// the patterns, compiled once per lexicon
const COMPILED = new WeakMap();
function compile(q) {
  if (!COMPILED.has(q)) {
    COMPILED.set(q, { words: new RegExp(q.words, 'i'), subject: new RegExp(q.subject, 'i'),
      pronoun: new RegExp(q.pronoun, 'i'), leading: new RegExp(q.leading, 'i') });
  }
  return COMPILED.get(q);
}

// Python's str.strip(" ,;."): those characters off both ends
const strip = (s) => s.replace(/^[ ,;.]+|[ ,;.]+$/g, '');

// The parts of a prompt, in order (one part: the prompt as it is): split_sequence.
export function splitSequence(prompt, q) {
  const re = compile(q);
  const parts = prompt.split(re.words).map(strip).filter((p) => p);
  if (parts.length < 2 || parts.length > q.max_parts) return [prompt];
  const found = re.subject.exec(parts[0]);
  const subject = found && !re.pronoun.test(found[0]) ? found[0].trim() : q.default_subject;
  const out = [parts[0]];
  for (let p of parts.slice(1)) {
    p = p.replace(re.leading, '');
    if (re.pronoun.test(p)) p = p.replace(re.pronoun, `${subject} `);
    else if (!re.subject.test(p)) p = `${subject} ${p}`;
    out.push(p);
  }
  return out;
}

// A length from path words for one seed (s): `seconds` (the words' kind's) times the length model's length for the
// seed over its median for the same prompt (`at`, `median`, s), whole multiples of `multiple` frames at `fps`, from
// `shortest` to `longest` frames (rounded inward to multiples): spread_seconds.
export function spreadSeconds(seconds, at, median, fps, shortest, longest, multiple) {
  const frames = roundHalfEven(seconds * at / median * fps / multiple) * multiple;
  return Math.min(Math.max(frames, Math.ceil(shortest / multiple) * multiple), Math.floor(longest / multiple) * multiple) / fps;
}

// `total` seconds shared among parts in proportion to their `own` lengths, each at least `minimum` where the total
// allows it: share_seconds.
export function shareSeconds(total, own, minimum = 0) {
  const sum = (xs) => xs.reduce((a, b) => a + b, 0);
  const short = new Set();
  for (;;) {
    const free = own.map((_, k) => k).filter((k) => !short.has(k));
    const rest = total - minimum * short.size;
    const whole = sum(free.map((k) => own[k]));
    const out = own.map((s, k) => (short.has(k) ? minimum : rest * s / whole));
    const under = free.filter((k) => out[k] < minimum);
    if (!under.length || total < minimum * own.length) {
      return total >= minimum * own.length ? out : own.map((s) => total * s / sum(own));
    }
    for (const k of under) short.add(k);
  }
}

// Python's round(): halves to the even neighbour.
export function roundHalfEven(x) {
  const r = Math.round(x);
  return Math.abs(x % 1) === 0.5 && r % 2 !== 0 ? r - 1 : r;
}

// The windows of a timeline of [prompt, frames] segments: plan_windows ({prompt, keep, new, segment, tail}).
export function planWindows(segments, maxFrames, overlap, tail) {
  const windows = [];
  let made = 0;
  segments.forEach(([prompt, frames], segment) => {
    for (let left = frames; left > 0;) {
      const keep = Math.min(overlap, made);
      const n = Math.min(left, maxFrames - keep - tail);
      windows.push({ prompt, keep, new: n, segment, tail });
      left -= n;
      made += n;
    }
  });
  return windows;
}
