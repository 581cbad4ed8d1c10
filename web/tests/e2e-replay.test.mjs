// End to end, replay: the real `softhaptic replay` serving a recorded session (started paused),
// the real viewer page in headless Chromium, the timeline driven with the mouse.
//
//   npm run test:e2e    (builds the server with cargo; SOFTHAPTIC_BIN to reuse a built one)
//
// Checks: the timeline appears with the recording's duration and nothing plays until asked;
// the speed selector and the play button are obeyed (the server's status says so), the time
// advances between the 1 Hz statuses and contact frames arrive; releasing the scrubber seeks
// (the server's answer confirms the position) and the force plot keeps what was played before
// the new position; pause holds the position and stops the frames;
// a seek while paused shows the recorded frame at the new position. Saves a screenshot to
// web/test-results/replay.png. Then, replaying a recording whose press went above the scene's
// safe force, the timeline marks the very stretches where the exported 1 kHz ticks did.
//
// The machine may be slow (software WebGL, two cores): the checks read the statuses the page
// logged rather than racing the replay's clock.
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { spawnSync } from 'node:child_process';
import { mkdirSync, mkdtempSync, readFileSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { fileURLToPath } from 'node:url';

import { launchBrowser } from './browser.mjs';
import { REPO, buildServer, startServer } from './server.mjs';

const RESULTS = fileURLToPath(new URL('../test-results/', import.meta.url));
const RECORDING = 'tests/sessions/sphere-press.mcap';
// The replay runs from the recording's first contact frame to its last: 150 frames at 50 Hz.
const DURATION_S = 2.98;
const WAIT = { timeout: 30000, polling: 'raf' };

let server;
let browser;
let page;
const pageErrors = [];

const replay = () => page.evaluate(() => window.__softhaptic.replay());

/**
 * Releases the scrubber at `fraction` of its track (a click: press and release) and waits for
 * the server's answer: the first status after the seek, exactly at the position asked for.
 * Returns the seek sent, the status log before it, and the answer.
 */
async function seekWithScrubber(fraction) {
  const before = await replay();
  // A click on the thumb where it already stands changes nothing, and a range input then fires
  // no `change`: on a slow machine the replay may have paused right there. Aim beside it.
  const current = before.scrubber.value / DURATION_S;
  if (Math.abs(current - fraction) < 0.05) fraction += fraction < 0.5 ? 0.1 : -0.1;
  const box = await page.locator('#replay-scrubber').boundingBox();
  await page.mouse.click(box.x + box.width * fraction, box.y + box.height / 2);
  await page.waitForFunction((n) => window.__softhaptic.replay().sent.length > n, before.sent.length, WAIT);
  const seek = (await replay()).sent.at(-1);
  assert.equal(seek.action, 'seek');
  // The answer to a control is sent at once, at the position it set (to the nanosecond).
  // The log keeps the last 50 statuses: those received since `before` are its last
  // (received now − received before).
  await page.waitForFunction(
    ({ from, target }) => {
      const r = window.__softhaptic.replay();
      const fresh = r.statusLog.slice(Math.max(0, r.statusLog.length - (r.statusesReceived - from)));
      return fresh.some((s) => Math.abs(s.time_s - target) < 1e-6);
    },
    { from: before.statusesReceived, target: seek.time_s },
    WAIT,
  );
  const after = await replay();
  const answer = after.statusLog
    .slice(Math.max(0, after.statusLog.length - (after.statusesReceived - before.statusesReceived)))
    .find((s) => Math.abs(s.time_s - seek.time_s) < 1e-6);
  return { seek, before, answer };
}

before(async () => {
  // A replay server of its own, even when SOFTHAPTIC_URL names a live one.
  server = await startServer({ command: ['replay', RECORDING, '--paused'], external: false });
  browser = await launchBrowser();
  page = await browser.newPage({ viewport: { width: 1280, height: 800 } });
  page.on('pageerror', (e) => pageErrors.push(e.message));
  await page.goto(server.url);
  await page.waitForFunction(() => window.__softhaptic?.ready(), null, { timeout: 120000 });
  // The first status comes within a second of connecting.
  await page.waitForFunction(() => window.__softhaptic.replay().known, null, WAIT);
});

after(async () => {
  await browser?.close();
  await server?.stop();
});

test('a paused replay shows the timeline with the duration of the recording and plays nothing', async () => {
  const r = await replay();
  assert.equal(r.panelVisible, true);
  assert.ok(await page.locator('#replay-panel').isVisible(), 'the timeline panel is on screen');
  assert.equal(r.lastStatus.duration_s, r.durationS);
  assert.ok(Math.abs(r.durationS - DURATION_S) < 1e-9, `duration ${r.durationS} s`);
  assert.equal(r.scrubber.max, r.durationS);
  assert.equal(r.paused, true);
  assert.equal(r.positionS, 0);
  assert.equal(r.file, 'sphere-press.mcap');
  assert.equal(await page.locator('#replay-time').textContent(), '0:00.0 / 0:02.9');
  assert.equal(await page.locator('#replay-play').textContent(), '▶ play');
  assert.equal(await page.locator('#mode').textContent(), 'replay');
  // The info panel names the recorded contact model (recordings older than the field: the law).
  const scene = await page.evaluate(() => window.__softhaptic.scene());
  const label = scene.contact_model?.label ?? 'Hertz';
  assert.equal(await page.locator('#v-model').textContent(), label);
  // Paused, the replay shows its first recorded frame (the tool where the session began) and
  // plays nothing more.
  await page.waitForFunction(() => window.__softhaptic.contactFrames() >= 1, null, WAIT);
  await page.waitForTimeout(1200);
  assert.equal(await page.evaluate(() => window.__softhaptic.contactFrames()), 1, 'paused: the first frame only');
  assert.equal((await replay()).positionS, 0);
});

// A quarter speed: the 3 s recording plays for 12 s of wall time, so that a loaded machine (software
// WebGL, two cores shared with a build) still seeks and pauses it before it ends.
test('at quarter speed, play advances the time between statuses and the contact frames arrive', async () => {
  await page.selectOption('#replay-speed', '0.25');
  await page.waitForFunction(
    () => {
      const s = window.__softhaptic.replay().lastStatus;
      return s.speed === 0.25 && s.paused;
    },
    null,
    WAIT,
  );
  await page.click('#replay-play');
  await page.waitForFunction(() => window.__softhaptic.replay().lastStatus.paused === false, null, WAIT);
  assert.equal(await page.locator('#replay-play').textContent(), '❚❚ pause');

  // Animation frames (ten, over at least a second): the scrubber moves every frame, not only when
  // a status arrives (once a second). How many frames a second the page draws depends on the
  // machine; whether it moves between two statuses does not.
  const samples = await page.evaluate(
    () =>
      new Promise((resolve) => {
        const out = [];
        const start = performance.now();
        const step = () => {
          const r = window.__softhaptic.replay();
          out.push({
            atMs: performance.now(),
            position: r.positionS,
            scrubber: r.scrubber.value,
            statuses: r.statusesReceived,
          });
          const elapsedMs = performance.now() - start;
          if ((out.length < 10 || elapsedMs < 1000) && elapsedMs < 30000) requestAnimationFrame(step);
          else resolve(out);
        };
        requestAnimationFrame(step);
      }),
  );
  for (let i = 1; i < samples.length; i++) {
    assert.ok(samples[i].position >= samples[i - 1].position, `position went back at sample ${i}`);
  }
  const advanced = samples.at(-1).position - samples[0].position;
  const elapsedS = (samples.at(-1).atMs - samples[0].atMs) / 1000;
  // At 0.25× the position moves a quarter as fast as the wall clock (a status may correct it by
  // the network's delay, a few milliseconds).
  assert.ok(Math.abs(advanced - 0.25 * elapsedS) < 0.1, `advanced ${advanced} s in ${elapsedS} s at 0.25×`);
  const movedBetweenStatuses = samples.some(
    (s, i) => i > 0 && s.statuses === samples[i - 1].statuses && s.scrubber > samples[i - 1].scrubber,
  );
  assert.ok(
    movedBetweenStatuses,
    `the scrubber moved only when a status arrived: ${JSON.stringify(samples.map((s) => [s.scrubber, s.statuses]))}`,
  );

  await page.waitForFunction(() => window.__softhaptic.contactFrames() > 10, null, WAIT);
  const c = await page.evaluate(() => window.__softhaptic.contact());
  assert.ok(c.valid, 'a contact is drawn');
});

test('releasing the scrubber while playing seeks, and the server answers at the new position', async () => {
  // A loaded machine may let the replay run to its end, where it pauses, before the seek lands:
  // then back near the start, play, and again (a few times at most). A seek that pauses a replay
  // that was playing fails every time.
  let seek;
  let before;
  let answer;
  for (let attempt = 0; attempt < 3; attempt++) {
    if ((await replay()).lastStatus.paused) {
      await seekWithScrubber(0.1);
      await page.click('#replay-play');
      await page.waitForFunction(() => window.__softhaptic.replay().lastStatus.paused === false, null, WAIT);
    }
    await page.waitForFunction(() => window.__softhaptic.replay().positionS > 1.2, null, WAIT);
    // A quarter of the way along the track: behind the position, away from the thumb.
    ({ seek, before, answer } = await seekWithScrubber(0.25));
    if (!answer.paused) break;
  }
  assert.ok(seek.time_s > 0.3 && seek.time_s < 1.1, `seek to ${seek.time_s} s`);
  assert.equal(answer.paused, false, 'a seek keeps playing');
  // The position before the seek was well past the target: the replay jumped back. (Not the last
  // status's: at 0.25× it can trail the replay by a quarter of a second, once a second.)
  assert.ok(before.positionS > seek.time_s + 0.2, `from ${before.positionS} s to ${seek.time_s} s`);
  assert.ok(answer.time_s < before.positionS - 0.2, `the server answered at ${answer.time_s} s`);
  assert.ok((await replay()).clockRestarts > before.clockRestarts, 'the frames after the jump are timed afresh');
  // The force plot keeps what was played before the new position; the frames after it come again.
  await page.waitForFunction(
    (target) => window.__softhaptic.forcePlotSamples().some((s) => s.timeMs / 1000 > target + 0.05),
    seek.time_s,
    WAIT,
  );
  const samples = await page.evaluate(() => window.__softhaptic.forcePlotSamples());
  assert.ok(
    samples.some((s) => s.timeMs / 1000 < seek.time_s - 0.2),
    `the plot starts at ${samples[0]?.timeMs} ms, after the seek to ${seek.time_s} s`,
  );
  assert.ok(
    samples.every((s, i) => i === 0 || s.timeMs > samples[i - 1].timeMs),
    'the plot is in time order',
  );
});

test('pause holds the position and the frames stop', async () => {
  // On a slow machine the replay may have reached its end (and paused) meanwhile, or be about
  // to: go back near the start and play on, so that the pause lands inside the recording.
  // A loaded machine may also let it run to the end between the play and the pause: then again,
  // a few times at most.
  let p1;
  for (let attempt = 0; attempt < 3; attempt++) {
    const r = await replay();
    if (r.paused || r.positionS > DURATION_S - 1) {
      await seekWithScrubber(0.2);
      if ((await replay()).lastStatus.paused) {
        await page.click('#replay-play');
        await page.waitForFunction(() => window.__softhaptic.replay().lastStatus.paused === false, null, WAIT);
      }
    }
    await page.click('#replay-play');
    await page.waitForFunction(() => window.__softhaptic.replay().lastStatus.paused === true, null, WAIT);
    p1 = await replay();
    if (p1.positionS > 0 && p1.positionS < DURATION_S) break;
  }
  const frames1 = await page.evaluate(() => window.__softhaptic.contactFrames());
  await page.waitForTimeout(1000);
  const p2 = await replay();
  const frames2 = await page.evaluate(() => window.__softhaptic.contactFrames());
  assert.equal(p2.positionS, p1.positionS);
  assert.equal(p2.positionS, p2.lastStatus.time_s);
  assert.ok(p2.positionS > 0 && p2.positionS < DURATION_S);
  assert.ok(frames2 - frames1 <= 1, `${frames2 - frames1} frames arrived while paused`);
  assert.equal(await page.locator('#replay-play').textContent(), '▶ play');
  assert.match(await page.locator('#contact-state').textContent(), /paused/);
});

test('a seek while paused shows the recorded frame at the new position', async () => {
  // Two thirds along: the sphere is held pressed there.
  const { seek, answer } = await seekWithScrubber(0.66);
  assert.equal(answer.paused, true, 'a seek keeps the replay paused');
  await page.waitForFunction(
    (target) => {
      const h = window.__softhaptic;
      const c = h.contact();
      // The frame in effect at the target: the last one at or before it (50 Hz).
      return c.valid && c.deviceTimeMs / 1000 <= target + 1e-9 && c.deviceTimeMs / 1000 > target - 0.021;
    },
    seek.time_s,
    WAIT,
  );
  const r = await replay();
  // Held where the server says (which counts in nanoseconds: 1e-6 s covers the rounding).
  assert.equal(r.positionS, r.lastStatus.time_s);
  assert.ok(Math.abs(r.positionS - seek.time_s) < 1e-6, `position ${r.positionS} s`);
  assert.ok(Math.abs(r.scrubber.value - seek.time_s) < 0.006, `scrubber at ${r.scrubber.value}`);
  const c = await page.evaluate(() => window.__softhaptic.contact());
  assert.ok(c.inContact && c.depthM > 1e-3, `pressed ${c.depthM} m deep at ${seek.time_s} s`);

  // A screenshot of the paused replay, the tool and the dimple in view, the model expanded.
  await page.click('#v-model');
  await page.evaluate((p) => window.__softhaptic.focusCamera(p, 0.12, 0.35), c.point);
  await page.waitForTimeout(1500);
  mkdirSync(RESULTS, { recursive: true });
  await page.screenshot({ path: `${RESULTS}replay.png` });
});

test('the replay viewer counted no malformed or unknown message and raised no page error', async () => {
  const conn = await page.evaluate(() => window.__softhaptic.connection());
  assert.equal(conn.stats.malformed, 0, conn.lastError ?? '');
  assert.equal(conn.stats.unknown, 0, 'replay statuses are known messages');
  // Speed, play, seek, pause, seek; and a seek (and a play) more when the replay had to be taken
  // back before the pause.
  const sent = (await replay()).sent;
  assert.equal(conn.stats.sent, sent.length);
  const actions = sent.map((c) => c.action);
  // The speed goes with the action that keeps the state: paused then.
  assert.equal(sent[0].speed, 0.25);
  assert.deepEqual(actions.slice(0, 3), ['pause', 'play', 'seek'], actions.join(', '));
  assert.deepEqual(actions.slice(-2), ['pause', 'seek'], actions.join(', '));
  assert.deepEqual(pageErrors, []);
});

/**
 * The stretches of a recording's 1 kHz ticks where |F| was above its scene's safe force, in
 * seconds from its first contact frame (replay time 0), read from what `softhaptic export`
 * writes (device.csv, contact.csv, metrics.json): each run of consecutive ticks above, from its
 * first tick to its last.
 */
function aboveSafeFromExport(recording) {
  const out = mkdtempSync(join(tmpdir(), 'softhaptic-export-'));
  try {
    const result = spawnSync(buildServer(), ['export', recording, '--out', out], { cwd: REPO, encoding: 'utf8' });
    assert.equal(result.status, 0, `softhaptic export failed: ${result.stderr}`);
    const rows = (name) => {
      const [header, ...lines] = readFileSync(join(out, name), 'utf8').trim().split('\n');
      const column = Object.fromEntries(header.split(',').map((h, i) => [h, i]));
      return lines.map((line) => {
        const cells = line.split(',');
        return (name) => cells[column[name]];
      });
    };
    const safeForceN = JSON.parse(readFileSync(join(out, 'metrics.json'), 'utf8')).safe_force_n;
    const startNs = BigInt(rows('contact.csv')[0]('time_ns'));
    const seconds = (ns) => Number(ns - startNs) * 1e-9;
    const spans = [];
    let open = null;
    for (const tick of rows('device.csv')) {
      const force = Math.hypot(...['force_x_n', 'force_y_n', 'force_z_n'].map((c) => Number(tick(c))));
      const timeNs = BigInt(tick('time_ns'));
      if (force > safeForceN) open = { start: open?.start ?? timeNs, end: timeNs };
      else if (open) {
        spans.push({ startS: seconds(open.start), endS: seconds(open.end) });
        open = null;
      }
    }
    if (open) spans.push({ startS: seconds(open.start), endS: seconds(open.end) });
    return { safeForceN, spans };
  } finally {
    rmSync(out, { recursive: true, force: true });
  }
}

test('the timeline marks where the recorded ticks pushed harder than the safe force', async () => {
  // The press of this recording peaks just above the default scene's 2 N.
  const recording = 'tests/sessions/fault-mid-press.mcap';
  const expected = aboveSafeFromExport(recording);
  assert.ok(expected.spans.length >= 1, `no tick above ${expected.safeForceN} N in ${recording}`);
  const other = await startServer({ command: ['replay', recording, '--paused'], external: false });
  const p = await browser.newPage({ viewport: { width: 1280, height: 800 } });
  const errors = [];
  p.on('pageerror', (e) => errors.push(e.message));
  try {
    await p.goto(other.url);
    await p.waitForFunction(() => window.__softhaptic?.ready(), null, { timeout: 120000 });
    await p.waitForFunction(() => window.__softhaptic.replay().known, null, WAIT);
    const r = await p.evaluate(() => window.__softhaptic.replay());
    // The server's status, to the nanosecond (ticks are a millisecond apart).
    const sent = r.lastStatus.above_safe ?? [];
    assert.equal(sent.length, expected.spans.length, JSON.stringify({ sent, expected }));
    sent.forEach((s, i) => {
      const e = expected.spans[i];
      assert.ok(
        Math.abs(s.start_s - e.startS) < 1e-9 && Math.abs(s.end_s - e.endS) < 1e-9,
        JSON.stringify({ sent, expected }),
      );
    });
    // The track: one mark per stretch, where it starts, saying how long it lasted.
    const marks = r.gaps.filter((g) => g.cause === 'above_safe');
    assert.equal(marks.length, expected.spans.length, JSON.stringify(r.gaps));
    marks.forEach((m, i) => {
      const e = expected.spans[i];
      assert.ok(Math.abs(m.leftPct - (100 * e.startS) / r.durationS) < 1e-3, `mark at ${m.leftPct} %`);
      const lastedS = sent[i].end_s - sent[i].start_s;
      assert.match(m.title, new RegExp(`^above the safe force for ${lastedS.toFixed(2)} s at `));
    });
    assert.deepEqual(errors, []);
  } finally {
    await p.close();
    await other.stop();
  }
});
