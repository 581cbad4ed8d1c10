// The exercise results report in a browser: `softhaptic results` on the shipped recordings,
// scored as attempts at the shipped press exercise, writes an HTML page; headless Chromium opens
// it and finds the attempts' table and one drawn plot per metric, each with the pass mark's line
// when the exercise sets one. The page needs no server and no script.
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { spawnSync } from 'node:child_process';
import { mkdtempSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { pathToFileURL } from 'node:url';

import { launchBrowser } from './browser.mjs';
import { REPO, buildServer } from './server.mjs';

let dir;
let browser;

before(async () => {
  dir = mkdtempSync(join(tmpdir(), 'softhaptic-results-'));
  browser = await launchBrowser();
});

after(async () => {
  await browser?.close();
  if (dir) rmSync(dir, { recursive: true, force: true });
});

test('the results report shows every attempt and a plot per metric', async () => {
  const recordings = ['sphere-press', 'slide', 'fault-mid-press'].map((n) =>
    join(REPO, 'tests', 'sessions', `${n}.mcap`),
  );
  const html = join(dir, 'results.html');
  const run = spawnSync(
    buildServer(),
    [
      'results',
      ...recordings,
      '--exercise',
      join(REPO, 'exercises', 'press-hold.toml'),
      '--trainee',
      'ana',
      '--csv',
      join(dir, 'results.csv'),
      '--html',
      html,
    ],
    { encoding: 'utf8' },
  );
  assert.equal(run.status, 0, run.stderr);
  const page = await browser.newPage();
  const errors = [];
  page.on('pageerror', (e) => errors.push(e.message));
  await page.goto(pathToFileURL(html).href);
  assert.equal(await page.locator('h1').textContent(), 'Press and hold 1 N');
  // A header row and one row per attempt, numbered in the order given.
  const rows = await page.locator('table tr').count();
  assert.equal(rows, 1 + recordings.length);
  assert.deepEqual(await page.locator('table tr td:nth-child(2)').allTextContents(), ['1', '2', '3']);
  // One plot per metric of a press, each an SVG with its trainee's line drawn.
  const plots = page.locator('figure.plot');
  const metrics = await plots.evaluateAll((figures) => figures.map((f) => f.dataset.metric));
  assert.deepEqual(metrics, ['hold_s', 'time_to_hold_s', 'hold_force_sd_n', 'peak_force_n', 'time_above_safe_s']);
  for (let i = 0; i < metrics.length; i++) {
    const svg = plots.nth(i).locator('svg');
    const box = await svg.boundingBox();
    assert.ok(box && box.width > 300 && box.height > 150, `${metrics[i]}: the plot is drawn (${JSON.stringify(box)})`);
    assert.ok((await svg.locator('polyline, path').count()) > 0, `${metrics[i]}: a line`);
    assert.ok(
      (await svg.locator('text').allTextContents()).some((t) => t.includes('ana')),
      `${metrics[i]}: the trainee's legend`,
    );
  }
  assert.deepEqual(errors, []);
});
