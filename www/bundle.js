// Scene bundles read lazily: a drive larger than LAZY_BYTES (or any, with ?lazy=1)
// is opened by its zip's directory and manifest.json only; the engine then asks for
// the files of one tile at a time, read from the dropped file through File.slice
// (or from a URL by range requests) and inflated here. The wasm heap holds one
// tile's files, never the drive (docs/ARCHITECTURE.md, "Lazy reading").
import { centralDirectory, readEntry, ArchiveError, problem } from './zip.js';

// Bundles above this size are read lazily.
export const LAZY_BYTES = 256 * 1024 * 1024;

export function lazyForced() {
  return new URLSearchParams(location.search).get('lazy') === '1';
}

// { name, names, sizes, manifest, read(path) } for a byte source (zip.js).
export async function openLazyBundle(src) {
  const entries = await centralDirectory(src);
  const names = [...entries.keys()].filter((n) => !n.endsWith('/'));
  if (!entries.has('manifest.json')) {
    throw new ArchiveError([problem('manifest.json', 'missing at the root of the bundle (a scene bundle is a zip with manifest.json at its root; docs/BUNDLE.md)')]);
  }
  const manifest = await readEntry(src, entries, 'manifest.json');
  return {
    name: src.name,
    size: src.size,
    names,
    sizes: names.map((n) => entries.get(n).size),
    manifest,
    read: (path) => readEntry(src, entries, path),
  };
}

// The engine's reader over several lazily read drives: [[drive, path], …] → bytes.
// Reads run a few at a time so that a tile's hundreds of files stream in order.
export function readerOf(bundles, onRead = () => {}) {
  return async (pairs) => {
    const out = new Array(pairs.length);
    let next = 0;
    const worker = async () => {
      while (next < pairs.length) {
        const i = next++;
        const [k, path] = pairs[i];
        out[i] = await bundles[k].read(path);
        onRead(out[i].length);
      }
    };
    await Promise.all(Array.from({ length: Math.min(8, pairs.length) }, worker));
    return out;
  };
}
