// End to end: the replay of a damaged recording marks the stretch it lost on the timeline. A copy
// of `tests/sessions/slide.mcap` with one byte flipped inside a chunk in its middle is replayed by the
// real server (`softhaptic replay`), the real viewer page in headless Chromium reads it through
// the page's test hook: the status lists the gap, the track shows one mark with its title, at the
// place of the lost second.
//
//   npm run test:e2e    (builds the server with cargo; SOFTHAPTIC_BIN to reuse a built one)
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { launchBrowser } from './browser.mjs';
import { REPO, startServer } from './server.mjs';

const WAIT = { timeout: 60000 };

/** Byte offsets of the top-level chunk records of an MCAP file (opcode 0x06). */
function chunkOffsets(bytes) {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const chunks = [];
  let pos = 8;
  while (pos + 9 <= bytes.length) {
    const op = bytes[pos];
    const len = Number(view.getBigUint64(pos + 1, true));
    if (op === 0x06) chunks.push({ pos, end: pos + 9 + len });
    if (op === 0x0f) break;
    pos += 9 + len;
  }
  return chunks;
}

let dir;
let server;
let browser;
let page;
const pageErrors = [];

before(async () => {
  const original = readFileSync(join(REPO, 'tests/sessions/slide.mcap'));
  const damaged = Buffer.from(original);
  const chunks = chunkOffsets(damaged);
  // The first chunk holds the schemas and the scene, the next ones a second of ticks each: the
  // third is a second in the middle of the session.
  assert.ok(chunks.length >= 4, `slide.mcap has ${chunks.length} chunks`);
  const middle = chunks[2];
  damaged[Math.floor((middle.pos + middle.end) / 2)] ^= 0x40;
  dir = mkdtempSync(join(tmpdir(), 'softhaptic-e2e-gaps-'));
  const file = join(dir, 'slide-damaged.mcap');
  writeFileSync(file, damaged);
  server = await startServer({ command: ['replay', file, '--paused'], external: false });
  browser = await launchBrowser();
  page = await browser.newPage({ viewport: { width: 1280, height: 800 } });
  page.on('pageerror', (e) => pageErrors.push(e.message));
  await page.goto(server.url);
  await page.waitForFunction(() => window.__softhaptic?.ready(), null, { timeout: 120000 });
  await page.waitForFunction(() => window.__softhaptic.replay().known, null, WAIT);
});

after(async () => {
  await browser?.close();
  await server?.stop();
  if (dir) rmSync(dir, { recursive: true, force: true });
});

test('the lost chunk is one gap in the status and one mark on the track', async () => {
  await page.waitForFunction(() => window.__softhaptic.replay().gaps.length > 0, null, WAIT);
  const replay = await page.evaluate(() => window.__softhaptic.replay());
  const gaps = replay.lastStatus.gaps;
  assert.equal(gaps.length, 1, JSON.stringify(gaps));
  const [gap] = gaps;
  assert.equal(gap.cause, 'damaged');
  // About a second of ticks (the writer closes a chunk each second of device time).
  assert.ok(gap.ticks > 500 && gap.ticks < 1500, JSON.stringify(gap));
  assert.ok(gap.start_s >= 0 && gap.end_s > gap.start_s && gap.end_s <= replay.durationS, JSON.stringify(gap));
  assert.equal(replay.gaps.length, 1);
  assert.equal(replay.gaps[0].cause, 'damaged');
  assert.match(replay.gaps[0].title, /^\d+ ticks not in the file \(damaged\) at 0:0\d\.\d$/);
  assert.ok(Math.abs(replay.gaps[0].leftPct - (100 * gap.start_s) / replay.durationS) < 0.01);
  assert.deepEqual(pageErrors, []);
});
