// End to end: the real server (default scene: the simulated hand presses the procedural liver
// again and again), the real viewer page in headless Chromium, through the page's test hook.
//
//   npm run test:e2e    (builds the server with cargo; SOFTHAPTIC_URL / SOFTHAPTIC_BIN to reuse one)
//
// Checks, on the frame the page drew during a press: the render vertices moved exactly as the
// JavaScript profile the scene names says for the contact the page rendered (so the vertex
// under the tool sank by about δ, and nothing beyond the profile's reach moved); the force plot
// shows the press; the depression map and the section view, turned on and off with the page's
// own checkboxes, colour and cut the press; the trainee panel writes every figure of the
// server's metrics message; the connection counted no malformed message. Then stops the server
// and starts it again on the same port:
// the page must notice, reconnect by itself and draw the new session. Saves a screenshot to
// web/test-results/e2e.png.
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdirSync } from 'node:fs';
import { fileURLToPath } from 'node:url';

import { launchBrowser } from './browser.mjs';
import {
  assertPressBendsMesh,
  freezeOffSurface,
  freezeOnPress,
  pixelDifference,
  sectionLinePixels,
} from './e2e-checks.mjs';
import { startServer } from './server.mjs';

const RESULTS = fileURLToPath(new URL('../test-results/', import.meta.url));
const SERVER_ARGS = ['--no-realtime', '--no-record'];

let server;
let browser;
let page;
const pageErrors = [];

before(async () => {
  server = await startServer({ extraArgs: SERVER_ARGS });
  browser = await launchBrowser();
  page = await browser.newPage({ viewport: { width: 1280, height: 800 } });
  page.on('pageerror', (e) => pageErrors.push(e.message));
  await page.goto(server.url);
  await page.waitForFunction(() => window.__softhaptic?.ready(), null, { timeout: 120000 });
});

after(async () => {
  await browser?.close();
  await server?.stop();
});

test('the page loads the scene and its render mesh and receives the stream', async () => {
  const info = await page.evaluate(() => ({
    scene: window.__softhaptic.scene(),
    vertices: window.__softhaptic.vertexCount(),
    connection: window.__softhaptic.connection(),
    webgl: window.__softhaptic.webgl(),
  }));
  assert.equal(info.vertices, info.scene.render_meshes[0].vertex_count);
  assert.ok(info.vertices > 1000, `render mesh has ${info.vertices} vertices`);
  assert.equal(info.connection.state, 'open');
  // The 1 Hz stats arrive.
  await page.waitForFunction(() => window.__softhaptic.lastStats() !== null, null, { timeout: 30000 });
  const stats = await page.evaluate(() => window.__softhaptic.lastStats());
  assert.ok(stats.loop_rate_hz > 0, `loop rate ${stats.loop_rate_hz}`);
  // The panel shows the server's counts: ticks lost, and ticks the standby thread ran.
  await page.waitForFunction(() => document.querySelector('#s-overruns').textContent !== '—', null, {
    timeout: 30000,
  });
  assert.match(await page.locator('#s-overruns').textContent(), /^\d+ \/ \d+$/);
  assert.ok(info.webgl || (await page.locator('#webgl-message').isVisible()), 'without WebGL the page says so');
});

test('from the default camera the dent shows through the see-through tool', async (t) => {
  const webgl = await page.evaluate(() => window.__softhaptic.webgl());
  if (!webgl) return; // the page without WebGL is checked below
  const REGION_PX = 80;
  // The default press holds about 3.4 mm; 2.5 mm catches the hold, not the approach.
  await freezeOnPress(page, 2.5e-3);
  // One frozen frame drawn three ways at the camera the page starts with: pressed, the same
  // contact with the object in its rest shape (the tool placed and see-through all the same),
  // and pressed again. The first two differ by the dent alone, not by the tool's pixels.
  const drawn = await page.evaluate((size) => {
    const h = window.__softhaptic;
    h.resetCamera();
    const c = h.contact();
    const at = h.toScreen(c.point);
    const pressed = { opacity: h.toolOpacity(), pixels: h.regionPixels(at.x, at.y, size) };
    h.restShape(true);
    const rest = { opacity: h.toolOpacity(), pixels: h.regionPixels(at.x, at.y, size) };
    h.restShape(false);
    const again = h.regionPixels(at.x, at.y, size);
    return { depthM: c.depthM, pressed, rest, again };
  }, REGION_PX);
  await page.evaluate(() => window.__softhaptic.pause(false));
  assert.ok(drawn.pressed.opacity < 0.5, `tool opacity in contact ${drawn.pressed.opacity}`);
  assert.equal(drawn.rest.opacity, drawn.pressed.opacity, 'the tool is drawn the same over the rest shape');
  const dent = pixelDifference(drawn.pressed.pixels, drawn.rest.pixels);
  const noise = pixelDifference(drawn.pressed.pixels, drawn.again);
  t.diagnostic(
    `δ ${(drawn.depthM * 1e3).toFixed(2)} mm: dent ${dent.mean.toFixed(2)} per channel (0–255), ` +
      `${(100 * dent.visible).toFixed(1)} % of the region visibly changed; the frame redrawn: ${noise.mean.toFixed(2)}`,
  );
  // The same frame drawn twice is the same picture, so any difference is the dent's.
  assert.equal(noise.mean, 0);
  // Measured: 3.1 to 3.8 per channel, 8 to 11 % of the region, for the 2.9 to 3.4 mm hold.
  assert.ok(dent.mean > 1.5, `the dent changes the region by ${dent.mean.toFixed(2)} per channel`);
  assert.ok(dent.visible > 0.04, `the dent visibly changes ${(100 * dent.visible).toFixed(1)} % of the region`);
});

test("the vertex shader draws the dent the CPU path draws, and the page's default is the shader", async (t) => {
  const webgl = await page.evaluate(() => window.__softhaptic.webgl());
  if (!webgl) return;
  assert.equal(await page.evaluate(() => window.__softhaptic.deformation()), 'gpu');
  const REGION_PX = 160;
  await freezeOnPress(page, 2e-3);
  // Close to the press and low down, the tool hidden: the pixels are the surface's alone.
  const c = await page.evaluate(() => window.__softhaptic.contact());
  const at = await page.evaluate((p) => {
    const h = window.__softhaptic;
    h.focusCamera(p, 0.06, 0.35);
    h.toolVisible(false);
    return h.toScreen(p);
  }, c.point);
  const drawn = await page.evaluate(
    ({ at, size }) => {
      const h = window.__softhaptic;
      const gpu = h.regionPixels(at.x, at.y, size);
      h.depressionMap(true);
      const gpuMap = h.regionPixels(at.x, at.y, size);
      h.deformation('cpu');
      const cpuMap = h.regionPixels(at.x, at.y, size);
      h.depressionMap(false);
      const cpu = h.regionPixels(at.x, at.y, size);
      h.deformation('gpu');
      return { gpu, cpu, gpuMap, cpuMap };
    },
    { at, size: REGION_PX },
  );
  // The same view with nothing pressed.
  await freezeOffSurface(page);
  const rest = await page.evaluate(({ at, size }) => window.__softhaptic.regionPixels(at.x, at.y, size), {
    at,
    size: REGION_PX,
  });
  await page.evaluate(() => {
    window.__softhaptic.toolVisible(true);
    window.__softhaptic.pause(false);
  });
  const meanDiff = (a, b) => {
    let sum = 0;
    for (let i = 0; i < a.length; i += 4) for (let k = 0; k < 3; k++) sum += Math.abs(a[i + k] - b[i + k]);
    return sum / ((a.length / 4) * 3);
  };
  const dent = meanDiff(drawn.cpu, rest);
  const paths = meanDiff(drawn.gpu, drawn.cpu);
  const map = meanDiff(drawn.cpuMap, drawn.cpu);
  const mapPaths = meanDiff(drawn.gpuMap, drawn.cpuMap);
  t.diagnostic(
    `dent ${dent.toFixed(2)}, GPU − CPU ${paths.toFixed(2)}; depression map ${map.toFixed(2)}, GPU − CPU ${mapPaths.toFixed(2)} (mean per channel, 0–255)`,
  );
  assert.ok(map > 3, `the CPU path's depression map changes the region by ${map.toFixed(2)} per channel`);
  assert.ok(
    mapPaths < 0.1 * map,
    `the maps differ by ${mapPaths.toFixed(2)} per channel, the map by ${map.toFixed(2)}`,
  );
  assert.ok(dent > 3, `the CPU path's dent changes the region by ${dent.toFixed(2)} per channel`);
  assert.ok(
    paths < 0.1 * dent,
    `GPU and CPU differ by ${paths.toFixed(2)} per channel, the dent by ${dent.toFixed(2)}`,
  );
});

test('a press bends the render mesh exactly as the profile says, and only within its reach', async () => {
  // The default scene holds its press about 3 mm deep; 2 mm catches the hold, not the approach.
  await freezeOnPress(page, 2e-3);
  const { contact: c, scene } = await assertPressBendsMesh(page);

  // The force plot shows the press.
  const samples = await page.evaluate(() => window.__softhaptic.forcePlotSamples());
  assert.ok(samples.length > 50, `${samples.length} force samples plotted`);
  const maxPlotted = Math.max(...samples.map((s) => s.forceN));
  assert.ok(c.forceMagnitudeN > 0, 'a press pushes back');
  assert.ok(maxPlotted >= 0.5 * c.forceMagnitudeN, `plot max ${maxPlotted} N vs drawn force ${c.forceMagnitudeN} N`);
  const peak = await page.evaluate(() => window.__softhaptic.peakForceN());
  assert.equal(peak, scene.device.peak_force_n);

  // A screenshot of the press, close up and from low down, so the dimple shows beside the tool.
  await page.evaluate((p) => window.__softhaptic.focusCamera(p, 0.1, 0.3), c.point);
  await page.waitForTimeout(1500);
  mkdirSync(RESULTS, { recursive: true });
  await page.screenshot({ path: `${RESULTS}e2e.png` });
  await page.evaluate(() => window.__softhaptic.pause(false));
});

test('the depression map colours the vertices that moved, and only while its checkbox is ticked', async () => {
  // The page's own checkbox, as a person ticks it: its listener turns the map on.
  await page.check('#map-toggle');
  assert.ok(await page.locator('#map-scale').isVisible(), 'the map shows its scale');
  await freezeOnPress(page, 2e-3);
  const on = await page.evaluate(() => {
    const h = window.__softhaptic;
    const c = h.contact();
    const under = h.findVertexNear(...c.point).index;
    const far = h.findVertexNear(c.point[0] + 0.05, c.point[1] - 0.02, c.point[2]).index;
    return {
      under: h.vertexColor(under),
      moved: h.vertexDisplacement(under),
      far: h.vertexColor(far),
      farMoved: h.vertexDisplacement(far),
      scale: document.getElementById('map-scale').textContent,
    };
  });
  assert.ok(on.moved > 1e-3, `the vertex under the tool moved ${on.moved} m`);
  assert.ok(on.under[0] < 0.95 && on.under[2] > on.under[0], `coloured: ${on.under}`);
  // 5 cm away the paper's profile moves nothing (white); the FEM surface's far tail moves it by
  // micrometres, a tint too faint to see.
  if (on.farMoved === 0) assert.deepEqual(on.far, [1, 1, 1]);
  else assert.ok(on.farMoved < 1e-4 && on.far.every((x) => x > 0.98), `far: ${on.far}, moved ${on.farMoved} m`);
  assert.equal(on.scale, 'white 0 … blue 5 mm');
  // Still frozen on the same press: unticked, the same vertex is drawn white again.
  await page.uncheck('#map-toggle');
  assert.equal(await page.locator('#map-scale').isVisible(), false, 'the scale goes with the map');
  const off = await page.evaluate(() => {
    const h = window.__softhaptic;
    return h.vertexColor(h.findVertexNear(...h.contact().point).index);
  });
  assert.deepEqual(off, [1, 1, 1]);
  await page.evaluate(() => window.__softhaptic.pause(false));
});

test('the section view cuts the object through the contact, along its normal, away from the camera', async () => {
  await freezeOnPress(page, 2e-3);
  // Still frozen on the press: the plane is placed from the contact the page holds, which a
  // slow machine's next frames cannot end before it is read. Turned on with the page's own
  // checkbox, as a person does.
  await page.check('#section-toggle');
  assert.ok(await page.locator('#section-key').isVisible(), 'the key to the undeformed line shows');
  assert.equal((await page.evaluate(() => window.__softhaptic.section())).on, true);
  // Placed on the next drawn frame (drawn while paused too).
  await page.waitForFunction(() => window.__softhaptic.section().constant !== 0, null, { timeout: 30000 });
  const c = await page.evaluate(() => window.__softhaptic.contact());
  const s = await page.evaluate(() => window.__softhaptic.section());
  const [nx, ny, nz] = s.normal;
  assert.ok(Math.abs(Math.hypot(nx, ny, nz) - 1) < 1e-6);
  // The plane holds the contact normal's direction (perpendicular to its own normal).
  assert.ok(Math.abs(nx * c.normal[0] + ny * c.normal[1] + nz * c.normal[2]) < 0.05, JSON.stringify({ s, c }));

  // The undeformed surface's line is drawn where the plane cuts it: through the contact point,
  // which lies on the undeformed surface. Close to the press, the region around that point read
  // with the line and, in the same frame, without it.
  const REGION_PX = 40;
  await page.evaluate((p) => window.__softhaptic.focusCamera(p, 0.06, 0.35), c.point);
  await page.waitForFunction(() => window.__softhaptic.sectionReference().segments > 0, null, { timeout: 30000 });
  const read = await page.evaluate(
    ({ p, size }) => {
      const h = window.__softhaptic;
      const at = h.toScreen(p);
      const line = h.sectionReference();
      const on = h.regionPixels(at.x, at.y, size);
      h.sectionReference(false);
      const off = h.regionPixels(at.x, at.y, size);
      h.sectionReference(true);
      return { line, on, off };
    },
    { p: c.point, size: REGION_PX },
  );
  assert.equal(read.line.visible, true);
  const on = sectionLinePixels(read.on, REGION_PX);
  const off = sectionLinePixels(read.off, REGION_PX);
  assert.equal(off.length, 0, 'nothing else in the view has the line colour');
  // A line across the region: in most of its columns.
  const columns = new Set(on.map(([x]) => x));
  assert.ok(columns.size >= REGION_PX / 2, `the line crosses ${columns.size} of ${REGION_PX} columns`);
  // Through the contact point (the region's centre), within half a millimetre (8 px here).
  const centre = REGION_PX / 2;
  const nearest = Math.min(...on.map(([x, y]) => Math.hypot(x - centre, y - centre)));
  assert.ok(nearest <= 8, `the line passes ${nearest.toFixed(1)} px from the contact point`);

  await page.uncheck('#section-toggle');
  assert.equal((await page.evaluate(() => window.__softhaptic.section())).on, false);
  assert.equal((await page.evaluate(() => window.__softhaptic.sectionReference())).visible, false);
  assert.equal(await page.locator('#section-key').isVisible(), false);
  await page.evaluate(() => {
    window.__softhaptic.resetCamera();
    window.__softhaptic.pause(false);
  });
});

/**
 * The trainee panel's rows as the panel must write them for metrics message `m` (the text a
 * person reads, spelled out here rather than taken from the page's code).
 */
function panelTextOf(m) {
  const flagsRaised = Object.values(m.flags_raised).reduce((a, b) => a + b, 0);
  return {
    peak: `${m.peak_force_n.toFixed(2)} N at ${m.peak_force_time_s.toFixed(1)} s`,
    above: `${m.time_above_safe_s.toFixed(2)} s over ${m.safe_force_n} N`,
    // Red once the trainee has pushed harder than the scene's safe force at all.
    aboveClass: m.time_above_safe_s > 0 ? 'severe' : '',
    contact: `${m.time_in_contact_s.toFixed(1)} s`,
    path: `${(m.path_length_in_contact_m * 1e3).toFixed(1)} mm`,
    pushes: String(m.pushes),
    jerk: `${m.mean_squared_jerk_m2_s6.toExponential(2)} m²/s⁶`,
    flags: `${m.device_fault_ticks} / ${flagsRaised}`,
  };
}

test("the trainee's metrics panel shows every figure of the server's metrics of the press", async () => {
  // The last message received and the panel's rows, read in one page task. The panel is
  // rewritten four times a second and a message comes once a second: the rows are read once the
  // message has been the last for 400 ms (so a rewrite came after it, however soon the poll saw
  // it arrive), and a later read (of a later message) is taken if a stalled page still lagged.
  const read = async (afterTicks) =>
    (
      await page.waitForFunction(
        (after) => {
          const m = window.__softhaptic.metrics().last;
          if (m === null || m.pushes < 1 || m.time_in_contact_s < 0.2 || m.ticks <= after) return null;
          const held = window.__metricsHeld;
          if (held === undefined || held.ticks !== m.ticks) {
            window.__metricsHeld = { ticks: m.ticks, since: performance.now() };
            return null;
          }
          if (performance.now() - held.since < 400) return null;
          const row = (id) => document.getElementById(id);
          return {
            sent: m,
            shown: {
              peak: row('t-peak').textContent,
              above: row('t-above').textContent,
              aboveClass: row('t-above').className,
              contact: row('t-contact').textContent,
              path: row('t-path').textContent,
              pushes: row('t-pushes').textContent,
              jerk: row('t-jerk').textContent,
              flags: row('t-flags').textContent,
            },
          };
        },
        afterTicks,
        { timeout: 60000 },
      )
    ).jsonValue();
  const reads = [];
  let afterTicks = -1;
  for (let attempt = 0; attempt < 10; attempt++) {
    const r = await read(afterTicks);
    reads.push(r);
    if (JSON.stringify(r.shown) === JSON.stringify(panelTextOf(r.sent))) break;
    afterTicks = r.sent.ticks;
  }
  const { sent, shown } = reads.at(-1);
  assert.deepEqual(
    shown,
    panelTextOf(sent),
    `the panel never showed the message it had received, in ${reads.length} reads: ${JSON.stringify(reads)}`,
  );
  // The simulated hand has pressed for a while: a path and a jerk; the default scene's 2 N safe
  // force; no device fault.
  assert.ok(sent.peak_force_n > 0.1, JSON.stringify(sent));
  assert.ok(sent.path_length_in_contact_m > 0 && sent.mean_squared_jerk_m2_s6 > 0, JSON.stringify(sent));
  assert.equal(sent.safe_force_n, 2);
  assert.equal(sent.device_fault_ticks, 0);
});

test("the trainee's metrics panel follows the server's metrics as they change", async () => {
  // The panel's time in contact once it shows the last message's (it catches up within a
  // quarter of a second; the server sends one a second) and differs from `before`.
  const shownAfter = async (before) =>
    (
      await page.waitForFunction(
        (previous) => {
          const m = window.__softhaptic.metrics();
          if (m.last === null) return null;
          const shown = m.shown.contact;
          return shown === `${m.last.time_in_contact_s.toFixed(1)} s` && shown !== previous
            ? { sent: m.last, shown: m.shown }
            : null;
        },
        before,
        { timeout: 60000 },
      )
    ).jsonValue();
  const first = await shownAfter(null);
  // The simulated hand goes on pressing: the time in contact grows, and the panel with it.
  const later = await shownAfter(first.shown.contact);
  assert.ok(
    later.sent.time_in_contact_s > first.sent.time_in_contact_s,
    `time in contact ${first.sent.time_in_contact_s} s, then ${later.sent.time_in_contact_s} s`,
  );
  assert.ok(later.sent.ticks > first.sent.ticks, 'a later message');
  assert.notEqual(later.shown.contact, first.shown.contact);
});

test('the viewer counted no malformed or unknown message and raised no page error', async () => {
  const conn = await page.evaluate(() => window.__softhaptic.connection());
  assert.equal(conn.stats.malformed, 0, conn.lastError ?? '');
  assert.equal(conn.stats.unknown, 0);
  assert.ok(conn.stats.messages > 50);
  assert.deepEqual(pageErrors, []);
});

test('a browser not under automation never downloads the test hook, and the page works without it', async () => {
  const p = await browser.newPage({ viewport: { width: 800, height: 600 } });
  const errors = [];
  p.on('pageerror', (e) => errors.push(e.message));
  const requested = [];
  p.on('request', (r) => requested.push(new URL(r.url()).pathname));
  try {
    // What a person's browser says: not driven by automation.
    await p.addInitScript(() => Object.defineProperty(Navigator.prototype, 'webdriver', { get: () => false }));
    await p.goto(server.url);
    // The page connects and draws the stream all the same.
    await p.waitForFunction(() => document.getElementById('conn-state').textContent === 'open', null, {
      timeout: 60000,
    });
    await p.waitForFunction(() => /^\d+\.\d\d mm$/.test(document.getElementById('v-depth').textContent), null, {
      timeout: 60000,
    });
    assert.ok(requested.includes('/src/main.js'), `requested: ${requested.join(', ')}`);
    assert.ok(!requested.some((path) => path.endsWith('/testhook.js')), `requested: ${requested.join(', ')}`);
    assert.equal(await p.evaluate(() => typeof window.__softhaptic), 'undefined');
    assert.deepEqual(errors, []);
  } finally {
    await p.close();
  }
});

test('a WebGL implementation that refuses the bending shader leaves the page bending on the CPU', async () => {
  const p = await browser.newPage({ viewport: { width: 800, height: 600 } });
  const errors = [];
  p.on('pageerror', (e) => errors.push(e.message));
  const logged = [];
  p.on('console', (m) => logged.push(m.text()));
  try {
    await p.goto(server.url);
    await p.waitForFunction(() => window.__softhaptic?.ready(), null, { timeout: 120000 });
    if (!(await p.evaluate(() => window.__softhaptic.webgl()))) return;
    assert.equal(await p.evaluate(() => window.__softhaptic.deformation()), 'gpu');
    await p.evaluate(() => window.__softhaptic.breakDeformationShader());
    await p.waitForFunction(() => window.__softhaptic.deformation() === 'cpu', null, {
      timeout: 120000,
      polling: 'raf',
    });
    // The press still bends the mesh, now in its vertex buffers.
    await freezeOnPress(p, 2e-3);
    const moved = await p.evaluate(() => window.__softhaptic.movedVertices().length);
    assert.ok(moved > 20, `${moved} vertices moved on the CPU path`);
    assert.ok(
      logged.some((l) => l.includes('did not compile')),
      `the failure is logged: ${logged.join(' | ')}`,
    );
    assert.deepEqual(errors, []);
  } finally {
    await p.close();
  }
});

test('without WebGL the page says so and still connects, plots and deforms', async () => {
  const noGl = await launchBrowser({ extraArgs: ['--disable-webgl', '--disable-3d-apis'] });
  try {
    const p = await noGl.newPage({ viewport: { width: 1000, height: 700 } });
    const errors = [];
    p.on('pageerror', (e) => errors.push(e.message));
    await p.goto(server.url);
    await p.waitForFunction(() => window.__softhaptic?.ready(), null, { timeout: 120000 });
    assert.equal(await p.evaluate(() => window.__softhaptic.webgl()), false);
    assert.ok(await p.locator('#webgl-message').isVisible(), 'the page explains that the 3D view is missing');
    // Enough frames for the plot check below, even if the page connected in the middle of a press.
    await p.waitForFunction(() => window.__softhaptic.contactFrames() > 20, null, { timeout: 30000 });
    await p.waitForFunction(
      () => {
        const h = window.__softhaptic;
        const c = h.contact();
        const pressed = c.valid && c.inContact && c.depthM >= 1e-3;
        if (pressed) h.pause(true); // hold this frame's deformation for the check below
        return pressed;
      },
      null,
      { timeout: 120000, polling: 'raf' },
    );
    const moved = await p.evaluate(() => window.__softhaptic.movedVertices().length);
    assert.ok(moved > 0, 'the mesh is still deformed (for the hook and a later WebGL context)');
    const plotted = await p.evaluate(() => window.__softhaptic.forcePlotSamples().length);
    assert.ok(plotted > 10, `${plotted} force samples plotted`);
    assert.equal(await p.locator('#conn-state').textContent(), 'open');
    assert.deepEqual(errors, []);
  } finally {
    await noGl.close();
  }
});

test('after a server restart the page reconnects by itself and draws the new session', async (t) => {
  if (process.env.SOFTHAPTIC_URL) {
    t.skip('the server was started outside this test (SOFTHAPTIC_URL)');
    return;
  }
  const before = await page.evaluate(() => window.__softhaptic.connection());
  const addr = new URL(server.url).host;
  await server.stop();
  await page.waitForFunction(() => window.__softhaptic.connection().state === 'reconnecting', null, { timeout: 30000 });
  server = await startServer({ extraArgs: SERVER_ARGS, addr });
  await page.waitForFunction(
    (old) => {
      const conn = window.__softhaptic.connection();
      return conn.state === 'open' && conn.sessionId !== null && conn.sessionId !== old;
    },
    before.sessionId,
    { timeout: 60000 },
  );
  // The device clock of the new server started again; frames of the new run are drawn.
  await freezeOnPress(page, 1e-3);
  const c = await page.evaluate(() => window.__softhaptic.contact());
  assert.ok(c.inContact && c.depthM >= 1e-3);
  await page.evaluate(() => window.__softhaptic.pause(false));
});
