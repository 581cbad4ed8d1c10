// The lab's page logic: the station an address names, the query added to the server's URLs, the
// station list's words, and the list drawn from a hub's answer (a scripted fetch, a fake
// document).
import { test } from 'node:test';
import assert from 'node:assert/strict';

import {
  StationList,
  ago,
  archiveOf,
  describeArchivedOnly,
  describeStation,
  stationOf,
  withStation,
} from '../src/lab.js';

test('the address names a station only with a valid name', () => {
  assert.equal(stationOf({ search: '?station=desk-1' }), 'desk-1');
  assert.equal(stationOf({ search: '?x=1&station=B_2' }), 'B_2');
  assert.equal(stationOf({ search: '' }), null);
  assert.equal(stationOf({ search: '?station=' }), null);
  assert.equal(stationOf({ search: '?station=a.b' }), null);
  assert.equal(stationOf({ search: '?station=%3Cscript%3E' }), null);
  assert.equal(stationOf({ search: `?station=${'x'.repeat(65)}` }), null);
});

test('an archived recording is named with its station only', () => {
  assert.equal(archiveOf({ search: '?station=d&archive=2026-12-01-a.mcap' }), '2026-12-01-a.mcap');
  assert.equal(archiveOf({ search: '?archive=a.mcap' }), null);
  assert.equal(archiveOf({ search: '?station=d&archive=../x.mcap' }), null);
  assert.equal(archiveOf({ search: '?station=d&archive=a.txt' }), null);
  assert.equal(withStation('/ws', 'd', 'a.mcap'), '/ws?station=d&archive=a.mcap');
});

test('the station goes into the query of the scene and the stream', () => {
  assert.equal(withStation('/api/scene', 'desk-1'), '/api/scene?station=desk-1');
  assert.equal(withStation('ws://h:1/ws', 'desk-1'), 'ws://h:1/ws?station=desk-1');
  assert.equal(withStation('/x?a=1', 'd'), '/x?a=1&station=d');
  assert.equal(withStation('/api/scene', null), '/api/scene');
});

test('a station is described by its state, since when, its scene and its viewers', () => {
  assert.equal(ago(0, 12_400), '12 s');
  assert.equal(ago(0, 185_000), '3 min');
  assert.equal(ago(0, 7_300_000), '2 h');
  assert.equal(ago(5000, 0), '0 s');
  const s = { state: 'live', since_unix_ms: 0, scene: 'liver, sphere 10 mm', viewers: 1, hub_viewers: 2 };
  assert.equal(describeStation(s, 61_000), 'live for 1 min · liver, sphere 10 mm · 3 viewers');
  assert.equal(
    describeStation({ ...s, viewers: 0, hub_viewers: 1 }, 0),
    'live for 0 s · liver, sphere 10 mm · 1 viewer',
  );
});

class FakeNode {
  constructor(tag) {
    this.tag = tag;
    this.children = [];
    this.dataset = {};
    this.className = '';
    this.textContent = '';
    this.hidden = true;
  }
  get ownerDocument() {
    return { createElement: (tag) => new FakeNode(tag) };
  }
  append(...nodes) {
    this.children.push(...nodes);
  }
  replaceChildren(...nodes) {
    this.children = nodes;
  }
}

test("a hub's answer is drawn as links to each station, the current one marked", async () => {
  const panel = new FakeNode('section');
  const list = new FakeNode('ul');
  const answers = [
    {
      hub: true,
      stations: [
        { name: 'desk-1', state: 'live', since_unix_ms: 0, scene: 'liver', viewers: 0, hub_viewers: 1 },
        { name: 'desk-2', state: 'offline', since_unix_ms: 0, scene: 'liver', viewers: 0, hub_viewers: 0 },
      ],
    },
    { hub: true, stations: [] },
  ];
  const asked = [];
  // The second time, the archive is empty too (a lab's first start).
  const archives = [{ archive: [{ station: 'desk-2', file: 'a.mcap', bytes: 10, digest: 'SHA-256=x' }] }, {}];
  const stations = new StationList({
    panel,
    list,
    current: 'desk-2',
    currentArchive: 'a.mcap',
    now: () => 1000,
    fetchJson: async (url) => {
      asked.push(url);
      return url === '/api/archive' ? archives.shift() : answers.shift();
    },
  });
  assert.equal(await stations.refresh(), true);
  assert.deepEqual(asked, ['/api/stations', '/api/archive']);
  assert.equal(panel.hidden, false);
  assert.equal(list.children.length, 2);
  const [one, two] = list.children;
  assert.equal(one.className, 'station live');
  assert.equal(two.className, 'station offline current');
  assert.equal(one.children[0].href, '?station=desk-1');
  assert.equal(one.children[0].textContent, 'desk-1');
  assert.equal(two.dataset.station, 'desk-2');
  // The archived recording of desk-2, a link to its replay, marked as the one shown.
  assert.equal(one.children.length, 2, 'desk-1 has no archive');
  const archived = two.children[2];
  assert.equal(archived.className, 'archived');
  assert.equal(archived.children[0].dataset.archive, 'a.mcap');
  assert.equal(archived.children[0].className, 'current');
  assert.equal(archived.children[0].children[0].href, '?station=desk-2&archive=a.mcap');
  // No station yet: said so.
  await stations.refresh();
  assert.equal(list.children.length, 1);
  assert.equal(list.children[0].textContent, 'no station has published yet');
});

test('a station is not a hub and draws nothing', async () => {
  const panel = new FakeNode('section');
  const list = new FakeNode('ul');
  const stations = new StationList({
    panel,
    list,
    current: null,
    fetchJson: async () => ({ hub: false, stations: [] }),
  });
  assert.equal(await stations.refresh(), false);
  assert.equal(stations.isHub, false);
  assert.equal(panel.hidden, true);
  assert.equal(list.children.length, 0);
});

test("a refresh keeps each station's element, so a link is never replaced under the pointer", async () => {
  const panel = new FakeNode('section');
  const list = new FakeNode('ul');
  const station = (since) => ({
    name: 'desk-1',
    state: 'live',
    since_unix_ms: since,
    scene: 'liver',
    viewers: 0,
    hub_viewers: 0,
  });
  const answers = [
    { hub: true, stations: [station(0)] },
    { hub: true, stations: [station(0)] },
  ];
  const stations = new StationList({
    panel,
    list,
    current: null,
    now: () => 5000,
    fetchJson: async (url) => (url === '/api/archive' ? { archive: [] } : answers.shift()),
  });
  await stations.refresh();
  const first = list.children[0];
  const link = first.children[0];
  await stations.refresh();
  assert.equal(list.children[0], first);
  assert.equal(list.children[0].children[0], link);
  assert.equal(first.children[1].textContent, ' live for 5 s · liver · 0 viewers');
});

test('a station known only from the archive is listed after the heard ones, with its replays', async () => {
  const panel = new FakeNode('section');
  const list = new FakeNode('ul');
  const heard = { name: 'desk-1', state: 'live', since_unix_ms: 0, scene: 'liver', viewers: 0, hub_viewers: 0 };
  const answers = [
    { hub: true, stations: [heard] },
    { hub: true, stations: [heard, { ...heard, name: 'old-desk' }] },
  ];
  const archive = {
    archive: [
      { station: 'old-desk', file: 'a.mcap', bytes: 10, digest: 'SHA-256=x' },
      { station: 'old-desk', file: 'b.mcap', bytes: 10, digest: 'SHA-256=y' },
    ],
  };
  const stations = new StationList({
    panel,
    list,
    current: null,
    now: () => 0,
    fetchJson: async (url) => (url === '/api/archive' ? archive : answers.shift()),
  });
  await stations.refresh();
  assert.equal(list.children.length, 2);
  const old = list.children[1];
  assert.equal(old.className, 'station archived');
  assert.equal(old.dataset.station, 'old-desk');
  // No live view to open: its name is not a link, its sessions are.
  assert.equal(old.children[0].tag, 'span');
  assert.equal(old.children[0].textContent, 'old-desk');
  assert.equal(old.children[1].textContent, ` ${describeArchivedOnly(2)}`);
  assert.equal(describeArchivedOnly(2), 'not heard by this hub · 2 archived sessions');
  assert.equal(describeArchivedOnly(1), 'not heard by this hub · 1 archived session');
  const replays = old.children[2].children.map((li) => li.children[0].href);
  assert.deepEqual(replays, ['?station=old-desk&archive=a.mcap', '?station=old-desk&archive=b.mcap']);
  // Once heard, it is a station like the others, with a link.
  await stations.refresh();
  assert.equal(list.children.length, 2);
  assert.equal(list.children[1].className, 'station live');
  assert.equal(list.children[1].children[0].tag, 'a');
  assert.equal(list.children[1].children[2].children.length, 2);
});
