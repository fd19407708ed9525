// PDIC light-map viewer: shows a PDIC-exported .glb lit ONLY by its baked light maps.
//
// Query parameters: model=URL of the .glb (default model.glb), w/h=canvas size in pixels
// (default: the window), ev=exposure in stops, mips=0 to sample base-colour textures
// without mipmaps (as PDIC's own camera render does), ui=0 to hide the controls.
//
// The light-map binding (pdic_addon/gltf_export.py): a material's extensions.MOZ_lightmap
// names the texture (TEXCOORD_1); extras.pdic_lightmap says it is RGBM with a range R:
// linear = rgb * a * R, the value being irradiance / pi. Outgoing radiance = base colour x
// that value, which is MeshBasicMaterial's lightMap term with intensity pi (three.js
// divides the light map by pi there).
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

const params = new URLSearchParams(location.search);
const width = Number(params.get('w')) || window.innerWidth;
const height = Number(params.get('h')) || window.innerHeight;
const useMips = params.get('mips') !== '0';
const status = document.getElementById('status');
if (params.get('ui') === '0') document.getElementById('ui').classList.add('hidden');

const renderer = new THREE.WebGLRenderer({ antialias: false, preserveDrawingBuffer: true });
renderer.setPixelRatio(1);
renderer.setSize(width, height);
renderer.outputColorSpace = THREE.SRGBColorSpace;
renderer.toneMapping = THREE.NoToneMapping;
document.body.appendChild(renderer.domElement);

const lightmapped = [];

// The light map exactly as stored: no premultiplied alpha, no colour conversion, no mipmaps.
async function loadLightmap(parser, textureIndex) {
  const json = parser.json;
  const image = json.images[json.textures[textureIndex].source];
  const bytes = await parser.getDependency('bufferView', image.bufferView);
  const blob = new Blob([bytes], { type: image.mimeType || 'image/png' });
  const bitmap = await createImageBitmap(blob, { premultiplyAlpha: 'none', colorSpaceConversion: 'none' });
  const texture = new THREE.Texture(bitmap);
  texture.flipY = false;                       // glTF: row 0 of the image is v = 0 of TEXCOORD
  texture.colorSpace = THREE.NoColorSpace;     // RGBM bytes are data
  texture.premultiplyAlpha = false;
  texture.magFilter = THREE.LinearFilter;
  texture.minFilter = THREE.LinearFilter;
  texture.generateMipmaps = false;
  texture.wrapS = texture.wrapT = THREE.ClampToEdgeWrapping;
  texture.channel = 1;                         // TEXCOORD_1
  texture.needsUpdate = true;
  return texture;
}

function rgbmMaterial(source, lightMap, range) {
  const material = new THREE.MeshBasicMaterial({
    color: source.color ? source.color.clone() : new THREE.Color(1, 1, 1),
    map: source.map || null,
    side: source.side,
    lightMap,
    lightMapIntensity: Math.PI,
  });
  if (material.map && !useMips) {
    material.map.minFilter = THREE.LinearFilter;
    material.map.generateMipmaps = false;
    material.map.needsUpdate = true;
  }
  material.onBeforeCompile = (shader) => {
    shader.uniforms.pdicRange = { value: range };
    shader.fragmentShader = 'uniform float pdicRange;\n' + shader.fragmentShader.replace(
      'lightMapTexel.rgb * lightMapIntensity',
      '( lightMapTexel.rgb * lightMapTexel.a * pdicRange ) * lightMapIntensity');
  };
  material.customProgramCacheKey = () => 'pdic-rgbm';
  lightmapped.push(material);
  return material;
}

async function bindLightmaps(gltf) {
  const parser = gltf.parser;
  const json = parser.json;
  const textures = new Map();
  const replacements = [];
  gltf.scene.traverse((object) => {
    if (!object.isMesh) return;
    const assoc = parser.associations.get(object.material);
    const def = assoc && assoc.materials !== undefined ? json.materials[assoc.materials] : null;
    const ext = def && def.extensions && def.extensions.MOZ_lightmap;
    replacements.push({ object, ext, extras: def && def.extras && def.extras.pdic_lightmap });
  });
  for (const { object, ext, extras } of replacements) {
    if (!ext) {  // not baked: no light reaches it in this viewer
      object.material = new THREE.MeshBasicMaterial({ color: 0x000000 });
      continue;
    }
    if (!textures.has(ext.index)) textures.set(ext.index, await loadLightmap(parser, ext.index));
    const range = extras && extras.encoding === 'RGBM' ? extras.range : 1.0;
    object.material = rgbmMaterial(object.material, textures.get(ext.index), range * (ext.intensity ?? 1));
  }
  return replacements.filter((r) => r.ext).length;
}

function sceneCamera(gltf, scene) {
  const box = new THREE.Box3().setFromObject(scene);
  const centre = box.getCenter(new THREE.Vector3());
  const camera = new THREE.PerspectiveCamera(50, width / height, 0.01, 1000);
  const source = gltf.cameras && gltf.cameras[0];
  if (source) {
    source.updateMatrixWorld(true);
    source.matrixWorld.decompose(camera.position, camera.quaternion, new THREE.Vector3());
    camera.fov = source.fov;
    camera.near = source.near;
    camera.far = source.far;
  } else {
    const size = box.getSize(new THREE.Vector3()).length();
    camera.position.copy(centre).add(new THREE.Vector3(0, size * 0.2, size));
    camera.lookAt(centre);
  }
  camera.aspect = width / height;
  camera.updateProjectionMatrix();
  // Orbit around the point ahead of the camera nearest the scene's centre: the first frame keeps its view.
  const forward = new THREE.Vector3(0, 0, -1).applyQuaternion(camera.quaternion);
  const distance = Math.max(centre.clone().sub(camera.position).dot(forward), 0.1);
  return { camera, target: camera.position.clone().addScaledVector(forward, distance) };
}

async function main() {
  const loader = new GLTFLoader();
  const gltf = await loader.loadAsync(params.get('model') || 'model.glb');
  const scene = new THREE.Scene();  // gltf.scene is a Group: background needs a Scene
  scene.add(gltf.scene);
  const pdic = (gltf.parser.json.extras || {}).pdic || {};
  const bg = pdic.background || [0, 0, 0];
  scene.background = new THREE.Color().setRGB(bg[0], bg[1], bg[2], THREE.LinearSRGBColorSpace);
  const bound = await bindLightmaps(gltf);
  const { camera, target } = sceneCamera(gltf, scene);
  const controls = new OrbitControls(camera, renderer.domElement);
  controls.target.copy(target);
  controls.update();
  const slider = document.getElementById('exposure');
  const setExposure = (ev) => {
    for (const m of lightmapped) m.lightMapIntensity = Math.PI * Math.pow(2, ev);
    document.getElementById('ev').textContent = `${Number(ev).toFixed(1)} EV`;
  };
  slider.addEventListener('input', () => setExposure(Number(slider.value)));
  if (params.get('ev')) { slider.value = params.get('ev'); setExposure(Number(params.get('ev'))); }
  renderer.setAnimationLoop(() => { controls.update(); renderer.render(scene, camera); });
  renderer.render(scene, camera);
  status.textContent = `${bound} light-mapped meshes`;
  window.pdicViewer = { ready: true, bound, lightmaps: (pdic.lightmaps || []).length, background: bg };
}

main().catch((error) => {
  status.textContent = `error: ${error.message}`;
  window.pdicViewer = { ready: false, error: String(error && error.stack || error) };
  console.error(error);
});
