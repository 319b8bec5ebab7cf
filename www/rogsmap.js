// Reads a map file (.rogsmap, docs/MAP.md) lazily: the zip's end record and central
// directory first, then each entry when a view needs it, through File.slice for
// dropped and picked files and HTTP range requests for ?map=URL. A 3.7 km map is
// never read whole: opening one costs its directory and map.json, and each view the
// tiles it shows. Problems are named by entry and field, as `rogs inspect` does.

import { ArchiveError, blobSource, urlSource, centralDirectory, readEntry, problem } from './zip.js';

export { blobSource, urlSource };
// A map's problems are the archive's (entries named as `rogs inspect` names them).
export { ArchiveError as MapError };
const MapError = ArchiveError;
const td = new TextDecoder();

const LEVEL_LIMIT = 1 << 22;

// Checks map.json as `rogs inspect` does for the fields a viewer relies on.
export function checkIndex(ix, entries) {
  const out = [];
  const f = (field, what) => out.push(problem(`map.json: ${field}`, what));
  if (typeof ix !== 'object' || ix === null || Array.isArray(ix)) { f('(root)', 'expected an object'); return out; }
  if (ix.format !== 'rogs-map') f('format', `found ${JSON.stringify(ix.format)}, expected "rogs-map"`);
  if (ix.version !== 1) f('version', `found ${JSON.stringify(ix.version)}, this page reads version 1`);
  const num = (k) => typeof ix[k] === 'number' && Number.isFinite(ix[k]);
  if (!num('resolution') || ix.resolution <= 0) f('resolution', `found ${JSON.stringify(ix.resolution)}, expected a positive number of metres per pixel`);
  if (!Array.isArray(ix.origin) || ix.origin.length !== 2 || !ix.origin.every(Number.isFinite)) f('origin', 'expected [x, y], finite world coordinates');
  for (const k of ['width', 'height']) {
    if (!Number.isInteger(ix[k]) || ix[k] < 1 || ix[k] > LEVEL_LIMIT) f(k, `found ${JSON.stringify(ix[k])}, expected 1 to ${LEVEL_LIMIT} pixels`);
  }
  if (ix.tile !== 256) f('tile', `found ${JSON.stringify(ix.tile)}, expected 256`);
  for (const k of ['layers', 'values', 'classes', 'trajectory']) {
    if (!Array.isArray(ix[k])) f(k, `expected an array, found ${JSON.stringify(ix[k])}`);
  }
  if (out.length) return out;
  const want = levelCount(ix.width, ix.height);
  if (ix.levels !== want) f('levels', `found ${ix.levels}, expected ${want} (halve until one tile holds the map)`);
  if (ix.present !== undefined) {
    if (!Array.isArray(ix.present) || ix.present.length !== want) f('present', `expected ${want} strings, one per level`);
    else {
      ix.present.forEach((p, k) => {
        const [tx, ty] = tilesOf(ix, k);
        if (typeof p !== 'string' || p.length !== tx * ty || /[^01]/.test(p)) f(`present[${k}]`, `expected ${tx * ty} characters 0 or 1 (${tx}×${ty} tiles)`);
      });
    }
  }
  if (!out.length && entries) {
    // The coarsest level must be there: it is the first view.
    const k = want - 1;
    for (const name of ix.layers) {
      const p = `layers/${name}/${k}/0_0.png`;
      if (isPresent(ix, k, 0, 0) && !entries.has(p)) out.push(problem(`map.json: layers["${name}"]`, `file "${p}" is not in the archive`));
    }
  }
  return out;
}

export function levelCount(w, h) {
  let k = 1;
  while (Math.ceil(Math.max(w, h) / 2 ** (k - 1)) > 256) k++;
  return k;
}
export function levelSize(ix, k) { return [Math.ceil(ix.width / 2 ** k), Math.ceil(ix.height / 2 ** k)]; }
export function tilesOf(ix, k) { const [w, h] = levelSize(ix, k); return [Math.ceil(w / 256), Math.ceil(h / 256)]; }
export function isPresent(ix, k, c, r) {
  if (!ix.present) return true;
  const [tx] = tilesOf(ix, k);
  return ix.present[k]?.[r * tx + c] === '1';
}

// Opens a map: its directory and index (named problems as a MapError), and readers
// for its tiles. Tiles that are not present are empty (null), never an error.
export async function openMap(src) {
  const entries = await centralDirectory(src);
  if (!entries.has('map.json')) {
    const hint = entries.has('manifest.json') ? ' This is a scene bundle: open it to build its map.' : '';
    throw new MapError([problem('map.json', `missing at the archive's root; a .rogsmap holds map.json (docs/MAP.md).${hint}`)]);
  }
  let index;
  try {
    index = JSON.parse(td.decode(await readEntry(src, entries, 'map.json')));
  } catch (e) {
    if (e instanceof MapError) throw e;
    throw new MapError([problem('map.json', `not valid JSON (${e.message})`)]);
  }
  const problems = checkIndex(index, entries);
  if (problems.length) throw new MapError(problems);
  const classNames = new Map(index.classes.map((c) => [c.id, c]));
  return {
    src, entries, index, classNames,
    name: index.name || src.name,
    // A layer's tile as an ImageBitmap, or null where the map has nothing.
    async tile(layer, k, c, r) {
      if (!isPresent(index, k, c, r)) return null;
      const path = `layers/${layer}/${k}/${c}_${r}.png`;
      const bytes = await readEntry(src, entries, path);
      try {
        return await createImageBitmap(new Blob([bytes], { type: 'image/png' }));
      } catch (e) {
        throw new MapError([problem(path, `cannot decode the image (${e.message || e})`)]);
      }
    },
    // A value tile as a Float32Array (NaN where empty), or null.
    async values(name, k, c, r) {
      if (!isPresent(index, k, c, r) || !index.values.includes(name)) return null;
      const path = `values/${name}/${k}/${c}_${r}.f32`;
      const b = await readEntry(src, entries, path);
      const [w, h] = tileSize(index, k, c, r);
      if (b.length !== 4 * w * h) throw new MapError([problem(path, `${b.length} bytes, expected ${4 * w * h} (${w}×${h} float32)`)]);
      return new Float32Array(b.slice().buffer);
    },
    // The stored thumbnail nearest to `frame` (frames listed in `thumbnails`), as
    // { frame, url } of a blob URL, or null when the map has none.
    async thumbnail(frame) {
      const t = index.thumbnails || [];
      if (!t.length) return null;
      const f = t.reduce((best, x) => (Math.abs(x - frame) < Math.abs(best - frame) ? x : best), t[0]);
      const bytes = await readEntry(src, entries, `thumbs/${String(f).padStart(6, '0')}.jpg`);
      return { frame: f, url: URL.createObjectURL(new Blob([bytes], { type: 'image/jpeg' })) };
    },
    async report() {
      try { return JSON.parse(td.decode(await readEntry(src, entries, index.report))); } catch { return null; }
    },
  };
}

export function tileSize(ix, k, c, r) {
  const [w, h] = levelSize(ix, k);
  return [Math.min(256, w - c * 256), Math.min(256, h - r * 256)];
}

// Whether a source holds a map (map.json) rather than a bundle: reads only the directory.
export async function isMapFile(src) {
  try { return (await centralDirectory(src)).has('map.json'); } catch { return false; }
}
