// The instructor's view of a palpation (docs/exercises.md): the palpation scene and exercise run
// at a station with tokens, and the instructor's page shows the two hidden lumps drawn inside
// the organ and the trainee's path over its surface, while the trainee's own page (the
// observer's link) shows neither (web/screenshots/palpation-instructor.jpg).
//
//   npm run screenshot:palpation    (builds and starts the server as the browser tests do;
//                                    SOFTHAPTIC_BIN to reuse a built one)
//
// The picture is a JPEG kept under 150 KB (the script says its size, and fails above it).
import { mkdtempSync, rmSync, statSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { fileURLToPath } from 'node:url';

import { launchBrowser } from './browser.mjs';
import { startServer } from './server.mjs';

const PICTURE = fileURLToPath(new URL('../screenshots/palpation-instructor.jpg', import.meta.url));
const MAX_BYTES = 150 * 1024;
const WAIT = { timeout: 120000 };

const dir = mkdtempSync(join(tmpdir(), 'softhaptic-screenshot-'));
const browser = await launchBrowser();
try {
  const server = await startServer({
    extraArgs: [
      '--no-realtime',
      '--scene',
      'scenes/palpation.toml',
      '--record-dir',
      join(dir, 'sessions'),
      '--tokens',
      '--exercises',
      'exercises/palpation.toml',
      '--trainee',
      'ana',
      '--exercise-pause',
      'wait',
    ],
    external: false,
  });
  try {
    const page = await browser.newPage({ viewport: { width: 1280, height: 800 } });
    await page.goto(server.url);
    await page.waitForFunction(() => window.__softhaptic?.ready(), null, WAIT);
    // A few seconds of the scripted hand's search, drawn as its path.
    await page.waitForFunction(() => window.__softhaptic.inclusions()?.pathPoints >= 60, null, WAIT);
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
