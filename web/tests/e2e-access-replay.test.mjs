// End to end, roles in a replay: the real `softhaptic replay --tokens` (started paused), an
// instructor's page and an observer's page in headless Chromium, each in a browser context of
// its own (as two machines would be).
//
//   npm run test:e2e    (builds the server with cargo; SOFTHAPTIC_BIN to reuse a built one)
//
// Checks: the observer sees the shared timeline but no replay controls; the instructor's play,
// seek and pause move the observer's timeline (the status the observer receives says so, and
// its scrubber follows); a replay control an observer sends all the same is refused with a
// reason shown beside the timeline, the connection stays open and the replay does not move;
// Chromium reports no CSP violation on either page.
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';

import { launchBrowser } from './browser.mjs';
import { watchCsp } from './e2e-checks.mjs';
import { startServer } from './server.mjs';

const RECORDING = 'tests/sessions/slide.mcap';
const WAIT = { timeout: 30000, polling: 'raf' };

let server;
let browser;
const pages = {};

const replay = (page) => page.evaluate(() => window.__softhaptic.replay());

/** A page for `url` in a context of its own, watched for CSP violations and page errors. */
async function openPage(url) {
  const context = await browser.newContext({ viewport: { width: 1280, height: 800 } });
  const page = await context.newPage();
  const errors = [];
  page.on('pageerror', (e) => errors.push(e.message));
  const csp = await watchCsp(page);
  await page.goto(url);
  await page.waitForFunction(() => window.__softhaptic?.ready(), null, { timeout: 120000 });
  // The first status comes within a second of connecting.
  await page.waitForFunction(() => window.__softhaptic.replay().known, null, WAIT);
  return { page, csp, errors };
}

/**
 * Waits until `page` has received a status at `timeS` (to the microsecond) after its first `from`
 * statuses. The log keeps the last 50: those received since are its last (received − from).
 */
async function statusAt(page, from, timeS) {
  await page.waitForFunction(
    ({ from, timeS }) => {
      const r = window.__softhaptic.replay();
      const fresh = r.statusLog.slice(Math.max(0, r.statusLog.length - (r.statusesReceived - from)));
      return fresh.some((s) => Math.abs(s.time_s - timeS) < 1e-6);
    },
    { from, timeS },
    WAIT,
  );
}

before(async () => {
  server = await startServer({ command: ['replay', RECORDING, '--paused', '--tokens'], external: false });
  assert.ok(server.observerUrl, `the replay printed an observer's link:\n${server.output()}`);
  browser = await launchBrowser();
  pages.instructor = await openPage(server.url);
  pages.observer = await openPage(server.observerUrl);
});

after(async () => {
  await browser?.close();
  await server?.stop();
});

test('the observer sees the shared timeline and its role, but no replay controls', async () => {
  const { page } = pages.observer;
  assert.equal(await page.evaluate(() => window.__softhaptic.role()), 'observer');
  assert.equal(await page.evaluate(() => window.__softhaptic.mode()), 'replay');
  assert.equal(await page.locator('#role').textContent(), 'observer');
  assert.ok(await page.locator('#replay-panel').isVisible(), 'the timeline is shown');
  assert.ok(!(await page.locator('#replay-play').isVisible()), 'no play/pause button');
  assert.ok(!(await page.locator('#replay-speed').isVisible()), 'no speed selector');
  assert.ok(await page.locator('#replay-scrubber').isDisabled(), 'the scrubber only shows the position');
  assert.match(await page.locator('#replay-hint').textContent(), /the instructor moves the timeline/);
  assert.equal((await replay(page)).controllable, false);

  const instructor = pages.instructor.page;
  assert.equal(await instructor.evaluate(() => window.__softhaptic.role()), 'instructor');
  assert.ok(await instructor.locator('#replay-play').isVisible());
  assert.ok(await instructor.locator('#replay-speed').isVisible());
  assert.ok(await instructor.locator('#replay-scrubber').isEnabled());
});

test('the instructor’s play, seek and pause move the observer’s timeline', async () => {
  const instructor = pages.instructor.page;
  const observer = pages.observer.page;
  const duration = (await replay(observer)).durationS;
  assert.ok(duration > 1, `the recording lasts ${duration} s`);

  // A quarter speed: the recording plays for 12 s, so that a loaded machine pauses it before
  // its end (a play at the end starts it over).
  await instructor.selectOption('#replay-speed', '0.25');
  await observer.waitForFunction(() => window.__softhaptic.replay().lastStatus.speed === 0.25, null, WAIT);
  const before = await replay(observer);
  await instructor.click('#replay-play');
  await observer.waitForFunction(() => window.__softhaptic.replay().lastStatus.paused === false, null, WAIT);
  await observer.waitForFunction(() => window.__softhaptic.contactFrames() > 5, null, WAIT);

  await instructor.click('#replay-play'); // pause
  await observer.waitForFunction(() => window.__softhaptic.replay().lastStatus.paused === true, null, WAIT);

  // A click on the scrubber's track at 70 %, away from where the replay stands, seeks there.
  const logged = (await replay(observer)).statusesReceived;
  const sent = (await replay(instructor)).sent.length;
  const box = await instructor.locator('#replay-scrubber').boundingBox();
  await instructor.mouse.click(box.x + box.width * 0.7, box.y + box.height / 2);
  await instructor.waitForFunction((n) => window.__softhaptic.replay().sent.length > n, sent, WAIT);
  const seek = (await replay(instructor)).sent.at(-1);
  assert.equal(seek.action, 'seek');
  await statusAt(observer, logged, seek.time_s);
  const seen = await replay(observer);
  assert.equal(seen.paused, true);
  assert.ok(Math.abs(seen.positionS - seek.time_s) < 1e-6, `the observer's timeline at ${seen.positionS} s`);
  assert.ok(Math.abs(seen.scrubber.value - seek.time_s) < 0.006, `the observer's scrubber at ${seen.scrubber.value}`);
  assert.ok(Math.abs(seek.time_s - before.positionS) > 0.3, 'the timeline jumped');
  assert.deepEqual(seen.sent, [], 'the observer sent nothing');
});

test('a control an observer sends all the same is refused beside the timeline, and the connection stays open', async () => {
  const { page } = pages.observer;
  const before = await page.evaluate(() => ({
    replay: window.__softhaptic.replay(),
    connection: window.__softhaptic.connection(),
  }));
  assert.equal(before.replay.paused, true);
  assert.equal(await page.evaluate(() => window.__softhaptic.sendReplayControl('play')), true);
  await page.waitForFunction(() => window.__softhaptic.replay().refusals.length > 0, null, WAIT);
  const after = await page.evaluate(() => ({
    replay: window.__softhaptic.replay(),
    connection: window.__softhaptic.connection(),
  }));
  assert.equal(after.replay.refusedShown, true);
  assert.match(after.replay.refusedText, /^refused: \S/);
  assert.ok(await page.locator('#replay-refused').isVisible());
  assert.equal(after.connection.state, 'open');
  assert.equal(after.connection.stats.connects, before.connection.stats.connects, 'not closed and reopened');
  assert.equal(after.connection.stats.malformed, 0);
  // The replay did not start: a second later it still stands where it was.
  await page.waitForTimeout(1200);
  const later = await replay(page);
  assert.equal(later.lastStatus.paused, true);
  assert.equal(later.positionS, before.replay.positionS);
  // The reason goes after a few seconds.
  await page.waitForFunction(() => !window.__softhaptic.replay().refusedShown, null, { timeout: 10000 });
});

test('Chromium reports no CSP violation and no page error on either page', async () => {
  for (const [role, { page, csp, errors }] of Object.entries(pages)) {
    assert.deepEqual(await csp.list(), [], role);
    assert.deepEqual(errors, [], role);
    const conn = await page.evaluate(() => window.__softhaptic.connection());
    assert.equal(conn.stats.unknown, 0, `${role}: every message known`);
  }
});
