// Checks shared by the browser tests: a viewer page opened and ready, a press drawn on the
// render mesh exactly as the profile says, how two reads of the drawn pixels differ, and the
// page's Content-Security-Policy violations. Each takes a Playwright page showing the viewer.
import assert from 'node:assert/strict';

import {
  depressionAt,
  profileSetup,
  surfaceFamilyFromJson,
  surfaceSetup,
  surfaceTable,
  surfaceTableAt,
  surfaceTableRadialAt,
  toolFromJson,
} from '../src/deformation.js';

// Vertex positions are float32 (≈ 1e-8 m at 0.1 m) and the displacement is recomputed from the
// same contact, so 1 µm is far above rounding and far below any real error (δ is millimetres).
export const TOLERANCE_M = 1e-6;

/**
 * Waits until the drawn contact is a press at least `minDepthM` deep and freezes the view on
 * that very frame (the check and the pause happen in the same page task, so no animation frame
 * can slip between them).
 */
export async function freezeOnPress(page, minDepthM, { timeout = 120000 } = {}) {
  await page.evaluate(() => window.__softhaptic.pause(false));
  await page.waitForFunction(
    (d) => {
      const h = window.__softhaptic;
      const c = h.contact();
      const pressed = c.valid && !c.stale && c.inContact && c.depthM >= d;
      if (pressed) h.pause(true);
      return pressed;
    },
    minDepthM,
    { timeout, polling: 'raf' },
  );
}

/** Like `freezeOnPress`, for a frame where the tool is off the surface. */
export async function freezeOffSurface(page, { timeout = 120000 } = {}) {
  await page.evaluate(() => window.__softhaptic.pause(false));
  await page.waitForFunction(
    () => {
      const h = window.__softhaptic;
      const c = h.contact();
      const free = c.valid && !c.stale && !c.inContact;
      if (free) h.pause(true);
      return free;
    },
    null,
    { timeout, polling: 'raf' },
  );
}

/**
 * How two reads of the same region (`regionPixels`: RGBA) differ: `mean`, the mean absolute
 * difference per colour channel (0–255), and `visible`, the fraction of pixels where some channel
 * differs by more than 10 levels (a change an eye sees).
 */
export function pixelDifference(a, b) {
  let sum = 0;
  let visible = 0;
  for (let i = 0; i < a.length; i += 4) {
    let most = 0;
    for (let k = 0; k < 3; k++) {
      const d = Math.abs(a[i + k] - b[i + k]);
      sum += d;
      if (d > most) most = d;
    }
    if (most > 10) visible++;
  }
  const pixels = a.length / 4;
  return { mean: sum / (3 * pixels), visible: visible / pixels };
}

/**
 * The pixels of a region (`regionPixels`: RGBA) drawn in the section's line colour (#7ee787, a
 * green found nowhere else in the view), as `[column, row]` from the region's bottom left.
 */
export function sectionLinePixels(pixels, sizePx) {
  const found = [];
  for (let i = 0; i < pixels.length; i += 4) {
    const [r, g, b] = [pixels[i], pixels[i + 1], pixels[i + 2]];
    if (g > 150 && g > r + 40 && g > b + 20) found.push([(i / 4) % sizePx, Math.floor(i / 4 / sizePx)]);
  }
  return found;
}

/**
 * The deformation profile a page draws for contact `c` of `scene` (its `render_profile`):
 * `{name, reachM, at(r), sideways(r)}`, the depression and the outward radial displacement at
 * undeformed radius r, no vertex at or beyond `reachM` from the contact axis moving (R_d,eff
 * for the paper's Bézier, which moves nothing sideways; the tabulated surface's reach for
 * `fem`, drawn from its radial table).
 */
export function drawnProfile(scene, c) {
  if (scene.render_profile === 'fem') {
    const p = surfaceSetup(surfaceFamilyFromJson(scene.calibration.surface), toolFromJson(scene.tool), c.depthM);
    const table = surfaceTable(p);
    return {
      name: 'fem',
      reachM: table.reachM,
      at: (r) => surfaceTableAt(table, r),
      sideways: (r) => surfaceTableRadialAt(table, r),
    };
  }
  const p = profileSetup(toolFromJson(scene.tool), c.depthM, c.contactRadiusM, c.deformedRadiusM);
  return { name: 'paper', reachM: p.rdEff, at: (r) => depressionAt(p, r), sideways: () => 0 };
}

/**
 * On a page frozen on a press (`freezeOnPress`): every render vertex within twice the profile's
 * reach of the contact point sits where the JavaScript profile the scene names puts it for the
 * drawn contact, the vertex under the tool sank by about δ, and vertices beyond the reach did
 * not move. Returns the frozen `{contact, scene, inside, beyond}` for further checks.
 */
export async function assertPressBendsMesh(page) {
  const frozen = await page.evaluate(() => ({
    contact: window.__softhaptic.contact(),
    scene: window.__softhaptic.scene(),
  }));
  const c = frozen.contact;
  const tool = toolFromJson(frozen.scene.tool);
  const profile = drawnProfile(frozen.scene, c);
  assert.ok(profile.reachM > 0);
  // Every vertex within twice the reach of the contact point: rest and drawn positions (world
  // frame).
  const near = await page.evaluate(
    ({ point, radius }) => {
      const h = window.__softhaptic;
      const out = [];
      for (let i = 0; i < h.vertexCount(); i++) {
        const v = h.vertex(i);
        const d = Math.hypot(v.rest[0] - point[0], v.rest[1] - point[1], v.rest[2] - point[2]);
        if (d <= radius) out.push([i, ...v.rest, ...v.now]);
      }
      return out;
    },
    { point: c.point, radius: 2 * profile.reachM },
  );
  const n = c.normal;
  let inside = 0;
  let beyond = 0;
  let underTool = null;
  for (const [i, rx, ry, rz, x, y, z] of near) {
    const vx = rx - c.point[0];
    const vy = ry - c.point[1];
    const vz = rz - c.point[2];
    const axial = vx * n[0] + vy * n[1] + vz * n[2];
    const ex = vx - axial * n[0],
      ey = vy - axial * n[1],
      ez = vz - axial * n[2];
    const r = Math.hypot(ex, ey, ez);
    const moves = Math.abs(axial) < profile.reachM;
    const expected = moves ? profile.at(r) : 0;
    // Outward along the radial direction e/r (nowhere on the axis).
    const out = moves && r > 0 ? profile.sideways(r) / r : 0;
    // The drawn vertex must sit at rest − n·z(r) + e_r·u(r).
    const err = Math.hypot(
      x - (rx - n[0] * expected + ex * out),
      y - (ry - n[1] * expected + ey * out),
      z - (rz - n[2] * expected + ez * out),
    );
    assert.ok(
      err <= TOLERANCE_M,
      `vertex ${i} at r = ${r} m, axial ${axial} m: off by ${err} m (${profile.name} profile ${expected} m, sideways ${out * r} m)`,
    );
    if (r >= profile.reachM) beyond++;
    else if (expected > 0) inside++;
    if (Math.abs(axial) < 2e-3 && (underTool === null || r < underTool.r))
      underTool = { i, r, moved: Math.hypot(x - rx, y - ry, z - rz) };
  }
  assert.ok(inside > 20, `${inside} vertices inside the reach moved`);
  assert.ok(beyond > 20, `${beyond} vertices beyond the reach were checked to be still`);
  assert.ok(underTool !== null, 'a render vertex lies near the contact point');
  // The vertex under the tool sank by about the depth: z(r) = δ − (R − √(R² − r²)) there.
  assert.ok(
    underTool.moved >= c.depthM - (underTool.r * underTool.r) / tool.radiusM - TOLERANCE_M,
    `vertex ${underTool.i} under the tool (r = ${underTool.r} m) moved ${underTool.moved} m for δ = ${c.depthM} m`,
  );
  return { contact: c, scene: frozen.scene, inside, beyond };
}

/**
 * Collects a page's Content-Security-Policy violations from the moment it is called, both as
 * Chromium reports them on the console ("Refused to ... because it violates the following
 * Content Security Policy directive") and as the page's `securitypolicyviolation` events (the
 * listener is installed before any of the page's scripts run, in every document it loads).
 * `list()` resolves with both, newest last.
 */
export async function watchCsp(page) {
  const fromConsole = [];
  page.on('console', (message) => {
    if (/Content Security Policy/i.test(message.text())) fromConsole.push(message.text());
  });
  await page.addInitScript(() => {
    window.__cspViolations = [];
    document.addEventListener('securitypolicyviolation', (e) => {
      window.__cspViolations.push(`${e.violatedDirective} blocked ${e.blockedURI || '(inline)'}`);
    });
  });
  return {
    list: async () => [...fromConsole, ...(await page.evaluate(() => window.__cspViolations ?? []))],
  };
}

/**
 * Opens the viewer at `url` in a new page of `browser` and waits for its test hook to say it is
 * ready; the page's uncaught errors are pushed to `pageErrors`.
 */
export async function openViewer(browser, url, pageErrors) {
  const page = await browser.newPage({ viewport: { width: 1024, height: 700 } });
  page.on('pageerror', (e) => pageErrors.push(e.message));
  await page.goto(url);
  await page.waitForFunction(() => window.__softhaptic?.ready(), null, { timeout: 120000 });
  return page;
}
