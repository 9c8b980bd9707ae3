// Motion files in JavaScript: the BVH text of a finished motion, written as `smf generate --format bvh` writes it
// (stablemofusion/motion/bvh.py: format_bvh). The numbers come from the graph pose.onnx (the Python's own pose_joints
// and matrix_to_euler, exported); here they are only formatted. Arrays are flat, frame-major:
// joints[(t * J + j) * 3 + k] metres, Y up.

// Joints (T, J, 3) moved so that the first root sits at the XZ origin, where features start (in place).
export function recentre(x, T, J) {
  const ox = x[0], oz = x[2];
  for (let i = 0; i < T * J; i++) { x[i * 3] -= ox; x[i * 3 + 2] -= oz; }
  return x;
}

// The BVH text (metres, Y up) of rigid joints (T, J, 3) posed by pose.onnx: `offsets` (J x 3) metres, `euler`
// (T x J x 3, flat) degrees about the axes of `order` (the graph's: web.json "bvh_order").
export function bvhText(joints, T, tree, offsets, euler, order, fps, precision = 6) {
  const J = tree.parents.length, names = tree.names;
  const num = (v) => (Math.round(v * 10 ** precision) / 10 ** precision + 0).toFixed(precision);
  const children = [...Array(J)].map(() => []);
  for (let j = 1; j < J; j++) children[tree.parents[j]].push(j);
  const rot = [...order].map((a) => `${a}rotation`).join(' ');
  const out = ['HIERARCHY'];
  const written = [];
  const emit = (j, depth) => {
    const ind = '\t'.repeat(depth);
    written.push(j);
    out.push(`${ind}${j === 0 ? 'ROOT' : 'JOINT'} ${names[j]}`, `${ind}{`, `${ind}\tOFFSET ${offsets[j].map(num).join(' ')}`,
      j === 0 ? `${ind}\tCHANNELS 6 Xposition Yposition Zposition ${rot}` : `${ind}\tCHANNELS 3 ${rot}`);
    for (const c of children[j]) emit(c, depth + 1);
    if (!children[j].length) {
      const len = Math.hypot(...offsets[j]);
      const site = len > 1e-9 ? offsets[j].map((v) => v * 0.05 / len) : [0, 0.05, 0];
      out.push(`${ind}\tEnd Site`, `${ind}\t{`, `${ind}\t\tOFFSET ${site.map(num).join(' ')}`, `${ind}\t}`);
    }
    out.push(`${ind}}`);
  };
  emit(0, 0);
  out.push('MOTION', `Frames: ${T}`, `Frame Time: ${Number((1 / fps).toPrecision(9))}`);
  for (let n = 0; n < T; n++) {
    const row = [joints[n * J * 3], joints[n * J * 3 + 1], joints[n * J * 3 + 2]];
    for (const j of written) row.push(euler[(n * J + j) * 3], euler[(n * J + j) * 3 + 1], euler[(n * J + j) * 3 + 2]);
    out.push(row.map(num).join(' '));
  }
  return out.join('\n') + '\n';
}
