// The instructor's view of a palpation (docs/exercises.md): the palpation scene at a station with
// tokens, searched with a SpaceMouse whose reports come from a script (pressed down, then slid
// around the top of the liver), and the instructor's page showing the two hidden lumps drawn
// inside the organ and the trainee's path over its surface; the trainee's own page (the
// observer's link) would show neither (web/screenshots/palpation-instructor.jpg).
//
//   npm run screenshot:palpation    (builds and starts the server as the browser tests do;
//                                    SOFTHAPTIC_BIN to reuse a built one)
//
// The picture is a JPEG kept under 150 KB (the script says its size, and fails above it).
import { mkdtempSync, readFileSync, rmSync, statSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { fileURLToPath } from 'node:url';

import { launchBrowser } from './browser.mjs';
import { REPO, startServer } from './server.mjs';

const PICTURE = fileURLToPath(new URL('../screenshots/palpation-instructor.jpg', import.meta.url));
const MAX_BYTES = 150 * 1024;
const WAIT = { timeout: 120000 };

/** A three-axis report of raw values, as hex bytes (id first). */
function axisReport(id, [x, y, z]) {
  const bytes = [id];
  for (const v of [x, y, z]) bytes.push(v & 0xff, (v >> 8) & 0xff);
  return bytes.map((b) => b.toString(16).padStart(2, '0')).join(' ');
}

/**
 * A trainee's search, as a SpaceMouse's reports (the backend's recorded-stream transport): the
 * puck pushed down onto the organ, then, still pushing, slid one way, across and back, so the
 * path crosses the top of the liver near the lumps. It starts 15 s in, once the page has loaded.
 */
function search() {
  const lines = ['# a palpation search', 'model 046d:c626', `0 ${axisReport(1, [0, 0, 0])}`];
  const legs = [
    [15000, 16500, [0, 0, 350]],
    [16500, 19000, [-250, 0, 300]],
    [19000, 20500, [0, 250, 300]],
    [20500, 23500, [250, 0, 300]],
    [23500, 25000, [0, -250, 300]],
    [25000, 90000, [0, 0, 300]],
  ];
  for (const [from, to, axes] of legs) for (let t = from; t < to; t += 16) lines.push(`${t} ${axisReport(1, axes)}`);
  lines.push('');
  return lines.join('\n');
}

/** The palpation scene with a SpaceMouse playing `scriptPath` (its files named from the repository). */
function scene(scriptPath) {
  const text = readFileSync(join(REPO, 'scenes/palpation.toml'), 'utf8');
  const device = [
    '[device]',
    'kind = "spacemouse"',
    `report_script = ${JSON.stringify(scriptPath)}`,
    '',
    '[device.rate]',
    'workspace_half_extent_m = [0.03, 0.006, 0.03]',
    'home_height_m = 0.004',
    '',
  ].join('\n');
  const start = text.indexOf('[device]');
  const end = text.indexOf('\n[', start + 1) + 1;
  return (text.slice(0, start) + device + text.slice(end)).replaceAll(
    '"calibration/',
    JSON.stringify(join(REPO, 'scenes/calibration')).slice(0, -1) + '/',
  );
}

const dir = mkdtempSync(join(tmpdir(), 'softhaptic-screenshot-'));
writeFileSync(join(dir, 'search.hid'), search());
writeFileSync(join(dir, 'scene.toml'), scene(join(dir, 'search.hid')));
const browser = await launchBrowser();
try {
  const server = await startServer({
    extraArgs: ['--no-realtime', '--scene', join(dir, 'scene.toml'), '--no-record', '--tokens'],
    external: false,
  });
  try {
    const page = await browser.newPage({ viewport: { width: 1280, height: 800 } });
    await page.goto(server.url);
    await page.waitForFunction(() => window.__softhaptic?.ready(), null, WAIT);
    // The search, drawn as its path (from 15 s of device time).
    await page.waitForFunction(() => window.__softhaptic.inclusions()?.pathPoints >= 60, null, WAIT);
    // The search's last leg, then the tool at rest.
    await page.waitForTimeout(3000);
    const drawn = await page.evaluate(() => window.__softhaptic.inclusions());
    // Close over the lumps, from above and to the side, so both spheres and the path show.
    const c = drawn.spheres
      .map((s) => s.centre)
      .reduce((a, p) => a.map((v, i) => v + p[i] / drawn.spheres.length), [0, 0, 0]);
    await page.evaluate((point) => window.__softhaptic.focusCamera(point, 0.14, 1.1), c);
    // The tool hides the path it has just made: the picture leaves it out.
    await page.evaluate(() => window.__softhaptic.toolVisible(false));
    await page.waitForTimeout(500);
    await page.screenshot({ path: PICTURE, type: 'jpeg', quality: 70 });
    const bytes = statSync(PICTURE).size;
    console.log(
      `${PICTURE}: ${(bytes / 1024).toFixed(0)} KB; ${drawn.spheres.length} lumps, ${drawn.pathPoints} path points`,
    );
    if (bytes > MAX_BYTES) {
      console.error(`larger than ${MAX_BYTES / 1024} KB: lower the quality or the size`);
      process.exitCode = 1;
    }
  } finally {
    await server.stop();
  }
} finally {
  await browser.close();
  rmSync(dir, { recursive: true, force: true });
}
