// Message decoding against the shared vectors and the wire contract, and the encoding of the
// messages a viewer sends.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { fileURLToPath } from 'node:url';

import {
  accessOf,
  contactModelOf,
  decodeMessage,
  DEVICE_STATUS_MESSAGES,
  deviceStatusMessage,
  encodeAuth,
  encodeMark,
  encodeReplayControl,
  forceFeedbackOf,
  marksAcceptedOf,
  ProtocolError,
  encodeExerciseControl,
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
      assert.ok(
        ![
          'hello',
          'scene',
          'contact',
          'stats',
          'replay',
          'refused',
          'exercise',
          'inclusions',
          'dashboard',
          'action_result',
        ].includes(type),
        `${v.name}`,
      );
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
  for (const type of [
    'hello',
    'scene',
    'contact',
    'stats',
    'replay',
    'refused',
    'exercise',
    'inclusions',
    'dashboard',
    'action_result',
  ])
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

test('exercise controls are encoded exactly as the Rust side reads them; others are refused here', () => {
  const list = JSON.parse(readFileSync(VECTORS, 'utf8'));
  const control = list.find((v) => v.json?.type === 'exercise_control');
  assert.ok(control, 'the vectors hold an exercise control');
  assert.deepEqual(JSON.parse(encodeExerciseControl(control.json.action)), control.json);
  assert.throws(() => encodeExerciseControl('skip'), ProtocolError);
  // An ended exercise carries its result; a running one none, and the time left.
  const [running, ended] = ['exercise_running', 'exercise_ended'].map(
    (name) => decodeMessage(JSON.stringify(list.find((v) => v.name === name).json)).message,
  );
  assert.equal(running.result, null);
  assert.ok(running.remaining_s > 0);
  assert.equal(ended.result.passed, true);
  assert.equal(ended.exercise.task.kind, 'press');
});

test('an inclusions message decodes, and one with a bad radius or centre is refused naming the field', () => {
  const list = JSON.parse(readFileSync(VECTORS, 'utf8'));
  const v = list.find((x) => x.name === 'inclusions_revealed');
  assert.ok(v, 'the vectors hold an inclusions message');
  const m = decodeMessage(JSON.stringify(v.json)).message;
  assert.equal(m.revealed, true);
  assert.equal(m.inclusions[0].radius_m, 0.005);
  const bad = structuredClone(v.json);
  bad.inclusions[0].radius_m = -1;
  assert.throws(() => decodeMessage(JSON.stringify(bad)), /inclusions\.inclusions\[0\]\.radius_m/);
  const short = structuredClone(v.json);
  short.inclusions[0].centre_m = [0, 0];
  assert.throws(() => decodeMessage(JSON.stringify(short)), /inclusions\.inclusions\[0\]\.centre_m/);
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
    [
      JSON.stringify(
        contact({
          guide: { force_n: [0, 0, 0], target_m: [0, 0, 0], progress: 1.5, gain: 1, effective_gain: 1, engaged: true },
        }),
      ),
      /contact.guide.progress: expected a value in \[0, 1\]/,
    ],
    [JSON.stringify(contact({ guide: { force_n: [0, 0] } })), /contact.guide.force_n/],
    [
      JSON.stringify({
        ...scene,
        guide: { source: 'e.mcap', path_m: [[0, 0, 0]], length_m: 0.01, max_force_n: 1.5, gain: { mode: 'fixed' } },
      }),
      /scene.guide.path_m: expected an array of at least 2 points/,
    ],
    [
      JSON.stringify({
        ...scene,
        guide: {
          source: 'e.mcap',
          path_m: [
            [0, 0, 0],
            [0.01, 0, 0],
          ],
          length_m: 0.01,
          max_force_n: 1.5,
          gain: { mode: 'always' },
        },
      }),
      /scene.guide.gain.mode: unknown mode "always"/,
    ],
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
    'force_latched',
    'failed',
    'needs_calibration_reset',
    'calibration_updating',
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

test('marks are offered where the server takes them: not through a hub unless its hello says so', () => {
  const live = decodeMessage(JSON.stringify(hello)).message;
  assert.equal(marksAcceptedOf(live, false), true, 'a station or a quick start takes marks');
  assert.equal(marksAcceptedOf(live, true), false, 'a hub that does not say records none');
  assert.equal(
    marksAcceptedOf(decodeMessage(JSON.stringify({ ...hello, accepts_marks: false })).message, false),
    false,
  );
  assert.equal(marksAcceptedOf(decodeMessage(JSON.stringify({ ...hello, accepts_marks: true })).message, true), true);
  assert.throws(
    () => decodeMessage(JSON.stringify({ ...hello, accepts_marks: 'yes' })),
    (e) => e instanceof ProtocolError && e.field === 'hello.accepts_marks',
  );
});
