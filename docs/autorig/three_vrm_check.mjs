// Loads a file with three.js's GLTFLoader and three-vrm's VRMLoaderPlugin (Node, no DOM).
import fs from 'fs';
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
import { VRMLoaderPlugin } from '@pixiv/three-vrm';
const file = process.argv[2];
const data = fs.readFileSync(file);
const buffer = data.buffer.slice(data.byteOffset, data.byteOffset + data.byteLength);
const loader = new GLTFLoader();
loader.register((parser) => new VRMLoaderPlugin(parser));
loader.parse(buffer, '', (gltf) => {
  const vrm = gltf.userData.vrm;
  if (!vrm) { console.log('NO VRM'); process.exit(1); }
  const bones = Object.keys(vrm.humanoid.humanBones).filter(k => vrm.humanoid.getRawBoneNode(k));
  const sb = vrm.springBoneManager;
  const joints = sb ? [...sb.joints] : [];
  const colliders = sb ? [...sb.colliders] : [];
  console.log(JSON.stringify({
    meta: vrm.meta && vrm.meta.name, metaVersion: vrm.meta && vrm.meta.metaVersion,
    humanBones: bones.length, hips: vrm.humanoid.getRawBoneNode('hips')?.name,
    springJoints: joints.map(j => [j.bone.name, j.child?.name, j.settings.stiffness, j.settings.hitRadius]),
    colliders: colliders.map(c => [c.parent?.name, c.shape.type, c.shape.radius]),
  }));
  // One second of the spring simulation, to see it runs.
  for (let i = 0; i < 60; i++) vrm.update(1 / 60);
  console.log('updated ok');
}, (e) => { console.log('ERROR', e.message || e); process.exit(1); });
