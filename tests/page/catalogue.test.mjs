// The catalogue of malformed bundles (`rogs example --malformed`: each breaks one thing
// of the tiny example) dropped on the page one after the other: each is refused with a
// problem that names its field or file and states its rule, and the page stays usable.
// tests/catalogue.rs runs the same cases through `rogs inspect` and `rogs reconstruct`.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { useBrowser, openPage, drop, fixtures } from './harness.mjs';

useBrowser();

test('every malformed bundle of the catalogue is refused by name in the page, which survives them all', async () => {
  const cases = JSON.parse(fs.readFileSync(path.join(fixtures, 'catalogue/catalogue.json'), 'utf8'));
  assert.ok(cases.length >= 50, `${cases.length} cases`);
  const { page, errors } = await openPage();
  const failures = [];
  for (const c of cases) {
    const name = `${c.name}.zip`;
    await drop(page, `catalogue/${name}`, name);
    await page.waitForFunction((n) => document.getElementById('status').textContent.includes(n)
      && !document.getElementById('status').textContent.startsWith('Checking'), name, { timeout: 30_000 });
    const status = await page.textContent('#status');
    const lines = await page.$$eval('#problem-list li', (li) => li.map((l) => l.textContent));
    const named = lines.some((l) => l.includes(c.names) && l.includes(c.says));
    if (!/is not a valid bundle/.test(status) || !named) {
      failures.push(`${c.name} (${c.breaks}): expected a problem naming ${JSON.stringify(c.names)} with ${JSON.stringify(c.says)}; status ${JSON.stringify(status)}, problems:\n  ${lines.join('\n  ')}`);
    }
  }
  // Still alive: the valid example opens and can be optimised.
  await drop(page, 'valid.zip');
  await page.waitForSelector('#summary:not([hidden])');
  assert.match(await page.textContent('#status'), /valid\.zip is a valid bundle/);
  assert.equal(await page.isHidden('#optimise'), false);
  assert.deepEqual(errors, []);
  assert.deepEqual(failures, [], failures.join('\n'));
  await page.close();
});
