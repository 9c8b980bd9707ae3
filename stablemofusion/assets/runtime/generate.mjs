// Text to motion from Node.js on a site folder written by `smf site` (its model and vendored ONNX Runtime Web):
//   node runtime/generate.mjs "a person waves both hands" [--seconds 4] [--seed 0] [--footskate post|off]
//                             [--path '[[0, 0], [0, 3], [3, 3]]']
// prints {"joints": [frames][22][3] metres, "fps", "prompt", "seed", "similarity", "outOfDomain", "closest"} as JSON.
import { dirname, join } from 'node:path';
import { fileURLToPath } from 'node:url';
import { loadRuntime } from './node.mjs';

const site = join(dirname(fileURLToPath(import.meta.url)), '..');
const args = process.argv.slice(2);
const option = (name, fallback) => {
  const i = args.indexOf(name);
  if (i < 0) return fallback;
  const [, value] = args.splice(i, 2);
  return value;
};
const seconds = option('--seconds', undefined);
const seed = Number(option('--seed', '0'));
const footskate = option('--footskate', 'post');
const pathText = option('--path', null);
const prompt = args.join(' ');

try {
  const runtime = await loadRuntime(site);
  const path = pathText === null ? null : JSON.parse(pathText);
  const motion = await runtime.generate({ prompt, seconds, seed, footskate, path });
  process.stdout.write(JSON.stringify(motion));
} catch (e) {
  process.stderr.write(`generate.mjs: ${e.message}\n`);
  process.exit(2);
}
