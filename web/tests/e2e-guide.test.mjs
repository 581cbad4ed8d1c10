// End to end, guidance: a station (the real server) guides its simulated trainee along the
// shipped slide recording (`--guide tests/sessions/slide.mcap`). In Chromium the page draws the
// expert's path, the expert's tool as a ghost at the guide's target (on the path), the path
// ahead of it split from the part covered as the trainee moves on, the guiding force as its own
// arrow, and the gain in the panel.
//
//   npm run test:e2e    (builds the server with cargo; SOFTHAPTIC_BIN to reuse a built one)
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { fileURLToPath } from 'node:url';

import { launchBrowser } from './browser.mjs';
import { openViewer } from './e2e-checks.mjs';
import { startServer } from './server.mjs';

const EXPERT = fileURLToPath(new URL('../../tests/sessions/slide.mcap', import.meta.url));
const WAIT_MS = 60000;

let browser;
const pageErrors = [];

/** Polls the page's guidance drawing until `predicate` holds of it (a generous deadline). */
async function guideWhere(page, predicate) {
  const deadline = Date.now() + WAIT_MS;
  for (;;) {
    const drawn = await page.evaluate(() => window.__softhaptic.guide());
    if (predicate(drawn)) return drawn;
    if (Date.now() > deadline) throw new Error(`the guidance never got there: ${JSON.stringify(drawn)}`);
    await new Promise((resolve) => setTimeout(resolve, 50));
  }
}

before(async () => {
  browser = await launchBrowser();
});

after(async () => {
  await browser?.close();
});

test('a guided station draws the ghost tool on the path, the path ahead and the guiding force', async () => {
  const server = await startServer({
    extraArgs: ['--no-realtime', '--no-record', '--guide', EXPERT, '--guide-gain', '0.75'],
    external: false,
  });
  try {
    const page = await openViewer(browser, server.url, pageErrors);
    const scene = await page.evaluate(() => window.__softhaptic.scene());
    assert.equal(scene.guide.source, 'slide.mcap');
    assert.deepEqual(scene.guide.gain, { mode: 'fixed', gain: 0.75 });
    const path = scene.guide.path_m;
    assert.ok(path.length > 10, `${path.length} points`);

    // Engaged, pulling: the ghost sits on the expert's path (within what blending two frames'
    // targets across a corner of it leaves) and the arrow is drawn.
    const pulling = await guideWhere(page, (g) => g.ghostVisible && g.engaged && g.arrowVisible);
    assert.equal(pulling.pathPoints, path.length);
    assert.equal(pulling.gain, 0.75);
    const onPath = Math.min(
      ...path.slice(0, -1).map((a, i) => distanceToSegment(pulling.ghostPosition, a, path[i + 1])),
    );
    assert.ok(onPath < 1e-3, `the ghost is ${onPath} m off the path`);
    assert.ok(pulling.arrowLengthM > 0.004, `arrow ${pulling.arrowLengthM} m`);
    assert.match(pulling.summary, /^gain 75 % · /);

    // The trainee moves on along the path (the demonstration's hand slides): the path ahead
    // starts further along.
    const later = await guideWhere(page, (g) => g.ghostVisible && g.aheadFrom > pulling.aheadFrom + 5);
    assert.ok(later.aheadFrom < path.length);

    // The panel shows it.
    await page.waitForFunction(
      () => {
        const row = document.getElementById('guide-row');
        return !row.hidden && /^gain 75 %/.test(document.getElementById('v-guide').textContent);
      },
      null,
      { timeout: WAIT_MS },
    );
    assert.deepEqual(pageErrors, []);
    await page.close();
  } finally {
    await server.stop();
  }
});

test('a station without a guide draws none and hides the row', async () => {
  const server = await startServer({ extraArgs: ['--no-realtime', '--no-record'], external: false });
  try {
    const page = await openViewer(browser, server.url, pageErrors);
    await page.waitForFunction(() => window.__softhaptic.contactFrames() > 20, null, { timeout: WAIT_MS });
    const drawn = await page.evaluate(() => window.__softhaptic.guide());
    assert.equal(drawn.source, null);
    assert.equal(drawn.pathPoints, 0);
    assert.equal(drawn.ghostVisible, false);
    assert.equal(drawn.arrowVisible, false);
    assert.equal(await page.evaluate(() => document.getElementById('guide-row').hidden), true);
    await page.close();
  } finally {
    await server.stop();
  }
});

function distanceToSegment(p, a, b) {
  const ab = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
  const ap = [p[0] - a[0], p[1] - a[1], p[2] - a[2]];
  const len2 = ab[0] ** 2 + ab[1] ** 2 + ab[2] ** 2;
  const u = len2 > 0 ? Math.min(1, Math.max(0, (ap[0] * ab[0] + ap[1] * ab[1] + ap[2] * ab[2]) / len2)) : 0;
  return Math.hypot(ap[0] - u * ab[0], ap[1] - u * ab[1], ap[2] - u * ab[2]);
}
