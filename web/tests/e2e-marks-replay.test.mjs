// End to end, instructor marks: a live session recorded to a scratch directory, a mark made in
// one browser during a press, seen in a second one (listed, and its marker drawn at the contact
// point), and then, after the server stops, in the replay of the
// recording in a third (the list beside the timeline and a mark on its track).
//
//   npm run test:e2e    (builds the server with cargo; SOFTHAPTIC_BIN to reuse a built one)
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, readdirSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { launchBrowser } from './browser.mjs';
import { freezeOnPress, pixelDifference, openViewer } from './e2e-checks.mjs';
import { startServer } from './server.mjs';

const NOTE = 'too fast into the capsule';
const WAIT = { timeout: 60000 };

let browser;
let recordDir;
const pageErrors = [];

before(async () => {
  recordDir = mkdtempSync(join(tmpdir(), 'softhaptic-marks-'));
  browser = await launchBrowser();
});

after(async () => {
  await browser?.close();
  if (recordDir) rmSync(recordDir, { recursive: true, force: true });
});

test('a mark made live shows in another browser and in the replay of the recording', async () => {
  const live = await startServer({
    extraArgs: ['--no-realtime', '--record-dir', recordDir],
    external: false,
  });
  let marked;
  try {
    const instructor = await openViewer(browser, live.url, pageErrors);
    const other = await openViewer(browser, live.url, pageErrors);
    assert.equal(await instructor.evaluate(() => window.__softhaptic.marks().formShown), true);
    // During a press, so the mark carries the point the tool touches.
    await freezeOnPress(instructor, 1e-3);
    const touched = (await instructor.evaluate(() => window.__softhaptic.contact())).point;
    await instructor.evaluate((note) => window.__softhaptic.submitMark(note), NOTE);
    await other.waitForFunction(() => window.__softhaptic.marks().marks.length === 1, null, WAIT);
    marked = (await other.evaluate(() => window.__softhaptic.marks())).marks[0];
    assert.equal(marked.note, NOTE);
    assert.deepEqual(marked.point_m, touched);

    // The other browser draws the mark's marker at its point: placed there, and seen there (the
    // region around the point on the screen, close up and with the tool hidden, read with the
    // markers and, in the same frame, without them). Read up to three times, a frame apart: on a
    // loaded machine one read has come back without the marker drawn in it.
    let drawn;
    let seen;
    for (let attempt = 0; attempt < 3; attempt++) {
      drawn = await other.evaluate((point) => {
        const h = window.__softhaptic;
        h.pause(true);
        h.toolVisible(false);
        h.focusCamera(point, 0.08);
        const at = h.toScreen(point);
        const markers = h.markers();
        const shown = h.regionPixels(at.x, at.y, 20);
        h.markersVisible(false);
        const hidden = h.regionPixels(at.x, at.y, 20);
        h.markersVisible(true);
        return { markers, shown, hidden };
      }, marked.point_m);
      seen = pixelDifference(drawn.shown, drawn.hidden);
      if (seen.mean > 20) break;
      await other.evaluate(() => new Promise((resolve) => requestAnimationFrame(() => resolve())));
    }
    assert.equal(drawn.markers.length, 1);
    assert.equal(drawn.markers[0].id, marked.id);
    assert.deepEqual(drawn.markers[0].position, marked.point_m);
    // Measured about 70 per channel: the marker fills the region.
    assert.ok(seen.mean > 20, `the marker changes the region around its point by ${seen.mean.toFixed(1)} per channel`);
  } finally {
    // A stop signal closes the recording properly.
    await live.stop();
  }

  const files = readdirSync(recordDir).filter((f) => f.endsWith('.mcap'));
  assert.equal(files.length, 1, `recordings: ${files.join(', ')}`);
  const replay = await startServer({
    command: ['replay', join(recordDir, files[0]), '--paused'],
    external: false,
  });
  try {
    const page = await openViewer(browser, replay.url, pageErrors);
    await page.waitForFunction(() => window.__softhaptic.marks().marks.length === 1, null, WAIT);
    const shown = await page.evaluate(() => window.__softhaptic.marks());
    assert.deepEqual(shown.marks[0], marked);
    assert.match(shown.listed[0], new RegExp(`^\\d+\\.\\d s: ${NOTE}$`));
    // A replay takes no new marks: the form is not offered.
    assert.equal(shown.formShown, false);
    // The first status puts the mark on the timeline's track, where it was made.
    await page.waitForFunction(() => window.__softhaptic.replay().gaps.some((g) => g.cause === 'mark'), null, WAIT);
    const r = await page.evaluate(() => window.__softhaptic.replay());
    const onTrack = r.gaps.filter((g) => g.cause === 'mark');
    assert.equal(onTrack.length, 1);
    assert.ok(onTrack[0].title.includes(NOTE), onTrack[0].title);
    const status = r.lastStatus.marks[0];
    assert.ok(Math.abs(onTrack[0].leftPct - (100 * status.time_s) / r.durationS) < 1e-3, JSON.stringify(onTrack));
  } finally {
    await replay.stop();
  }
  assert.deepEqual(pageErrors, []);
});
