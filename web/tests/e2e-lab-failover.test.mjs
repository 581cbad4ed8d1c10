// End to end: hubs are interchangeable behind a load balancer. A real nats-server, one real
// station, two real hubs, and in front of them a small TCP balancer (here, in this file) that
// sends each new connection to the first hub that accepts it, as a load balancer with health
// checks does. The viewer page, in headless Chromium, opens the station through the balancer;
// the first hub is killed; the page's own reconnection (no reload, no test action) lands on the
// second hub and carries on live: the same session, frames again, later ones than before.
//
//   npm run test:e2e    (builds the server with cargo; SOFTHAPTIC_BIN to reuse a built one;
//                        needs nats-server, which `make test` installs)
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, rmSync } from 'node:fs';
import { createServer, connect } from 'node:net';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { logTail, openPage, startLab, waitOnPage } from './e2e-fixtures.mjs';

/**
 * A TCP balancer on a free loopback port: each connection goes to the first of `backends`
 * (ports) that accepts it, and is closed when either side closes. Resolves with
 * `{port, served, close}`; `served[i]` counts the connections backend `i` took.
 */
function startBalancer(backends) {
  const served = backends.map(() => 0);
  const sockets = new Set();
  const server = createServer((client) => {
    sockets.add(client);
    client.on('close', () => sockets.delete(client));
    client.on('error', () => client.destroy());
    client.pause();
    const tryBackend = (i) => {
      if (i === backends.length) {
        client.destroy();
        return;
      }
      const upstream = connect(backends[i], '127.0.0.1');
      let connected = false;
      upstream.once('error', () => {
        // A refused connection goes to the next backend; an error later just ends this one.
        if (connected) return;
        upstream.destroy();
        tryBackend(i + 1);
      });
      upstream.once('connect', () => {
        connected = true;
        served[i]++;
        sockets.add(upstream);
        upstream.on('close', () => {
          sockets.delete(upstream);
          client.destroy();
        });
        upstream.on('error', () => upstream.destroy());
        client.on('close', () => upstream.destroy());
        client.pipe(upstream);
        upstream.pipe(client);
        client.resume();
      });
    };
    tryBackend(0);
  });
  return new Promise((resolve, reject) => {
    server.once('error', reject);
    server.listen(0, '127.0.0.1', () =>
      resolve({
        port: server.address().port,
        served,
        close: () =>
          new Promise((done) => {
            for (const s of sockets) s.destroy();
            server.close(() => done());
          }),
      }),
    );
  });
}

const dir = mkdtempSync(join(tmpdir(), 'softhaptic-e2e-lab-failover-'));
let lab;
let balancer;
let view;
let page;

before(async () => {
  lab = await startLab(dir, { stations: [['--no-record', '--station', 'desk-1']], hubs: 2 });
  balancer = await startBalancer(lab.hubs.map((h) => Number(new URL(h.url).port)));
  view = await openPage();
  page = view.page;
});

after(async () => {
  await view?.close();
  await balancer?.close();
  await lab?.stop();
  rmSync(dir, { recursive: true, force: true });
});

const waitFor = (what, predicate, arg = null) =>
  waitOnPage(page, what, predicate, arg, () => lab.hubs.map((h, i) => logTail(`hub ${i + 1}`, h, 10)).join('\n'));

const shown = () =>
  page.evaluate(() => ({
    connection: window.__softhaptic.connection(),
    frames: window.__softhaptic.contactFrames(),
    seq: window.__softhaptic.contact().seq,
  }));

test("a hub's viewer carries on live through another hub when the first is killed", async () => {
  await page.goto(`http://127.0.0.1:${balancer.port}/?station=desk-1`);
  await waitFor('the station drawn', () => window.__softhaptic?.ready());
  await waitFor('frames through the first hub', () => window.__softhaptic.contactFrames() > 20);
  const before = await shown();
  assert.equal(before.connection.state, 'open');
  assert.equal(balancer.served[1], 0, 'the second hub took no connection while the first was up');
  const session = before.connection.sessionId;
  assert.ok(session, JSON.stringify(before));

  // A crash, not a shutdown: the page learns of it only from its socket closing.
  lab.hubs[0].child.kill('SIGKILL');
  await waitFor(
    'the page reconnected',
    (connects) => window.__softhaptic.connection().stats.connects > connects,
    before.connection.stats.connects,
  );
  await waitFor(
    'frames through the second hub',
    (frames) => window.__softhaptic.contactFrames() > frames + 20,
    before.frames,
  );
  const afterwards = await shown();
  assert.equal(afterwards.connection.state, 'open');
  assert.equal(afterwards.connection.sessionId, session, 'the same session, through the other hub');
  assert.ok(afterwards.seq > before.seq + 20, `seq ${before.seq} then ${afterwards.seq}`);
  assert.ok(balancer.served[1] >= 1, 'the second hub served the reconnection');
  assert.deepEqual(view.pageErrors, []);
});
