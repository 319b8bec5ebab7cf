// The surfel PLY files as a real Gaussian-splat reader sees them: PlayCanvas's
// splat-transform converts our fixtures (z up, y up, class colours) to CSV, and every
// value must be what the surfels hold, transformed here independently of the writer.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { execFileSync } from 'node:child_process';
import { root, fixtures } from './harness.mjs';

const C0 = 0.28209479177387814;
const FLAT = -9.21;
const cli = path.join(root, 'node_modules/@playcanvas/splat-transform/bin/cli.mjs');

function read(name) {
  const out = path.join(fixtures, `${name}.csv`);
  execFileSync(process.execPath, [cli, '-q', '-w', path.join(fixtures, `${name}.ply`), out]);
  const [head, ...rows] = fs.readFileSync(out, 'utf8').trim().split('\n');
  const cols = head.split(',');
  return rows.map((r) => Object.fromEntries(r.split(',').map((v, i) => [cols[i], Number(v)])));
}

const near = (a, b, what, tol = 1e-5) => assert.ok(Math.abs(a - b) <= tol, `${what}: read ${a}, expected ${b}`);

function expectations(up, colours) {
  const s = JSON.parse(fs.readFileSync(path.join(fixtures, 'splats.json'), 'utf8'));
  return s.pos.map((p, i) => {
    const q0 = s.rotation[i];
    const n0 = Math.hypot(...q0);
    let [w, x, y, z] = q0.map((v) => v / n0);
    let pos = p;
    if (up === 'y') {
      // −90° about x: (x, y, z) → (x, z, −y); the rotation composed on the left.
      pos = [p[0], p[2], -p[1]];
      const h = Math.SQRT1_2;
      [w, x, y, z] = [h * w + h * x, h * x - h * w, h * y + h * z, h * z - h * y];
    }
    const rgb = colours ? s.class_colours[i].map((c) => c / 255) : s.rgb[i];
    return {
      pos, rot: [w, x, y, z], dc: rgb.map((c) => (c - 0.5) / C0), scale: [...s.log_scale[i], FLAT], opacity: s.opacity[i],
      normal: [2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)],
    };
  });
}

for (const [name, up, colours] of [['splats-z', 'z', false], ['splats-y', 'y', false], ['splats-semantic', 'z', true]]) {
  test(`${name}.ply reads back in splat-transform with every surfel as written`, () => {
    const rows = read(name);
    const want = expectations(up, colours);
    assert.equal(rows.length, want.length);
    rows.forEach((r, i) => {
      const e = want[i];
      ['x', 'y', 'z'].forEach((k, j) => near(r[k], e.pos[j], `surfel ${i} ${k}`));
      [0, 1, 2, 3].forEach((j) => near(r[`rot_${j}`], e.rot[j], `surfel ${i} rot_${j}`));
      [0, 1, 2].forEach((j) => near(r[`f_dc_${j}`], e.dc[j], `surfel ${i} f_dc_${j}`));
      [0, 1, 2].forEach((j) => near(r[`scale_${j}`], e.scale[j], `surfel ${i} scale_${j}`));
      ['nx', 'ny', 'nz'].forEach((k, j) => near(r[k], e.normal[j], `surfel ${i} ${k}`));
      near(r.opacity, e.opacity, `surfel ${i} opacity`);
    });
    // The header says which axis is up.
    const head = fs.readFileSync(path.join(fixtures, `${name}.ply`)).subarray(0, 600).toString('latin1');
    assert.match(head, new RegExp(`comment up ${up}`));
  });
}

test('with y up, every position and normal is the z-up one turned: (x, y, z) → (x, z, −y)', () => {
  const z = read('splats-z'), y = read('splats-y');
  z.forEach((a, i) => {
    const b = y[i];
    near(b.x, a.x, 'x'); near(b.y, a.z, 'y'); near(b.z, -a.y, 'z');
    near(b.nx, a.nx, 'nx'); near(b.ny, a.nz, 'ny'); near(b.nz, -a.ny, 'nz');
  });
});
