// End to end, exercises: a station (the real server, with tokens) runs two exercises for a
// trainee. In Chromium, the instructor's page and the observer's show the task (its name, the
// target, the ring or the path drawn in the 3-D view), the countdown running down and the result
// at the end; the instructor starts the next exercise and stops it with the panel's buttons; the
// observer is offered no buttons, and the control it sends anyway is refused.
//
//   npm run test:e2e    (builds the server with cargo; SOFTHAPTIC_BIN to reuse a built one)
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { launchBrowser } from './browser.mjs';
import { openViewer } from './e2e-checks.mjs';
import { startServer } from './server.mjs';

const WAIT = { timeout: 60000 };

// The simulated device's scripted hand peaks near 1.4 N: this press ends by its 1 s limit.
const PRESS = `name = "Press and hold 1.8 N"
instructions = "Press the ring with 1.8 N and hold it."
kind = "press"
time_limit_s = 1.0

[press]
site_radius_m = 0.005
target_force_n = 1.8
tolerance_n = 0.1
hold_s = 0.9
`;

const TRACE = `name = "Trace a line"
instructions = "Follow the line from end to end."
kind = "trace"
time_limit_s = 600.0

[trace]
path_m = [[-0.0297, 0.0681, 0.0068], [-0.01495, 0.0700, 0.00667]]
tolerance_m = 0.003
min_coverage = 0.9
`;

let browser;
let dir;
const pageErrors = [];

/** Polls the page's exercise panel until `predicate` holds of it (a generous deadline). */
async function exerciseWhere(page, predicate) {
  const deadline = Date.now() + WAIT.timeout;
  for (;;) {
    const shown = await page.evaluate(() => window.__softhaptic.exercise());
    if (predicate(shown)) return shown;
    if (Date.now() > deadline) throw new Error(`the exercise panel never got there: ${JSON.stringify(shown)}`);
    await new Promise((resolve) => setTimeout(resolve, 100));
  }
}

before(async () => {
  dir = mkdtempSync(join(tmpdir(), 'softhaptic-exercise-'));
  writeFileSync(join(dir, 'press.toml'), PRESS);
  writeFileSync(join(dir, 'trace.toml'), TRACE);
  browser = await launchBrowser();
});

after(async () => {
  await browser?.close();
  if (dir) rmSync(dir, { recursive: true, force: true });
});

test('a station runs exercises: the task, the countdown and the result shown; an instructor moves them on', async () => {
  const server = await startServer({
    extraArgs: [
      '--no-realtime',
      '--record-dir',
      join(dir, 'sessions'),
      '--tokens',
      '--exercises',
      join(dir, 'press.toml'),
      join(dir, 'trace.toml'),
      '--trainee',
      'ana',
      '--exercise-pause',
      'wait',
    ],
    external: false,
  });
  try {
    const instructor = await openViewer(browser, server.url, pageErrors);
    const observer = await openViewer(browser, server.observerUrl, pageErrors);

    // The press, for ana, with its ring drawn around the site; it ends by its time limit and
    // waits for the instructor.
    const press = await exerciseWhere(instructor, (e) => e.shown && e.index === 0 && e.state === 'ended');
    assert.equal(press.name, 'Press and hold 1.8 N');
    assert.equal(press.progress, '1 of 2 · attempt 1 · ana');
    assert.match(press.target, /^press 1\.8 ± 0\.1 N within 5 mm of the ring, hold 0\.9 s/);
    assert.equal(press.drawn.kind, 'press');
    assert.equal(press.drawn.points.length, 49);
    assert.equal(press.countdown, 'ended');
    assert.ok(press.resultShown);
    assert.equal(press.verdict, 'not passed');
    assert.equal(press.nextIn, 'the next exercise starts when the instructor says');
    assert.equal(press.controlsShown, true);

    // The observer sees the same, without the buttons; a control it sends anyway is refused.
    const seen = await exerciseWhere(observer, (e) => e.shown && e.state === 'ended');
    assert.equal(seen.name, press.name);
    assert.equal(seen.verdict, 'not passed');
    assert.equal(seen.controlsShown, false);
    await observer.evaluate(() => window.__softhaptic.sendExerciseControl('next'));
    const refused = await exerciseWhere(observer, (e) => e.refused.length > 0);
    assert.match(refused.refused, /only an instructor starts, repeats or stops an exercise/);
    assert.equal(refused.index, 0, 'the refused control moved nothing');

    // The instructor starts the next one: both pages show the trace, its path drawn, the clock
    // running down from 600 s.
    await instructor.evaluate(() => window.__softhaptic.exerciseButton('next'));
    const trace = await exerciseWhere(observer, (e) => e.index === 1 && e.state === 'running');
    assert.equal(trace.name, 'Trace a line');
    assert.equal(trace.progress, '2 of 2 · attempt 1 · ana');
    assert.equal(trace.resultShown, false);
    assert.equal(trace.drawn.kind, 'trace');
    assert.equal(trace.drawn.points.length, 2);
    // Drawn 0.6 mm off the surface, along its normal, over the path's points.
    const path = [
      [-0.0297, 0.0681, 0.0068],
      [-0.01495, 0.07, 0.00667],
    ];
    trace.drawn.points.forEach((p, i) => {
      const off = Math.hypot(p[0] - path[i][0], p[1] - path[i][1], p[2] - path[i][2]);
      assert.ok(Math.abs(off - 0.0006) < 1e-9, `point ${i} is ${off} m off the path`);
    });
    assert.ok(trace.remainingS > 500 && trace.remainingS <= 600, `${trace.remainingS} s left`);
    const later = await exerciseWhere(observer, (e) => e.index === 1 && e.remainingS < trace.remainingS - 0.5);
    assert.match(later.countdown, /^\d+\.\d s$/);

    // The instructor stops it: the result, and all exercises done.
    await instructor.evaluate(() => window.__softhaptic.exerciseButton('stop'));
    const stopped = await exerciseWhere(observer, (e) => e.index === 1 && e.state === 'ended');
    assert.equal(stopped.verdict, 'not passed');
    assert.equal(stopped.nextIn, 'all exercises done');
    assert.ok(stopped.marks.length === 0);
  } finally {
    await server.stop();
  }
  assert.deepEqual(pageErrors, []);
});
