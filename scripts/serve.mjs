// A minimal static file server for the page (no dependencies). Serves www/ and, for
// tests, extra folders mounted under a prefix. Binds to 127.0.0.1 only.
import http from 'node:http';
import fs from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';

const TYPES = {
  '.html': 'text/html; charset=utf-8', '.js': 'text/javascript', '.mjs': 'text/javascript',
  '.css': 'text/css', '.wasm': 'application/wasm', '.json': 'application/json',
  '.png': 'image/png', '.zip': 'application/zip', '.svg': 'image/svg+xml',
  '.rogsmap': 'application/zip',
};

// One file, whole or as the single byte range a `Range: bytes=a-b` (or `bytes=-n`)
// header asks for: the page reads map files lazily by range requests.
function serveFile(req, res, file) {
  fs.stat(file, (err, st) => {
    if (err || !st.isFile()) { res.writeHead(404, { 'content-type': 'text/plain' }); res.end('not found'); return; }
    const headers = {
      'content-type': TYPES[path.extname(file)] || 'application/octet-stream',
      'cache-control': 'no-store', 'accept-ranges': 'bytes',
      // A page on another origin may open what is served here (?url= names a server).
      'access-control-allow-origin': '*',
    };
    const m = /^bytes=(\d*)-(\d*)$/.exec(req.headers.range || '');
    let start = 0, end = st.size - 1, status = 200;
    if (m && (m[1] || m[2])) {
      if (m[1]) { start = Number(m[1]); if (m[2]) end = Math.min(end, Number(m[2])); }
      else start = Math.max(0, st.size - Number(m[2]));
      if (start > end || start >= st.size) {
        res.writeHead(416, { 'content-range': `bytes */${st.size}` });
        res.end();
        return;
      }
      status = 206;
      headers['content-range'] = `bytes ${start}-${end}/${st.size}`;
    }
    headers['content-length'] = String(end - start + 1);
    res.writeHead(status, headers);
    if (req.method === 'HEAD') { res.end(); return; }
    fs.createReadStream(file, { start, end }).pipe(res);
  });
}

/** mounts: [[urlPrefix, directory]], longest prefix first. */
export function createServer(mounts) {
  return http.createServer((req, res) => {
    const url = decodeURIComponent(new URL(req.url, 'http://x').pathname);
    for (const [prefix, dir] of mounts) {
      if (!url.startsWith(prefix)) continue;
      let rel = url.slice(prefix.length) || 'index.html';
      if (rel.endsWith('/')) rel += 'index.html';
      const file = path.resolve(dir, rel);
      if (!file.startsWith(path.resolve(dir) + path.sep)) break;
      serveFile(req, res, file);
      return;
    }
    res.writeHead(404, { 'content-type': 'text/plain' });
    res.end('not found');
  });
}

if (process.argv[1] === fileURLToPath(import.meta.url)) {
  const i = process.argv.indexOf('--port');
  const port = i > 0 ? Number(process.argv[i + 1]) : 8080;
  const r = process.argv.indexOf('--root');
  const root = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '..');
  const dir = r > 0 ? path.resolve(process.argv[r + 1]) : path.join(root, 'www');
  createServer([['/', dir]]).listen(port, '127.0.0.1', () => {
    console.log(`rogs is running at http://127.0.0.1:${port}/  (Ctrl+C to stop)`);
  });
}
