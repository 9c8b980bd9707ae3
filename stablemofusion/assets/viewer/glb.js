// Show a .glb motion (`smf convert ... .glb`, `?format=glb`) in the viewer's three.js scene: the skinned body
// and its one animation, played by an AnimationMixer; viewer.js shows it beside the skeleton.
import * as THREE from 'three';
import { GLTFLoader } from '/viewer/vendor/loaders/GLTFLoader.js';

// data: an ArrayBuffer (a fetched or dropped .glb). Returns {root, mixer, action, fps, frames, duration};
// call mixer.update(seconds) each frame, or mixer.setTime(t) to scrub; scene.remove(root) to drop it.
export async function loadGlb(scene, data) {
  const gltf = await new GLTFLoader().parseAsync(data, '');
  const root = gltf.scene;
  root.traverse((o) => { if (o.isMesh) { o.castShadow = true; o.frustumCulled = false; } });
  scene.add(root);
  const mixer = new THREE.AnimationMixer(root);
  const clip = gltf.animations[0];
  const action = mixer.clipAction(clip);
  action.play();
  const extras = gltf.parser.json.extras || {};
  return { root, mixer, action, fps: extras.fps || 20, frames: extras.frames || null, duration: clip.duration };
}

// The joint positions (metres, Y up) of frame f of a loaded .glb, in the order of `names` (our joint names):
// for drawing the same stick figure and root path as the JSON motions.
export function glbJoints(loaded, names, f) {
  loaded.mixer.setTime(f / loaded.fps);
  loaded.root.updateMatrixWorld(true);
  const v = new THREE.Vector3();
  return names.map((n) => loaded.root.getObjectByName(n).getWorldPosition(v).toArray());
}
