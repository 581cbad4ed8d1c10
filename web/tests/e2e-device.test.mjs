// End to end through the OpenHaptics backend: the real server with `scenes/phantom.toml`, its
// device played by the stand-in for libHD (tests/standin/hd_standin.c, loaded from
// SOFTHAPTIC_HD_LIBRARY as the vendor's library would be), the real viewer page in headless
// Chromium, read through the page's test hook.
//
//   npm run test:e2e    (builds the server and the stand-in with cargo; SOFTHAPTIC_BIN to reuse a
//                        built server)
//
// The stand-in's own hand presses the liver along the device's −y every 3 s (20 mm above the
// surface to 8 mm below it, closed through the force it is sent). Checks: the scene names the
// device as OpenHaptics reports it (the stand-in's serial); frames arrive and a press pushes
// back with a real force and bends the render mesh under the tool; the server says the device
// is ok and the panel shows it; the connection counted no malformed or unknown message and the
// page raised no error.
//
// The machine may be slow (software WebGL, two cores): every check waits for what it needs with
// a generous deadline instead of sleeping and then counting. On such a machine the stand-in's
// servo thread (an ordinary thread, unlike the vendor's) is sometimes held back 10 ms and more;
// the loop's watchdog then rightly reports the device not answering until it ticks again, so
// the device check waits for "ok" rather than asserting that it never changes.
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';

import { toolFromJson } from '../src/deformation.js';
import { drawnProfile } from './e2e-checks.mjs';
import { launchBrowser } from './browser.mjs';
import { hdStandinPath, startServer } from './server.mjs';

// The serial number the stand-in reports (SERIAL in tests/standin/hd_standin.c).
const STANDIN_SERIAL = 'STANDIN-0001';
// A press worth the name: a few tenths of a newton and a millimetre deep (the hand goes 8 mm
// below the surface and the liver pushes back with newtons there).
const PRESS_FORCE_N = 0.3;
const PRESS_DEPTH_M = 1e-3;
// Float32 vertex positions, recomputed from the same contact: 1 µm is far above rounding.
const TOLERANCE_M = 1e-6;
const WAIT = { timeout: 60000 };

let server;
let browser;
let page;
const pageErrors = [];

before(async () => {
  // A server of its own, even when SOFTHAPTIC_URL names a running one: it needs the stand-in.
  server = await startServer({
    extraArgs: ['--scene', 'scenes/phantom.toml', '--no-record'],
    env: { SOFTHAPTIC_HD_LIBRARY: hdStandinPath() },
    external: false,
  });
  browser = await launchBrowser();
  page = await browser.newPage({ viewport: { width: 1280, height: 800 } });
  page.on('pageerror', (e) => pageErrors.push(e.message));
  await page.goto(server.url);
  await page.waitForFunction(() => window.__softhaptic?.ready(), null, { timeout: 120000 });
});

/**
 * Waits until `predicate(arg)` holds in the page; on a timeout says `what` was awaited, with the
 * end of the server's log (the device backend logs every change of the device's state).
 */
async function waitFor(what, predicate, arg = null, options = {}) {
  try {
    await page.waitForFunction(predicate, arg, { ...WAIT, ...options });
  } catch (e) {
    const log = server.output().split('\n').slice(-20).join('\n');
    throw new Error(`${what}: ${e.message}\nserver log (end):\n${log}`, { cause: e });
  }
}

after(async () => {
  await browser?.close();
  await server?.stop();
});

test('the scene names the OpenHaptics device with the stand-in serial number', async () => {
  const scene = await page.evaluate(() => window.__softhaptic.scene());
  assert.match(scene.device.name, /OpenHaptics/, scene.device.name);
  assert.ok(scene.device.name.includes(`serial ${STANDIN_SERIAL}`), scene.device.name);
  assert.ok(scene.device.peak_force_n > 0);
  const vertices = await page.evaluate(() => window.__softhaptic.vertexCount());
  assert.equal(vertices, scene.render_meshes[0].vertex_count);
});

test('the stand-in hand presses the liver: a real force pushes back and the mesh bends under the tool', async () => {
  await waitFor('contact frames', () => window.__softhaptic.contactFrames() > 20);
  // Freeze the view on the first drawn frame of a press (check and pause in one page task).
  await waitFor(
    'a press drawn',
    ({ forceN, depthM }) => {
      const h = window.__softhaptic;
      const c = h.contact();
      const pressed = c.valid && !c.stale && c.inContact && c.forceMagnitudeN >= forceN && c.depthM >= depthM;
      if (pressed) h.pause(true);
      return pressed;
    },
    { forceN: PRESS_FORCE_N, depthM: PRESS_DEPTH_M },
    { polling: 'raf' },
  );
  try {
    const { contact: c, scene } = await page.evaluate(() => ({
      contact: window.__softhaptic.contact(),
      scene: window.__softhaptic.scene(),
    }));
    assert.ok(c.forceMagnitudeN <= scene.device.peak_force_n + 1e-9, `${c.forceMagnitudeN} N beyond the peak`);
    const tool = toolFromJson(scene.tool);
    const profile = drawnProfile(scene, c);
    assert.ok(profile.reachM > 0);
    // Every moved vertex: its rest position, and how far it moved (world frame).
    const moved = await page.evaluate(() =>
      window.__softhaptic.movedVertices().map((i) => {
        const v = window.__softhaptic.vertex(i);
        return [i, ...v.rest, v.displacementM];
      }),
    );
    assert.ok(moved.length > 20, `${moved.length} render vertices moved`);
    const n = c.normal;
    let underTool = null;
    for (const [i, rx, ry, rz, displacementM] of moved) {
      const vx = rx - c.point[0];
      const vy = ry - c.point[1];
      const vz = rz - c.point[2];
      const axial = vx * n[0] + vy * n[1] + vz * n[2];
      const r = Math.hypot(vx - axial * n[0], vy - axial * n[1], vz - axial * n[2]);
      // The deformation stays within the profile's reach (R_d for the paper's) and never sinks
      // deeper than δ.
      assert.ok(
        r <= profile.reachM + TOLERANCE_M,
        `vertex ${i} moved at r = ${r} m, beyond the ${profile.name} profile's reach ${profile.reachM} m`,
      );
      assert.ok(displacementM <= c.depthM + TOLERANCE_M, `vertex ${i} moved ${displacementM} m for δ = ${c.depthM} m`);
      if (Math.abs(axial) < 2e-3 && (underTool === null || r < underTool.r)) underTool = { i, r, displacementM };
    }
    assert.ok(underTool !== null, 'a moved render vertex lies near the contact point');
    // The vertex under the tool sank by about the depth: z(r) = δ − (R − √(R² − r²)) there.
    assert.ok(
      underTool.displacementM >= c.depthM - (underTool.r * underTool.r) / tool.radiusM - TOLERANCE_M,
      `vertex ${underTool.i} under the tool (r = ${underTool.r} m) moved ${underTool.displacementM} m for δ = ${c.depthM} m`,
    );
  } finally {
    await page.evaluate(() => window.__softhaptic.pause(false));
  }
  // The force plot shows the press.
  const maxPlotted = await page.evaluate(() =>
    Math.max(0, ...window.__softhaptic.forcePlotSamples().map((s) => s.forceN)),
  );
  assert.ok(maxPlotted >= PRESS_FORCE_N, `force plot max ${maxPlotted} N`);
});

test('the server reports the device ok and the haptic loop panel shows it', async () => {
  await waitFor('"device ok" from the server and in the panel', () => {
    const d = window.__softhaptic.device();
    return d.status === 'ok' && d.shown === 'device ok';
  });
  const stats = await page.evaluate(() => window.__softhaptic.lastStats());
  assert.ok(stats.loop_rate_hz > 0, `loop rate ${stats.loop_rate_hz} Hz`);
  assert.equal(await page.locator('#s-device').textContent(), 'device ok');
  const severe = await page.locator('#s-device').evaluate((e) => e.classList.contains('severe'));
  assert.equal(severe, false, 'the device line is not marked severe');
});

test('the viewer counted no malformed or unknown message and raised no page error', async () => {
  const conn = await page.evaluate(() => window.__softhaptic.connection());
  assert.equal(conn.state, 'open');
  assert.equal(conn.stats.malformed, 0, conn.lastError ?? '');
  assert.equal(conn.stats.unknown, 0);
  assert.ok(conn.stats.messages > 50, `${conn.stats.messages} messages`);
  assert.deepEqual(pageErrors, []);
});
