// The page tests' harness: a static server for www/ and the fixtures (with range
// requests), one headless Chromium with WebGPU on SwiftShader, and helpers to open the
// page and drop a file on it. Screenshots go to target/screenshots/.
import { before, after } from 'node:test';
import fs from 'node:fs';
import path from 'node:path';
import { chromium } from 'playwright-core';
import { createServer } from '../../scripts/serve.mjs';
import { gpuAccountingScript } from './gpu-accounting.mjs';

export const root = path.resolve(import.meta.dirname, '../..');
export const fixtures = path.join(root, 'target/page-fixtures');
export const shots = path.join(root, 'target/screenshots');
const FLAGS = [
  '--no-sandbox', '--enable-unsafe-webgpu', '--enable-features=Vulkan', '--use-vulkan=swiftshader',
  '--use-angle=swiftshader', '--no-first-run', '--disable-background-networking',
  '--disable-component-update', '--disable-sync', '--disable-quic',
];

export const env = { server: null, browser: null, base: '' };

// Registers the file's before/after hooks: the server and the browser. `site`: the
// folder served at / (www/, or dist/ for the published site with its own demo).
export function useBrowser({ site = 'www' } = {}) {
  before(async () => {
    fs.mkdirSync(shots, { recursive: true });
    const www = path.join(root, site);
    env.server = createServer(site === 'www'
      ? [['/fixtures/', fixtures], ['/demo/', fixtures], ['/', www]]
      : [['/fixtures/', fixtures], ['/', www]]);
    await new Promise((r) => env.server.listen(0, '127.0.0.1', r));
    env.base = `http://127.0.0.1:${env.server.address().port}`;
    env.browser = await chromium.launch({ executablePath: '/usr/bin/chromium', args: FLAGS });
  });
  after(async () => {
    await env.browser?.close();
    env.server?.close();
  });
}

// `gpuAccounting`: counts the bytes of every GPU buffer the page creates, as held until
// the buffer or its device is destroyed (window.gpuLiveBytes()): a garbage-collected
// buffer counts as held, so the figure is an upper bound.
export async function openPage(query = '', { gpuAccounting = false } = {}) {
  const page = await env.browser.newPage({ viewport: { width: 1100, height: 800 } });
  const errors = [];
  page.on('pageerror', (e) => errors.push(String(e)));
  const requests = [];
  page.on('request', (r) => requests.push(r.url()));
  // Every Content-Security-Policy violation, as the page saw it.
  await page.addInitScript(() => {
    window.cspViolations = [];
    document.addEventListener('securitypolicyviolation', (e) => window.cspViolations.push(`${e.effectiveDirective} ${e.blockedURI}`));
  });
  if (gpuAccounting) await page.addInitScript(gpuAccountingScript);
  await page.goto(`${env.base}/${query}`);
  await page.waitForSelector('body[data-gpu-checked="true"]', { timeout: 60_000 });
  return { page, errors, requests };
}

export async function cspViolations(page) {
  return page.evaluate(() => window.cspViolations);
}

export async function drop(page, file, name = file) {
  await dropMany(page, [[file, name]]);
}

// Drops several fixture files at once: [[file, name as dropped], …].
export async function dropMany(page, list) {
  const items = list.map(([file, name]) => ({ b64: fs.readFileSync(path.join(fixtures, file)).toString('base64'), name }));
  const dt = await page.evaluateHandle((items) => {
    const t = new DataTransfer();
    for (const { b64, name } of items) {
      const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
      t.items.add(new File([bytes], name, { type: 'application/zip' }));
    }
    return t;
  }, items);
  await page.dispatchEvent('body', 'drop', { dataTransfer: dt });
}
