// End to end, the lab dashboard: a real nats-server, four real stations (tests/dashboard-lab.mjs:
// one pressing calmly, one pressing above its 0.05 N safe force, one whose SpaceMouse is unplugged
// and stays so, one running an exercise for a trainee), a real hub with tokens, and its
// `/dashboard` page in headless Chromium, read through the page's DOM and its test hook.
//
//   npm run test:e2e    (builds the server with cargo; SOFTHAPTIC_BIN to reuse a built one;
//                        needs nats-server, which `make test` installs)
//
// Checks: every station has its tile; the alerts are on the right tiles (above the safe force on
// desk-hard, a device fault on desk-unplugged, none on the others) and in the alert list; an
// instructor's acknowledgement on a tile clears desk-unplugged's alert for good (its device
// stays down, and no new alert comes), and one from the alert list acknowledges desk-hard's (the
// hub's next messages say who acknowledged them); an instructor's mark reaches the station (a viewer of the station is sent
// it), a repeat restarts the station's exercise (attempt 2), and a re-arm of the simulated device
// (which has no force output to re-arm) is answered with the station's refusal; the observer's page shows every tile and alert
// but no control, and an action sent from it anyway is refused and changes nothing; Chromium
// reports no CSP violation and the pages no error; the sort, filter and size an instructor chose
// are the page's again after a reload; fifty compact tiles (forty-six of them another station's
// heartbeat published again under other names) fit a 1280 × 800 screen without scrolling, and a
// compact tile's buttons open on hover and work.
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { launchBrowser } from './browser.mjs';
import { copyHeartbeats, startDashboardLab, writeStationFiles } from './dashboard-lab.mjs';
import { watchCsp } from './e2e-checks.mjs';
import { logTail, waitOnPage } from './e2e-fixtures.mjs';

const dir = mkdtempSync(join(tmpdir(), 'softhaptic-e2e-dashboard-'));
const NAMES = ['desk-calm', 'desk-hard', 'desk-unplugged', 'desk-exercise'];
let lab;
let browser;
/** The instructor's page and the observer's: `{page, errors, csp}`. */
let teacher;
let watcher;

async function openDashboard(url) {
  const context = await browser.newContext({ viewport: { width: 1280, height: 800 } });
  const page = await context.newPage();
  const errors = [];
  page.on('pageerror', (e) => errors.push(e.message));
  const csp = await watchCsp(page);
  await page.goto(url);
  return { page, errors, csp };
}

const logs = () => [logTail('hub', lab.hub), ...[...lab.stations].map(([name, s]) => logTail(name, s, 10))].join('\n');
const waitFor = (page, what, predicate, arg = null) => waitOnPage(page, what, predicate, arg, logs);
const tiles = (page) => page.evaluate(() => window.__dashboard.tiles());
const tileOf = async (page, name) => (await tiles(page)).find((t) => t.name === name);

before(async () => {
  const args = writeStationFiles(dir);
  lab = await startDashboardLab(dir, [
    ['desk-calm', args.calm],
    ['desk-hard', args.hard],
    ['desk-unplugged', args.unplugged],
    ['desk-exercise', args.exercises('ana')],
  ]);
  browser = await launchBrowser();
  teacher = await openDashboard(lab.dashboardUrl);
  watcher = await openDashboard(lab.observerDashboardUrl);
});

after(async () => {
  await browser?.close();
  await lab?.stop();
  rmSync(dir, { recursive: true, force: true });
});

test('every station has its tile, live, with its summary', async () => {
  await waitFor(teacher.page, 'the instructor greeted', () => window.__dashboard?.role() === 'instructor');
  // The token leaves the address bar at once.
  assert.ok(!teacher.page.url().includes('token'), teacher.page.url());
  await waitFor(
    teacher.page,
    'four tiles with summaries',
    (names) => {
      const m = window.__dashboard.message();
      return (
        m !== null &&
        names.every((n) => m.stations.some((s) => s.name === n && s.state !== 'offline' && s.summary !== null))
      );
    },
    NAMES,
  );
  const shown = await tiles(teacher.page);
  assert.deepEqual(shown.map((t) => t.name).sort(), [...NAMES].sort());
  for (const t of shown) {
    assert.equal(t.href, `/?station=${t.name}`);
    assert.equal(t.offline, false, t.name);
    assert.equal(t.actionsShown, true, t.name);
  }
  assert.equal((await tileOf(teacher.page, 'desk-exercise')).trainee, 'ana');
  // The sparkline's history fills from the summaries' force samples (the calm station presses).
  await waitFor(teacher.page, 'a press in desk-calm’s history', () =>
    (window.__dashboard.history('desk-calm') ?? []).some((f) => f !== null && f > 0.1),
  );
});

test('the alerts are on the right tiles and in the list', async () => {
  await waitFor(teacher.page, 'desk-hard in alert: above the safe force', () =>
    window.__dashboard
      .tiles()
      .some((t) => t.name === 'desk-hard' && t.alert && t.openAlerts.some((a) => a.kind === 'above_safe_force')),
  );
  await waitFor(teacher.page, 'desk-unplugged in alert: a device fault', () =>
    window.__dashboard
      .tiles()
      .some((t) => t.name === 'desk-unplugged' && t.alert && t.openAlerts.some((a) => a.kind === 'device_fault')),
  );
  const shown = await tiles(teacher.page);
  const byName = Object.fromEntries(shown.map((t) => [t.name, t]));
  assert.match(byName['desk-unplugged'].device, /disconnected/);
  assert.equal(byName['desk-calm'].alert, false, JSON.stringify(byName['desk-calm']));
  assert.deepEqual(byName['desk-calm'].openAlerts, []);
  assert.ok(!byName['desk-hard'].openAlerts.some((a) => a.kind === 'device_fault'));
  assert.ok(!byName['desk-unplugged'].openAlerts.some((a) => a.kind === 'above_safe_force'));
  // Sorted alerts first: the two tiles in alert lead.
  assert.deepEqual(
    shown
      .slice(0, 2)
      .map((t) => t.name)
      .sort(),
    ['desk-hard', 'desk-unplugged'],
  );
  const list = await teacher.page.evaluate(() => window.__dashboard.alertList());
  assert.ok(list.some((a) => a.station === 'desk-hard' && a.open && /above the safe force/.test(a.text)));
  assert.ok(list.some((a) => a.station === 'desk-unplugged' && a.open && /device fault/.test(a.text)));
  assert.ok(
    list.every((a) => /^\d\d:\d\d:\d\d/.test(a.text)),
    'each alert with its time',
  );
});

test('the observer sees every tile and alert but no control, and the hub refuses its action', async () => {
  const p = watcher.page;
  await waitFor(p, 'the observer greeted', () => window.__dashboard?.role() === 'observer');
  await waitFor(p, 'desk-hard in alert on the observer’s page', () =>
    window.__dashboard.tiles().some((t) => t.name === 'desk-hard' && t.alert),
  );
  const shown = await tiles(p);
  assert.equal(shown.length, NAMES.length);
  for (const t of shown) {
    assert.equal(t.actionsShown, false, `${t.name}: no controls`);
    assert.equal(t.ackButtons, 0, `${t.name}: no acknowledge`);
  }
  assert.equal(await p.locator('#alert-list button').count(), 0);
  const [open] = (await tileOf(p, 'desk-hard')).openAlerts;
  await p.evaluate((id) => window.__dashboard.act('desk-hard', { kind: 'acknowledge', alert: id }), open.id);
  await waitFor(p, 'the refusal on desk-hard’s tile', () =>
    window.__dashboard.tiles().some((t) => t.name === 'desk-hard' && t.result.startsWith('refused:')),
  );
  assert.match((await tileOf(p, 'desk-hard')).result, /instructor/);
  // Nothing changed: the alert is still open a few messages later.
  const seen = await p.evaluate(() => window.__dashboard.message().time_unix_ms);
  await waitFor(p, 'three more dashboard messages', (t) => window.__dashboard.message().time_unix_ms >= t + 2500, seen);
  const still = await tileOf(p, 'desk-hard');
  assert.ok(
    still.openAlerts.some((a) => a.id === open.id),
    `alert ${open.id} still open: ${JSON.stringify(still)}`,
  );
});

test('an instructor’s acknowledgement clears the alert, and the hub says who acknowledged it', async () => {
  const p = teacher.page;
  // desk-unplugged's device stays disconnected: acknowledged, its fault raises no new alert, so
  // the tile leaves its alert state and stays out of it.
  const unplugged = await tileOf(p, 'desk-unplugged');
  const faults = unplugged.openAlerts.map((a) => a.id);
  assert.ok(faults.length > 0, JSON.stringify(unplugged));
  for (const id of faults) await p.click(`.tile[data-station="desk-unplugged"] button.ack[data-alert="${id}"]`);
  await waitFor(p, 'desk-unplugged out of alert', () =>
    window.__dashboard.tiles().some((t) => t.name === 'desk-unplugged' && !t.alert),
  );
  const seen = await p.evaluate(() => window.__dashboard.message().time_unix_ms);
  await waitFor(p, 'three more dashboard messages', (t) => window.__dashboard.message().time_unix_ms >= t + 2500, seen);
  const after = await tileOf(p, 'desk-unplugged');
  assert.equal(after.alert, false, JSON.stringify(after));
  assert.match(after.device, /disconnected/, 'the device is still down: only the alert was acknowledged');
  const m = await p.evaluate(() => window.__dashboard.message());
  const alerts = m.stations.find((s) => s.name === 'desk-unplugged').summary.alerts;
  for (const id of faults) {
    const a = alerts.find((x) => x.id === id);
    assert.match(a?.acknowledged?.by ?? '', /instructor/, JSON.stringify(alerts));
  }
  // desk-hard's, from the alert list: that alert is acknowledged (its trainee, still pressing
  // above the safe force, may have raised a new one since).
  const [first] = (await tileOf(p, 'desk-hard')).openAlerts;
  await p.click(`#alert-list li[data-station="desk-hard"][data-alert="${first.id}"] button`);
  await waitFor(
    p,
    `desk-hard's alert ${first.id} acknowledged`,
    (id) =>
      window.__dashboard
        .message()
        .stations.find((s) => s.name === 'desk-hard')
        .summary.alerts.some((a) => a.id === id && a.acknowledged !== null),
    first.id,
  );
  await waitFor(
    p,
    'the alert list says who acknowledged it',
    (id) =>
      window.__dashboard
        .alertList()
        .some(
          (a) => a.station === 'desk-hard' && a.id === id && !a.open && /acknowledged .* by instructor/.test(a.text),
        ),
    first.id,
  );
  const sent = await p.evaluate(() => window.__dashboard.sent());
  assert.deepEqual(
    sent.map((x) => [x.station, x.action.kind, x.action.alert]),
    [...faults.map((id) => ['desk-unplugged', 'acknowledge', id]), ['desk-hard', 'acknowledge', first.id]],
  );
});

test('an instructor’s mark reaches the station, a repeat restarts its exercise, a re-arm is answered', async () => {
  const p = teacher.page;
  // A viewer of the station itself: the station sends it every mark of its session.
  const viewer = await browser.newPage({ viewport: { width: 800, height: 600 } });
  try {
    await viewer.goto(lab.stations.get('desk-exercise').url);
    await viewer.waitForFunction(() => window.__softhaptic?.connection().state === 'open', null, { timeout: 60000 });

    const note = 'dashboard: check the grip';
    await p.click('.tile[data-station="desk-exercise"] button[data-act="mark"]');
    await p.fill('.tile[data-station="desk-exercise"] .mark-form input', note);
    await p.press('.tile[data-station="desk-exercise"] .mark-form input', 'Enter');
    await waitFor(p, 'the mark done', () =>
      window.__dashboard.tiles().some((t) => t.name === 'desk-exercise' && t.result === 'mark: done'),
    );
    try {
      await viewer.waitForFunction((n) => window.__softhaptic.marks().marks.some((m) => m.note === n), note, {
        timeout: 60000,
      });
    } catch (e) {
      throw new Error(`the mark never reached the station's viewer: ${e.message}\n${logs()}`, { cause: e });
    }

    await waitFor(p, 'desk-exercise running its first attempt', () => {
      const s = window.__dashboard.message().stations.find((x) => x.name === 'desk-exercise');
      return s.summary?.exercise?.attempt === 1;
    });
    await p.click('.tile[data-station="desk-exercise"] button[data-act="repeat"]');
    await waitFor(p, 'the repeat done', () =>
      window.__dashboard.tiles().some((t) => t.name === 'desk-exercise' && t.result === 'exercise: done'),
    );
    await waitFor(p, 'attempt 2 on the tile', () => {
      const s = window.__dashboard.message().stations.find((x) => x.name === 'desk-exercise');
      return s.summary?.exercise?.attempt === 2 && s.summary.exercise.state === 'running';
    });
    // The station's own viewer is told the same: the station carried the repeat out.
    await viewer.waitForFunction(() => window.__softhaptic.exercise().attempt === 2, null, { timeout: 60000 });
  } finally {
    await viewer.close();
  }

  // A re-arm of the simulated device, which has no force output to re-arm: the station says why not.
  await p.evaluate(() => window.__dashboard.act('desk-calm', { kind: 'rearm_device' }));
  await waitFor(p, 'the station’s answer to the re-arm', () =>
    window.__dashboard
      .tiles()
      .some((t) => t.name === 'desk-calm' && t.result.startsWith('re-arm:') && !t.result.endsWith('sent…')),
  );
  const calm = await tileOf(p, 'desk-calm');
  assert.match(calm.result, /^re-arm: .*no haptic device/, 'the station refuses: nothing to re-arm');
  assert.equal(calm.rearmShown, false, 'the button shows only for a latched device');
});

test('the order, filter and size an instructor chose survive a reload', async () => {
  const p = teacher.page;
  await p.selectOption('#sort', 'peak');
  await p.selectOption('#show', 'device');
  await p.fill('#filter', 'desk');
  await p.check('#compact');
  await waitFor(p, 'only the unplugged station shown', () => {
    const shown = window.__dashboard.tiles();
    return shown.length === 1 && shown[0].name === 'desk-unplugged';
  });
  await p.reload();
  await waitFor(p, 'the instructor greeted again', () => window.__dashboard?.role() === 'instructor');
  const controls = await p.evaluate(() => ({
    sort: document.getElementById('sort').value,
    show: document.getElementById('show').value,
    filter: document.getElementById('filter').value,
    compact: document.getElementById('compact').checked,
    tilesCompact: document.getElementById('tiles').classList.contains('compact'),
  }));
  assert.deepEqual(controls, { sort: 'peak', show: 'device', filter: 'desk', compact: true, tilesCompact: true });
  await waitFor(p, 'the same single tile after the reload', () => {
    const shown = window.__dashboard.tiles();
    return shown.length === 1 && shown[0].name === 'desk-unplugged';
  });
  // Back to the page's defaults for what follows.
  await p.selectOption('#sort', 'alerts');
  await p.selectOption('#show', 'all');
  await p.fill('#filter', '');
  await p.uncheck('#compact');
  await waitFor(p, 'every tile again', (n) => window.__dashboard.tiles().length === n, NAMES.length);
});

test('fifty compact tiles fit a 1280 × 800 screen, and a tile’s buttons open over it', async () => {
  // Forty-six more stations: desk-calm's heartbeat published again under other names.
  const copies = Array.from({ length: 46 }, (_, i) => `desk-c${String(i + 1).padStart(2, '0')}`);
  const copying = await copyHeartbeats(lab.natsUrl, 'desk-calm', copies);
  try {
    for (const opened of [teacher, watcher]) {
      const p = opened.page;
      await p.check('#compact');
      await waitFor(p, 'fifty tiles', () => window.__dashboard.tiles().length === 50);
      const fit = await p.evaluate(() => {
        const outside = [...document.querySelectorAll('#tiles .tile')]
          .filter((t) => {
            const r = t.getBoundingClientRect();
            return r.top < 0 || r.left < 0 || r.bottom > window.innerHeight || r.right > window.innerWidth;
          })
          .map((t) => t.dataset.station);
        return { outside, scrolls: document.scrollingElement.scrollHeight > window.innerHeight };
      });
      assert.deepEqual(fit, { outside: [], scrolls: false }, 'every tile in view, nothing to scroll');
    }
    // The buttons are out of the way until the pointer is on the tile, then usable.
    const p = teacher.page;
    const tile = p.locator('#tiles .tile[data-station="desk-calm"]');
    assert.equal(await tile.locator('.tools').isVisible(), false);
    await tile.hover();
    assert.equal(await tile.locator('.tools').isVisible(), true);
    await tile.locator('button[data-act="mark"]').click();
    await tile.locator('.mark-form input').fill('checked from the compact tile');
    await tile.locator('.mark-form input').press('Enter');
    await waitFor(p, 'the mark answered', () =>
      window.__dashboard.tiles().some((t) => t.name === 'desk-calm' && t.result === 'mark: done'),
    );
    // An observer's tile opens nothing.
    const watched = watcher.page.locator('#tiles .tile[data-station="desk-calm"]');
    await watched.hover();
    assert.equal(await watched.locator('.tools').isVisible(), false);
  } finally {
    await copying.stop();
    for (const opened of [teacher, watcher]) await opened.page.uncheck('#compact');
  }
});

test('no CSP violation and no page error', async () => {
  for (const [who, opened] of [
    ['instructor', teacher],
    ['observer', watcher],
  ]) {
    assert.deepEqual(await opened.csp.list(), [], `${who}: CSP violations`);
    assert.deepEqual(opened.errors, [], `${who}: page errors`);
    const conn = await opened.page.evaluate(() => window.__dashboard.connection());
    assert.equal(conn.state, 'open', who);
    assert.equal(conn.stats.malformed, 0, `${who}: ${conn.lastError}`);
    assert.equal(conn.stats.unknown, 0, who);
  }
});
