// Removes the custom sections a browser never reads (function names, producers,
// debug info) from a wasm file, in place: `node scripts/strip-wasm.mjs FILE.wasm`.
//
// Why here and not in Cargo: wasm-bindgen finds its externref table by name, so the
// engine is compiled with its name section kept (`strip = "none"` in Cargo.toml's
// wasm-release profile); a module stripped before wasm-bindgen exports the function
// table in its place and fails to load ("WebAssembly.Table.set(): Argument 1 is
// invalid for table"). After wasm-bindgen the names only cost bytes. Custom sections
// carry no semantics, so removing them cannot change what the module does.
import fs from 'node:fs';

const file = process.argv[2];
if (!file) {
  console.error('usage: node scripts/strip-wasm.mjs FILE.wasm');
  process.exit(2);
}
const bytes = fs.readFileSync(file);
if (bytes.length < 8 || bytes.readUInt32LE(0) !== 0x6d736100) {
  console.error(`${file}: not a wasm module (no \\0asm header)`);
  process.exit(3);
}

/** Reads an unsigned LEB128 at `pos`: [value, next position]. */
function leb(pos) {
  let value = 0;
  let shift = 0;
  for (;;) {
    if (pos >= bytes.length) throw new Error(`${file}: truncated at byte ${pos}`);
    const b = bytes[pos++];
    value += (b & 0x7f) * 2 ** shift;
    shift += 7;
    if (!(b & 0x80)) return [value, pos];
  }
}

const keep = [bytes.subarray(0, 8)];
const dropped = [];
let pos = 8;
while (pos < bytes.length) {
  const start = pos;
  const id = bytes[pos];
  const [size, body] = leb(pos + 1);
  const end = body + size;
  if (end > bytes.length) throw new Error(`${file}: section at byte ${start} runs past the end`);
  if (id === 0) {
    const [len, name] = leb(body);
    dropped.push(`${bytes.subarray(name, name + len).toString()} (${end - start} bytes)`);
  } else {
    keep.push(bytes.subarray(start, end));
  }
  pos = end;
}
const out = Buffer.concat(keep);
fs.writeFileSync(file, out);
console.log(`strip-wasm: ${file}: ${bytes.length} → ${out.length} bytes${dropped.length ? `, removed ${dropped.join(', ')}` : ''}`);
