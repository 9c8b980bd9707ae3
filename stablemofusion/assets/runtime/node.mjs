// The JavaScript runtime of a site folder loaded in Node.js: its vendored ONNX Runtime Web (one WebAssembly thread)
// and tokenizer, the model read from the folder's model/.
import { readFile } from 'node:fs/promises';
import { join } from 'node:path';
import { pathToFileURL } from 'node:url';
import { MotionRuntime } from './smf.js';

export async function loadRuntime(site) {
  const ortDir = join(site, 'vendor', 'onnxruntime-web');
  const ort = await import(pathToFileURL(join(ortDir, 'ort.wasm.min.mjs')).href);
  ort.env.wasm.numThreads = 1;
  ort.env.wasm.wasmPaths = pathToFileURL(ortDir + '/').href;
  const { Tokenizer } = await import(pathToFileURL(join(site, 'vendor', 'tokenizers', 'tokenizers.min.mjs')).href);
  const read = async (name, kind) => {
    const bytes = await readFile(join(site, 'model', name));
    return kind === 'json' ? JSON.parse(bytes.toString('utf8')) : new Uint8Array(bytes);
  };
  return MotionRuntime.load({ ort, Tokenizer, read });
}
