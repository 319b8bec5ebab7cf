// Reads a map file (.rogsmap, docs/MAP.md) lazily: the zip's end record and central
// directory first, then each entry when a view needs it, through File.slice for
// dropped and picked files and HTTP range requests for ?map=URL. A 3.7 km map is
// never read whole: opening one costs its directory and map.json, and each view the
// tiles it shows. Problems are named by entry and field, as `rogs inspect` does.

const td = new TextDecoder();

// A source of bytes: a File or Blob.
export function blobSource(blob, name) {
  return {
    name: name || blob.name || 'map',
    size: blob.size,
    lazy: true,
    read: async (offset, length) => new Uint8Array(await blob.slice(offset, offset + length).arrayBuffer()),
  };
}

// A source of bytes: a URL read by range requests. Servers that ignore ranges send
// the whole file, which then is read from memory (and `lazy` is false).
export async function urlSource(url) {
  const res = await fetch(url, { headers: { Range: 'bytes=-65558' } });
  if (res.status === 206) {
    const m = /\/(\d+)\s*$/.exec(res.headers.get('content-range') || '');
    if (!m) throw new Error(`${url}: the server's Content-Range gives no size`);
    const size = Number(m[1]);
    const tail = new Uint8Array(await res.arrayBuffer());
    return {
      name: url,
      size,
      lazy: true,
      tail: { offset: size - tail.length, bytes: tail },
      async read(offset, length) {
        if (offset >= this.tail.offset && offset + length <= size) {
          const o = offset - this.tail.offset;
          return this.tail.bytes.subarray(o, o + length);
        }
        const r = await fetch(url, { headers: { Range: `bytes=${offset}-${offset + length - 1}` } });
        if (r.status !== 206 && r.status !== 200) throw new Error(`${url}: the server answered ${r.status} ${r.statusText} for bytes ${offset}…`);
        const b = new Uint8Array(await r.arrayBuffer());
        return r.status === 200 ? b.subarray(offset, offset + length) : b;
      },
    };
  }
  if (!res.ok) throw new Error(`${url}: the server answered ${res.status} ${res.statusText}`);
  const all = new Uint8Array(await res.arrayBuffer());
  return { name: url, size: all.length, lazy: false, read: async (o, n) => all.subarray(o, o + n) };
}

export class MapError extends Error {
  constructor(problems) {
    super(problems.map((p) => p.message).join('; '));
    this.problems = problems;
  }
}
const problem = (location, what) => ({ location, message: `${location}: ${what}` });

const u16 = (b, o) => b[o] | (b[o + 1] << 8);
const u32 = (b, o) => (b[o] | (b[o + 1] << 8) | (b[o + 2] << 16) | (b[o + 3] << 24)) >>> 0;
const u64 = (b, o) => u32(b, o) + u32(b, o + 4) * 2 ** 32;

// The zip's entries: name → { method, compressed, size, offset (local header) }.
async function centralDirectory(src) {
  const name = src.name;
  const n = Math.min(src.size, 65558);
  if (src.size < 22) throw new MapError([problem(name, `${src.size} bytes: too short to be a zip archive`)]);
  const tail = await src.read(src.size - n, n);
  let e = -1;
  for (let i = tail.length - 22; i >= 0; i--) {
    if (u32(tail, i) === 0x06054b50) { e = i; break; }
  }
  if (e < 0) throw new MapError([problem(name, 'not a zip archive (no end of central directory); a .rogsmap is a zip')]);
  let count = u16(tail, e + 10), cdSize = u32(tail, e + 12), cdOffset = u32(tail, e + 16);
  if (cdOffset === 0xffffffff || count === 0xffff) {
    // Zip64: the locator sits just before the end record.
    const loc = e - 20;
    if (loc < 0 || u32(tail, loc) !== 0x07064b50) throw new MapError([problem(name, 'zip64 locator missing')]);
    const z = await src.read(u64(tail, loc + 8), 56);
    count = u64(z, 32); cdSize = u64(z, 40); cdOffset = u64(z, 48);
  }
  if (cdOffset + cdSize > src.size) throw new MapError([problem(name, 'the central directory lies past the end of the file (truncated?)')]);
  const cd = await src.read(cdOffset, cdSize);
  const entries = new Map();
  let p = 0;
  for (let i = 0; i < count; i++) {
    if (p + 46 > cd.length || u32(cd, p) !== 0x02014b50) throw new MapError([problem(name, `central directory entry ${i} is damaged`)]);
    const nameLen = u16(cd, p + 28), extraLen = u16(cd, p + 30), commentLen = u16(cd, p + 32);
    const entry = {
      method: u16(cd, p + 10), compressed: u32(cd, p + 20), size: u32(cd, p + 24), offset: u32(cd, p + 42),
    };
    const ename = td.decode(cd.subarray(p + 46, p + 46 + nameLen));
    // Zip64 extra field: the 64-bit values of the fields that read 0xffffffff.
    let x = p + 46 + nameLen;
    const xEnd = x + extraLen;
    while (x + 4 <= xEnd) {
      const id = u16(cd, x), len = u16(cd, x + 2);
      if (id === 1) {
        let q = x + 4;
        if (entry.size === 0xffffffff) { entry.size = u64(cd, q); q += 8; }
        if (entry.compressed === 0xffffffff) { entry.compressed = u64(cd, q); q += 8; }
        if (entry.offset === 0xffffffff) entry.offset = u64(cd, q);
      }
      x += 4 + len;
    }
    entries.set(ename, entry);
    p = xEnd + commentLen;
  }
  return entries;
}

async function inflate(bytes) {
  const s = new Blob([bytes]).stream().pipeThrough(new DecompressionStream('deflate-raw'));
  return new Uint8Array(await new Response(s).arrayBuffer());
}

// One entry's bytes (one read for the local header and the data, a second only when
// the local header's extra field is longer than guessed).
async function readEntry(src, entries, path) {
  const e = entries.get(path);
  if (!e) throw new MapError([problem(path, 'not in the archive')]);
  const guess = 30 + path.length + 64;
  let b = await src.read(e.offset, Math.min(guess + e.compressed, src.size - e.offset));
  if (u32(b, 0) !== 0x04034b50) throw new MapError([problem(path, 'local header damaged')]);
  const start = 30 + u16(b, 26) + u16(b, 28);
  if (start + e.compressed > b.length) b = await src.read(e.offset, start + e.compressed);
  const data = b.subarray(start, start + e.compressed);
  if (e.method === 0) return data;
  if (e.method === 8) {
    try { return await inflate(data); } catch (err) { throw new MapError([problem(path, `cannot inflate (${err.message || err})`)]); }
  }
  throw new MapError([problem(path, `compression method ${e.method} is not supported (stored or deflate)`)]);
}

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
