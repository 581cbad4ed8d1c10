// End to end through a teaching lab: a real nats-server, two real stations (the default liver
// pressed by a sphere, and by a cone) publishing to it, and a real hub; the viewer page on the
// hub in headless Chromium, read through the page's test hook. Checks: the page lists both
// stations as links; picking one shows that station's stream (its tool, its frames) without the
// mark form (a hub takes no marks); switching to the other shows the other's; a station that
// stops archives its recording in the lab's object store, and the hub's page lists it and
// replays it; no page error.
//
//   npm run test:e2e    (builds the server with cargo; SOFTHAPTIC_BIN to reuse a built one;
//                        needs nats-server, which `make test` installs)
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { logTail, openPage, startLab, waitOnPage } from './e2e-fixtures.mjs';

const dir = mkdtempSync(join(tmpdir(), 'softhaptic-e2e-lab-'));
let lab;
let view;
let page;

before(async () => {
  lab = await startLab(dir, {
    stations: [
      ['--record-dir', join(dir, 'recordings'), '--station', 'desk-1'],
      ['--no-record', '--station', 'desk-2', '--scene', 'scenes/cone.toml'],
    ],
  });
  view = await openPage();
  page = view.page;
  await page.goto(lab.hubs[0].url);
});

after(async () => {
  await view?.close();
  await lab?.stop();
  rmSync(dir, { recursive: true, force: true });
});

const waitFor = (what, predicate, arg = null) =>
  waitOnPage(page, what, predicate, arg, () => logTail('hub', lab.hubs[0]));

test('the hub lists both stations as links', async () => {
  await waitFor('two stations listed', () => window.__softhaptic?.stations().listed.length === 2);
  const s = await page.evaluate(() => window.__softhaptic.stations());
  assert.equal(s.isHub, true);
  assert.equal(s.current, null);
  assert.deepEqual(
    s.listed.map((l) => [l.name, l.href]),
    [
      ['desk-1', '?station=desk-1'],
      ['desk-2', '?station=desk-2'],
    ],
  );
  assert.match(s.listed[1].text, /cone/);
});

test('picking a station shows its stream, and switching shows the other', async () => {
  for (const [name, shape] of [
    ['desk-2', 'cone'],
    ['desk-1', 'sphere'],
  ]) {
    await page.click(`li[data-station="${name}"] a`);
    await waitFor(`${name} drawn`, () => window.__softhaptic?.ready());
    await waitFor(`frames of ${name}`, () => window.__softhaptic.contactFrames() > 10);
    await waitFor(`the hello of ${name}`, () => window.__softhaptic.role() !== null);
    const shown = await page.evaluate(() => ({
      stations: window.__softhaptic.stations(),
      scene: window.__softhaptic.scene(),
      connection: window.__softhaptic.connection().state,
      role: window.__softhaptic.role(),
      marks: window.__softhaptic.marks(),
    }));
    assert.equal(shown.stations.current, name);
    // An instructor, yet no mark form: the hub records nothing and refuses marks.
    assert.equal(shown.role, 'instructor');
    assert.equal(shown.marks.formShown, false);
    assert.equal(shown.scene.tool.shape, shape);
    assert.equal(shown.connection, 'open');
    assert.ok(shown.scene.render_meshes[0].url.startsWith(`/stations/${name}/`));
  }
  assert.deepEqual(view.pageErrors, []);
});

test('a stopped station archives its recording, and the hub replays it', async () => {
  // Stopping desk-1 closes its recording and uploads it before the process ends.
  await lab.stations[0].stop();
  assert.match(lab.stations[0].output(), /recording archived in the lab \(verified\)/);
  await waitFor('the archived recording listed', () =>
    window.__softhaptic.stations().listed.some((s) => s.name === 'desk-1' && s.archived.length === 1),
  );
  const listed = await page.evaluate(() => window.__softhaptic.stations().listed);
  const [archived] = listed.find((s) => s.name === 'desk-1').archived;
  assert.match(archived.href, /^\?station=desk-1&archive=.+\.mcap$/);
  await page.click(`li[data-archive="${archived.file}"] a`);
  await waitFor('the replay drawn', () => window.__softhaptic?.ready());
  await waitFor('the replay status', () => window.__softhaptic.replay().known);
  const shown = await page.evaluate(() => ({
    mode: window.__softhaptic.mode(),
    replay: window.__softhaptic.replay(),
    stations: window.__softhaptic.stations(),
  }));
  assert.equal(shown.mode, 'replay');
  assert.equal(shown.replay.file, archived.file);
  assert.ok(shown.replay.durationS > 0.5, JSON.stringify(shown.replay));
  assert.equal(shown.stations.archive, archived.file);
  assert.deepEqual(view.pageErrors, []);
});
