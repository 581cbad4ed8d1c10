// Message decoding against the shared vectors and the wire contract; the WebSocket URL; the
// connection's reconnection with backoff, its token (`auth` first) and its answer to the close
// codes of access and limits, driven by a scripted socket and mocked timers.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { fileURLToPath } from 'node:url';

import {
  DEVICE_STATUS_MESSAGES,
  ProtocolError,
  UNAUTHORIZED_REASONS,
  ViewerConnection,
  accessOf,
  backoffDelayMs,
  contactModelOf,
  decodeMessage,
  deviceStatusMessage,
  encodeMark,
  forceFeedbackOf,
  encodeAuth,
  encodeReplayControl,
  webSocketUrl,
} from '../src/protocol.js';
import { contact, contactModel, hello, legacyHello, scene, stats } from './fixtures.mjs';

const VECTORS = fileURLToPath(new URL('../../proto/vectors/messages.json', import.meta.url));

test('every shared message vector decodes or is refused as the Rust side says', () => {
  const vectors = JSON.parse(readFileSync(VECTORS, 'utf8'));
  const list = Array.isArray(vectors) ? vectors : vectors.vectors;
  assert.ok(Array.isArray(list) && list.length > 0);
  const seen = new Set();
  for (const v of list) {
    if (v.valid === false) {
      assert.throws(() => decodeMessage(v.raw), ProtocolError, `${v.name} must be refused`);
      continue;
    }
    const text = v.raw ?? JSON.stringify(v.json);
    const decoded = decodeMessage(text);
    const type = (v.json ?? JSON.parse(v.raw)).type;
    if (decoded.kind === 'unknown') {
      assert.ok(!['hello', 'scene', 'contact', 'stats', 'replay', 'refused'].includes(type), `${v.name}`);
    } else {
      assert.equal(decoded.message.type, type, v.name);
      seen.add(type);
      if (type === 'scene') {
        // With or without `contact_model`, the panel has a model to show.
        const model = contactModelOf(decoded.message);
        assert.ok(model.label.length > 0, v.name);
        if (v.json.contact_model) {
          assert.equal(model.label, v.json.contact_model.label, v.name);
          assert.equal(model.limitsSource, v.json.contact_model.limits_source, v.name);
        } else {
          assert.equal(model.limitsSource, null, `${v.name}: an older scene states no source`);
        }
      }
    }
  }
  for (const type of ['hello', 'scene', 'contact', 'stats', 'replay', 'refused'])
    assert.ok(seen.has(type), `vectors cover ${type}`);
});

test('the auth message is encoded exactly as the Rust side reads it; the hello and refused vectors decode', () => {
  const list = JSON.parse(readFileSync(VECTORS, 'utf8'));
  const auth = list.find((v) => v.json?.type === 'auth');
  assert.ok(auth, 'the vectors hold the auth message');
  assert.deepEqual(JSON.parse(encodeAuth(auth.json.token)), auth.json);
  // A viewer → server message is not one the viewer receives: unknown, ignored, not refused.
  assert.equal(decodeMessage(JSON.stringify(auth.json)).kind, 'unknown');
  const access = list
    .filter((v) => v.json?.type === 'hello')
    .map((v) => accessOf(decodeMessage(JSON.stringify(v.json)).message));
  for (const expected of [
    { role: 'instructor', mode: 'live' },
    { role: 'observer', mode: 'live' },
    { role: 'instructor', mode: 'replay' },
  ]) {
    assert.ok(
      access.some((a) => a.role === expected.role && a.mode === expected.mode),
      `a hello vector for ${JSON.stringify(expected)}`,
    );
  }
  const refused = list.find((v) => v.json?.type === 'refused');
  assert.ok(refused, 'the vectors hold a refused message');
  const decoded = decodeMessage(JSON.stringify(refused.json));
  assert.equal(decoded.kind, 'message');
  assert.equal(decoded.message.request, 'replay_control');
  assert.ok(decoded.message.reason.length > 0);
});

test('replay controls are encoded exactly as the Rust side writes them', () => {
  const list = JSON.parse(readFileSync(VECTORS, 'utf8'));
  const controls = list.filter((v) => v.json?.type === 'replay_control');
  assert.equal(controls.length, 3);
  for (const v of controls) {
    const options = {};
    if (v.json.time_s !== undefined) options.timeS = v.json.time_s;
    if (v.json.speed !== undefined) options.speed = v.json.speed;
    assert.deepEqual(JSON.parse(encodeReplayControl(v.json.action, options)), v.json, v.name);
  }
});

test('the four message types of the contract decode', () => {
  for (const m of [hello, scene, contact(), stats]) {
    const decoded = decodeMessage(JSON.stringify(m));
    assert.equal(decoded.kind, 'message');
    assert.deepEqual(decoded.message, m);
  }
  const cone = { ...scene, tool: { shape: 'cone', half_angle_rad: 0.785, radius_m: 0.01 } };
  assert.equal(decodeMessage(JSON.stringify(cone)).message.tool.shape, 'cone');
});

test('an unknown type is reported as unknown, not as an error', () => {
  assert.deepEqual(decodeMessage('{"type":"telemetry","x":1}'), { kind: 'unknown', type: 'telemetry' });
});

test('malformed messages are refused with the field and the value', () => {
  const cases = [
    ['not json', /frame: not JSON/],
    ['[1,2]', /message: expected an object/],
    ['{"seq":1}', /message.type: expected a string/],
    [JSON.stringify({ ...hello, protocol_version: 2 }), /hello.protocol_version: .*protocol 1.*2/],
    [JSON.stringify(contact({ depth_m: -0.001 })), /contact.depth_m: expected a number ≥ 0, got -0.001/],
    [JSON.stringify(contact({ depth_m: 'deep' })), /contact.depth_m: expected a finite number, got "deep"/],
    [JSON.stringify(contact({ normal: [0, 1] })), /contact.normal: expected an array of 3 numbers/],
    [JSON.stringify(contact({ normal: [0, null, 0] })), /contact.normal\[1\]/],
    [JSON.stringify(contact({ flags: ['melting'] })), /contact.flags\[0\]: unknown flag "melting"/],
    [JSON.stringify(contact({ seq: -1 })), /contact.seq: expected a non-negative integer/],
    [JSON.stringify(contact({ seq: 1.5 })), /contact.seq/],
    [JSON.stringify(contact({ in_contact: 1 })), /contact.in_contact: expected true or false/],
    [
      JSON.stringify(contact({ tip_in_world: { position_m: [0, 0, 0], orientation: [0, 0, 0, 2] } })),
      /contact.tip_in_world.orientation: expected a unit quaternion/,
    ],
    [JSON.stringify({ ...scene, tool: { shape: 'cube', radius_m: 0.01 } }), /scene.tool: tool.shape/],
    [JSON.stringify({ ...scene, material: { youngs_modulus_pa: -5, poisson_ratio: 0.3 } }), /youngs_modulus_pa/],
    [JSON.stringify({ ...scene, material: { youngs_modulus_pa: 5, poisson_ratio: 0.5 } }), /poisson_ratio/],
    [JSON.stringify({ ...scene, render_meshes: [{ name: 'x' }] }), /scene.render_meshes\[0\].url/],
    [JSON.stringify({ ...scene, calibration: { ...scene.calibration, format: 'csv' } }), /scene.calibration.format/],
    [JSON.stringify({ ...stats, period_error_us: { p50: 1 } }), /stats.period_error_us.p99/],
    [JSON.stringify({ ...stats, device: 'on fire' }), /stats.device: unknown device state "on fire"/],
    [JSON.stringify(contact({ buttons: -1 })), /contact.buttons: expected a non-negative integer/],
  ];
  for (const [text, pattern] of cases) {
    assert.throws(
      () => decodeMessage(text),
      (e) => e instanceof ProtocolError && pattern.test(e.message),
      text,
    );
  }
});

test('every device state has words for the trainee, and a stats without one reads as ok', () => {
  const states = [
    'ok',
    'disconnected',
    'not_answering',
    'force_disabled',
    'needs_calibration',
    'overrun',
    'driver_error',
  ];
  assert.deepEqual(Object.keys(DEVICE_STATUS_MESSAGES), states);
  for (const state of states) {
    assert.equal(decodeMessage(JSON.stringify({ ...stats, device: state })).message.device, state);
    assert.ok(DEVICE_STATUS_MESSAGES[state].startsWith('device '), state);
  }
  const older = { ...stats };
  delete older.device;
  assert.equal(decodeMessage(JSON.stringify(older)).message.device, undefined);
});

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

test('a scene without contact_model (older servers and recordings) shows the law and its limits', () => {
  assert.equal(scene.contact_model, undefined);
  const decoded = decodeMessage(JSON.stringify(scene)).message;
  assert.deepEqual(contactModelOf(decoded), {
    label: 'Hertz',
    corrections: [],
    validDepthM: 0.0043,
    validInclinationRad: 0.38,
    limitsSource: null,
    spec: null,
  });
  const cone = { ...scene, model: { name: 'sneddon_cone', valid_depth_m: 0.006, valid_inclination_rad: 0.16 } };
  assert.equal(contactModelOf(decodeMessage(JSON.stringify(cone)).message).label, 'Sneddon cone');
  const other = { ...scene, model: { ...scene.model, name: 'some_future_law' } };
  assert.equal(contactModelOf(decodeMessage(JSON.stringify(other)).message).label, 'some_future_law');
  // A server that writes the absent field as null is read the same way.
  const withNull = { ...scene, contact_model: null };
  assert.equal(contactModelOf(decodeMessage(JSON.stringify(withNull)).message).label, 'Hertz');
});

test('a scene with contact_model shows its label, corrections and the source of its limits', () => {
  const decoded = decodeMessage(JSON.stringify({ ...scene, contact_model: contactModel })).message;
  assert.deepEqual(contactModelOf(decoded), {
    label: 'Hertz + exact sphere + curvature + neo-Hookean fit',
    corrections: ['exact_sphere', 'curvature', 'hyperelastic'],
    validDepthM: 0.0058,
    validInclinationRad: 0.38,
    limitsSource: contactModel.limits_source,
    spec: contactModel.spec,
  });
  // Only the label is needed; absent limits read as "not known".
  const bare = decodeMessage(JSON.stringify({ ...scene, contact_model: { label: 'Hertz' } })).message;
  assert.deepEqual(contactModelOf(bare), {
    label: 'Hertz',
    corrections: [],
    validDepthM: null,
    validInclinationRad: null,
    limitsSource: null,
    spec: null,
  });
});

test('a contact_model that breaks the contract is refused with the field', () => {
  const cases = [
    [{ ...contactModel, label: 3 }, /scene.contact_model.label: expected a string, got 3/],
    [{ ...contactModel, corrections: 'curvature' }, /scene.contact_model.corrections: expected an array of names/],
    [{ ...contactModel, corrections: ['curvature', 7] }, /scene.contact_model.corrections\[1\]: expected a string/],
    [{ ...contactModel, valid_depth_m: -0.001 }, /scene.contact_model.valid_depth_m: expected a number ≥ 0/],
    [{ ...contactModel, valid_inclination_rad: 'wide' }, /scene.contact_model.valid_inclination_rad/],
    [{ ...contactModel, limits_source: 42 }, /scene.contact_model.limits_source: expected a string/],
    [{ ...contactModel, spec: [1] }, /scene.contact_model.spec: expected an object/],
    ['Hertz', /scene.contact_model: expected an object/],
  ];
  for (const [c, pattern] of cases) {
    assert.throws(
      () => decodeMessage(JSON.stringify({ ...scene, contact_model: c })),
      (e) => e instanceof ProtocolError && pattern.test(e.message),
      JSON.stringify(c),
    );
  }
});

// ----- roles, tokens, refusals -----

const TOKEN = '0123456789abcdef0123456789abcdef';

test('hello says the role and the mode; one from before roles reads through its old role', () => {
  for (const role of ['instructor', 'observer']) {
    for (const mode of ['live', 'replay']) {
      const m = decodeMessage(JSON.stringify({ ...hello, role, mode })).message;
      assert.deepEqual(accessOf(m), { role, mode });
    }
  }
  assert.deepEqual(accessOf(decodeMessage(JSON.stringify(legacyHello)).message), { role: 'observer', mode: 'live' });
  const legacyReplay = decodeMessage(JSON.stringify({ ...legacyHello, role: 'replay' })).message;
  assert.deepEqual(accessOf(legacyReplay), { role: 'instructor', mode: 'replay' }, 'anyone moved an old replay');
  const noMode = { ...hello };
  delete noMode.mode;
  assert.deepEqual(accessOf(decodeMessage(JSON.stringify(noMode)).message), { role: 'instructor', mode: 'live' });
});

test('a hello with an unknown role or mode is refused with the field', () => {
  const cases = [
    [{ ...hello, role: 'admin' }, /hello.role: unknown role "admin" \(known: instructor, observer\)/],
    [{ ...hello, role: 'replay' }, /hello.role: unknown role "replay"/], // the old names go without `mode` only
    [{ ...hello, mode: 'rewind' }, /hello.mode: unknown mode "rewind" \(known: live, replay\)/],
    [{ ...hello, mode: 1 }, /hello.mode: unknown mode 1/],
    [{ ...legacyHello, role: 'admin' }, /hello.role: unknown role "admin"/],
    [{ ...hello, role: 7 }, /hello.role: expected a string, got 7/],
  ];
  for (const [m, pattern] of cases) {
    assert.throws(
      () => decodeMessage(JSON.stringify(m)),
      (e) => e instanceof ProtocolError && pattern.test(e.message),
      JSON.stringify(m),
    );
  }
});

test('a refused request decodes with its reason; one without a reason or request is refused', () => {
  const refused = { type: 'refused', request: 'replay_control', reason: 'observers cannot control the replay' };
  assert.deepEqual(decodeMessage(JSON.stringify(refused)), { kind: 'message', message: refused });
  assert.throws(
    () => decodeMessage(JSON.stringify({ ...refused, reason: undefined })),
    /refused.reason: expected a string/,
  );
  assert.throws(
    () => decodeMessage(JSON.stringify({ ...refused, request: 3 })),
    /refused.request: expected a string, got 3/,
  );
});

test('the auth message carries the token as the server reads it; no token, no message', () => {
  assert.deepEqual(JSON.parse(encodeAuth(TOKEN)), { type: 'auth', token: TOKEN });
  for (const bad of ['', null, undefined, 42])
    assert.throws(() => encodeAuth(bad), /auth.token: expected a non-empty token/);
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

test('an input-only device says the force is not felt and names its unplug as the input device', () => {
  const spacemouse = decodeMessage(JSON.stringify({ ...hello, force_feedback: false })).message;
  assert.equal(forceFeedbackOf(spacemouse), false);
  assert.equal(forceFeedbackOf(decodeMessage(JSON.stringify({ ...hello, force_feedback: true })).message), true);
  // A server before the field drove force-rendering devices only.
  const older = { ...hello };
  delete older.force_feedback;
  assert.equal(forceFeedbackOf(decodeMessage(JSON.stringify(older)).message), true);
  assert.throws(
    () => decodeMessage(JSON.stringify({ ...hello, force_feedback: 'no' })),
    (e) => e instanceof ProtocolError && e.field === 'hello.force_feedback',
  );
  assert.throws(
    () => decodeMessage(JSON.stringify({ ...scene, device: { ...scene.device, force_feedback: 0 } })),
    (e) => e instanceof ProtocolError && e.field === 'scene.device.force_feedback',
  );
  assert.equal(deviceStatusMessage('disconnected', false), 'input device disconnected');
  assert.equal(deviceStatusMessage('disconnected', true), 'device disconnected');
  assert.equal(deviceStatusMessage('ok', false), 'input device ok');
  assert.equal(deviceStatusMessage('not_answering', false), DEVICE_STATUS_MESSAGES.not_answering);
});

test('a mark is encoded trimmed, with its point, and refused empty, overlong or with a bad point', () => {
  assert.deepEqual(JSON.parse(encodeMark('  look here ', [0.01, 0.02, 0.03])), {
    type: 'add_mark',
    note: 'look here',
    point_m: [0.01, 0.02, 0.03],
  });
  assert.deepEqual(JSON.parse(encodeMark('moment only')), { type: 'add_mark', note: 'moment only' });
  for (const [note, point, field] of [
    ['   ', null, 'add_mark.note'],
    ['x'.repeat(281), null, 'add_mark.note'],
    ['ok', [0, Number.NaN, 0], 'add_mark.point_m'],
  ]) {
    assert.throws(
      () => encodeMark(note, point),
      (e) => e instanceof ProtocolError && e.field.startsWith(field),
    );
  }
});
