// End to end, what each role sees of a palpation scene's inclusions (docs/roles.md): the real
// server runs the palpation scene and exercise with tokens. In Chromium, the trainee's page (the
// observer's link) receives no `inclusions` message and no coordinate of a lump in any
// WebSocket message while the attempt runs, and draws nothing; the instructor's page draws the
// two lumps as translucent spheres inside the organ, seen through its surface, with the
// trainee's path. Once the instructor stops the attempt, the trainee's page is sent the answer
// and draws it.
//
//   SOFTHAPTIC_BIN=…/target/debug/softhaptic node --test tests/e2e-inclusions.test.mjs
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { launchBrowser } from './browser.mjs';
import { startServer } from './server.mjs';

const TIMEOUT_MS = 60000;

let browser;
let dir;
const pageErrors = [];

/** Opens `url`, keeping the text of every WebSocket message the page receives in `received`. */
async function openViewer(url, received) {
  const page = await browser.newPage({ viewport: { width: 1024, height: 700 } });
  page.on('pageerror', (e) => pageErrors.push(e.message));
  page.on('websocket', (ws) =>
    ws.on('framereceived', ({ payload }) => received.push(typeof payload === 'string' ? payload : '')),
  );
  await page.goto(url);
  await page.waitForFunction(() => window.__softhaptic?.ready(), null, { timeout: 120000 });
  return page;
}

/** Polls `read` on the page until `predicate` holds of its answer. */
async function until(page, read, predicate, what) {
  const deadline = Date.now() + TIMEOUT_MS;
  for (;;) {
    const value = await page.evaluate(read);
    if (predicate(value)) return value;
    if (Date.now() > deadline) throw new Error(`${what}: never; last ${JSON.stringify(value)}`);
    await new Promise((resolve) => setTimeout(resolve, 100));
  }
}

before(async () => {
  dir = mkdtempSync(join(tmpdir(), 'softhaptic-inclusions-'));
  browser = await launchBrowser();
});

after(async () => {
  await browser?.close();
  if (dir) rmSync(dir, { recursive: true, force: true });
});

test('the trainee is sent no lump before the end; the instructor sees them drawn, with the path', async () => {
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
    const traineeReceived = [];
    const trainee = await openViewer(server.observerUrl, traineeReceived);
    const instructor = await openViewer(server.url, []);

    // The instructor's page draws both lumps: translucent, drawn through the surface, where the
    // server says they are; and the path of the trainee's contact.
    const drawn = await until(
      instructor,
      () => window.__softhaptic.inclusions(),
      (s) => s?.shown && s.pathPoints > 0,
      'the instructor draws the inclusions and the path',
    );
    assert.equal(drawn.revealed, false);
    assert.equal(drawn.spheres.length, 2);
    for (const s of drawn.spheres) {
      assert.equal(s.radius, 0.005);
      assert.ok(s.opacity > 0 && s.opacity < 1, `translucent: ${s.opacity}`);
      assert.equal(s.depthTest, false, 'seen through the surface');
    }
    assert.ok(drawn.pathDrawn === drawn.pathPoints);
    // The lumps' coordinates, as JSON writes them (what a leak would carry).
    const secrets = drawn.spheres.flatMap((s) => s.centre.map((v) => JSON.stringify(v)));
    assert.equal(secrets.length, 6);

    // The trainee's page: frames and the exercise, nothing that says where the lumps are.
    await until(trainee, () => window.__softhaptic.contact().valid, Boolean, 'the trainee draws frames');
    await until(
      trainee,
      () => window.__softhaptic.exercise(),
      (e) => e.shown && e.state === 'running',
      'the trainee is shown the exercise',
    );
    const seenBefore = traineeReceived.length;
    assert.ok(seenBefore > 20, `${seenBefore} messages`);
    for (const text of traineeReceived) {
      assert.ok(!text.startsWith('{"type":"inclusions"'), text);
      for (const secret of secrets) assert.ok(!text.includes(secret), `${secret} in ${text.slice(0, 200)}`);
    }
    // Each frame in contact says the force ratio there (what the trainee feels, and the dent
    // drawn less by it), only where the tool is.
    const ratios = traineeReceived
      .filter((t) => t.startsWith('{"type":"contact"') && t.includes('"in_contact":true'))
      .map((t) => JSON.parse(t).inclusion_force_ratio);
    assert.ok(ratios.length > 0 && ratios.every((r) => r >= 1), `ratios ${ratios.slice(0, 5)}`);
    const nothing = await trainee.evaluate(() => window.__softhaptic.inclusions());
    assert.equal(nothing.shown, false);
    assert.equal(nothing.spheres.length, 0);

    // The instructor stops the attempt: the answer is the trainee's too.
    await instructor.evaluate(() => window.__softhaptic.exerciseButton('stop'));
    const revealed = await until(
      trainee,
      () => window.__softhaptic.inclusions(),
      (s) => s?.shown && s.revealed,
      'the trainee is shown the answer',
    );
    assert.deepEqual(
      revealed.spheres.map((s) => s.centre),
      drawn.spheres.map((s) => s.centre),
    );
    // Nothing before the exercise's end named a lump.
    const endAt = traineeReceived.findIndex((t) => t.startsWith('{"type":"exercise"') && t.includes('"state":"ended"'));
    const toldAt = traineeReceived.findIndex((t) => t.startsWith('{"type":"inclusions"'));
    assert.ok(endAt >= 0 && toldAt >= 0);
    // The check above can see a leak: the answer, when it comes, carries every one of them.
    for (const secret of secrets) assert.ok(traineeReceived[toldAt].includes(secret), secret);
    for (const text of traineeReceived.slice(0, Math.min(endAt, toldAt))) {
      for (const secret of secrets) assert.ok(!text.includes(secret), `${secret} in ${text.slice(0, 200)}`);
    }
    assert.deepEqual(pageErrors, []);
  } finally {
    await server.stop();
  }
});
