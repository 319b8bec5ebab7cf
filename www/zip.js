// Reads zip archives lazily: the end record and central directory first, then each
// entry when it is needed, through File.slice for dropped and picked files and HTTP
// range requests for URLs. Map files (.rogsmap, rogsmap.js) and long scene bundles
// (bundle.js) are read through it, never whole. Problems are named by entry.

const td = new TextDecoder();

// A source of bytes: a File or Blob.
export function blobSource(blob, name) {
  return {
    name: name || blob.name || 'file',
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

export class ArchiveError extends Error {
  constructor(problems) {
    super(problems.map((p) => p.message).join('; '));
    this.problems = problems;
  }
}
export const problem = (location, what) => ({ location, message: `${location}: ${what}` });

const u16 = (b, o) => b[o] | (b[o + 1] << 8);
const u32 = (b, o) => (b[o] | (b[o + 1] << 8) | (b[o + 2] << 16) | (b[o + 3] << 24)) >>> 0;
const u64 = (b, o) => u32(b, o) + u32(b, o + 4) * 2 ** 32;

// The zip's entries: name → { method, compressed, size, offset (local header) }.
export async function centralDirectory(src) {
  const name = src.name;
  const n = Math.min(src.size, 65558);
  if (src.size < 22) throw new ArchiveError([problem(name, `${src.size} bytes: too short to be a zip archive`)]);
  const tail = await src.read(src.size - n, n);
  let e = -1;
  for (let i = tail.length - 22; i >= 0; i--) {
    if (u32(tail, i) === 0x06054b50) { e = i; break; }
  }
  if (e < 0) throw new ArchiveError([problem(name, 'not a zip archive (no end of central directory)')]);
  let count = u16(tail, e + 10), cdSize = u32(tail, e + 12), cdOffset = u32(tail, e + 16);
  if (cdOffset === 0xffffffff || count === 0xffff) {
    // Zip64: the locator sits just before the end record.
    const loc = e - 20;
    if (loc < 0 || u32(tail, loc) !== 0x07064b50) throw new ArchiveError([problem(name, 'zip64 locator missing')]);
    const z = await src.read(u64(tail, loc + 8), 56);
    count = u64(z, 32); cdSize = u64(z, 40); cdOffset = u64(z, 48);
  }
  if (cdOffset + cdSize > src.size) throw new ArchiveError([problem(name, 'the central directory lies past the end of the file (truncated?)')]);
  const cd = await src.read(cdOffset, cdSize);
  const entries = new Map();
  let p = 0;
  for (let i = 0; i < count; i++) {
    if (p + 46 > cd.length || u32(cd, p) !== 0x02014b50) throw new ArchiveError([problem(name, `central directory entry ${i} is damaged`)]);
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
export async function readEntry(src, entries, path) {
  const e = entries.get(path);
  if (!e) throw new ArchiveError([problem(path, 'not in the archive')]);
  const guess = 30 + path.length + 64;
  let b = await src.read(e.offset, Math.min(guess + e.compressed, src.size - e.offset));
  if (u32(b, 0) !== 0x04034b50) throw new ArchiveError([problem(path, 'local header damaged')]);
  const start = 30 + u16(b, 26) + u16(b, 28);
  if (start + e.compressed > b.length) b = await src.read(e.offset, start + e.compressed);
  const data = b.subarray(start, start + e.compressed);
  if (e.method === 0) return data;
  if (e.method === 8) {
    try { return await inflate(data); } catch (err) { throw new ArchiveError([problem(path, `cannot inflate (${err.message || err})`)]); }
  }
  throw new ArchiveError([problem(path, `compression method ${e.method} is not supported (stored or deflate)`)]);
}

