// The viewer's connection: the WebSocket URL, reconnection with backoff, its token (`auth`
// first) and its answer to the close codes of access and limits, driven by a scripted socket and
// mocked timers.
import { test } from 'node:test';
import assert from 'node:assert/strict';

import { backoffDelayMs, UNAUTHORIZED_REASONS, ViewerConnection, webSocketUrl } from '../src/connection.js';
import { encodeReplayControl } from '../src/protocol.js';
import { contact, hello, legacyHello } from './fixtures.mjs';

const TOKEN = '0123456789abcdef0123456789abcdef';

test('the WebSocket URL follows the page, and carries neither its query nor its fragment', () => {
  assert.equal(webSocketUrl({ protocol: 'http:', host: '127.0.0.1:8080', search: '' }), 'ws://127.0.0.1:8080/ws');
  // The upgrade's URL reaches request logs: a token pasted into the query must not go with it.
  assert.equal(
    webSocketUrl({ protocol: 'https:', host: 'sim.example:443', search: '?token=abc', hash: '#token=abc' }),
    'wss://sim.example:443/ws',
  );
});

test('backoff grows exponentially to its cap, with jitter within [half, full]', () => {
  const opts = { initialMs: 250, maxMs: 8000, factor: 2 };
  assert.equal(
    backoffDelayMs(0, () => 0, opts),
    125,
  );
  assert.equal(
    backoffDelayMs(0, () => 1, opts),
    250,
  );
  assert.equal(
    backoffDelayMs(3, () => 1, opts),
    2000,
  );
  assert.equal(
    backoffDelayMs(10, () => 1, opts),
    8000,
  );
  assert.equal(
    backoffDelayMs(10, () => 0, opts),
    4000,
  );
});

/** A scripted WebSocket: the test opens, feeds and closes it. */
class FakeSocket {
  static instances = [];
  constructor(url) {
    this.url = url;
    this.closed = null;
    /** Text frames the viewer sent, parsed. */
    this.sent = [];
    FakeSocket.instances.push(this);
  }
  send(text) {
    this.sent.push(JSON.parse(text));
  }
  close(code, reason) {
    this.closed = { code, reason };
  }
  serverOpen() {
    this.onopen?.({});
  }
  serverSend(message) {
    this.onmessage?.({ data: typeof message === 'string' ? message : JSON.stringify(message) });
  }
  serverClose(code = 1006, reason = '') {
    this.onclose?.({ code, reason });
  }
}

function connection(extra = {}) {
  FakeSocket.instances = [];
  const received = [];
  const states = [];
  const details = [];
  const warnings = [];
  const conn = new ViewerConnection({
    url: 'ws://host/ws',
    WebSocketImpl: FakeSocket,
    onMessage: (m) => received.push(m),
    onStateChange: (s, d) => {
      states.push(s);
      details.push(d);
    },
    random: () => 0.5,
    now: () => 0,
    warn: (w) => warnings.push(w),
    ...extra,
  });
  return { conn, received, states, details, warnings };
}

/** Runs timers until a new socket appears (or `limitMs` passes); returns the wait in ms. */
function waitForRetry(t, limitMs = 20000) {
  const before = FakeSocket.instances.length;
  let waited = 0;
  while (FakeSocket.instances.length === before && waited < limitMs) {
    t.mock.timers.tick(1);
    waited++;
  }
  return FakeSocket.instances.length === before ? null : waited;
}

test('connection delivers messages, counts unknown ones, and reconnects after a malformed one', (t) => {
  t.mock.timers.enable({ apis: ['setTimeout'] });
  const { conn, received, states, warnings } = connection();
  conn.start();
  const s1 = FakeSocket.instances[0];
  assert.equal(s1.url, 'ws://host/ws');
  s1.serverOpen();
  s1.serverSend(hello);
  s1.serverSend(contact());
  s1.serverSend({ type: 'future_thing' });
  assert.deepEqual(
    received.map((m) => m.type),
    ['hello', 'contact'],
  );
  assert.equal(conn.stats.unknown, 1);
  assert.match(warnings[0], /unknown type "future_thing"/);
  s1.serverSend(contact({ depth_m: NaN })); // serialises as null: malformed
  assert.deepEqual(s1.closed, { code: 1007, reason: 'malformed message' });
  assert.equal(conn.stats.malformed, 1);
  assert.match(conn.lastError, /contact.depth_m/);
  assert.equal(conn.state, 'reconnecting');
  // Messages from the closed socket are ignored.
  s1.serverSend(contact());
  assert.equal(received.length, 2);
  // First retry after 0.75 × 250 ms (random 0.5, equal jitter).
  t.mock.timers.tick(187);
  assert.equal(FakeSocket.instances.length, 1);
  t.mock.timers.tick(1);
  assert.equal(FakeSocket.instances.length, 2);
  FakeSocket.instances[1].serverOpen();
  assert.deepEqual(states, ['connecting', 'open', 'reconnecting', 'connecting', 'open']);
  conn.stop();
  assert.equal(FakeSocket.instances[1].closed.code, 1000);
  assert.equal(conn.state, 'stopped');
});

test('repeated failures back off exponentially and a hello resets the backoff', (t) => {
  t.mock.timers.enable({ apis: ['setTimeout'] });
  const { conn } = connection({ random: () => 1 });
  conn.start();
  const delays = [];
  let last = 0;
  for (let k = 0; k < 6; k++) {
    FakeSocket.instances.at(-1).serverClose(1006);
    // Find when the next socket appears.
    let waited = 0;
    while (FakeSocket.instances.length === last + 1) {
      t.mock.timers.tick(1);
      waited++;
      assert.ok(waited < 20000, 'a retry happens');
    }
    last++;
    delays.push(waited);
  }
  assert.deepEqual(delays, [250, 500, 1000, 2000, 4000, 8000]);
  assert.match(conn.lastError, /code 1006/);
  const s = FakeSocket.instances.at(-1);
  s.serverOpen();
  s.serverSend(hello);
  assert.equal(conn.lastError, null);
  s.serverClose(1006);
  let waited = 0;
  const before = FakeSocket.instances.length;
  while (FakeSocket.instances.length === before) {
    t.mock.timers.tick(1);
    waited++;
  }
  assert.equal(waited, 250, 'after a healthy session the first retry is quick again');
  conn.stop();
  t.mock.timers.tick(100000);
  assert.equal(FakeSocket.instances.length, before + 1, 'no retry after stop');
});

test('a socket constructor that throws is retried like a failed connection', (t) => {
  t.mock.timers.enable({ apis: ['setTimeout'] });
  let calls = 0;
  class Throwing {
    constructor() {
      calls++;
      throw new Error('bad url');
    }
  }
  const { conn } = connection({ WebSocketImpl: Throwing });
  conn.start();
  assert.equal(conn.state, 'reconnecting');
  assert.match(conn.lastError, /bad url/);
  t.mock.timers.tick(250);
  assert.equal(calls, 2);
  conn.stop();
});

test('with a token, auth is the first message on every connection, before anything the viewer sends', (t) => {
  t.mock.timers.enable({ apis: ['setTimeout'] });
  let conn;
  const sentOnOpen = [];
  ({ conn } = connection({
    token: TOKEN,
    // Whatever reacts to `open` (a control queued by the page) is sent after the token.
    onStateChange: (s) => {
      if (s === 'open') sentOnOpen.push(conn.send(encodeReplayControl('pause')));
    },
  }));
  conn.start();
  const s1 = FakeSocket.instances[0];
  assert.deepEqual(s1.sent, [], 'nothing before the socket opens');
  s1.serverOpen();
  assert.deepEqual(s1.sent, [
    { type: 'auth', token: TOKEN },
    { type: 'replay_control', action: 'pause' },
  ]);
  assert.equal(conn.stats.auths, 1);
  assert.equal(conn.stats.sent, 1, '`sent` counts the page’s messages, not the token');
  s1.serverClose(1006);
  t.mock.timers.tick(250);
  const s2 = FakeSocket.instances[1];
  s2.serverOpen();
  assert.deepEqual(s2.sent[0], { type: 'auth', token: TOKEN }, 'presented again after a reconnection');
  assert.ok(!JSON.stringify(conn.lastError ?? '').includes(TOKEN));
  conn.stop();
});

test('without a token nothing is sent on open, and a server without tokens greets at once', () => {
  const { conn, received } = connection();
  conn.start();
  const s = FakeSocket.instances[0];
  s.serverOpen();
  assert.deepEqual(s.sent, []);
  s.serverSend(legacyHello);
  assert.equal(received[0].type, 'hello');
  conn.stop();
});

test('a 4401 to a viewer without a token stops the retries: it needs a token', (t) => {
  t.mock.timers.enable({ apis: ['setTimeout'] });
  const { conn, states, details } = connection();
  conn.start();
  const s = FakeSocket.instances[0];
  s.serverOpen();
  s.serverClose(4401, 'no token presented');
  assert.equal(conn.state, 'unauthorized');
  assert.deepEqual(details.at(-1), { reason: 'needs_token', code: 4401, serverReason: 'no token presented' });
  assert.equal(conn.lastError, UNAUTHORIZED_REASONS.needs_token);
  assert.equal(waitForRetry(t, 60000), null, 'no reconnection: the same request would be refused again');
  assert.deepEqual(states, ['connecting', 'open', 'unauthorized']);
});

test('a 4401 after a token says it was refused; a new token reconnects at once and is presented', (t) => {
  t.mock.timers.enable({ apis: ['setTimeout'] });
  const { conn, details, received } = connection({ token: TOKEN });
  conn.start();
  const s1 = FakeSocket.instances[0];
  s1.serverOpen();
  s1.serverClose(4401, 'token not valid for this server');
  assert.equal(conn.state, 'unauthorized');
  assert.equal(details.at(-1).reason, 'token_refused');
  assert.match(conn.lastError, /not valid for this server, or has expired/);
  assert.equal(waitForRetry(t, 60000), null);

  const other = 'fedcba9876543210fedcba9876543210';
  conn.setToken(other);
  assert.equal(FakeSocket.instances.length, 1, 'setToken alone does not connect');
  conn.reconnectNow();
  const s2 = FakeSocket.instances[1];
  assert.equal(conn.state, 'connecting');
  s2.serverOpen();
  assert.deepEqual(s2.sent, [{ type: 'auth', token: other }]);
  s2.serverSend({ ...hello, role: 'observer' });
  assert.equal(received.at(-1).role, 'observer');
  assert.equal(conn.lastError, null);
  assert.equal(conn.unauthorized, null);
  conn.stop();
});

test('reconnectNow drops a waiting retry and an open socket and connects from the shortest backoff', (t) => {
  t.mock.timers.enable({ apis: ['setTimeout'] });
  const { conn } = connection({ random: () => 1 });
  conn.start();
  for (let k = 0; k < 4; k++) {
    FakeSocket.instances.at(-1).serverClose(1006);
    waitForRetry(t);
  }
  FakeSocket.instances.at(-1).serverClose(1006); // the next retry would wait 4 s
  conn.reconnectNow();
  assert.equal(FakeSocket.instances.length, 6, 'at once');
  t.mock.timers.tick(10000);
  assert.equal(FakeSocket.instances.length, 6, 'the dropped retry does not fire');
  const open = FakeSocket.instances.at(-1);
  open.serverOpen();
  conn.reconnectNow();
  assert.deepEqual(open.closed, { code: 1000, reason: 'viewer reconnects' });
  open.serverClose(1000); // the old socket's close is not a new outage
  assert.equal(FakeSocket.instances.length, 7);
  FakeSocket.instances.at(-1).serverClose(1006);
  assert.equal(waitForRetry(t), 250, 'the backoff starts over');
  conn.stop();
});

test('a 4429 (too many viewers) is shown and retried with the growing backoff', (t) => {
  t.mock.timers.enable({ apis: ['setTimeout'] });
  const { conn, details } = connection({ random: () => 1 });
  conn.start();
  const delays = [];
  for (let k = 0; k < 3; k++) {
    const s = FakeSocket.instances.at(-1);
    s.serverOpen();
    s.serverClose(4429, 'too many viewers');
    assert.equal(conn.state, 'reconnecting');
    assert.equal(conn.lastError, 'too many viewers on this server (code 4429: too many viewers)');
    assert.equal(details.at(-1).error, conn.lastError);
    delays.push(waitForRetry(t));
  }
  assert.deepEqual(delays, [250, 500, 1000]);
  conn.stop();
});

test('a 1008 (too many messages) is shown and retried with backoff', (t) => {
  t.mock.timers.enable({ apis: ['setTimeout'] });
  const { conn } = connection({ random: () => 1 });
  conn.start();
  const s = FakeSocket.instances[0];
  s.serverOpen();
  s.serverSend(hello);
  s.serverClose(1008, 'message rate limit');
  assert.equal(conn.state, 'reconnecting');
  assert.match(conn.lastError, /too many messages \(code 1008: message rate limit\)/);
  assert.equal(waitForRetry(t), 250);
  conn.stop();
});
