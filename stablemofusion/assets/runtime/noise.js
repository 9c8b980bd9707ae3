// One seeded noise for every runtime: the JavaScript twin of stablemofusion/core/noise.py (its docstring is the
// definition). noise(seed, frames, dims, {stream, draw}) -> Float32Array of frames * dims standard normals,
// the same numbers numpy gives (to the last float32 bit, up to one unit where Math.log/cos/sin round differently).

const M1 = 0x7feb352d;
const M2 = 0x846ca68b;
const GOLDEN = 0x9e3779b9;
const TWO32 = 4294967296;

export function mix(x) {
  x = x >>> 0;
  x ^= x >>> 16;
  x = Math.imul(x, M1) >>> 0;
  x ^= x >>> 15;
  x = Math.imul(x, M2) >>> 0;
  x ^= x >>> 16;
  return x >>> 0;
}

export function drawKey(seed, stream = 0, draw = 0) {
  if (!Number.isSafeInteger(seed) || seed < 0) throw new RangeError(`noise seeds are whole numbers from 0 to 2**53 - 1, got ${seed}`);
  const lo = seed % TWO32;
  const hi = Math.floor(seed / TWO32);
  let k = mix((lo ^ GOLDEN) >>> 0);
  k = mix((k ^ hi) >>> 0);
  k = mix((k ^ stream) >>> 0);
  return mix((k ^ draw) >>> 0);
}

export function normal(seed, count, { stream = 0, draw = 0 } = {}) {
  const k = drawKey(seed, stream, draw);
  const out = new Float32Array(count);
  for (let p = 0; 2 * p < count; p++) {
    const a = mix((mix(2 * p) ^ k) >>> 0);
    const b = mix((mix(2 * p + 1) ^ k) >>> 0);
    const u = ((a >>> 8) + 1) / 16777216;
    const v = (b >>> 8) * (2 * Math.PI / 16777216);
    const r = Math.sqrt(-2 * Math.log(u));
    out[2 * p] = r * Math.cos(v);
    if (2 * p + 1 < count) out[2 * p + 1] = r * Math.sin(v);
  }
  return out;
}

// The uniform of a draw: a number in (0, 1), from the first word of its pair 0 (the Python's uniform).
export function uniform(seed, { stream = 0, draw = 0 } = {}) {
  const a = mix((mix(0) ^ drawKey(seed, stream, draw)) >>> 0);
  return ((a >>> 8) + 0.5) / 16777216;
}

export function noise(seed, frames, dims, opts = {}) {
  return normal(seed, frames * dims, opts);
}
