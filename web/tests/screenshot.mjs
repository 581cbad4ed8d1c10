// The README's screenshot of the viewer (web/screenshots/dent-and-metrics.jpg): the default
// scene's press close up with the depression map on and the section through the contact, the
// see-through tool over the dent, a mark in the list, and the whole panel with the trainee's
// metrics.
//
//   npm run screenshot    (builds and starts the server as the browser tests do; SOFTHAPTIC_BIN
//                          to reuse a built one)
//
// The window is as tall as the panel, so nothing in it is cut off; the picture is a JPEG kept
// under 150 KB (the script says its size, and fails above it).
import { statSync } from 'node:fs';
import { fileURLToPath } from 'node:url';

import { launchBrowser } from './browser.mjs';
import { freezeOffSurface, freezeOnPress } from './e2e-checks.mjs';
import { startServer } from './server.mjs';

const OUT = fileURLToPath(new URL('../screenshots/dent-and-metrics.jpg', import.meta.url));
const MAX_BYTES = 150 * 1024;
const WIDTH_PX = 1280;
const WAIT = { timeout: 120000 };

const server = await startServer({ extraArgs: ['--no-realtime', '--no-record'] });
const browser = await launchBrowser();
try {
  const page = await browser.newPage({ viewport: { width: WIDTH_PX, height: 900 } });
  await page.goto(server.url);
  await page.waitForFunction(() => window.__softhaptic?.ready(), null, WAIT);
  // A few presses, so the trainee's metrics have something to say.
  await page.waitForFunction(() => (window.__softhaptic.metrics().last?.pushes ?? 0) >= 2, null, WAIT);
  // A mark made between presses (listed under the legend; no marker, as nothing was touched).
  await freezeOffSurface(page);
  await page.evaluate(() => window.__softhaptic.submitMark('second press: steadier, well under the safe force'));
  await page.waitForFunction(() => window.__softhaptic.marks().marks.length === 1, null, WAIT);
  // Tall enough for the whole panel: its height is held to the window's less 110 px (style.css).
  const heightPx = await page.evaluate(() => Math.ceil(document.getElementById('status').scrollHeight + 110 + 4));
  await page.setViewportSize({ width: WIDTH_PX, height: Math.max(heightPx, 800) });

  await page.evaluate(() => window.__softhaptic.depressionMap(true));
  // The default press holds about 3.4 mm; 3 mm catches the hold.
  await freezeOnPress(page, 3e-3);
  const c = await page.evaluate(() => window.__softhaptic.contact());
  // Close and low, cut open through the contact: the dent's profile, coloured by the map, under
  // the see-through tool and against the line of the surface before the press.
  await page.evaluate((p) => {
    window.__softhaptic.focusCamera(p, 0.06, 0.12);
    window.__softhaptic.section(true);
  }, c.point);
  // Drawn and written: the panel shows the frozen depth (it updates four times a second), and
  // two more animation frames have passed since.
  await page.waitForFunction(
    (depth) => document.getElementById('v-depth').textContent === `${(depth * 1e3).toFixed(2)} mm`,
    c.depthM,
    WAIT,
  );
  await page.evaluate(
    () => new Promise((resolve) => requestAnimationFrame(() => requestAnimationFrame(() => resolve()))),
  );
  await page.screenshot({ path: OUT, type: 'jpeg', quality: 70 });
  const bytes = statSync(OUT).size;
  console.log(`${OUT}: ${(bytes / 1024).toFixed(0)} KB, ${WIDTH_PX} × ${Math.max(heightPx, 800)} px`);
  if (bytes > MAX_BYTES) {
    console.error(`larger than ${MAX_BYTES / 1024} KB: lower the quality or the size`);
    process.exitCode = 1;
  }
} finally {
  await browser.close();
  await server.stop();
}
