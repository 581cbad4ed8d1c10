// End to end through the SpaceMouse backend: the real server with the default scene driven by a
// SpaceMouse whose reports come from a report script (the backend's recorded-stream transport,
// named by the scene's `report_script`), the real viewer page in headless Chromium, read through
// the page's test hook.
//
//   npm run test:e2e    (builds the server with cargo; SOFTHAPTIC_BIN to reuse a built one)
//
// The script pushes the puck down for a few seconds (the tool goes into the liver until the
// scene's box stops it 5 mm under the press site), lets go (the tool rests there, pressing),
// then the device is unplugged for good. Checks: the page says the force is not felt and names the SpaceMouse; a press shows a
// real force and R_d, drawn though not felt; the unplug reads "input device disconnected"; no
// page error.
//
// Every check waits for what it needs with a generous deadline (a slow machine only delays it).
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { logTail, openPage, waitOnPage } from './e2e-fixtures.mjs';
import { REPO, startServer } from './server.mjs';

/** A three-axis report of raw values, as hex bytes (id first). */
function axisReport(id, [x, y, z]) {
  const bytes = [id];
  for (const v of [x, y, z]) bytes.push(v & 0xff, (v >> 8) & 0xff);
  return bytes.map((b) => b.toString(16).padStart(2, '0')).join(' ');
}

/**
 * The puck pushed down (HID +z) from 1 s to 5 s, a report every 16 ms; the tool then rests on the
 * box's floor, pressing, until the device is unplugged at 25 s (time for a slow machine to load
 * the page while the press lasts).
 */
function script() {
  const lines = ['# the e2e test puck', 'model 046d:c626', `0 ${axisReport(1, [0, 0, 0])}`];
  for (let t = 1000; t < 5000; t += 16) lines.push(`${t} ${axisReport(1, [0, 0, 350])}`);
  lines.push(`5000 ${axisReport(1, [0, 0, 0])}`, '25000 unplug', '');
  return lines.join('\n');
}

/** The default scene with a SpaceMouse playing `scriptPath` and a box floor 5 mm deep. */
function scene(scriptPath) {
  const text = readFileSync(join(REPO, 'scenes/default.toml'), 'utf8');
  const table = join(REPO, 'scenes/calibration/sphere10_50kpa.json');
  const device = [
    '[device]',
    'kind = "spacemouse"',
    `report_script = ${JSON.stringify(scriptPath)}`,
    '',
    '[device.rate]',
    'workspace_half_extent_m = [0.06, 0.005, 0.06]',
    'home_height_m = 0.004',
    '',
  ].join('\n');
  const start = text.indexOf('[device]');
  const end = text.indexOf('\n[', start + 1) + 1;
  return (text.slice(0, start) + device + text.slice(end)).replace(
    '"calibration/sphere10_50kpa.json"',
    JSON.stringify(table),
  );
}

const dir = mkdtempSync(join(tmpdir(), 'softhaptic-e2e-spacemouse-'));
let server;
let view;
let page;

before(async () => {
  const scriptPath = join(dir, 'puck.hid');
  writeFileSync(scriptPath, script());
  writeFileSync(join(dir, 'scene.toml'), scene(scriptPath));
  server = await startServer({
    extraArgs: ['--scene', join(dir, 'scene.toml'), '--no-record'],
    external: false,
  });
  view = await openPage();
  page = view.page;
  await page.goto(server.url);
  await page.waitForFunction(() => window.__softhaptic?.ready(), null, { timeout: 120000 });
});

after(async () => {
  await view?.close();
  await server?.stop();
  rmSync(dir, { recursive: true, force: true });
});

const waitFor = (what, predicate, arg = null) =>
  waitOnPage(page, what, predicate, arg, () => logTail('server', server));

test('the page says the force is not felt and names the SpaceMouse', async () => {
  await waitFor('the hello', () => window.__softhaptic.role() !== null);
  const feedback = await page.evaluate(() => window.__softhaptic.forceFeedback());
  assert.deepEqual(feedback, { felt: false, shown: 'not felt' });
  const scene = await page.evaluate(() => window.__softhaptic.scene());
  assert.equal(scene.device.force_feedback, false);
  assert.match(scene.device.name, /SpaceNavigator \(SpaceMouse, report stream .*puck\.hid; renders no force\)/);
});

test('a push shows a real force and R_d, drawn though not felt', async () => {
  await waitFor('a press of the liver', () => {
    const c = window.__softhaptic.contact();
    return c.valid && c.inContact && c.depthM > 0.002 && c.forceMagnitudeN > 0.1;
  });
  const c = await page.evaluate(() => window.__softhaptic.contact());
  assert.ok(c.deformedRadiusM > c.depthM, JSON.stringify(c));
});

test('an unplug reads "input device disconnected"', async () => {
  await waitFor('the unplug in the panel', () => window.__softhaptic.device().shown === 'input device disconnected');
  const device = await page.evaluate(() => window.__softhaptic.device());
  assert.equal(device.status, 'disconnected');
  assert.deepEqual(view.pageErrors, []);
});
