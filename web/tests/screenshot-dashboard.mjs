// The instructor's dashboard of docs/dashboard.md (web/screenshots/dashboard.jpg): a lab of ten
// real stations on a real nats-server (tests/dashboard-lab.mjs): five running an exercise for a
// trainee (three still running, two failed at their 20 s time limit), two pressing calmly, two
// whose trainees press above a 0.05 N safe force, one whose SpaceMouse was unplugged; the hub's
// `/dashboard` in headless Chromium, the instructor's link. One of the alerts is acknowledged
// first, so the alert list shows both kinds of entry. Then the same lab as a room of fifty in
// compact tiles (web/screenshots/dashboard-compact.jpg): forty more stations, two of the real
// ones' heartbeats published again under other names, the pointer on one tile.
//
//   npm run screenshot:dashboard    (builds and starts the servers as the browser tests do;
//                                    SOFTHAPTIC_BIN to reuse a built one; needs nats-server)
//
// Each picture is a JPEG kept under 150 KB (the script says its size, and fails above it).
import { mkdtempSync, rmSync, statSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { fileURLToPath } from 'node:url';

import { launchBrowser } from './browser.mjs';
import { copyHeartbeats, startDashboardLab, writeStationFiles } from './dashboard-lab.mjs';

const PICTURE = fileURLToPath(new URL('../screenshots/dashboard.jpg', import.meta.url));
const COMPACT_PICTURE = fileURLToPath(new URL('../screenshots/dashboard-compact.jpg', import.meta.url));
const MAX_BYTES = 150 * 1024;
const WAIT = { timeout: 120000 };

const dir = mkdtempSync(join(tmpdir(), 'softhaptic-screenshot-dashboard-'));
const args = writeStationFiles(dir);
const stations = [
  ['desk-1', args.exercises('Ana Costa', { timeLimitS: 300 })],
  ['desk-2', args.exercises('Ben Okafor', { timeLimitS: 300 })],
  ['desk-3', args.hard],
  ['desk-4', args.calm],
  ['desk-5', args.exercises('Chloé Martin')],
  ['desk-6', args.unplugged],
  ['desk-7', args.exercises('Dev Patel', { timeLimitS: 300 })],
  ['desk-8', args.calm],
  ['desk-9', args.hard],
  ['desk-10', args.exercises('Eli Novak')],
];
/** Says a picture's size, and fails the run when it is above `MAX_BYTES`. */
function report(picture, count) {
  const bytes = statSync(picture).size;
  console.log(`${picture}: ${(bytes / 1024).toFixed(0)} KB; ${count} stations`);
  if (bytes > MAX_BYTES) {
    console.error(`larger than ${MAX_BYTES / 1024} KB: lower the quality or the size`);
    process.exitCode = 1;
  }
}

const lab = await startDashboardLab(dir, stations);
const copying = [];
const browser = await launchBrowser();
try {
  const page = await browser.newPage({ viewport: { width: 1280, height: 800 } });
  await page.goto(lab.dashboardUrl);
  await page.waitForFunction(
    (n) => window.__dashboard?.message()?.stations.filter((s) => s.summary !== null).length === n,
    stations.length,
    WAIT,
  );
  // The three stations in alert, then desk-9's first alert acknowledged.
  await page.waitForFunction(() => window.__dashboard.tiles().filter((t) => t.alert).length >= 3, null, WAIT);
  const [first] = (await page.evaluate(() => window.__dashboard.tiles())).find((t) => t.name === 'desk-9').openAlerts;
  await page.click(`.tile[data-station="desk-9"] button.ack[data-alert="${first.id}"]`);
  await page.waitForFunction(
    (id) => window.__dashboard.alertList().some((a) => a.station === 'desk-9' && a.id === id && !a.open),
    first.id,
    WAIT,
  );
  // Twenty seconds of presses in the sparklines.
  await page.waitForTimeout(20000);
  await page.screenshot({ path: PICTURE, type: 'jpeg', quality: 70 });
  report(PICTURE, stations.length);

  // A room of fifty in compact tiles: forty more stations saying what desk-4 (calm) and desk-2
  // (an exercise) say, the pointer on one tile to open its buttons.
  const more = Array.from({ length: 40 }, (_, i) => `desk-${i + 11}`);
  copying.push(await copyHeartbeats(lab.natsUrl, 'desk-4', more.slice(0, 28)));
  copying.push(await copyHeartbeats(lab.natsUrl, 'desk-2', more.slice(28)));
  await page.check('#compact');
  await page.waitForFunction(() => window.__dashboard.tiles().length === 50, null, WAIT);
  await page.waitForTimeout(3000);
  await page.hover('.tile[data-station="desk-13"] .spark');
  // Fifty tiles of fine print: a lower quality keeps the picture under the bound.
  await page.screenshot({ path: COMPACT_PICTURE, type: 'jpeg', quality: 50 });
  report(COMPACT_PICTURE, 50);
  await page.uncheck('#compact');
} finally {
  for (const c of copying) await c.stop();
  await browser.close();
  await lab.stop();
  rmSync(dir, { recursive: true, force: true });
}
