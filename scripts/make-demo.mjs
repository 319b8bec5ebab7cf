// Writes the page's demo scene (www/demo/demo.zip) and its truth map
// (www/demo/demo-truth.rogsmap) with the wasm engine in Node, so that `npm start`
// needs no native build: `node scripts/make-demo.mjs` after wasm-pack has built
// www/pkg. The same scene as `rogs synth --preset demo --seed 1 --lidar
// --pose-noise-m 0.05 --pose-noise-deg 0.5`.
import fs from 'node:fs';
import path from 'node:path';

const root = path.resolve(import.meta.dirname, '..');
const pkg = path.join(root, 'www/pkg');
const { default: init, demo_scene } = await import(path.join(pkg, 'rogs.js'));
await init({ module_or_path: fs.readFileSync(path.join(pkg, 'rogs_bg.wasm')) });
const t0 = Date.now();
process.stdout.write('generating the demo scene with the wasm engine (about 15 s)… ');
const { bundle, truth_map: map } = demo_scene();
fs.mkdirSync(path.join(root, 'www/demo'), { recursive: true });
fs.writeFileSync(path.join(root, 'www/demo/demo.zip'), bundle);
fs.writeFileSync(path.join(root, 'www/demo/demo-truth.rogsmap'), map);
console.log(`done in ${((Date.now() - t0) / 1000).toFixed(0)} s: www/demo/demo.zip (${(bundle.length / 1048576).toFixed(1)} MiB), www/demo/demo-truth.rogsmap`);
